"""The pinhole camera of a bundle (``PinholeCamera`` of ``core/src/camera/pinhole.rs``) and
its rays, vectorised."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any, Dict, Optional, Tuple

import numpy as np

from ._validate import pinhole

F32 = np.float32

__all__ = ["Camera", "ndc_rays"]


@dataclass(frozen=True)
class Camera:
    """Pinhole camera: ``width``×``height`` pixels, focal lengths and principal point in pixels
    (float32, as nerf-render stores them), ``pixel_center`` "integer" or "half_pixel", and
    optional OpenCV ``distortion`` {k1, k2, p1, p2}."""

    width: int
    height: int
    fx: np.float32
    fy: np.float32
    cx: np.float32
    cy: np.float32
    pixel_center: str = "integer"
    distortion: Optional[Dict[str, float]] = None

    @classmethod
    def from_scene(cls, cam: Dict[str, Any]) -> "Camera":
        """scene.json's camera; bundles with ``focal`` alone get fx = fy = focal, the principal
        point at the centre and integer pixel centres."""
        c = pinhole(cam)
        return cls(int(c["width"]), int(c["height"]), F32(c["fx"]), F32(c["fy"]), F32(c["cx"]), F32(c["cy"]),
                   c["pixel_center"], c["distortion"])

    def resized(self, width: int, height: Optional[int] = None) -> "Camera":
        """The same camera at ``width``×``height``: focal lengths and principal point scale with
        each side (float32, as ``PinholeCamera::resized``). Without ``height`` it keeps the
        aspect, rounded as nerf-render's ``--width`` does: (w·H + W/2) // W."""
        if height is None:
            height = (int(width) * self.height + self.width // 2) // self.width
        sx = F32(width) / F32(self.width)
        sy = F32(height) / F32(self.height)
        return replace(self, width=int(width), height=int(height), fx=F32(self.fx * sx), fy=F32(self.fy * sy),
                       cx=F32(self.cx * sx), cy=F32(self.cy * sy))

    def directions(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Camera-space (OpenGL) directions ``(x, −y, −1)`` [N, 3] float32 of the rays through
        pixel columns ``i`` and rows ``j`` (normalised coordinates in float64, undistorted by
        Newton's method when the camera has distortion)."""
        o = 0.5 if self.pixel_center == "half_pixel" else 0.0
        xd = (np.asarray(i, np.float32).astype(np.float64) + o - np.float64(self.cx)) / np.float64(self.fx)
        yd = (np.asarray(j, np.float32).astype(np.float64) + o - np.float64(self.cy)) / np.float64(self.fy)
        x, y = (xd, yd) if self.distortion is None else undistort(xd, yd, self.distortion)
        out = np.empty((len(x), 3), F32)
        out[:, 0] = x.astype(F32)
        out[:, 1] = (-y).astype(F32)
        out[:, 2] = -1.0
        return out

    def rays(self, c2w: np.ndarray, i: np.ndarray, j: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """World rays (origins, directions) [N, 3] float32 through pixels (i, j) for the
        camera-to-world ``c2w`` [4, 4] (directions not normalised)."""
        c2w = np.asarray(c2w, F32)
        cam = self.directions(i, j)
        r = c2w[:3, :3]
        # rotation · v as glam's Mat3 × Vec3: col0·x + col1·y + col2·z.
        d = (r[:, 0][None] * cam[:, 0:1] + r[:, 1][None] * cam[:, 1:2]) + r[:, 2][None] * cam[:, 2:3]
        o = np.broadcast_to(c2w[:3, 3], d.shape).astype(F32)
        return o, d.astype(F32)


def undistort(xd: np.ndarray, yd: np.ndarray, k: Dict[str, float]) -> Tuple[np.ndarray, np.ndarray]:
    """OpenCV radial-tangential distortion undone by Newton's method in float64, as
    ``OpenCvDistortion::undistort``: at most 20 steps, a ray stops once its step is below 1e-12
    or its Jacobian is singular."""
    k1, k2, p1, p2 = (np.float64(np.float32(k[n])) for n in ("k1", "k2", "p1", "p2"))
    x, y = xd.copy(), yd.copy()
    active = np.ones(len(x), bool)
    for _ in range(20):
        r2 = x * x + y * y
        radial = 1 + r2 * (k1 + k2 * r2)
        dr = k1 + 2 * k2 * r2
        drx, dry = dr * 2 * x, dr * 2 * y
        fx = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x) - xd
        fy = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y - yd
        a = radial + x * drx + 2 * p1 * y + 6 * p2 * x
        b = x * dry + 2 * p1 * x + 2 * p2 * y
        c = y * drx + 2 * p1 * x + 2 * p2 * y
        d = radial + y * dry + 6 * p1 * y + 2 * p2 * x
        det = a * d - b * c
        active &= np.abs(det) >= 1e-12
        safe = np.where(active, det, 1.0)
        dx, dy = (d * fx - b * fy) / safe, (a * fy - c * fx) / safe
        x, y = np.where(active, x - dx, x), np.where(active, y - dy, y)
        active &= np.maximum(np.abs(dx), np.abs(dy)) >= 1e-12
        if not active.any():
            break
    return x, y


def ndc_rays(ndc: Dict[str, float], o: np.ndarray, d: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """nerf-pytorch's ndc_rays, term by term, with separate focal lengths (float32)."""
    W, H, fx, fy, near = (F32(ndc[k]) for k in ("width", "height", "fx", "fy", "near"))
    t = -(near + o[:, 2]) / d[:, 2]
    o = o + t[:, None] * d
    ax, ay = F32(-2) * fx / W, F32(-2) * fy / H
    o2 = np.stack([ax * o[:, 0] / o[:, 2], ay * o[:, 1] / o[:, 2], 1 + 2 * near / o[:, 2]], 1)
    d2 = np.stack([ax * (d[:, 0] / d[:, 2] - o[:, 0] / o[:, 2]), ay * (d[:, 1] / d[:, 2] - o[:, 1] / o[:, 2]), -2 * near / o[:, 2]], 1)
    return o2.astype(F32), d2.astype(F32)


def reference_orbit(frames: int) -> list:
    """``Pose::orbit``: ``frames`` poses at azimuths −180 + 360k/frames, elevation −30°, radius 4."""
    out = []
    for k in range(frames):
        theta = np.deg2rad(F32(-180.0) + F32(360.0) * F32(k) / F32(frames))
        phi = np.deg2rad(F32(-30.0))
        trans = np.eye(4, dtype=np.float64)
        trans[2, 3] = 4.0
        cp, sp = np.cos(phi), np.sin(phi)
        rot_phi = np.array([[1, 0, 0, 0], [0, cp, -sp, 0], [0, sp, cp, 0], [0, 0, 0, 1]])
        ct, st = np.cos(theta), np.sin(theta)
        rot_theta = np.array([[ct, 0, -st, 0], [0, 1, 0, 0], [st, 0, ct, 0], [0, 0, 0, 1]])
        swap = np.array([[-1, 0, 0, 0], [0, 0, 1, 0], [0, 1, 0, 0], [0, 0, 0, 1]], np.float64)
        out.append((swap @ rot_theta @ rot_phi @ trans).astype(F32))
    return out
