"""Render rays of a nerf-rs scene bundle with numpy and onnxruntime only, following the
documented contract, and compare them with nerf-render's exact output (--npy).

usage: render_rays.py <bundle-dir> --npy <frame.npy> (--test-pose K | --orbit-pose K)
                      [--rays 64] [--seed 0] [--dense] [--tolerance 1e-4]

The renderer below is the whole recipe a consumer needs (scene.json says the same):
  rays      (xd, yd) = ((i + o - cx)/fx, (j + o - cy)/fy), o = 0.5 for "half_pixel" centres, else 0;
            (x, y) = undistort(xd, yd) (OpenCV k1 k2 p1 p2, Newton) when the camera has distortion;
            d = c2w[:3,:3] @ (x, -y, -1) (not normalised), origin c2w[:3,3]. A bundle with `focal`
            alone: fx = fy = focal, (cx, cy) = (W/2, H/2), integer centres (no +0.5).
  ndc       when sampling has "ndc" {width, height, fx, fy, near} (forward-facing captures), the
            rays are warped as nerf-pytorch's ndc_rays: t = -(near + o_z)/d_z, o += t·d, then
            o' = (-2fx/W·o_x/o_z, -2fy/H·o_y/o_z, 1 + 2near/o_z),
            d' = (-2fx/W·(d_x/d_z - o_x/o_z), -2fy/H·(d_y/d_z - o_y/o_z), -2near/o_z);
            everything below uses (o', d'), except viewdirs, which stay the world d/|d|.
  coarse    t_k = near·(1 - k/(n-1)) + far·k/(n-1)  (test time: no jitter; lindisp in 1/t)
  networks  points o + t·d and viewdirs d/|d| → rgb [N,3], sigma [N,1]
  weights   delta = (t_{k+1} - t_k)·|d| (last 1e10·|d|), alpha = 1 - exp(-sigma·delta),
            w = alpha · exclusive cumprod(1 - alpha + 1e-10)
  fine      inverse CDF of w[1:-1] + 1e-5 over the coarse midpoints at u = linspace(0, 1, n_fine)
            (right-side search), merged and sorted with the coarse t, then the fine network
  pixel     rgb = Σ w·c (+ 1 - Σ w on a white background), depth = Σ w·t, acc = Σ w
With occupancy.bin (nerf-render's default; --dense turns it off) rays are marched instead:
  march     march_steps (scene.json, default 256) equal intervals over [near, far], a sample at
            each middle, only samples in occupied cells evaluated (fine network), delta =
            interval·|d|, front to back in segments of 16 per ray, a ray stops after the segment
            where its transmittance falls below 1e-4.
scene.json names the graphs by role: "graphs" {"field": ...} (one graph for every sample) or
{"coarse": ..., "fine": ...}; bundles of format nerf-rs-scene-1 name them under "networks"
(a hash-grid field's as "networks.coarse").
A bounded field (scene.json "bounded": true, e.g. the hash grid) is always marched: with --dense
through one occupied cell covering the grid's cube (the field is only defined there).
The .npy written by `nerf-render --npy` is float32 [H, W, 5]: r, g, b, depth, acc.
"""
import argparse
import json
import os
import sys

import numpy as np
import onnxruntime as ort

F32 = np.float32

# A bundle comes from someone else: the limits of core/src/io/limits.rs (a test checks they agree).
MAX_IMAGE_SIDE = 16_384
MAX_FRAME_PIXELS = 16_777_216
MAX_FRAMES = 10_000
MAX_SAMPLES_PER_RAY = 4_096
MAX_GRID_RESOLUTION = 512
MAX_JSON_BYTES = 67_108_864
MAX_GRAPH_BYTES = 2_147_483_648


class BundleError(Exception):
    """A bundle file breaks the contract or a limit; the message names the file and the field."""


def bounded_file(path, max_bytes):
    """A regular file of at most max_bytes (checked before reading)."""
    if not os.path.isfile(path):
        raise BundleError(f"{path}: missing or not a regular file")
    size = os.path.getsize(path)
    if size > max_bytes:
        raise BundleError(f"{path}: {size} bytes is more than the limit of {max_bytes} for this file")
    return path


def bundle_file(path, name, field):
    """path/name for a file name read from scene.json: a plain name inside the bundle (not
    absolute, no "..", no separator); a symbolic link must resolve inside the bundle."""
    where = os.path.join(path, "scene.json")
    if not isinstance(name, str) or name in ("", ".", "..") or any(c in name for c in "/\\\0"):
        raise BundleError(f'{where}: {field}: {name!r} is not a plain file name inside the directory (no paths, no "..")')
    full = os.path.join(path, name)
    root, real = os.path.realpath(path), os.path.realpath(full)
    if os.path.commonpath([root, real]) != root:
        raise BundleError(f"{where}: {field}: {name!r} is a symbolic link to {real}, outside {path}")
    return full


