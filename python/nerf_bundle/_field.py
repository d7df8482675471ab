"""One bundle graph as onnxruntime sessions (``runtime/src/network.rs``): a call is split
across ``workers`` sessions with one intra-op thread each, every session evaluating pieces of
at most ``points_per_run`` points, run side by side from a thread pool (onnxruntime releases
the GIL). On a GPU (``device="cuda"``), one session of onnxruntime's CUDA provider evaluates
pieces of ``GPU_POINTS_PER_RUN`` points."""
from __future__ import annotations

import re
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable, List, Optional, Sequence, Tuple

import numpy as np

from . import _native
from ._limits import POINTS_PER_RUN
from ._onnx import check_graph_bytes, op_types
from ._validate import BundleError

F32 = np.float32
MIN_POINTS_PER_WORKER = 256
#: Points per session run on a GPU unless told otherwise: a GPU wants large batches.
GPU_POINTS_PER_RUN = 1 << 21
#: How to get onnxruntime's CUDA build (errors name it).
HOW_TO_INSTALL_GPU = ("pip install onnxruntime-gpu==1.31.1 (the CUDA 13 build; in place of onnxruntime, which has the same "
                      "module name), or `bash scripts/setup.sh --gpu`, which installs it into $NERF_HOME/venv-gpu "
                      "(~/.cache/nerf-rs/venv-gpu): run $NERF_HOME/venv-gpu/bin/python")


def parse_device(device: str) -> Optional[int]:
    """``"cpu"`` → None, ``"cuda"`` → 0, ``"cuda:N"`` → N; ValueError otherwise."""
    if device == "cpu":
        return None
    m = re.fullmatch(r"cuda(?::([0-9]{1,9}))?", device) if isinstance(device, str) else None
    if m is None:
        raise ValueError(f"unknown device {device!r}: expected cpu, cuda or cuda:N (N a GPU index: 0, 1, …)")
    return int(m.group(1) or 0)


def cuda_providers(gpu: int) -> List[Any]:
    """onnxruntime's CUDA provider on GPU ``gpu`` with TF32 off (TF32 matmuls move the field
    by up to 6e-3 from the CPU's; without, 2e-7); BundleError when the installed onnxruntime
    has no CUDA provider (the CPU wheel)."""
    import onnxruntime as ort

    available = ort.get_available_providers()
    if "CUDAExecutionProvider" not in available:
        raise BundleError(f"device cuda:{gpu}: the installed onnxruntime {ort.__version__} has no CUDAExecutionProvider "
                          f"(it has {', '.join(available)}): {HOW_TO_INSTALL_GPU}")
    return [("CUDAExecutionProvider", {"device_id": gpu, "use_tf32": 0})]


