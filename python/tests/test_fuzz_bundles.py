"""Property: whatever is done to a valid bundle's scene.json or occupancy.bin header, Bundle.open
either refuses it with a BundleError naming the file, or opens a bundle whose poses, orbit and
rays then render without an exception. The mutations (seeded): keys deleted, values replaced
by wrong types, strings, NaN/∞/0/negative/huge numbers, nesting, lists grown and cut, JSON
text cut or spliced, header words set to special values, the grid file cut or grown.

The suite runs a few hundred cases; the long run (docs/robustness.md):

    $NERF_PYTHON python/tests/test_fuzz_bundles.py --cases 10000 --seed 1
"""
from __future__ import annotations

import argparse
import json
import random
import shutil
import struct
import sys
import tempfile
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, List, Optional

import numpy as np

HERE = Path(__file__).resolve().parent
MODELS = HERE.parents[1] / "models"
if __name__ == "__main__":
    sys.path.insert(0, str(HERE.parent))  # the package beside these tests

import nerf_bundle  # noqa: E402
from nerf_bundle import BundleError  # noqa: E402

# Numbers at the edges: zero, signs, float32's range, past float64's, integers past 2^32/2^64.
NUMBERS: List[Any] = [0, -0.0, 1, -1, 0.5, 2, 3, 255, 4096, 4097, 16_385, 2**31, 2**32, 2**53, 2**64, 10**30, 10**400,
                      1e-45, 1e-300, 3.4e38, 3.5e38, 1e39, 1e300, -1e300, float("nan"), float("inf"), float("-inf")]
STRINGS = ["", ".", "..", "../../etc/passwd", "/etc/hostname", "/dev/zero", "a/b", "a" * 5000, "\0\n", "ü€😀",
           "coarse.onnx", "fine.onnx", "occupancy.bin", "scene.json", "nerf-rs-scene-1", "nerf-rs-scene-2", "ngp", "mlp",
           "field", "integer", "half_pixel", "llff"]
DEPTHS = [2, 127, 128, 1000, 100_000]
NESTED = "__fuzz_nested_{}__"


def _pointers(v: Any, at: tuple = ()) -> List[tuple]:
    out = []
    items = v.items() if isinstance(v, dict) else enumerate(v) if isinstance(v, list) else []
    for k, c in items:
        out.append(at + (k,))
        out.extend(_pointers(c, at + (k,)))
    return out


def _mutate_tree(rng: random.Random, doc: Any) -> Any:
    """One edit of one node: removed, replaced (number, string, other type, nesting), nudged,
    its array grown or cut."""
    pointers = _pointers(doc)
    if not pointers:
        return rng.choice(NUMBERS + STRINGS + [None, [], {}])
    # A depth first (the top level a third of the time), then a node at it: the few top-level
    # keys are hit as often as the many matrix entries.
    depth = 1 if rng.randrange(3) == 0 else rng.randrange(max(len(p) for p in pointers)) + 1
    *parent_keys, key = rng.choice([p for p in pointers if len(p) == depth] or pointers)
    parent = doc
    for k in parent_keys:
        parent = parent[k]
    node = parent[key]
    action = rng.randrange(8)
    if action == 0:
        del parent[key]
    elif action == 1:
        parent[key] = rng.choice(NUMBERS)
    elif action == 2:
        parent[key] = rng.choice(STRINGS)
    elif action == 3:
        parent[key] = rng.choice([None, True, False, [], {}, [node], {"x": node}])
    elif action == 4:
        if isinstance(node, (int, float)) and not isinstance(node, bool):
            parent[key] = rng.choice([node + 1, node - 1, -node, node * 1024, node / 1024, 0])
        else:
            parent[key] = rng.choice(NUMBERS)
    elif action == 5:
        if isinstance(node, list) and node:
            node.extend([node[rng.randrange(len(node))]] * rng.choice([1, 2, 7, 100, 10_001]))
        else:
            parent[key] = [node, node]
    elif action == 6:
        if isinstance(node, list) and node:
            node.pop()
        elif isinstance(node, str) and node:
            parent[key] = node[:-1]
        else:
            parent[key] = None
    else:
        parent[key] = NESTED.format(rng.choice(DEPTHS))
    return doc