def check_scene(scene, where):
    """The limits nerf-render applies (SceneDescription::check), before anything is allocated."""
    cam, s = pinhole(scene["camera"]), scene["sampling"]
    w, h = cam["width"], cam["height"]
    if not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE and w * h <= MAX_FRAME_PIXELS):
        raise BundleError(f"{where}: camera: {w}×{h} pixels is outside the limits ({MAX_IMAGE_SIDE} per side, {MAX_FRAME_PIXELS} per frame)")
    for key in ("fx", "fy"):
        if not (np.isfinite(cam[key]) and cam[key] > 0):
            raise BundleError(f"{where}: camera.{key}: {cam[key]} is not a positive finite focal length")
    for key in ("cx", "cy"):
        if not np.isfinite(cam[key]):
            raise BundleError(f"{where}: camera.{key}: {cam[key]} is not a finite principal point")
    if cam["distortion"] is not None and not all(np.isfinite(cam["distortion"][k]) for k in ("k1", "k2", "p1", "p2")):
        raise BundleError(f"{where}: camera.distortion: {cam['distortion']} has a non-finite coefficient")
    if s.get("ndc") is not None:
        ndc = s["ndc"]
        if not (0 <= s["near"] < s["far"] <= 1):
            raise BundleError(f"{where}: sampling: NDC rays need 0 <= near < far <= 1, got near {s['near']} far {s['far']}")
        if not all(np.isfinite(ndc[k]) and ndc[k] > 0 for k in ("width", "height", "fx", "fy", "near")):
            raise BundleError(f"{where}: sampling.ndc: {ndc} needs positive finite width, height, fx, fy and near")
    elif not (np.isfinite(s["near"]) and np.isfinite(s["far"]) and 0 < s["near"] < s["far"]):
        raise BundleError(f"{where}: sampling: need finite 0 < near < far, got near {s['near']} far {s['far']}")
    if not (1 <= s["n_coarse"] and 0 <= s["n_fine"] and s["n_coarse"] + s["n_fine"] <= MAX_SAMPLES_PER_RAY):
        raise BundleError(f"{where}: sampling: n_coarse + n_fine = {s['n_coarse'] + s['n_fine']} samples per ray is outside 1..{MAX_SAMPLES_PER_RAY}")
    for key in ("test", "orbit"):
        if len(scene["poses"][key]) > MAX_FRAMES:
            raise BundleError(f"{where}: poses.{key}: {len(scene['poses'][key])} poses is more than the limit of {MAX_FRAMES}")
    if not 1 <= scene.get("march_steps", 256) <= MAX_SAMPLES_PER_RAY:
        raise BundleError(f"{where}: march_steps: {scene['march_steps']} is outside 1..{MAX_SAMPLES_PER_RAY}")
    if is_bounded(scene) and not scene.get("occupancy"):
        raise BundleError(f"{where}: occupancy: a bounded field is defined inside its box only and marched through its occupancy grid: the bundle needs one")
    occ = scene.get("occupancy")
    if occ and not 1 <= occ["resolution"] <= MAX_GRID_RESOLUTION:
        raise BundleError(f"{where}: occupancy.resolution: {occ['resolution']} cells per axis is outside 1..{MAX_GRID_RESOLUTION}")


def is_bounded(scene):
    """A field defined inside its grid's box only: "bounded", or a version-1 hash-grid bundle."""
    return scene.get("bounded", False) or (scene.get("format") == "nerf-rs-scene-1" and scene.get("field", "mlp") == "ngp")


def graph_files(scene):
    """{role: (scene.json key, file)}: "graphs" by role, or nerf-rs-scene-1's "networks"."""
    if scene.get("graphs"):
        return {role: (f"graphs.{role}", name) for role, name in scene["graphs"].items()}
    nets = scene["networks"]
    first = "field" if is_bounded(scene) else "coarse"
    files = {first: ("networks.coarse", nets["coarse"])}
    if nets.get("fine"):
        files["fine"] = ("networks.fine", nets["fine"])
    return files