class Graph:
    """A graph of the contract: ``points``, ``viewdirs`` [N, 3] in; ``rgb`` [N, 3], ``sigma``
    [N, 1] out."""

    def __init__(self, path: str, workers: int, providers: Optional[Sequence] = None,
                 points_per_run: int = POINTS_PER_RUN, gpu: Optional[int] = None, whole_graph: bool = False) -> None:
        import onnxruntime as ort

        self.path = path
        self.points_per_run = max(1, points_per_run)
        self.seconds = 0.0  # wall time inside evaluate (onnxruntime and the split/join)
        self.evaluated = 0
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        if gpu is not None:
            providers, workers = cuda_providers(gpu), 1
        providers = list(providers) if providers else ["CPUExecutionProvider"]
        try:
            with open(path, "rb") as f:
                model = f.read()
        except OSError as e:
            raise BundleError(f"{path}: cannot read the graph: {e.strerror}") from None
        # Before onnxruntime sees it: it would follow external data out of the bundle.
        check_graph_bytes(path, model)
        if gpu is not None and "BitwiseXor" in op_types(model):
            # onnxruntime's CUDA provider has no BitwiseXor kernel (measured on an H200: a
            # 400×400 lego-ngp frame's field 0.90 s bitwise, 0.09 s portable).
            warnings.warn(f"{path}: the bitwise lowering's BitwiseXor nodes run on the CPU, with copies to and from GPU "
                          f"{gpu}; `nerf export --bundle <this bundle> --portable --out <dir>` makes one that runs wholly "
                          "on the GPU, with the same pixels", stacklevel=3)
        #: A hash-grid graph on onnxruntime's CPU provider, split as nerf-render splits it
        #: (``HashEncoder`` of :mod:`_native`, where the native module is installed and
        #: ``whole_graph`` is not asked; it checks the whole graph's contract): the encodings in
        #: Rust, the head in the sessions; None: the sessions run the whole graph.
        self.encoder = _native.hash_encoder(path, model) if providers == ["CPUExecutionProvider"] and not whole_graph else None
        if self.encoder is not None:
            model = self.encoder.head
        # On a GPU, an error rather than onnxruntime's fall-back to the CPU (at load or run).
        strict = {"enable_fallback": 0} if gpu is not None else {}
        try:
            first = ort.InferenceSession(model, opts, providers=providers, **strict)
        except Exception as e:  # onnxruntime raises its own exception types
            if gpu is not None:
                raise BundleError(f"{path}: cannot create a CUDA session on GPU {gpu} (onnxruntime: {e}); "
                                  "is there a GPU, with the CUDA 13 libraries onnxruntime-gpu needs?") from None
            raise BundleError(f"{path}: cannot load the graph (truncated, not an ONNX model, or not following the graph "
                              f"contract: inputs points, viewdirs [N, 3]; outputs rgb [N, 3], sigma [N, 1]): {e}") from None
        # onnxruntime falls back to the CPU quietly when the CUDA provider cannot start.
        if gpu is not None and first.get_providers()[:1] != ["CUDAExecutionProvider"]:
            raise BundleError(f"{path}: onnxruntime did not start its CUDA provider on GPU {gpu} (the session has "
                              f"{', '.join(first.get_providers())}; its log says why): is there a GPU, with the CUDA 13 "
                              "libraries onnxruntime-gpu needs?")
        self.gpu = gpu
        inputs = sorted(i.name for i in first.get_inputs())
        outputs = sorted(o.name for o in first.get_outputs())
        expected = ["points", "viewdirs"] if self.encoder is None else sorted([self.encoder.FEATURES, self.encoder.SH])
        if inputs != expected or not {"rgb", "sigma"} <= set(outputs):
            raise BundleError(f"{path}: inputs {inputs} and outputs {outputs} break the graph contract "
                              "(inputs points, viewdirs [N, 3]; outputs rgb [N, 3], sigma [N, 1])")
        self.sessions = [first] + [ort.InferenceSession(model, opts, providers=providers, **strict) for _ in range(workers - 1)]
        self.pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="nerf-bundle") if workers > 1 else None
        self._lock = threading.Lock()

    def _run_part(self, k: int, points: np.ndarray, viewdirs: np.ndarray, rgb: np.ndarray, sigma: np.ndarray) -> None:
        session, piece = self.sessions[k], self.points_per_run
        if self.encoder is not None and len(points):
            features, sh = self.encoder.encode(points, viewdirs)
        for s in range(0, len(points), piece):
            e = min(s + piece, len(points))
            if self.encoder is not None:
                inputs = {self.encoder.FEATURES: features[s:e], self.encoder.SH: sh[s:e]}
            else:
                inputs = {"points": points[s:e], "viewdirs": viewdirs[s:e]}
            try:
                out_rgb, out_sigma = session.run(["rgb", "sigma"], inputs)
            except Exception as err:  # onnxruntime's own types; on a CPU its errors are bugs, left as they are
                if self.gpu is None:
                    raise
                raise BundleError(f"{self.path}: onnxruntime failed on GPU {self.gpu} ({e - s} points): {err}") from None
            rgb[s:e] = out_rgb
            sigma[s:e] = np.asarray(out_sigma).reshape(-1)

    def on_session(self, k: int) -> Callable[[np.ndarray, np.ndarray], Tuple[np.ndarray, np.ndarray]]:
        """The graph evaluated by session ``k`` alone, in the calling thread: for loops run side
        by side, one per session (:attr:`seconds` then sums their calls)."""
        def evaluate(points: np.ndarray, viewdirs: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
            start = time.perf_counter()
            points = np.ascontiguousarray(points, F32)
            viewdirs = np.ascontiguousarray(viewdirs, F32)
            rgb = np.empty((len(points), 3), F32)
            sigma = np.empty(len(points), F32)
            self._run_part(k, points, viewdirs, rgb, sigma)
            with self._lock:
                self.seconds += time.perf_counter() - start
                self.evaluated += len(points)
            return rgb, sigma
        return evaluate

    def __call__(self, points: np.ndarray, viewdirs: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """rgb [N, 3] and sigma [N] (float32) at ``points`` seen along unit ``viewdirs``."""
        start = time.perf_counter()
        n = len(points)
        points = np.ascontiguousarray(points, F32)
        viewdirs = np.ascontiguousarray(viewdirs, F32)
        rgb = np.empty((n, 3), F32)
        sigma = np.empty(n, F32)
        workers = min(len(self.sessions), max(1, n // MIN_POINTS_PER_WORKER))
        if n == 0:
            pass
        elif workers == 1 or self.pool is None:
            self._run_part(0, points, viewdirs, rgb, sigma)
        else:
            bounds = [n * k // workers for k in range(workers + 1)]
            futures = [self.pool.submit(self._run_part, k, points[a:b], viewdirs[a:b], rgb[a:b], sigma[a:b])
                       for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:]))]
            for f in futures:
                f.result()
        with self._lock:
            self.seconds += time.perf_counter() - start
            self.evaluated += n
        return rgb, sigma
