"""The Python API: poses, camera, raw field values, rays vs frames."""
from __future__ import annotations

import numpy as np
import pytest

import nerf_bundle
from conftest import MODELS


@pytest.fixture(scope="module")
def spheres() -> nerf_bundle.Bundle:
    return nerf_bundle.Bundle.open(MODELS / "spheres", threads=2)


def test_description(spheres):
    assert spheres.field_kind == "mlp"
    assert nerf_bundle.Bundle.open(MODELS / "lego-ngp", threads=1).field_kind == "ngp"
    poses = spheres.poses("test")
    assert len(poses) == 8 and all(p.shape == (4, 4) and p.dtype == np.float32 for p in poses)
    assert len(spheres.poses("orbit")) == 40
    assert spheres.pose_names("test")[0] == "r_0"
    with pytest.raises(ValueError):
        spheres.poses("train")


def test_camera_resize_matches_nerf_render_rounding(spheres):
    cam = spheres.camera
    assert (cam.width, cam.height) == (64, 64)
    small = spheres.camera_at(48)
    assert (small.width, small.height) == (48, 48)
    assert small.fx == np.float32(cam.fx * np.float32(48 / 64))
    lego = nerf_bundle.Bundle.open(MODELS / "lego", threads=1).camera.resized(101, 33)
    assert (lego.width, lego.height) == (101, 33)
    # Height keeps the aspect, rounded: (w·H + W/2) // W.
    wide = nerf_bundle.Camera(300, 200, np.float32(100), np.float32(100), np.float32(150), np.float32(100))
    assert wide.resized(101).height == (101 * 200 + 150) // 300


def test_field_and_render_rays_agree_with_frames(spheres):
    pose = spheres.poses("test")[0]
    frame = spheres.render(pose, 32)
    assert frame.rgb.shape == (32, 32, 3) and frame.depth.shape == (32, 32) and frame.acc.shape == (32, 32)
    assert frame.rgb.dtype == np.float32
    cam = spheres.camera_at(32)
    i, j = np.meshgrid(np.arange(32), np.arange(32))
    o, d = cam.rays(pose, i.ravel(), j.ravel())
    rays = spheres.render_rays(o, d, chunk=77)
    # (ulp-level differences: onnxruntime sees other batch sizes with another chunk)
    np.testing.assert_allclose(rays.rgb.reshape(32, 32, 3), frame.rgb, atol=1e-6)
    np.testing.assert_allclose(rays.acc.reshape(32, 32), frame.acc, atol=1e-6)
    rgb, sigma = spheres.field(np.zeros((5, 3)), np.tile([0, 0, 1.0], (5, 1)))
    assert rgb.shape == (5, 3) and sigma.shape == (5,)


def test_frame_images(spheres):
    pytest.importorskip("PIL")
    frame = spheres.render(spheres.poses("test")[0], 16)
    img = frame.to_pil()
    assert img.size == (16, 16)
    assert frame._repr_png_()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_options(spheres):
    with pytest.raises(ValueError, match="chunk"):
        spheres.render(spheres.poses("test")[0], 8, chunk=100_000)
    with pytest.raises(ValueError, match="threads"):
        nerf_bundle.Bundle.open(MODELS / "spheres", threads=0)
    with pytest.raises(ValueError, match="width"):
        spheres.render(spheres.poses("test")[0], 100_000_000)