def read_grid(path):
    """occupancy.bin: the header (resolution checked against the limit) before the cells."""
    with open(path, "rb") as f:
        header = f.read(20)
        if len(header) < 20 or header[:8] != b"NERFOCC1":
            raise BundleError(f"{path}: not an occupancy grid (missing NERFOCC1 header)")
        res, = np.frombuffer(header[8:12], "<u4")
        bound, threshold = np.frombuffer(header[12:20], "<f4")
        if not 1 <= res <= MAX_GRID_RESOLUTION:
            raise BundleError(f"{path}: header resolution: {res} cells per axis is outside 1..{MAX_GRID_RESOLUTION}")
        want = 20 + 4 * int(res) ** 3
        if os.path.getsize(path) != want:
            raise BundleError(f"{path}: {os.path.getsize(path)} bytes, expected {want} for a {res}³ grid (truncated?)")
        density = np.frombuffer(f.read(want - 20), "<f4").reshape(res, res, res)
    return density, bound, threshold


class Bundle:
    def __init__(self, path, dense=False):
        where = bounded_file(os.path.join(path, "scene.json"), MAX_JSON_BYTES)
        try:
            with open(where) as f:
                self.scene = json.load(f)
            check_scene(self.scene, where)
        except (KeyError, TypeError, ValueError) as e:
            raise BundleError(f"{where}: missing or malformed field: {e!r}") from e
        opts = ort.SessionOptions()

        def session(key, name):
            graph = bounded_file(bundle_file(path, name, key), MAX_GRAPH_BYTES)
            return ort.InferenceSession(graph, opts, providers=["CPUExecutionProvider"])

        graphs = graph_files(self.scene)
        # One graph for the whole field serves both stages.
        coarse = graphs.get("field") or graphs["coarse"]
        self.coarse = session(*coarse)
        self.fine = session(*graphs["fine"]) if "fine" in graphs else None
        self.occupied = None
        occ = self.scene.get("occupancy")
        if occ and not dense:
            grid = bundle_file(path, occ["file"], "occupancy.file")
            density, bound, threshold = read_grid(bounded_file(grid, MAX_GRAPH_BYTES))
            self.occupied, self.bound = density > threshold, F32(bound)
        elif is_bounded(self.scene):
            self.occupied, self.bound = np.ones((1, 1, 1), bool), F32(occ["bound"])

    def is_occupied(self, points):
        """Cell (i, j, k) of point p: floor((p + b) / 2b · R) per axis; outside the cube is empty."""
        if self.occupied is None:
            return np.ones(len(points), bool)
        res = self.occupied.shape[0]
        u = (points + self.bound) / (F32(2) * self.bound) * F32(res)
        inside = np.all((u >= 0) & (u < res), axis=1)
        ijk = np.where(inside[:, None], u, 0).astype(np.int64)
        return inside & self.occupied[ijk[:, 0], ijk[:, 1], ijk[:, 2]]

    def field(self, session, points, viewdirs):
        rgb = np.zeros((len(points), 3), F32)
        sigma = np.zeros(len(points), F32)
        keep = self.is_occupied(points)
        if keep.any():
            out_rgb, out_sigma = session.run(["rgb", "sigma"], {"points": points[keep], "viewdirs": viewdirs[keep]})
            rgb[keep], sigma[keep] = out_rgb, out_sigma[:, 0]
        return rgb, sigma


def pinhole(cam):
    """scene.json's camera as the full model; bundles written before it have `focal` alone
    (fx = fy = focal, principal point at the centre, integer pixel centres)."""
    fx = cam.get("fx", cam.get("focal", float("nan")))
    return {"width": cam["width"], "height": cam["height"], "fx": fx, "fy": cam.get("fy", fx),
            "cx": cam.get("cx", 0.5 * cam["width"]), "cy": cam.get("cy", 0.5 * cam["height"]),
            "pixel_center": cam.get("pixel_center", "integer"), "distortion": cam.get("distortion")}


def undistort(xd, yd, k):
    """OpenCV radial-tangential distortion undone by Newton's method in float64, as
    OpenCvDistortion::undistort: from (xd, yd), at most 20 steps, a ray stops once its step is
    below 1e-12 or its Jacobian is singular."""
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