def mutate_scene(rng: random.Random, text: str) -> bytes:
    """1–4 stacked edits of scene.json: mostly tree edits, sometimes edits of the text."""
    data = text
    # Half the time one edit (a single fault must be found on its own), else up to four.
    for _ in range(1 if rng.randrange(2) else 1 + rng.randrange(2) + rng.randrange(2) * rng.randrange(3)):
        try:
            doc = json.loads(data)
        except (ValueError, RecursionError):
            doc = None
        if doc is not None and rng.randrange(4) != 0:
            doc = _mutate_tree(rng, doc)
            data = json.dumps(doc, indent=rng.choice([None, 2]))  # NaN and ±inf as NaN, Infinity
            for depth in DEPTHS:
                data = data.replace(f'"{NESTED.format(depth)}"', "[" * depth + "]" * depth)
            continue
        action = rng.randrange(5)
        i = rng.randrange(len(data) + 1)
        if action == 0:
            data = data[:i]
        elif action == 1:
            data = data[:i] + rng.choice(['"', "{", "[", "]", "}", ",", ":", "-", "e", "\\", "\0", "NaN"]) + data[i:]
        elif action == 2:
            data = data[:i] + data[i + 1 + rng.randrange(64):]
        elif action == 3:
            j = rng.randrange(len(data) + 1)
            data = data[:i] + data[j:j + 256] + data[i:]  # a piece repeated: duplicate keys, broken nesting
        else:
            return (data[:i].encode() + bytes([rng.randrange(256)]) + data[i:].encode())
    return data.encode()


#: What the sweep puts in place of each value: deleted, null, wrong types, past float32's range.
DELETE = object()
SWEEP = [DELETE, None, "x", 1e39, -1, [], {}, True]


def sweep(text: str) -> List[bytes]:
    """scene.json with one value changed, for every key of the first two levels (and the first
    entry of each list there) and every edit of SWEEP: each fault on its own."""
    doc = json.loads(text)
    out = []
    for pointer in _pointers(doc):
        if len(pointer) > 2 or any(isinstance(k, int) and k > 0 for k in pointer):
            continue
        for value in SWEEP:
            edited = json.loads(text)
            parent = edited
            for k in pointer[:-1]:
                parent = parent[k]
            if value is DELETE:
                del parent[pointer[-1]]
            else:
                parent[pointer[-1]] = value
            out.append(json.dumps(edited).encode())
    return out


def mutate_grid(rng: random.Random, grid: bytes) -> bytes:
    """1–3 edits of occupancy.bin, mostly of its 20-byte header (magic, resolution, bound, threshold)."""
    data = bytearray(grid)
    for _ in range(1 + rng.randrange(3)):
        action = rng.randrange(6)
        if action == 0:
            at = rng.choice([12, 16])
            data[at:at + 4] = struct.pack("<f", rng.choice([0.0, -0.0, -1.5, 1.0, 2.0, 1.5000001, 1e-45, 3.4e38,
                                                            float("nan"), float("inf"), float("-inf")]))
        elif action == 1:
            data[8:12] = struct.pack("<I", rng.choice([0, 1, 16, 31, 33, 512, 513, 2**31, 2**32 - 1]))
        elif action == 2 and len(data) > 0:
            i = rng.randrange(min(len(data), 24))
            data[i] ^= 1 << rng.randrange(8)
        elif action == 3:
            del data[rng.randrange(len(data) + 1):]
        elif action == 4:
            data.extend(bytes(rng.choice([1, 4, 1024])))
        else:
            data[0:8] = rng.choice([b"NERFOCC2", b"\0" * 8, b"nerfocc1"])
    return bytes(data)


@dataclass
class Report:
    cases: int = 0
    opened: int = 0
    refused: int = 0
    seconds: float = 0.0
    #: Exceptions other than BundleError (a traceback for a user), with the input kept.
    crashes: List[str] = field(default_factory=list)
    #: BundleErrors whose message does not name the file.
    unnamed: List[str] = field(default_factory=list)

    def summary(self) -> str:
        return (f"{self.cases} cases in {self.seconds:.1f} s: {self.opened} opened and rendered, {self.refused} refused; "
                f"{len(self.crashes)} tracebacks, {len(self.unnamed)} errors not naming the file")


