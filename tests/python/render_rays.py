"""Render a view of a nerf-rs scene bundle with the Python package (python/, nerf_bundle: numpy
and onnxruntime only) and compare it with nerf-render's exact output (--npy): the whole frame,
and the reported sample of rays (half where nerf-render saw the scene). One Python renderer:
this script only drives the package.

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
import sys

import numpy as np

try:
    import nerf_bundle
    from nerf_bundle import BundleError
    from nerf_bundle._validate import MAX_FRAMES, MAX_FRAME_PIXELS, MAX_GRAPH_BYTES, MAX_GRID_RESOLUTION, MAX_IMAGE_SIDE, MAX_JSON_BYTES, MAX_SAMPLES_PER_RAY  # noqa: F401
except ImportError as e:
    sys.exit(f"error: the nerf_bundle package is not installed ({e}): run scripts/setup.sh, or pip install ./python")


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
        bundle = nerf_bundle.Bundle.open(a.bundle, skip_empty_space=not a.dense)
        c2w = bundle.poses("test")[a.test_pose] if a.test_pose is not None else bundle.poses("orbit")[a.orbit_pose]
    except BundleError as e:
        print(f"error: {e}", file=sys.stderr)
        sys.exit(2)
    expected = np.load(a.npy)
    height, width = expected.shape[:2]
    frame = bundle.render(c2w, width=width, height=height)
    got = frame.raw
    rng = np.random.default_rng(a.seed)
    # The reported sample: half the rays where nerf-render saw the scene (acc > 0.5), half anywhere.
    hit = np.argwhere(expected[..., 4] > 0.5)
    picks = [hit[rng.integers(len(hit), size=min(len(hit), a.rays // 2))]] if len(hit) else []
    rest = a.rays - sum(map(len, picks))
    picks.append(np.stack([rng.integers(height, size=rest), rng.integers(width, size=rest)], 1))
    rows_cols = np.concatenate(picks)
    want, have = expected[rows_cols[:, 0], rows_cols[:, 1]], got[rows_cols[:, 0], rows_cols[:, 1]]
    diff = np.abs(have - want).max(axis=0)
    whole = np.abs(got - expected).max(axis=(0, 1))
    print(f"{len(rows_cols)} rays ({int((want[:, 4] > 0.5).sum())} on the scene): max |Δrgb| {diff[:3].max():.2e}, "
          f"|Δacc| {diff[4]:.2e}, |Δdepth| {diff[3]:.2e}; whole {width}×{height} frame: max |Δrgb| {whole[:3].max():.2e}, "
          f"|Δacc| {whole[4]:.2e} (tolerance {a.tolerance:g})")
    if not (whole[:3].max() <= a.tolerance and whole[4] <= a.tolerance):
        print("FAIL: the Python package and nerf-render disagree", file=sys.stderr)
        sys.exit(1)
    if (expected[..., 4] > 0.5).sum() == 0:
        print("FAIL: no ray hit the scene; the comparison would mean nothing", file=sys.stderr)
        sys.exit(1)


if __name__ == "__main__":
    main()