def camera_rays(scene, c2w, width, height, pixels):
    """PinholeCamera at width×height (focal lengths and principal point scale with each side):
    ((i + o − cx)/fx, (j + o − cy)/fy) undistorted, then (x, −y, −1) rotated by the pose."""
    cam = pinhole(scene["camera"])
    sx, sy = np.float32(width / cam["width"]), np.float32(height / cam["height"])
    fx, fy = np.float32(cam["fx"]) * sx, np.float32(cam["fy"]) * sy
    cx, cy = np.float32(cam["cx"]) * sx, np.float32(cam["cy"]) * sy
    o = 0.5 if cam["pixel_center"] == "half_pixel" else 0.0
    xd = (pixels[:, 0].astype(np.float64) + o - np.float64(cx)) / np.float64(fx)
    yd = (pixels[:, 1].astype(np.float64) + o - np.float64(cy)) / np.float64(fy)
    x, y = (xd, yd) if cam["distortion"] is None else undistort(xd, yd, cam["distortion"])
    dirs = np.stack([x.astype(F32), (-y).astype(F32), -np.ones(len(x), F32)], axis=1)
    d = (dirs @ c2w[:3, :3].T).astype(F32)
    o = np.broadcast_to(c2w[:3, 3], d.shape).astype(F32)
    return o, d


def ndc_rays(ndc, o, d):
    """nerf-pytorch's ndc_rays, term by term, with separate focal lengths."""
    W, H, fx, fy, near = (F32(ndc[k]) for k in ("width", "height", "fx", "fy", "near"))
    t = -(near + o[:, 2]) / d[:, 2]
    o = o + t[:, None] * d
    ax, ay = F32(-2) * fx / W, F32(-2) * fy / H
    o2 = np.stack([ax * o[:, 0] / o[:, 2], ay * o[:, 1] / o[:, 2], 1 + 2 * near / o[:, 2]], 1)
    d2 = np.stack([ax * (d[:, 0] / d[:, 2] - o[:, 0] / o[:, 2]), ay * (d[:, 1] / d[:, 2] - o[:, 1] / o[:, 2]), -2 * near / o[:, 2]], 1)
    return o2.astype(F32), d2.astype(F32)


def weights_of(t, sigma, dnorm):
    delta = np.concatenate([t[:, 1:] - t[:, :-1], np.full((len(t), 1), 1e10, F32)], axis=1) * dnorm[:, None]
    alpha = F32(1) - np.exp(-np.maximum(sigma, 0) * delta)
    trans = np.cumprod(F32(1) - alpha + F32(1e-10), axis=1)
    trans = np.concatenate([np.ones((len(t), 1), F32), trans[:, :-1]], axis=1)
    return alpha * trans


def sample_pdf(bins, weights, n):
    w = weights + F32(1e-5)
    cdf = np.cumsum(w / w.sum(axis=1, keepdims=True), axis=1)
    cdf = np.concatenate([np.zeros((len(w), 1), F32), cdf], axis=1)
    u = np.linspace(0, 1, n, dtype=F32)
    out = np.empty((len(w), n), F32)
    for r in range(len(w)):
        above = np.searchsorted(cdf[r], u, side="right")
        below = np.maximum(above - 1, 0)
        above = np.minimum(above, cdf.shape[1] - 1)
        c0, c1 = cdf[r, below], cdf[r, above]
        denom = np.where(c1 - c0 < 1e-5, F32(1), c1 - c0)
        out[r] = bins[r, below] + (u - c0) / denom * (bins[r, above] - bins[r, below])
    return out


def march(bundle, o, d, view, segment=16, min_transmittance=1e-4):
    s = bundle.scene["sampling"]
    steps = bundle.scene.get("march_steps", 256)
    near, far = F32(s["near"]), F32(s["far"])
    interval = (far - near) / F32(steps)
    t = near + (np.arange(steps, dtype=F32) + F32(0.5)) * interval
    session = bundle.fine or bundle.coarse
    out_rgb, out_depth, out_acc = np.zeros((len(o), 3), F32), np.zeros(len(o), F32), np.zeros(len(o), F32)
    for r in range(len(o)):
        pts = (o[r] + t[:, None] * d[r]).astype(F32)
        keep = bundle.is_occupied(pts)
        ts, pts = t[keep], pts[keep]
        if len(ts) == 0:
            continue
        norm = np.linalg.norm(d[r]).astype(F32)
        viewdirs = np.repeat((view[r] / np.linalg.norm(view[r]))[None], len(ts), 0).astype(F32)
        rgb, sigma = session.run(["rgb", "sigma"], {"points": pts, "viewdirs": viewdirs})
        alpha = F32(1) - np.exp(-np.maximum(sigma[:, 0], 0) * (interval * norm))
        trans = F32(1)
        for start in range(0, len(ts), segment):
            for k in range(start, min(start + segment, len(ts))):
                w = alpha[k] * trans
                out_rgb[r] += w * rgb[k]
                out_depth[r] += w * ts[k]
                out_acc[r] += w
                trans *= F32(1) - alpha[k] + F32(1e-10)
            if trans < min_transmittance:
                break
    if bundle.scene["white_background"]:
        out_rgb += (1 - out_acc)[:, None]
    return out_rgb, out_depth, out_acc


