"""Bad bundles are refused with one BundleError naming the file and the problem: the cases of
runtime/tests/cli.rs (broken_bundles_give_clear_errors, untrusted_bundles_are_refused)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

import nerf_bundle
from nerf_bundle import BundleError
from conftest import MODELS, copy_bundle, edited_bundle

SPHERES = MODELS / "spheres"


def refused(bundle: Path, *needles: str) -> str:
    start = time.perf_counter()
    with pytest.raises(BundleError) as e:
        nerf_bundle.Bundle.open(bundle, threads=1)
    assert time.perf_counter() - start < 20
    text = str(e.value)
    for n in needles:
        assert n in text, f"{text!r} should mention {n!r}"
    return text


def test_broken_bundles_give_clear_errors(tmp_path):
    refused(tmp_path / "nowhere", "nowhere", "no such bundle directory")

    missing = copy_bundle(SPHERES, tmp_path / "missing")
    (missing / "fine.onnx").unlink()
    refused(missing, "fine.onnx", "cannot read")

    truncated = copy_bundle(SPHERES, tmp_path / "truncated")
    data = (truncated / "coarse.onnx").read_bytes()
    (truncated / "coarse.onnx").write_bytes(data[: len(data) // 2])
    refused(truncated, "coarse.onnx", "truncated")

    onnx = pytest.importorskip("onnx")
    renamed = copy_bundle(SPHERES, tmp_path / "renamed")
    model = onnx.load_from_string(data)
    model.graph.output[0].name = "colour"
    (renamed / "coarse.onnx").write_bytes(model.SerializeToString())
    refused(renamed, "coarse.onnx", "colour", "contract")

    no_camera = edited_bundle(tmp_path / "no-camera", lambda j: j.pop("camera"))
    refused(no_camera, "scene.json", "camera")
    bad_near = edited_bundle(tmp_path / "bad-near", lambda j: j["sampling"].__setitem__("near", "two"))
    refused(bad_near, "scene.json", "near")
    far = edited_bundle(tmp_path / "far-before-near", lambda j: j["sampling"].__setitem__("far", 1.0))
    refused(far, "scene.json", "near < far")

    grid = copy_bundle(SPHERES, tmp_path / "grid")
    (grid / "occupancy.bin").write_bytes((grid / "occupancy.bin").read_bytes()[:1000])
    refused(grid, "occupancy.bin", "truncated")

    nan_pose = edited_bundle(tmp_path / "nan-pose", lambda j: j["poses"]["orbit"][0][0].__setitem__(0, float("nan")))
    refused(nan_pose, "scene.json", "poses.orbit[0]", "non-finite")


def test_untrusted_bundles_are_refused(tmp_path):
    def edit(name, f):
        return edited_bundle(tmp_path / name, f)

    def set_path(*keys_value):
        *keys, value = keys_value

        def f(j):
            for k in keys[:-1]:
                j = j[k]
            j[keys[-1]] = value
        return f

    refused(edit("absolute", set_path("networks", "coarse", "/etc/hostname")),
            "scene.json: networks.coarse: '/etc/hostname' is not a plain file name")
    shutil.copy(SPHERES / "fine.onnx", tmp_path / "fine.onnx")
    refused(edit("dotdot", set_path("networks", "fine", "../fine.onnx")),
            "scene.json: networks.fine: '../fine.onnx' is not a plain file name")
    refused(edit("subdir", set_path("networks", "coarse", "nets/coarse.onnx")), "scene.json", "networks.coarse", "not a plain file name")
    refused(edit("grid-path", set_path("occupancy", "file", "../../occupancy.bin")), "scene.json: occupancy.file", "not a plain file name")

    link = copy_bundle(SPHERES, tmp_path / "link")
    (link / "coarse.onnx").unlink()
    os.symlink(tmp_path / "fine.onnx", link / "coarse.onnx")
    refused(link, "scene.json", "networks.coarse", "symbolic link", "outside")
    fifo = copy_bundle(SPHERES, tmp_path / "fifo")
    (fifo / "coarse.onnx").unlink()
    os.mkfifo(fifo / "coarse.onnx")
    refused(fifo, "coarse.onnx", "networks.coarse", "not a regular file")

    def huge(j):
        j["camera"]["width"] = 100_000_000
        j["camera"]["height"] = 100_000_000
    refused(edit("huge-camera", huge), "scene.json: camera: 100000000×100000000 pixels", "16384")
    refused(edit("samples", set_path("sampling", "n_fine", 1_000_000)),
            "scene.json: sampling: n_coarse + n_fine = 1000032 samples per ray", "4096")
    refused(edit("grid-res", set_path("occupancy", "resolution", 100_000)),
            "scene.json: occupancy.resolution: 100000 cells per axis", "512")
    header = copy_bundle(SPHERES, tmp_path / "grid-header")
    grid = bytearray((header / "occupancy.bin").read_bytes())
    grid[8:12] = (2**32 - 1).to_bytes(4, "little")
    (header / "occupancy.bin").write_bytes(bytes(grid))
    refused(header, "occupancy.bin: header resolution: 4294967295 cells per axis", "512")
    refused(edit("poses", lambda j: j["poses"].__setitem__("orbit", [j["poses"]["orbit"][0]] * 10_001)),
            "scene.json: poses.orbit: 10001 poses", "10000")
    refused(edit("pose-name", lambda j: j["poses"]["test"][0].__setitem__("name", "../../escaped")),
            "scene.json: poses.test[0].name", "not a plain file name")
    big = copy_bundle(SPHERES, tmp_path / "big-json")
    with open(big / "scene.json", "r+b") as f:
        f.truncate((64 << 20) + 1)
    refused(big, "scene.json: 67108865 bytes is more than the limit of 67108864")
    refused(edit("march", set_path("march_steps", 100_000)), "scene.json: march_steps: 100000")


def test_cli_reports_bundle_errors(tmp_path):
    out = tmp_path / "out"
    done = subprocess.run([sys.executable, "-m", "nerf_bundle", "render", str(tmp_path / "nowhere"), "--orbit", "--out", str(out)],
                          capture_output=True, text=True)
    assert done.returncode == 1 and done.stderr.startswith("error: ") and "no such bundle directory" in done.stderr
    assert not out.exists()
