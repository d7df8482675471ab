"""The Python API: poses, camera, raw field values against onnxruntime run whole, frames and rays against nerf-render."""
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


def test_render_and_render_rays_match_nerf_render(spheres, nerf_render):
    """Both paths against nerf-render's own frame of the view: they share ``_render_chunk``, so
    comparing them with each other would miss a bug in it."""
    native = nerf_render(MODELS / "spheres", "--split", "test", "--width", "32")
    assert native.shape == (32, 32, 5) and native[..., 4].max() > 0.5, "the view sees the scene"
    pose = spheres.poses("test")[0]
    frame = spheres.render(pose, 32)
    assert frame.rgb.shape == (32, 32, 3) and frame.depth.shape == (32, 32) and frame.acc.shape == (32, 32)
    assert frame.rgb.dtype == np.float32
    cam = spheres.camera_at(32)
    i, j = np.meshgrid(np.arange(32), np.arange(32))
    o, d = cam.rays(pose, i.ravel(), j.ravel())
    # Another chunk: onnxruntime sees other batch sizes (ulp-level differences).
    rays = spheres.render_rays(o, d, chunk=77)
    assert rays.rgb.shape == (32 * 32, 3) and rays.depth.shape == (32 * 32,) and rays.acc.shape == (32 * 32,)
    ray_frame = np.concatenate([rays.rgb, rays.depth[:, None], rays.acc[:, None]], axis=1).reshape(32, 32, 5)
    for what, got in [("render", frame.raw), ("render_rays", ray_frame)]:
        diff = np.abs(got - native).max(axis=(0, 1))
        assert diff.max() <= 1e-4, f"{what}: max |Δ| r g b depth acc against nerf-render {diff}"


def test_field_values_match_one_onnxruntime_session(spheres):
    """``field`` splits points over sessions and pieces: the same values as the graph run whole."""
    import onnxruntime as ort

    rng = np.random.default_rng(3)
    points = rng.uniform(-1.5, 1.5, (3000, 3)).astype(np.float32)
    dirs = rng.normal(size=(3000, 3)).astype(np.float32)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rgb, sigma = spheres.field(points, dirs)
    assert rgb.shape == (3000, 3) and sigma.shape == (3000,)
    session = ort.InferenceSession(spheres.graphs["fine"].path, providers=["CPUExecutionProvider"])
    want_rgb, want_sigma = session.run(["rgb", "sigma"], {"points": points, "viewdirs": dirs})
    np.testing.assert_allclose(rgb, want_rgb, atol=1e-6)
    np.testing.assert_allclose(sigma, want_sigma.reshape(-1), atol=1e-5, rtol=1e-6)
    assert sigma.max() > 1.0, "no point inside the scene: the comparison would be lenient"


def test_frame_images(spheres):
    pytest.importorskip("PIL")
    frame = spheres.render(spheres.poses("test")[0], 16)
    img = frame.to_pil()
    assert img.size == (16, 16)
    assert frame._repr_png_()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bad_options(spheres):
    with pytest.raises(ValueError, match="chunk"):
        spheres.render(spheres.poses("test")[0], 8, chunk=300_000)
    with pytest.raises(ValueError, match="threads"):
        nerf_bundle.Bundle.open(MODELS / "spheres", threads=0)
    with pytest.raises(ValueError, match="width"):
        spheres.render(spheres.poses("test")[0], 100_000_000)


def test_loops_side_by_side_render_the_frame_of_one_loop():
    """threads=3 with the numpy loop marches the chunks dealt out to three loops, each on its
    own session: the same frame as one loop, bit for bit (onnxruntime's output for a point does
    not depend on the other points of its call), with the three loops' stages averaged."""
    one = nerf_bundle.Bundle.open(MODELS / "lego-ngp", threads=1, loop="numpy")
    three = nerf_bundle.Bundle.open(MODELS / "lego-ngp", threads=3, loop="numpy")
    pose = one.poses("test")[0]
    want = one.render(pose, 60, chunk=500)
    got = three.render(pose, 60, chunk=500)
    assert np.array_equal(got.raw, want.raw)
    assert got.acc.max() > 0.5, "the view sees the scene"
    assert (got.stages.loops, want.stages.loops) == (3, 1)
    assert 0 < got.field_seconds < got.seconds
    # Fewer chunks than sessions: one loop per chunk.
    assert three.render(pose, 20, chunk=300).stages.loops == 2
