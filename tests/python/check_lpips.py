"""LPIPS (AlexNet) compiled by nerf-rs against an independent NumPy forward pass.

    python check_lpips.py <alex.onnx> <alexnet.ckpt> [--lego DIR] [--pair a.npy b.npy VALUE]

Reads the checkpoint with its own restricted unpickler (numpy arrays and plain containers
only), runs the `lpips` package's definition in NumPy (float64: own im2col convolution, own
max-pool) and the graph through onnxruntime, on random pairs, an odd-sized pair and, with
--lego, lego val views at 400×400 (on white); every pair must agree to 1e-5, and a pair of
identical images must give exactly 0. --pair also checks a value the Rust runtime computed.
Prints `ok <pair> onnx <v> numpy <v>` per pair (the Rust test counts them).
"""

import argparse
import pickle
import sys

import numpy as np
import onnxruntime as ort

TOLERANCE = 1e-5
SHIFT = np.array([-0.030, -0.088, -0.188]).reshape(3, 1, 1)
SCALE = np.array([0.458, 0.448, 0.450]).reshape(3, 1, 1)
# torchvision's AlexNet features: (kernel, stride, padding) per convolution; a 3x3 stride-2
# max-pool before the second and third.
CONVS = [(11, 4, 2), (5, 1, 2), (3, 1, 1), (3, 1, 1), (3, 1, 1)]


class ArraysOnly(pickle.Unpickler):
    """numpy's array reconstruction and nothing else: no other global can be loaded."""

    ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
    }

    def find_class(self, module, name):
        if (module, name) not in self.ALLOWED:
            raise pickle.UnpicklingError(f"refusing {module}.{name}")
        if name == "_reconstruct":
            return np.ndarray.__reduce__(np.zeros(1))[0]  # numpy's own _reconstruct, wherever it lives
        return getattr(np, name)


def load_weights(path):
    with open(path, "rb") as f:
        params = ArraysOnly(f).load()
    convs = []
    for k in range(5):
        layer = params["AlexNet_0"][f"Conv_{k}"]
        kernel = np.asarray(layer["kernel"], np.float64)  # flax: [kh, kw, in, out]
        convs.append((kernel.transpose(3, 2, 0, 1), np.asarray(layer["bias"], np.float64)))
    lins = [np.asarray(params[f"NetLinLayer_{k}"]["Conv_0"]["kernel"], np.float64).reshape(-1) for k in range(5)]
    return convs, lins


def conv(x, weight, bias, stride, pad):
    """x [C, H, W], weight [O, C, k, k]: im2col, then one matrix product."""
    c, _, _ = x.shape
    o, _, k, _ = weight.shape
    x = np.pad(x, ((0, 0), (pad, pad), (pad, pad)))
    h = (x.shape[1] - k) // stride + 1
    w = (x.shape[2] - k) // stride + 1
    columns = np.empty((c, k, k, h, w))
    for dy in range(k):
        for dx in range(k):
            columns[:, dy, dx] = x[:, dy : dy + stride * (h - 1) + 1 : stride, dx : dx + stride * (w - 1) + 1 : stride]
    out = weight.reshape(o, c * k * k) @ columns.reshape(c * k * k, h * w)
    return (out + bias[:, None]).reshape(o, h, w)


def max_pool(x, k=3, stride=2):
    c, hh, ww = x.shape
    h, w = (hh - k) // stride + 1, (ww - k) // stride + 1
    out = np.full((c, h, w), -np.inf)
    for dy in range(k):
        for dx in range(k):
            out = np.maximum(out, x[:, dy : dy + stride * (h - 1) + 1 : stride, dx : dx + stride * (w - 1) + 1 : stride])
    return out