def _seeds() -> List[str]:
    """scene.json of models/spheres as written (nerf-rs-scene-1) and as today's format writes it."""
    v1 = (MODELS / "spheres" / "scene.json").read_text()
    v2 = json.loads(v1)
    v2["format"] = "nerf-rs-scene-2"
    v2["graphs"] = {"coarse": v2["networks"]["coarse"], "fine": v2["networks"]["fine"]}
    del v2["networks"]
    return [v1, json.dumps(v2, indent=2)]


def _exercise(bundle: Any) -> None:
    """What a user does with an opened bundle: its poses, its orbit, a few rays of a view."""
    poses = bundle.poses("test") + bundle.orbit()
    c2w = poses[0] if poses else np.eye(4, dtype=np.float32) + np.array([[0, 0, 0, 0], [0, 0, 0, 0], [0, 0, 0, 4], [0, 0, 0, 0]], np.float32)
    cam = bundle.camera
    i = np.array([0, cam.width - 1, cam.width // 2])
    j = np.array([0, cam.height - 1, cam.height // 2])
    o, d = cam.rays(c2w, i, j)
    bundle.render_rays(o, d)


def run(cases: int, seed: int, keep: Optional[Path] = None, swept: bool = True) -> Report:
    """The :func:`sweep` of both seeds (``swept``), then ``cases`` mutated bundles from ``seed``;
    inputs that crash are copied under ``keep``."""
    rng = random.Random(seed)
    report = Report()
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="nerf-fuzz-") as tmp:
        bundle = Path(tmp) / "bundle"
        shutil.copytree(MODELS / "spheres", bundle)
        seeds, grid = _seeds(), (bundle / "occupancy.bin").read_bytes()
        fixed = [edit for s in seeds for edit in sweep(s)] if swept else []
        for case in range(len(fixed) + cases):
            scene = rng.choice(seeds).encode()
            occupancy = grid
            which = rng.randrange(3)
            if case < len(fixed):
                scene = fixed[case]
            else:
                if which != 1:
                    scene = mutate_scene(rng, scene.decode())
                if which != 0:
                    occupancy = mutate_grid(rng, grid)
            (bundle / "scene.json").write_bytes(scene)
            (bundle / "occupancy.bin").write_bytes(occupancy)
            report.cases += 1
            try:
                b = nerf_bundle.Bundle.open(bundle, threads=1, skip_empty_space=rng.randrange(4) != 0)
                _exercise(b)
                report.opened += 1
            except BundleError as e:
                report.refused += 1
                if str(bundle) not in str(e):
                    report.unnamed.append(str(e)[:300])
            except Exception:  # noqa: BLE001 - anything else is what the property forbids
                report.crashes.append(f"case {case}: {traceback.format_exc(limit=4)}")
                if keep is not None:
                    saved = keep / f"case-{seed}-{case}"
                    saved.mkdir(parents=True, exist_ok=True)
                    (saved / "scene.json").write_bytes(scene)
                    (saved / "occupancy.bin").write_bytes(occupancy)
    report.seconds = time.perf_counter() - start
    return report


def test_mutated_bundles_are_refused_with_the_file_named_or_render(tmp_path):
    report = run(300, seed=0, keep=tmp_path)
    print(report.summary())
    assert report.crashes == [], "\n".join(report.crashes[:3])
    assert report.unnamed == [], report.unnamed[:5]
    # Both outcomes occur: a fuzzer whose every input is refused tests only the first check.
    assert report.refused > 500 and report.opened > 30, report.summary()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--cases", type=int, default=10_000)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--keep", type=Path, default=Path("fuzz-crashes/python"), help="where crashing inputs are copied")
    a = p.parse_args()
    report = run(a.cases, a.seed, a.keep)
    print(report.summary())
    for line in report.crashes[:5] + report.unnamed[:5]:
        print(line)
    return 1 if report.crashes or report.unnamed else 0


if __name__ == "__main__":
    sys.exit(main())
