"""Check a hash-grid graph written by nerf-export (the encodings graph or a whole field).

usage: check_hash_grid.py <graph.onnx> <reference.json>

reference.json (written by the Rust tests from the Rust/burn evaluation):
  {"inputs": {name: [[...], ...]}, "outputs": {name: {"values": [[...]], "relative": bool,
   "min_scale": float}}, "tolerance": float, "bitwise": bool}

Checks onnx.checker (full_check), strict shape inference (every input and output [N, cols]
with N dynamic), the operators (BitwiseXor present when "bitwise"; otherwise no bitwise operator
and no int64 data), an empty batch, and onnxruntime's outputs against the reference: max |Δ| ≤
tolerance (divided by max(1, |reference|) per value when "relative"), and max |reference| ≥
min_scale so that the comparison is not lenient. Prints one line; exits non-zero on failure.
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
    inputs = {k: np.asarray(v, np.float32) for k, v in ref["inputs"].items()}
    outputs = {k: (np.asarray(v["values"], np.float32), v) for k, v in ref["outputs"].items()}

    model = onnx.load(path)
    onnx.checker.check_model(model, full_check=True)
    graph = onnx.shape_inference.infer_shapes(model, strict_mode=True).graph
    dims = {v.name: [d.dim_param or d.dim_value for d in v.type.tensor_type.shape.dim] for v in list(graph.input) + list(graph.output)}
    want = {k: ["N", v.shape[1]] for k, v in inputs.items()}
    want.update({k: ["N", v.shape[1]] for k, (v, _) in outputs.items()})
    if dims != want:
        fail(f"{path}: inputs/outputs {dims}, expected {want}")
    ops = {n.op_type for n in graph.node}
    bitwise = {"BitwiseXor", "BitwiseAnd"}
    if ref["bitwise"] and not ops & bitwise:
        fail(f"{path}: no bitwise operators in {sorted(ops)}")
    if not ref["bitwise"] and ops & bitwise:
        fail(f"{path}: the bitwise-free lowering uses {sorted(ops & bitwise)}")
    if not ref["bitwise"]:
        # No int64 data: int64 only in the small shape/axis constants Slice, Unsqueeze and Reshape read.
        for t in graph.initializer:
            if t.data_type == onnx.TensorProto.INT64 and (len(t.dims) != 1 or t.dims[0] > 3):
                fail(f"{path}: the portable lowering holds int64 data {t.name} {list(t.dims)}")
        for n in graph.node:
            if n.op_type == "Cast" and any(a.name == "to" and a.i == onnx.TensorProto.INT64 for a in n.attribute):
                fail(f"{path}: the portable lowering casts to int64 ({n.name})")

    session = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    names = list(outputs)
    got = dict(zip(names, session.run(names, inputs)))
    report = []
    for name, (want_values, spec) in outputs.items():
        if got[name].shape != want_values.shape:
            fail(f"{path}: {name} has shape {got[name].shape}, expected {want_values.shape}")
        diff = np.abs(got[name] - want_values)
        if spec.get("relative"):
            diff = diff / np.maximum(1.0, np.abs(want_values))
        diff = float(diff.max())
        scale = float(np.abs(want_values).max())
        if not diff <= ref["tolerance"]:
            fail(f"{path}: {name} differs by {diff} > {ref['tolerance']}")
        if scale < spec.get("min_scale", 0.0):
            fail(f"{path}: {name} only reaches {scale} < {spec['min_scale']}: the comparison would be lenient")
        report.append(f"{name} max |Δ| {diff:.2e} (up to {scale:.3g})")
    empty = session.run(names, {k: v[:0] for k, v in inputs.items()})
    if [e.shape for e in empty] != [(0, outputs[n][0].shape[1]) for n in names]:
        fail(f"{path}: empty batch gives {[e.shape for e in empty]}")
    n = len(next(iter(inputs.values())))
    print(f"ok {path}: {len(graph.node)} nodes, {n} points, " + ", ".join(report))


if __name__ == "__main__":
    main()
