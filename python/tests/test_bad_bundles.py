"""Bad bundles are refused with one BundleError naming the file and the problem: the cases of
runtime/tests/cli.rs (broken_bundles_give_clear_errors, untrusted_bundles_are_refused)."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
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

    no_camera = edited_bundle(tmp_path / "no-camera", lambda j: j.pop("camera"))
    refused(no_camera, "scene.json", "camera")
    bad_near = edited_bundle(tmp_path / "bad-near", lambda j: j["sampling"].__setitem__("near", "two"))
    refused(bad_near, "scene.json", "near")
    far = edited_bundle(tmp_path / "far-before-near", lambda j: j["sampling"].__setitem__("far", 1.0))
    refused(far, "scene.json", "near < far")

    grid = copy_bundle(SPHERES, tmp_path / "grid")
    (grid / "occupancy.bin").write_bytes((grid / "occupancy.bin").read_bytes()[:1000])
    refused(grid, "occupancy.bin", "truncated")

    # 1e39 is a finite JSON number but infinite as the float32 nerf-render stores.
    inf_pose = edited_bundle(tmp_path / "inf-pose", lambda j: j["poses"]["orbit"][0][0].__setitem__(0, 1e39))
    refused(inf_pose, "scene.json: poses.orbit[0]", "non-finite")
    # NaN is not JSON at all (json.dumps writes it; serde_json refuses it).
    nan_pose = edited_bundle(tmp_path / "nan-pose", lambda j: j["poses"]["test"][0]["transform_matrix"][1].__setitem__(2, float("nan")))
    refused(nan_pose, "scene.json: not valid JSON", "NaN")


@pytest.fixture
def onnx():
    """The onnx package, for the cases that edit a graph; they alone skip without it."""
    return pytest.importorskip("onnx")


def edited_graph(onnx, to: Path, edit) -> Path:
    """models/spheres with ``edit(model)`` applied to coarse.onnx."""
    b = copy_bundle(SPHERES, to)
    model = onnx.load_from_string((b / "coarse.onnx").read_bytes())
    edit(model)
    (b / "coarse.onnx").write_bytes(model.SerializeToString())
    return b


def test_a_graph_breaking_the_contract_is_refused(tmp_path, onnx):
    renamed = edited_graph(onnx, tmp_path / "renamed", lambda m: setattr(m.graph.output[0], "name", "colour"))
    refused(renamed, "coarse.onnx", "colour", "contract")


def test_external_data_and_odd_initializer_types_are_refused_before_onnxruntime(tmp_path, onnx):
    secret = tmp_path / "secret.bin"
    secret.write_bytes(b"\0" * 4096)

    def external(tensor):
        # The weights' bytes moved out: onnxruntime would read them from the named file.
        tensor.ClearField("raw_data")
        tensor.data_location = onnx.TensorProto.EXTERNAL
        for key, value in (("location", "../secret.bin"), ("offset", "0"), ("length", str(4 * int(np.prod(tensor.dims))))):
            entry = tensor.external_data.add()
            entry.key, entry.value = key, value

    b = edited_graph(onnx, tmp_path / "external", lambda m: external(m.graph.initializer[0]))
    name = onnx.load_from_string((b / "coarse.onnx").read_bytes()).graph.initializer[0].name
    refused(b, str(b / "coarse.onnx"), repr(name), "outside the graph file (ONNX external data)")

    def constant_node(m):
        # A Constant node's value: a tensor in an attribute, not an initializer.
        value = onnx.helper.make_tensor("c", onnx.TensorProto.FLOAT, [1], [0.0])
        external(value)
        m.graph.node.insert(0, onnx.helper.make_node("Constant", [], ["unused_constant"], value=value))
    refused(edited_graph(onnx, tmp_path / "constant", constant_node), "coarse.onnx", "attribute tensor 'c'", "external data")

    def double(m):
        t = m.graph.initializer[0]
        t.data_type = onnx.TensorProto.DOUBLE
        t.raw_data = np.zeros(int(np.prod(t.dims)), np.float64).tobytes()
    text = refused(edited_graph(onnx, tmp_path / "double", double), "coarse.onnx", "element type 11", "float32")
    assert text.startswith(str(tmp_path / "double" / "coarse.onnx")), text


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


def test_every_field_is_checked_when_the_bundle_opens(tmp_path):
    """Fields read at render time, wrong types, missing keys and deep nesting: refused by
    Bundle.open with the file and the field named (before: KeyError, ZeroDivisionError,
    ValueError or RecursionError, some only at render time)."""
    def edit(name, f):
        return edited_bundle(tmp_path / name, f)

    cases = [
        ("no-white", lambda j: j.pop("white_background"), "scene.json: white_background: missing"),
        ("white-string", lambda j: j.__setitem__("white_background", "yes"), "scene.json: white_background: expected true or false, got the string 'yes'"),
        ("no-grid-file", lambda j: j["occupancy"].pop("file"), "scene.json: occupancy.file: missing"),
        ("grid-file-number", lambda j: j["occupancy"].__setitem__("file", 7), "scene.json: occupancy.file: expected a string"),
        ("no-matrix", lambda j: j["poses"]["test"][0].pop("transform_matrix"), "scene.json: poses.test[0].transform_matrix: missing"),
        ("short-matrix", lambda j: j["poses"]["test"][0]["transform_matrix"].pop(), "poses.test[0].transform_matrix: expected an array of 4, got 3"),
        ("string-entry", lambda j: j["poses"]["test"][0]["transform_matrix"][2].__setitem__(1, "x"),
         "poses.test[0].transform_matrix[2][1]: expected a number, got the string 'x'"),
        ("inf-matrix", lambda j: j["poses"]["test"][0]["transform_matrix"][2].__setitem__(1, 1e39), "poses.test[0].transform_matrix: has a non-finite entry"),
        ("bool-width", lambda j: j["camera"].__setitem__("width", True), "scene.json: camera.width: expected an integer"),
        ("float-width", lambda j: j["camera"].__setitem__("width", 64.0), "scene.json: camera.width: expected an integer"),
        ("no-convention", lambda j: j["camera"].pop("convention"), "scene.json: camera.convention: missing"),
        ("lindisp", lambda j: j["sampling"].__setitem__("lindisp", 0), "scene.json: sampling.lindisp: expected true or false"),
        ("sampling-extra", lambda j: j["sampling"].__setitem__("jitter", 1), "scene.json: sampling: unknown field 'jitter'"),
        ("march-float", lambda j: j.__setitem__("march_steps", 2.5), "scene.json: march_steps: expected an integer"),
        ("march-null", lambda j: j.__setitem__("march_steps", None), "scene.json: march_steps: expected an integer in 0..2^64, got null"),
        ("bounded-string", lambda j: j.__setitem__("bounded", "false"), "scene.json: bounded: expected true or false"),
        ("grid-bound-zero", lambda j: j["occupancy"].__setitem__("bound", 0), "scene.json: occupancy.bound: 0.0 is not a positive finite bound"),
        ("format", lambda j: j.__setitem__("format", "nerf-rs-scene-9"), "scene.json: format: 'nerf-rs-scene-9', expected one of"),
        ("top-list", lambda j: j.clear(), "scene.json: format: missing"),
        ("role", lambda j: j.__setitem__("graphs", {"colour": "coarse.onnx"}), "scene.json: graphs: unknown role 'colour'"),
        ("no-fine", lambda j: j["networks"].__setitem__("fine", None), "scene.json: networks: graphs [coarse] with sampling.n_fine 64"),
        ("encoding", lambda j: j["position_encoding"].__setitem__("frequencies", "many"), "scene.json: position_encoding.frequencies: expected an array"),
        ("placement", lambda j: j.__setitem__("placement", {"format": "blender"}), "scene.json: placement.transform: missing"),
        ("appearance-kind", lambda j: j.__setitem__("appearance", {"fixed": "median"}), "scene.json: appearance.fixed: 'median' is not \"mean\" or \"image\""),
        ("appearance-extra", lambda j: j.__setitem__("appearance", {"fixed": "mean", "image": "r_0"}), "scene.json: appearance: unknown field 'image'"),
        ("appearance-no-image", lambda j: j.__setitem__("appearance", {"fixed": "image"}), "scene.json: appearance.image: missing"),
        ("appearance-newline", lambda j: j.__setitem__("appearance", {"fixed": "image", "image": "a\nb"}), "scene.json: appearance.image: 'a\\nb' is not an image name"),
    ]
    for name, f, needle in cases:
        refused(edit(name, f), needle)

    # A fixed appearance is recorded for people and tools: the graph holds it already.
    for fixed in ({"fixed": "mean"}, {"fixed": "image", "image": "r_7"}):
        nerf_bundle.Bundle.open(edit("appearance-" + fixed["fixed"], lambda j: j.__setitem__("appearance", fixed)), threads=1)

    deep = copy_bundle(SPHERES, tmp_path / "deep")
    scene = (deep / "scene.json").read_text()
    for depth, needle in ((200, "white_background: expected true or false, got an array"), (100_000, "not valid JSON: arrays or objects nested too deeply")):
        (deep / "scene.json").write_text(scene.replace('"white_background": true', '"white_background": ' + "[" * depth + "]" * depth))
        refused(deep, f"scene.json: {needle}")
    (deep / "scene.json").write_text(scene[: len(scene) // 2])
    refused(deep, "scene.json: not valid JSON")
    (deep / "scene.json").write_text(scene.replace('"white_background": true', '"white_background": true, "white_background": false'))
    refused(deep, "scene.json: not valid JSON: duplicate key 'white_background'")
    (deep / "scene.json").write_bytes(b"\xff" + scene.encode())
    refused(deep, "scene.json: not UTF-8 text")


def test_the_occupancy_header_is_checked_and_matched_with_scene_json(tmp_path):
    """bound and threshold finite, bound > 0, resolution and bound as scene.json says (bound 0
    opened and then divided by zero at render time; NaN raised a ValueError)."""
    def with_header(name, offset, value):
        b = copy_bundle(SPHERES, tmp_path / name)
        grid = bytearray((b / "occupancy.bin").read_bytes())
        grid[offset:offset + 4] = np.array([value], "<f4").tobytes()
        (b / "occupancy.bin").write_bytes(bytes(grid))
        return b

    for name, offset, value, needle in [("bound-0", 12, 0.0, "bound 0.0"), ("bound-nan", 12, np.nan, "bound nan"),
                                        ("bound-neg", 12, -1.5, "bound -1.5"), ("threshold-inf", 16, np.inf, "threshold inf")]:
        refused(with_header(name, offset, value), "occupancy.bin: bad header", needle)
    refused(with_header("bound-other", 12, 2.0), "scene.json: occupancy: the grid file is 32³ over ±2.0, scene.json says 32³ over ±1.5")
    res = edited_bundle(tmp_path / "res-other", lambda j: j["occupancy"].__setitem__("resolution", 16))
    refused(res, "scene.json: occupancy: the grid file is 32³", "says 16³")
    # Dense sampling does not read the grid, so its header cannot stop it (as nerf-render --dense).
    nerf_bundle.Bundle.open(with_header("dense", 12, 0.0), threads=1, skip_empty_space=False)


def test_cli_refuses_bad_options_and_bundles_without_a_traceback(tmp_path):
    def cli(*args):
        done = subprocess.run([sys.executable, "-m", "nerf_bundle", "render", *map(str, args)], capture_output=True, text=True)
        assert "Traceback" not in done.stderr, done.stderr
        return done

    out = tmp_path / "out"
    for chunk, needle in [("0", "--chunk: must be at least 1"), ("1000000000", "--chunk: 1000000000 rays is more than the limit of 1048576"),
                          ("300000", "--chunk: 300000 rays × 16 samples = 4800000 points per network call is more than the limit of 4194304")]:
        done = cli(SPHERES, "--orbit", "--limit", "1", "--npy", "--out", out, "--chunk", chunk)
        assert done.returncode == 2 and done.stderr.startswith("error: ") and needle in done.stderr, done.stderr
    done = cli(SPHERES, "--orbit", "--npy", "--out", out, "--chunk", "many")
    assert done.returncode == 2 and "--chunk: invalid int value: 'many'" in done.stderr, done.stderr
    assert not out.exists()
    no_white = edited_bundle(tmp_path / "no-white", lambda j: j.pop("white_background"))
    done = cli(no_white, "--split", "test", "--npy", "--out", out)
    assert done.returncode == 1 and done.stderr == f"error: {no_white / 'scene.json'}: white_background: missing\n", done.stderr


def test_the_default_chunk_keeps_a_call_within_the_points_limit(tmp_path):
    """As nerf-render's default_chunk: 4096 rays; marching sends at most 16 samples a ray per
    call, however many intervals it marches (2048 here), the dense path all of its samples
    (64 + 128 without the grid: 4096 rays)."""
    assert nerf_bundle.Bundle.open(SPHERES, threads=1).default_chunk == 4096
    b = nerf_bundle.Bundle.open(edited_bundle(tmp_path / "steps", lambda j: j.__setitem__("march_steps", 2048)), threads=1)
    assert (b.samples_per_ray, b.default_chunk, b.check_chunk(None)) == (16, 4096, 4096)
    with pytest.raises(ValueError, match="300000 rays × 16 samples = 4800000 points"):
        b.check_chunk(300000)
    rays = b.render_rays(np.zeros((3, 3), np.float32) + [0, 0, 4], np.array([[0, 0, -1]] * 3, np.float32))
    assert rays.rgb.shape == (3, 3)
    dense = nerf_bundle.Bundle.open(SPHERES, threads=1, skip_empty_space=False)
    assert dense.samples_per_ray == 96
    # On a GPU, as nerf-render: 262,144 rays a batch, fewer where 96 samples a ray pass 2^22.
    for bundle, gpu_chunk in [(b, 262_144), (dense, 4_194_304 // 96)]:
        bundle.device = "cuda:0"
        assert bundle.default_chunk == gpu_chunk
        bundle.device = "cpu"
    with pytest.raises(ValueError, match="50000 rays × 96 samples = 4800000 points"):
        dense.check_chunk(50000)


def test_a_pose_of_huge_finite_numbers_renders(tmp_path):
    """2^64 is finite as float32, but a ray's length then overflows: the marcher's block size
    took int(inf) (found by the long fuzz run); such rays are now marched sample by sample."""
    huge = edited_bundle(tmp_path / "huge", lambda j: j["poses"]["test"][0]["transform_matrix"][0].__setitem__(2, 2**64))
    b = nerf_bundle.Bundle.open(huge, threads=1)
    with np.errstate(over="ignore"):
        frame = b.render(b.poses("test")[0], width=4)
    assert frame.rgb.shape == (4, 4, 3)
