"""Whole frames against nerf-render --npy: max |Δ| ≤ 1e-4 on rgb, depth and acc."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

import nerf_bundle
from conftest import MODELS

TOL = 1e-4


def check(frame: nerf_bundle.Frame, native: np.ndarray) -> None:
    assert frame.raw.shape == native.shape
    diff = np.abs(frame.raw - native).max(axis=(0, 1))
    print(f"max |Δ| r g b depth acc: {diff}")
    assert diff[:3].max() <= TOL and diff[3] <= TOL and diff[4] <= TOL, diff
    assert native[..., 4].max() > 0.5, "the view sees the scene"


@pytest.mark.parametrize("name,width,dense", [
    ("spheres", 64, False),
    ("spheres", 48, True),
    ("lego", 50, False),
    ("lego", 50, True),
    ("lego-ngp", 100, False),
    ("lego-ngp", 40, True),
])
def test_test_pose_matches_nerf_render(nerf_render, name, width, dense):
    args = ["--split", "test", "--width", str(width)] + (["--dense"] if dense else [])
    native = nerf_render(MODELS / name, *args)
    bundle = nerf_bundle.Bundle.open(MODELS / name, skip_empty_space=not dense)
    check(bundle.render(bundle.poses("test")[0], width=width), native)


@pytest.mark.parametrize("width,dense", [(64, False), (40, True)])
def test_distorted_camera_matches_nerf_render(nerf_render, captured, width, dense):
    args = ["--split", "test", "--width", str(width)] + (["--dense"] if dense else [])
    native = nerf_render(captured, *args)
    bundle = nerf_bundle.Bundle.open(captured, skip_empty_space=not dense)
    assert bundle.camera.distortion is not None
    check(bundle.render(bundle.poses("test")[0], width=width), native)


def test_width_and_height_and_small_chunks(nerf_render):
    native = nerf_render(MODELS / "lego", "--split", "test", "--width", "37", "--height", "29")
    bundle = nerf_bundle.Bundle.open(MODELS / "lego", threads=1)
    check(bundle.render(bundle.poses("test")[0], 37, 29, chunk=100), native)


def test_orbit_through_the_cli(nerf_render, tmp_path):
    native = nerf_render(MODELS / "spheres", "--orbit", "--width", "32", name="frame_000")
    done = subprocess.run([sys.executable, "-m", "nerf_bundle", "render", str(MODELS / "spheres"), "--orbit", "--limit", "1",
                           "--width", "32", "--out", str(tmp_path), "--npy"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "frame_000.png").exists()
    ours = np.load(tmp_path / "frame_000.npy")
    assert ours.dtype == np.float32 and ours.shape == (32, 32, 5)
    assert np.abs(ours - native).max() <= TOL


def test_cli_test_split_names_views_as_nerf_render(tmp_path):
    done = subprocess.run([sys.executable, "-m", "nerf_bundle", "render", str(MODELS / "spheres"), "--split", "test", "--limit", "2",
                           "--width", "16", "--out", str(tmp_path), "--npy"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r_0.npy", "r_0.png", "r_1.npy", "r_1.png"]


def test_mlp_without_grid_terminates_early_as_nerf_render(nerf_render, tmp_path):
    """No occupancy.bin: the dense 64 + 128 path, front to back with early termination."""
    from conftest import edited_bundle
    b = edited_bundle(tmp_path / "no-grid", lambda j: j.pop("occupancy"))
    (b / "occupancy.bin").unlink()
    native = nerf_render(b, "--split", "test", "--width", "40")
    bundle = nerf_bundle.Bundle.open(b)
    assert bundle.grid is None
    check(bundle.render(bundle.poses("test")[0], width=40), native)


def test_another_orbit_frame_count_is_the_reference_orbit(nerf_render):
    native = nerf_render(MODELS / "spheres", "--orbit", "--frames", "3", "--width", "32", name="frame_000")
    bundle = nerf_bundle.Bundle.open(MODELS / "spheres")
    poses = bundle.orbit(3)
    assert len(poses) == 3
    check(bundle.render(poses[0], width=32), native)


def test_cli_renders_a_pose_from_a_file_and_refuses_a_bad_one(tmp_path):
    bundle = nerf_bundle.Bundle.open(MODELS / "spheres")
    pose = bundle.poses("test")[1]
    (tmp_path / "pose.json").write_text(json.dumps({"transform_matrix": pose.tolist()}))
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "nerf_bundle", "render", str(MODELS / "spheres"), "--pose", str(tmp_path / "pose.json"),
                           "--width", "16", "--out", str(out), "--npy"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "1/1 pose" in done.stderr
    assert np.array_equal(np.load(out / "pose.npy"), bundle.render(pose, width=16).raw)
    (tmp_path / "bad.json").write_text("[[1, 2], [3, 4]]")
    done = subprocess.run([sys.executable, "-m", "nerf_bundle", "render", str(MODELS / "spheres"), "--pose", str(tmp_path / "bad.json"),
                           "--out", str(out)], capture_output=True, text=True)
    assert done.returncode != 0 and "bad.json" in done.stderr and "4×4" in done.stderr, done.stderr
