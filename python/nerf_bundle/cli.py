"""``python -m nerf_bundle render BUNDLE (--split test | --orbit [--frames N] | --pose FILE) --out DIR
[--width W [--height H]] [--npy] [--limit K] [--threads N] [--chunk N] [--dense] [--loop native|numpy]
[--whole-graph]``

Writes ``<name>.png`` per view (needs Pillow) and, with ``--npy``, ``<name>.npy`` float32
[H, W, 5] = r, g, b, depth, acc, named as nerf-render names them: a bundle's test views by
their pose names (``r_0``, ...), orbit frames ``frame_000``, ...; ``--pose FILE`` (JSON: a 4×4
or 3×4 OpenGL camera-to-world matrix, or an object with ``transform_matrix``) writes ``pose``.
A line per frame (``k/N``) reports progress. ``--device cuda[:N]`` renders on a GPU.

``python -m nerf_bundle bench BUNDLE [--device cpu|cuda[:N]] [--view N] [--repeat K] [--width W]
[--threads N] [--loop native|numpy] [--whole-graph] [--parity] [--json]`` renders test view N K times and prints,
per frame, the total seconds, the seconds inside onnxruntime (the wall time of the field calls;
with numpy loops side by side, each loop's on average), the rest (outside) and its stages (the
native loop's marching, packing and compositing are one pass: its ``march``); ``--parity`` also renders the view with onnxruntime's CPU provider
and prints the largest |Δ| of r, g, b, depth, acc; ``--json`` prints one JSON object instead."""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import List, Optional

import numpy as np

from ._validate import BundleError
from .bundle import Bundle


LOOP_HELP = "the marching loop on the CPU: native (Rust, nerf_bundle_native) or numpy (default: native where installed)"
WHOLE_HELP = ("run a hash-grid graph whole in onnxruntime (default on the CPU with nerf_bundle_native: its encodings in "
              "Rust, the rest in onnxruntime, as nerf-render)")


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m nerf_bundle", description="Render nerf-rs scene bundles with onnxruntime")
    sub = p.add_subparsers(dest="command", required=True)
    r = sub.add_parser("render", help="render a bundle's test views or its orbit")
    r.add_argument("bundle", help="bundle directory (scene.json + ONNX graphs + occupancy.bin)")
    which = r.add_mutually_exclusive_group(required=True)
    which.add_argument("--split", choices=["test"], help="the bundle's test poses")
    which.add_argument("--orbit", action="store_true", help="the bundle's orbit")
    which.add_argument("--pose", help="a JSON file: a camera-to-world matrix (OpenGL, the bundle's frame)")
    r.add_argument("--frames", type=int, help="orbit frames (another count than the bundle's: the reference orbit)")
    r.add_argument("--limit", type=int, help="only the first K views")
    r.add_argument("--out", required=True, help="output directory")
    r.add_argument("--width", type=int, help="render at this width (the camera scales with it)")
    r.add_argument("--height", type=int, help="render at this height (needs --width)")
    r.add_argument("--npy", action="store_true", help="also write <name>.npy: float32 [H, W, 5] = r, g, b, depth, acc")
    r.add_argument("--threads", type=int, help="onnxruntime sessions side by side (default: one per core)")
    r.add_argument("--chunk", type=int, help="rays per batch (default: 4096 on the CPU, 262,144 on a GPU, fewer where a call would pass the points limit)")
    r.add_argument("--dense", action="store_true", help="ignore occupancy.bin (as nerf-render --dense)")
    r.add_argument("--device", help="cpu (default), or cuda / cuda:N: onnxruntime's CUDA provider on GPU N (needs onnxruntime-gpu)")
    r.add_argument("--loop", choices=["native", "numpy"], help=LOOP_HELP)
    r.add_argument("--whole-graph", action="store_true", help=WHOLE_HELP)
    b = sub.add_parser("bench", help="time frames: total, inside onnxruntime, outside, and the stages")
    b.add_argument("bundle", help="bundle directory")
    b.add_argument("--device", default="cpu", help="cpu (default), or cuda / cuda:N (needs onnxruntime-gpu)")
    b.add_argument("--view", type=int, default=0, help="test view index (default 0)")
    b.add_argument("--repeat", type=int, default=3, help="frames to render (default 3; the first one warms up)")
    b.add_argument("--width", type=int, help="render at this width (the camera scales with it)")
    b.add_argument("--threads", type=int, help="onnxruntime sessions side by side on the CPU (default: one per core)")
    b.add_argument("--loop", choices=["native", "numpy"], help=LOOP_HELP)
    b.add_argument("--whole-graph", action="store_true", help=WHOLE_HELP)
    b.add_argument("--parity", action="store_true", help="also render on the CPU provider and print the largest |Δ|")
    b.add_argument("--json", action="store_true", help="print one JSON object")
    return p


def _read_pose(path: str) -> np.ndarray:
    """A camera-to-world matrix from a JSON file, checked (BundleError names the file)."""
    import json

    try:
        with open(path) as f:
            value = json.load(f)
    except (OSError, ValueError) as e:
        raise BundleError(f"{path}: cannot read a pose: {e}") from None
    if isinstance(value, dict):
        value = value.get("transform_matrix")
    m = np.asarray(value, dtype=np.float64) if isinstance(value, list) else None
    if m is None or m.shape not in ((4, 4), (3, 4)) or not np.isfinite(m).all():
        raise BundleError(f"{path}: expected a finite 4×4 or 3×4 camera-to-world matrix (or {{\"transform_matrix\": ...}})")
    full = np.eye(4, dtype=np.float32)
    full[:3] = m[:3]
    return full


