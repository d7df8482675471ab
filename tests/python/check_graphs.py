"""Check a nerf-rs scene bundle's ONNX graphs with the onnx package and onnxruntime.

usage: check_graphs.py <bundle-dir> [--reference reference.json]

For every graph named in scene.json: onnx.checker (full_check), strict shape inference, the
documented contract (inputs points/viewdirs [N,3], outputs rgb [N,3] and sigma [N,1], float32,
N dynamic, metadata and doc strings present), and a run in onnxruntime on a batch (and an empty
batch) with rgb in [0, 1] and sigma >= 0. With --reference (written by the Rust tests from the
plain network's reference forward pass), the outputs must match it to 1e-5.
Prints one line per graph with its size; exits non-zero on the first failure.
"""
import json
import os
import sys

import numpy as np
import onnx
import onnxruntime as ort


def fail(msg):
    print(f"FAIL: {msg}", file=sys.stderr)
    sys.exit(1)


def dims(value_info):
    return [d.dim_param or d.dim_value for d in value_info.type.tensor_type.shape.dim]


def check_graph(path, reference):
    model = onnx.load(path)
    onnx.checker.check_model(model, full_check=True)
    inferred = onnx.shape_inference.infer_shapes(model, strict_mode=True)
    graph = inferred.graph
    inputs = {i.name: i for i in graph.input}
    outputs = {o.name: o for o in graph.output}
    if list(inputs) != ["points", "viewdirs"] or list(outputs) != ["rgb", "sigma"]:
        fail(f"{path}: inputs {list(inputs)}, outputs {list(outputs)}")
    for name, want in [("points", ["N", 3]), ("viewdirs", ["N", 3]), ("rgb", ["N", 3]), ("sigma", ["N", 1])]:
        v = inputs.get(name) or outputs.get(name)
        if dims(v) != want or v.type.tensor_type.elem_type != onnx.TensorProto.FLOAT or not v.doc_string:
            fail(f"{path}: {name} has dims {dims(v)}, type {v.type.tensor_type.elem_type}, doc {v.doc_string!r}")
    meta = {p.key: p.value for p in model.metadata_props}
    for key in ["nerf.contract", "nerf.network", "nerf.near", "nerf.far", "nerf.n_coarse", "nerf.n_fine", "nerf.stage"]:
        if key not in meta:
            fail(f"{path}: metadata {key} missing")
    if not graph.doc_string or model.opset_import[0].version < 17:
        fail(f"{path}: graph doc string or opset missing")
    names = [t.name for t in graph.initializer]
    if len(names) != len(set(names)):
        fail(f"{path}: duplicated initializers")
    ops = {n.op_type for n in graph.node}
    if not {"Sin", "Cos"} <= ops:
        fail(f"{path}: the encoding is not in the graph (ops {sorted(ops)})")

    session = ort.InferenceSession(path, providers=["CPUExecutionProvider"])
    rng = np.random.default_rng(0)
    points = rng.uniform(-1.5, 1.5, (4096, 3)).astype(np.float32)
    dirs = rng.normal(size=(4096, 3)).astype(np.float32)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    rgb, sigma = session.run(["rgb", "sigma"], {"points": points, "viewdirs": dirs})
    if rgb.shape != (4096, 3) or sigma.shape != (4096, 1):
        fail(f"{path}: output shapes {rgb.shape} {sigma.shape}")
    if rgb.min() < 0 or rgb.max() > 1 or sigma.min() < 0 or not np.isfinite(sigma).all():
        fail(f"{path}: rgb outside [0, 1] or sigma negative")
    rgb0, sigma0 = session.run(["rgb", "sigma"], {"points": points[:0], "viewdirs": dirs[:0]})
    if rgb0.shape != (0, 3) or sigma0.shape != (0, 1):
        fail(f"{path}: empty batch gives {rgb0.shape} {sigma0.shape}")

    detail = ""
    if reference is not None:
        p = np.asarray(reference["points"], np.float32).reshape(-1, 3)
        d = np.asarray(reference["viewdirs"], np.float32).reshape(-1, 3)
        rgb, sigma = session.run(["rgb", "sigma"], {"points": p, "viewdirs": d})
        want_rgb = np.asarray(reference["rgb"], np.float32).reshape(-1, 3)
        want_sigma = np.maximum(np.asarray(reference["raw_sigma"], np.float32).reshape(-1, 1), 0)
        diff = max(np.abs(rgb - want_rgb).max(), np.abs(sigma - want_sigma).max() / max(1.0, np.abs(want_sigma).max()))
        if not diff <= 1e-5:
            fail(f"{path}: differs from the reference forward pass by {diff}")
        detail = f", max diff vs reference {diff:.2e} over {len(p)} points"
    print(f"ok {path}: {os.path.getsize(path)} bytes, {len(graph.node)} nodes, "
          f"{sum(int(np.prod(t.dims)) for t in graph.initializer if t.data_type == onnx.TensorProto.FLOAT)} weights{detail}")


def main():
    args = sys.argv[1:]
    if not args:
        fail(__doc__)
    bundle = args[0]
    references = {}
    if "--reference" in args:
        with open(args[args.index("--reference") + 1]) as f:
            references = json.load(f)
    with open(os.path.join(bundle, "scene.json")) as f:
        scene = json.load(f)
    # Graphs by role ("graphs"), or nerf-rs-scene-1's "networks".
    for stage, file in (scene.get("graphs") or scene["networks"]).items():
        if file is not None:
            check_graph(os.path.join(bundle, file), references.get(stage))


if __name__ == "__main__":
    main()