def features(image, convs):
    """image [H, W, 3] in [0, 1] → the five ReLU outputs [C, h, w]."""
    x = (2.0 * image.transpose(2, 0, 1) - 1.0 - SHIFT) / SCALE
    out = []
    for k, ((weight, bias), (_, stride, pad)) in enumerate(zip(convs, CONVS)):
        if k in (1, 2):
            x = max_pool(x)
        x = np.maximum(conv(x, weight, bias, stride, pad), 0.0)
        out.append(x)
    return out


def lpips_numpy(a, b, weights):
    convs, lins = weights
    total = 0.0
    for fa, fb, lin in zip(features(a.astype(np.float64), convs), features(b.astype(np.float64), convs), lins):
        na = fa / (np.sqrt((fa**2).sum(axis=0, keepdims=True)) + 1e-10)
        nb = fb / (np.sqrt((fb**2).sum(axis=0, keepdims=True)) + 1e-10)
        total += np.tensordot(lin, (na - nb) ** 2, axes=1).mean()
    return total


def lego_view(path):
    from PIL import Image

    rgba = np.asarray(Image.open(path).convert("RGBA"), np.float32) / 255.0
    return rgba[..., :3] * rgba[..., 3:] + (1.0 - rgba[..., 3:])


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("graph")
    parser.add_argument("checkpoint")
    parser.add_argument("--lego")
    parser.add_argument("--pair", nargs=3, metavar=("A", "B", "VALUE"))
    args = parser.parse_args()
    weights = load_weights(args.checkpoint)
    session = ort.InferenceSession(args.graph, providers=["CPUExecutionProvider"])

    rng = np.random.default_rng(7)
    smooth = lambda h, w: np.clip(0.5 + 0.4 * np.sin(np.linspace(0, 6, w))[None, :, None] * np.cos(np.linspace(0, 4, h))[:, None, None] + rng.normal(0, 0.05, (h, w, 3)), 0, 1)
    pairs = {
        "random 64x64": (rng.random((64, 64, 3)), rng.random((64, 64, 3))),
        "random 96x80": (rng.random((96, 80, 3)), rng.random((96, 80, 3))),
        "odd 47x35": (smooth(47, 35), smooth(47, 35)),
        "smallest 31x31": (rng.random((31, 31, 3)), rng.random((31, 31, 3))),
    }
    if args.lego:
        r0, r1, r2 = (lego_view(f"{args.lego}/val/r_{k}.png") for k in (0, 1, 2))
        pairs["lego r_0 vs r_1 400x400"] = (r0, r1)
        pairs["lego r_2 vs r_2 + noise 400x400"] = (r2, np.clip(r2 + rng.normal(0, 0.03, r2.shape), 0, 1))
    if args.pair:
        pairs["rust " + args.pair[0]] = (np.load(args.pair[0]), np.load(args.pair[1]))

    failed = False
    for name, (a, b) in pairs.items():
        a, b = a.astype(np.float32), b.astype(np.float32)
        (onnx,) = session.run(["lpips"], {"image0": a[None], "image1": b[None]})
        expected = lpips_numpy(a, b, weights)
        same = session.run(["lpips"], {"image0": a[None], "image1": a[None]})[0][0]
        good = abs(onnx[0] - expected) <= TOLERANCE and same == 0.0 and expected > 0.0
        if name.startswith("rust "):
            rust = float(args.pair[2])
            good = good and abs(rust - expected) <= TOLERANCE
            name += f" (rust {rust:.7f})"
        print(f"{'ok' if good else 'FAIL'} {name}: onnx {onnx[0]:.7f} numpy {expected:.7f} diff {abs(onnx[0] - expected):.2e} self {same}")
        failed |= not good
    # A batch of (x, y) and (y, x): one value each, equal (LPIPS is symmetric).
    x, y = (v.astype(np.float32) for v in pairs["random 64x64"])
    batch = session.run(["lpips"], {"image0": np.stack([x, y]), "image1": np.stack([y, x])})[0]
    if batch.shape != (2,) or abs(batch[0] - batch[1]) > 1e-6:
        print(f"FAIL batch of (x, y) and (y, x): {batch}")
        failed = True
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
