"""Check a hash-grid encodings graph written by nerf-export (`compile_encodings`).

usage: check_hash_grid.py <graph.onnx> <reference.json>

onnx.checker (full_check), strict shape inference (features [N, L*F], sh [N, 16]), the
expected operators (BitwiseXor/BitwiseAnd, or none of them when reference["bitwise"] is
false), an empty batch, and onnxruntime's outputs against the Rust encoding's (reference.json:
points, viewdirs, features, sh) to reference["tolerance"]. Prints one line; exits non-zero on
the first failure.
"""
import json
import sys

import numpy as np
import onnx
import onnxruntime as ort


def fail(msg):
    print(f"FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def main():
    if len(sys.argv) != 3:
        fail(__doc__)
    path, ref_path = sys.argv[1:]
    with open(ref_path) as f:
        ref = json.load(f)
    width = ref["width"]
    model = onnx.load(path)
    onnx.checker.check_model(model, full_check=True)
    graph = onnx.shape_inference.infer_shapes(model, strict_mode=True).graph
    dims = {v.name: [d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim] for v in list(graph.input) + list(graph.output)}
    want = {"points": ["N", 3], "viewdirs": ["N", 3], "features": ["N", width], "sh": ["N", 16]}
    if dims != want:
        fail(f"{path}: inputs/outputs {dims}, expected {want}")
    ops = {n.op_type for n in graph.node}
    bitwise = {"BitwiseXor", "BitwiseAnd"}
    if ref["bitwise"] and not bitwise <= ops:
        fail(f"{path}: no bitwise operators in {sorted(ops)}")
    if not ref["bitwise"] and ops & bitwise:
        fail(f"{path}: the arithmetic lowering uses {sorted(ops & bitwise)}")

    session = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    points = np.asarray(ref["points"], np.float32).reshape(-1, 3)
    dirs = np.asarray(ref["viewdirs"], np.float32).reshape(-1, 3)
    features, sh = session.run(["features", "sh"], {"points": points, "viewdirs": dirs})
    want_features = np.asarray(ref["features"], np.float32).reshape(-1, width)
    want_sh = np.asarray(ref["sh"], np.float32).reshape(-1, 16)
    if features.shape != want_features.shape or sh.shape != want_sh.shape:
        fail(f"{path}: shapes {features.shape} {sh.shape}")
    d_features = float(np.abs(features - want_features).max())
    d_sh = float(np.abs(sh - want_sh).max())
    scale = float(np.abs(want_features).max())
    if not (d_features <= ref["tolerance"] and d_sh <= ref["tolerance"]):
        fail(f"{path}: max |Δfeatures| {d_features}, |Δsh| {d_sh} > {ref['tolerance']}")
    if scale < 0.1:
        fail(f"{path}: features only reach {scale}: the comparison would be lenient")
    f0, s0 = session.run(["features", "sh"], {"points": points[:0], "viewdirs": dirs[:0]})
    if f0.shape != (0, width) or s0.shape != (0, 16):
        fail(f"{path}: empty batch gives {f0.shape} {s0.shape}")
    print(f"ok {path}: {len(graph.node)} nodes, {len(points)} points, max |Δfeatures| {d_features:.2e} "
          f"(features up to {scale:.3f}), max |Δsh| {d_sh:.2e}")


if __name__ == "__main__":
    main()