def main(argv: Optional[List[str]] = None) -> int:
    a = _parser().parse_args(argv)
    if a.command == "bench":
        return bench(a)
    if a.height is not None and a.width is None:
        print("error: --height needs --width", file=sys.stderr)
        return 2
    if a.frames is not None and not a.orbit:
        print("error: --frames needs --orbit", file=sys.stderr)
        return 2
    try:
        import PIL  # noqa: F401

        have_pil = PIL is not None
    except ImportError:
        have_pil = False
    if not have_pil and not a.npy:
        print("error: writing PNGs needs Pillow: pip install 'nerf_bundle[images]' (or pass --npy for raw arrays only)", file=sys.stderr)
        return 2
    try:
        bundle = Bundle.open(a.bundle, threads=a.threads, skip_empty_space=not a.dense, device=a.device, loop=a.loop, whole_graph=a.whole_graph)
        if a.pose:
            poses, names = [_read_pose(a.pose)], ["pose"]
        elif a.orbit:
            poses = bundle.orbit(a.frames)
            names = [f"frame_{k:03}" for k in range(len(poses))]
        if not a.pose and not a.orbit:
            poses, names = bundle.poses("test"), bundle.pose_names("test")
        poses, names = poses[:a.limit], names[:a.limit]
        if not poses:
            print("error: nothing to render: no poses", file=sys.stderr)
            return 1
        cam = bundle.camera_at(a.width, a.height)
        chunk = bundle.check_chunk(a.chunk, "--chunk")
    except BundleError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except (ValueError, NotImplementedError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if not have_pil:
        print("note: Pillow is not installed: writing .npy only (pip install 'nerf_bundle[images]' for PNGs)", file=sys.stderr)
    os.makedirs(a.out, exist_ok=True)
    start = time.perf_counter()
    for k, (pose, name) in enumerate(zip(poses, names)):
        frame = bundle.render(pose, a.width, a.height, chunk=chunk)
        if have_pil:
            frame.to_pil().save(os.path.join(a.out, f"{name}.png"))
        if a.npy:
            np.save(os.path.join(a.out, f"{name}.npy"), frame.raw)
        print(f"{k + 1}/{len(poses)} {name}: {frame.seconds:.2f} s ({frame.field_seconds:.2f} s in onnxruntime)", file=sys.stderr)
    seconds = time.perf_counter() - start
    print(f"{len(poses)} frames at {cam.width}×{cam.height} in {seconds:.1f} s ({seconds / len(poses):.2f} s per frame, "
          f"{'dense sampling' if bundle.grid is None else 'empty space skipped' if not a.dense else 'marched through the box'}) into {a.out}")
    return 0


def bench(a: argparse.Namespace) -> int:
    """``bench``: time ``--repeat`` frames of one test view (and the CPU provider's parity)."""
    try:
        if a.repeat < 1 or a.repeat > 1000:
            raise ValueError(f"--repeat: {a.repeat} is outside 1..1000")
        bundle = Bundle.open(a.bundle, threads=a.threads, device=a.device, loop=a.loop, whole_graph=a.whole_graph)
        poses = bundle.poses("test")
        if not 0 <= a.view < len(poses):
            raise ValueError(f"--view: {a.view} is not a test view (the bundle has {len(poses)})")
        cam = bundle.camera_at(a.width)
    except BundleError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except ValueError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    frames, last = [], None
    try:
        for k in range(a.repeat):
            last = bundle.render(poses[a.view], a.width)
            stages = {name: round(getattr(last.stages, name), 4) for name in ("rays", "march", "gather", "composite")}
            row = {"total_s": round(last.seconds, 4), "onnxruntime_s": round(last.field_seconds, 4),
                   "outside_s": round(last.seconds - last.field_seconds, 4), "stages_s": stages}
            frames.append(row)
            if not a.json:
                split = ", ".join(f"{n} {v:.3f}" for n, v in stages.items())
                print(f"frame {k + 1}/{a.repeat}: {row['total_s']:.3f} s, onnxruntime {row['onnxruntime_s']:.3f} s, "
                      f"outside {row['outside_s']:.3f} s ({split})", flush=True)
        parity = None
        if a.parity:
            cpu = Bundle.open(a.bundle, threads=a.threads, loop=a.loop, whole_graph=a.whole_graph).render(poses[a.view], a.width)
            assert last is not None
            diff = np.abs(last.raw.astype(np.float64) - cpu.raw)
            parity = {"max_abs": float(diff.max()), "max_abs_rgb_depth_acc": [float(v) for v in diff.max(axis=(0, 1))]}
    except BundleError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    best = min(frames[1:] or frames, key=lambda f: f["total_s"])
    loop = "GPU (CuPy)" if bundle._gpu_loop is not None else bundle.loop
    encoding = "rust" if any(g.encoder is not None for g in bundle.graphs.values()) else "graph"
    if a.json:
        print(json.dumps({"bundle": a.bundle, "device": bundle.device, "view": a.view, "width": cam.width, "height": cam.height,
                          "loop": loop, "encoding": encoding, "frames": frames, "best": best, "parity_vs_cpu": parity}))
    else:
        print(f"{cam.width}×{cam.height} on {bundle.device}, {loop} loop, "
              f"{'hash encoding in Rust' if encoding == 'rust' else 'whole graph'}: best {best['total_s']:.3f} s per frame, "
              f"{best['onnxruntime_s']:.3f} s in onnxruntime, {best['outside_s']:.3f} s outside"
              + ("" if len(frames) == 1 else " (the first frame, warming up, left out)"))
        if parity is not None:
            print(f"parity against the CPU provider: max |Δ| {parity['max_abs']:.3g} "
                  f"(r g b depth acc: {' '.join(f'{v:.3g}' for v in parity['max_abs_rgb_depth_acc'])})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
