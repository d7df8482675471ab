"""Shared fixtures: the repository's bundles and nerf-render's frames (--npy) as ground truth."""
from __future__ import annotations

import json
import shutil
import subprocess
from pathlib import Path
from typing import Callable, Dict, Optional

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[2]
MODELS = REPO / "models"


def native_command() -> Optional[str]:
    """A shell prefix that runs nerf-render (scripts/env.sh sets onnxruntime and the target dir)."""
    env = REPO / "scripts" / "env.sh"
    if not env.exists():
        return None
    probe = subprocess.run(["bash", "-c", f". {env} >/dev/null 2>&1; echo ${{CARGO_TARGET_DIR:-{REPO}/target}}"],
                           capture_output=True, text=True)
    target = Path(probe.stdout.strip() or REPO / "target")
    binary = target / "release" / "nerf-render"
    if not binary.exists():
        return None
    return f". {env} >/dev/null 2>&1; {binary}"


@pytest.fixture(scope="session")
def nerf_render(tmp_path_factory) -> Callable[..., np.ndarray]:
    """nerf_render(bundle, *args) → the first frame's [H, W, 5] array (cached per arguments)."""
    prefix = native_command()
    if prefix is None:
        pytest.skip("nerf-render is not built (cargo build --release -p nerf-runtime)")
    cache: Dict[tuple, np.ndarray] = {}
    root = tmp_path_factory.mktemp("native")

    def run(bundle: Path, *args: str, name: str = "r_0") -> np.ndarray:
        key = (str(bundle),) + args
        if key not in cache:
            out = root / f"out{len(cache)}"
            cmd = f"{prefix} --bundle '{bundle}' {' '.join(args)} --limit 1 --out '{out}' --npy"
            done = subprocess.run(["bash", "-c", cmd], capture_output=True, text=True)
            assert done.returncode == 0, done.stdout + done.stderr
            cache[key] = np.load(out / f"{name}.npy")
        return cache[key]

    return run


def assert_same_points(calls: list, reference: list, per_call: int) -> None:
    """The field calls ``calls`` evaluated the points of ``reference``'s, each as often (in
    other calls: march_grid sends a round's samples lane after lane), none more than
    ``per_call`` points."""
    got = np.unique(np.concatenate(calls), axis=0, return_counts=True)
    want = np.unique(np.concatenate(reference), axis=0, return_counts=True)
    assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1]), "the same points"
    assert max(len(c) for c in calls) <= per_call


def copy_bundle(src: Path, to: Path) -> Path:
    to.mkdir(parents=True, exist_ok=True)
    for f in src.iterdir():
        shutil.copy(f, to / f.name)
    return to


def edited_bundle(to: Path, edit: Callable[[dict], None], src: Path = MODELS / "spheres") -> Path:
    b = copy_bundle(src, to)
    scene = json.loads((b / "scene.json").read_text())
    edit(scene)
    (b / "scene.json").write_text(json.dumps(scene))
    return b


def distort(scene: dict) -> None:
    """A real capture's camera, as runtime/tests/cli.rs python_consumer_matches_nerf_render."""
    cam = scene["camera"]
    cam.pop("focal", None)
    cam.update({"fx": 70.0, "fy": 66.5, "cx": 29.3, "cy": 35.9, "pixel_center": "half_pixel",
                "distortion": {"k1": -0.21, "k2": 0.05, "p1": 0.003, "p2": -0.002}})


@pytest.fixture(scope="session")
def captured(tmp_path_factory) -> Path:
    """A copy of models/spheres whose camera has distortion and an off-centre principal point."""
    return edited_bundle(tmp_path_factory.mktemp("captured") / "captured", distort)


def sessions_that_say_cuda(monkeypatch) -> None:
    """onnxruntime as if it were the GPU wheel: CPU sessions that report the CUDA provider."""
    import onnxruntime as ort

    monkeypatch.setattr(ort, "get_available_providers", lambda: ["CUDAExecutionProvider", "CPUExecutionProvider"])
    real = ort.InferenceSession

    class SaysCuda:
        def __init__(self, model, opts, providers=None, **kw):
            self._s = real(model, opts, providers=["CPUExecutionProvider"])

        def get_providers(self):
            return ["CUDAExecutionProvider", "CPUExecutionProvider"]

        def __getattr__(self, name):
            return getattr(self._s, name)

    monkeypatch.setattr(ort, "InferenceSession", SaysCuda)
