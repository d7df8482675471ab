"""Reference values for core/tests/real_captures.rs: nerf-pytorch's LLFF pose pipeline
(load_llff_data with factor=None, bd_factor=0.75, recenter=True, spherify=False) in numpy.

    $NERF_PYTHON scripts/llff_reference.py ../shared/data/real/fern

prints the recentred pose of the last view (3x4) and nerf-pytorch's no-NDC near/far
(0.9 * min bound, max bound) after the bd_factor scaling.
"""
import sys

import numpy as np


def unit(v):
    return v / np.linalg.norm(v)


def average_pose(poses):
    """poses_avg: mean centre, summed back axes, up re-orthogonalised (viewmatrix)."""
    z = unit(poses[:, :3, 2].sum(0))
    x = unit(np.cross(poses[:, :3, 1].sum(0), z))
    y = unit(np.cross(z, x))
    m = np.eye(4)
    m[:3, :4] = np.stack([x, y, z, poses[:, :3, 3].mean(0)], 1)
    return m


def main(scene):
    rows = np.load(f"{scene}/poses_bounds.npy")
    mats = rows[:, :15].reshape(-1, 3, 5)
    bounds = rows[:, 15:].astype(np.float32)
    # [down, right, back] -> [right, up, back]
    poses = np.concatenate([mats[:, :, 1:2], -mats[:, :, 0:1], mats[:, :, 2:4]], 2).astype(np.float32)
    scale = 1.0 / (bounds.min() * 0.75)
    poses[:, :, 3] *= scale
    bounds *= scale
    full = np.tile(np.eye(4), (len(poses), 1, 1))
    full[:, :3, :4] = poses
    centred = np.linalg.inv(average_pose(poses)) @ full
    np.set_printoptions(precision=7, suppress=True)
    print("last pose", centred[-1, :3, :4].tolist())
    print("near far", float(bounds.min() * 0.9), float(bounds.max()))


if __name__ == "__main__":
    main(sys.argv[1])