def render(bundle, o, d, view):
    scene = bundle.scene
    s = scene["sampling"]
    near, far, n_coarse, n_fine = F32(s["near"]), F32(s["far"]), s["n_coarse"], s["n_fine"]
    k = np.arange(n_coarse, dtype=F32) / F32(max(n_coarse - 1, 1))
    t = 1 / (1 / near * (1 - k) + 1 / far * k) if s["lindisp"] else near * (1 - k) + far * k
    t = np.broadcast_to(t.astype(F32), (len(o), n_coarse))
    dnorm = np.linalg.norm(d, axis=1).astype(F32)
    viewdirs = view / np.linalg.norm(view, axis=1)[:, None]

    def stage(session, t):
        pts = (o[:, None, :] + t[..., None] * d[:, None, :]).reshape(-1, 3).astype(F32)
        dirs = np.repeat(viewdirs, t.shape[1], axis=0)
        rgb, sigma = bundle.field(session, pts, dirs)
        w = weights_of(t, sigma.reshape(t.shape), dnorm)
        return w, rgb.reshape(*t.shape, 3)

    w, rgb = stage(bundle.coarse, t)
    if n_fine > 0:
        mids = F32(0.5) * (t[:, 1:] + t[:, :-1])
        extra = sample_pdf(mids, w[:, 1:-1], n_fine)
        t = np.sort(np.concatenate([t, extra], axis=1), axis=1)
        w, rgb = stage(bundle.fine, t)
    acc = w.sum(axis=1)
    colour = (w[..., None] * rgb).sum(axis=1)
    if scene["white_background"]:
        colour = colour + (1 - acc)[:, None]
    return colour, (w * t).sum(axis=1), acc


def main():
    p = argparse.ArgumentParser()
    p.add_argument("bundle")
    p.add_argument("--npy", required=True)
    p.add_argument("--test-pose", type=int)
    p.add_argument("--orbit-pose", type=int)
    p.add_argument("--rays", type=int, default=64)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--dense", action="store_true", help="ignore occupancy.bin (as nerf-render --dense)")
    p.add_argument("--tolerance", type=float, default=1e-4)
    a = p.parse_args()
    try:
        bundle = Bundle(a.bundle, a.dense)
    except BundleError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    poses = bundle.scene["poses"]
    if a.test_pose is not None:
        c2w = np.array(poses["test"][a.test_pose]["transform_matrix"], F32)
    else:
        c2w = np.array(poses["orbit"][a.orbit_pose], F32)
    expected = np.load(a.npy)
    height, width = expected.shape[:2]
    rng = np.random.default_rng(a.seed)
    # Half the rays where nerf-render saw the scene (acc > 0.5), half anywhere.
    hit = np.argwhere(expected[..., 4] > 0.5)
    picks = [hit[rng.integers(len(hit), size=min(len(hit), a.rays // 2))]] if len(hit) else []
    picks.append(np.stack([rng.integers(height, size=a.rays - sum(map(len, picks))), rng.integers(width, size=a.rays - sum(map(len, picks)))], 1))
    rows_cols = np.concatenate(picks)
    pixels = rows_cols[:, ::-1]  # (column i, row j)
    o, d = camera_rays(bundle.scene, c2w, width, height, pixels)
    view = d
    if bundle.scene["sampling"].get("ndc") is not None:
        o, d = ndc_rays(bundle.scene["sampling"]["ndc"], o, d)
    rgb, depth, acc = render(bundle, o, d, view) if bundle.occupied is None else march(bundle, o, d, view)
    want = expected[rows_cols[:, 0], rows_cols[:, 1]]
    diff_rgb = np.abs(rgb - want[:, :3]).max()
    diff_acc = np.abs(acc - want[:, 4]).max()
    diff_depth = np.abs(depth - want[:, 3]).max()
    print(f"{len(pixels)} rays ({int((want[:, 4] > 0.5).sum())} on the scene): max |Δrgb| {diff_rgb:.2e}, "
          f"|Δacc| {diff_acc:.2e}, |Δdepth| {diff_depth:.2e} (tolerance {a.tolerance:g})")
    if not (diff_rgb <= a.tolerance and diff_acc <= a.tolerance):
        print("FAIL: the numpy renderer and nerf-render disagree", file=sys.stderr)
        sys.exit(1)
    if (want[:, 4] > 0.5).sum() == 0:
        print("FAIL: no ray hit the scene; the comparison would mean nothing", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
