"""``Bundle``: open a scene bundle, render frames, rays and raw field values."""
from __future__ import annotations

import os
import time
import warnings
from dataclasses import dataclass
from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np

from . import _gpu, _native
from . import _render as R
from ._field import GPU_POINTS_PER_RUN, Graph, parse_device
from ._limits import (DEFAULT_CHUNK, DEFAULT_MARCH_STEPS, MAX_FRAMES, MAX_FRAME_PIXELS, MAX_GRAPH_BYTES, MAX_IMAGE_SIDE,
                      MAX_POINTS_PER_CALL, MAX_THREADS, POINTS_PER_RUN)
from ._validate import (CONTRACTED_BOUND, bounded_file, bundle_file, check_chunk, check_count, check_grid_matches, check_pose,
                        contraction_of, graph_files, is_bounded, read_grid, read_scene)
from .camera import Camera, ndc_rays, reference_orbit

F32 = np.float32
#: Rays per batch on a GPU unless told otherwise (nerf-render's ``GPU_CHUNK``): a 400×400 frame
#: marches in one batch.
GPU_CHUNK = 262_144


def _joined(parts: List[R.Marched]) -> R.Marched:
    """Batches' results one after the other."""
    if not parts:
        return R.Marched(np.zeros((0, 3), F32), np.zeros(0, F32), np.zeros(0, F32), None)
    return R.Marched(np.concatenate([p.rgb for p in parts]), np.concatenate([p.depth for p in parts]),
                     np.concatenate([p.acc for p in parts]), None)


@dataclass
class Frame:
    """A rendered view: ``rgb`` [H, W, 3], ``depth`` [H, W], ``acc`` [H, W], float32."""

    rgb: np.ndarray
    depth: np.ndarray
    acc: np.ndarray
    #: Wall seconds of the frame, and of its onnxruntime calls (with loops side by side, each
    #: loop's on average).
    seconds: float = 0.0
    field_seconds: float = 0.0
    stages: Optional[R.Stages] = None

    @property
    def raw(self) -> np.ndarray:
        """float32 [H, W, 5] = r, g, b, depth, acc (what ``nerf-render --npy`` writes)."""
        return np.concatenate([self.rgb, self.depth[..., None], self.acc[..., None]], axis=2).astype(F32)

    def to_uint8(self) -> np.ndarray:
        """rgb quantised as nerf-render's PNGs: clamp to [0, 1], ×255, round."""
        return np.round(np.clip(self.rgb, 0, 1) * F32(255)).astype(np.uint8)

    def to_pil(self) -> Any:
        """The colour image as a ``PIL.Image`` (needs Pillow: ``pip install nerf_bundle[images]``)."""
        try:
            from PIL import Image
        except ImportError:
            raise ImportError("Frame.to_pil needs Pillow: pip install 'nerf_bundle[images]' (or pip install Pillow)") from None
        return Image.fromarray(self.to_uint8(), "RGB")

    def _repr_png_(self) -> Optional[bytes]:
        try:
            img = self.to_pil()
        except ImportError:
            return None
        import io

        buf = io.BytesIO()
        img.save(buf, format="PNG")
        return buf.getvalue()


@dataclass
class Rays:
    """Per-ray results: ``rgb`` [N, 3], ``depth`` [N], ``acc`` [N] float32."""

    rgb: np.ndarray
    depth: np.ndarray
    acc: np.ndarray


class Bundle:
    """A scene bundle opened for rendering. Use :meth:`Bundle.open`."""

    def __init__(self, path: str, scene: Dict[str, Any], graphs: Dict[str, Graph], grid: Optional[R.Grid],
                 skip_empty_space: bool) -> None:
        self.path = path
        self.scene = scene
        self.graphs = graphs
        self.grid = grid
        self.skip_empty_space = skip_empty_space
        self.device = "cpu"
        self.camera = Camera.from_scene(scene["camera"])
        s = scene["sampling"]
        self.near, self.far = F32(s["near"]), F32(s["far"])
        self.n_coarse, self.n_fine, self.lindisp = int(s["n_coarse"]), int(s["n_fine"]), bool(s.get("lindisp", False))
        self.ndc = s.get("ndc")
        self.march_steps = int(scene.get("march_steps", DEFAULT_MARCH_STEPS))
        self.white_background = bool(scene["white_background"])
        self._gpu_loop: Optional[_gpu.GpuLoop] = None
        #: The marching loop on the CPU: "native" (nerf-core's, in Rust: :mod:`_native`) or
        #: "numpy" (:func:`_render.march_grid`, loops side by side).
        self.loop = "native" if _native.available() else "numpy"

    @classmethod
    def open(cls, path: "str | os.PathLike[str]", *, providers: Optional[Sequence[Any]] = None, threads: Optional[int] = None,
             skip_empty_space: bool = True, points_per_run: Optional[int] = None, device: Optional[str] = None,
             loop: Optional[str] = None, whole_graph: bool = False) -> "Bundle":
        """Open and check the bundle at ``path`` as nerf-render does (limits of untrusted bundles,
        file names inside the bundle, the graph contract); raises :class:`BundleError` naming
        the file and the problem.

        ``device``: ``"cpu"`` (the default) or ``"cuda"`` / ``"cuda:N"``: onnxruntime's CUDA
        provider on GPU N with TF32 off, one session per graph on pieces of ``points_per_run``
        (default 2**21) points, in batches of up to 262,144 rays; with CuPy installed
        (``cupy-cuda13x``) the marching and compositing run on the GPU too (``_gpu``: the same
        samples, one field call per round through IO binding), without it (or where its
        kernels cannot start) in numpy on the CPU, with a warning; BundleError when the
        installed onnxruntime has no CUDA provider (the CPU
        wheel: ``pip install onnxruntime-gpu==1.31.1``) or the session cannot start on the GPU,
        never a quiet fall-back to the CPU. ``providers``: onnxruntime execution providers for
        the CPU path (default CPU); with ``device`` a ValueError (say one or the other).
        ``threads``: onnxruntime sessions per graph run side by side (default
        ``os.cpu_count()``; on a GPU one), each with one intra-op thread on pieces of
        ``points_per_run`` points (default 2,048); the numpy loop runs one loop per session
        (:meth:`_march_side_by_side`), the native one a loop whose calls the sessions split. ``skip_empty_space=False`` ignores
        occupancy.bin (nerf-render ``--dense``). ``loop``: the marching loop on the CPU,
        ``"native"`` (nerf-core's, in Rust: ``nerf_bundle_native``, which ``scripts/setup.sh``
        builds; ValueError where it is not installed) or ``"numpy"``; by default native where
        installed. Both take the same samples and make the same field calls; their pixels agree
        to float32 rounding (nerf-render's are the native loop's). With the native module, a
        hash-grid graph on the CPU provider is split as nerf-render splits it: the hash grid and
        the harmonics in Rust, the rest of the graph in onnxruntime (its ``Gather`` of the
        table's rows is most of the whole graph's time); ``whole_graph=True`` runs it whole
        (``nerf-render --whole-graph``)."""
        path = os.fspath(path)
        if loop not in (None, "native", "numpy"):
            raise ValueError(f"loop={loop!r}: expected \"native\" or \"numpy\"")
        if loop == "native" and not _native.available():
            raise ValueError(f"loop=\"native\": the native loop (nerf_bundle_native) is not installed: {_native.HOW_TO_BUILD}")
        gpu = parse_device(device) if device is not None else None
        if device is not None and providers is not None:
            raise ValueError(f"device={device!r} and providers=...: pass one of them (device picks the providers)")
        if gpu is not None and threads not in (None, 1):
            raise ValueError(f"threads: {threads!r} sessions per graph; on a GPU one session runs each graph (leave threads out)")
        if points_per_run is None:
            points_per_run = GPU_POINTS_PER_RUN if gpu is not None else POINTS_PER_RUN
        workers = 1 if gpu is not None else check_count(threads if threads is not None else (os.cpu_count() or 1), MAX_THREADS, "threads", "threads")
        points_per_run = check_count(points_per_run, MAX_POINTS_PER_CALL, "points_per_run", "points")
        scene = read_scene(path)
        graphs: Dict[str, Graph] = {}
        for role, (key, name) in graph_files(scene).items():
            file = bounded_file(bundle_file(path, name, key), MAX_GRAPH_BYTES, key)
            graphs[role] = Graph(file, workers, providers, points_per_run, gpu, whole_graph)
        occ = scene.get("occupancy")
        grid = None
        contraction = contraction_of(scene)
        if occ and skip_empty_space:
            file = bounded_file(bundle_file(path, occ["file"], "occupancy.file"), MAX_GRAPH_BYTES, "occupancy.file")
            density, bound, threshold, grid_contraction = read_grid(file)
            check_grid_matches(os.path.join(path, "scene.json"), scene, file, density.shape[0], bound, grid_contraction)
            grid = R.Grid((density > threshold).reshape(-1), density.shape[0], bound, contraction)
        elif is_bounded(scene):
            # One occupied cell over the field's box (``marching_grid``): a contracted field's is the whole world.
            box = CONTRACTED_BOUND if contraction is not None else F32(occ["bound"])
            grid = R.Grid(np.ones(1, bool), 1, box, contraction)
        bundle = cls(path, scene, graphs, grid, skip_empty_space)
        if loop is not None:
            bundle.loop = loop
        if gpu is not None:
            bundle.device = f"cuda:{gpu}"
            cupy = _gpu.cupy_or_none() if grid is not None and grid.contraction is None else None
            why = "CuPy is not installed (pip install cupy-cuda13x, or `bash scripts/setup.sh --gpu`)"
            if grid is not None and grid.contraction is not None:
                why = "the GPU loop does not march contracted grids yet"
            if cupy is not None:
                try:
                    bundle._gpu_loop = _gpu.GpuLoop(cupy, gpu, grid)
                except Exception as e:  # CuPy's compile and CUDA errors
                    why = f"the GPU loop's kernels cannot start ({e})"
            if grid is not None and bundle._gpu_loop is None:
                warnings.warn(f"{path}: {why}: the loop around the field runs on the CPU ({bundle.loop}), most of a GPU frame's time",
                              stacklevel=2)
        for split in ("test", "orbit"):
            bundle.poses(split)  # non-finite or malformed poses are refused now
        return bundle

    # -- description ---------------------------------------------------------------------------

    @property
    def field_kind(self) -> str:
        """"ngp" for a hash-grid field (one ``field`` graph), "mlp" for NeRF MLPs."""
        return str(self.scene.get("field", "ngp" if "field" in self.graphs else "mlp"))

    def poses(self, split: str = "test") -> List[np.ndarray]:
        """The bundle's camera-to-world poses, [4, 4] float32 each: ``"test"`` or ``"orbit"``."""
        where = os.path.join(self.path, "scene.json")
        if split == "test":
            return [check_pose(p["transform_matrix"], where, f"poses.test[{k}]") for k, p in enumerate(self.scene["poses"]["test"])]
        if split == "orbit":
            return [check_pose(p, where, f"poses.orbit[{k}]") for k, p in enumerate(self.scene["poses"]["orbit"])]
        raise ValueError(f"split must be 'test' or 'orbit', not {split!r}")

    def pose_names(self, split: str = "test") -> List[str]:
        """File names nerf-render gives the views: test poses by their ``name`` (r_0, ...),
        orbit frames frame_000, ..."""
        if split == "test":
            return [p["name"] for p in self.scene["poses"]["test"]]
        return [f"frame_{k:03}" for k in range(len(self.scene["poses"]["orbit"]))]

    def orbit(self, frames: Optional[int] = None) -> List[np.ndarray]:
        """The orbit: the bundle's own, or ``frames`` poses of the reference orbit (radius 4,
        elevation −30°) when another count is asked for."""
        own = self.poses("orbit")
        if frames is None or frames == len(own):
            return own
        check_count(frames, MAX_FRAMES, "frames", "frames")
        if self.scene.get("placement") and self.scene["placement"].get("orbit"):
            raise NotImplementedError("another frame count along a capture's recorded camera path is not supported; use nerf-render")
        return reference_orbit(frames)

    def camera_at(self, width: Optional[int] = None, height: Optional[int] = None) -> Camera:
        """The bundle's camera, resized as nerf-render's ``--width``/``--height``."""
        if width is None:
            if height is not None:
                raise ValueError("height needs width")
            return self.camera
        h = height if height is not None else (int(width) * self.camera.height + self.camera.width // 2) // self.camera.width
        if not (0 < width <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE and width * h <= MAX_FRAME_PIXELS):
            raise ValueError(f"width/height: {width}×{h} pixels is outside the limits ({MAX_IMAGE_SIDE} per side, {MAX_FRAME_PIXELS} per frame)")
        return self.camera.resized(width, h)

    # -- evaluation ----------------------------------------------------------------------------

    def _graph(self, stage: str) -> Graph:
        if "field" in self.graphs:
            return self.graphs["field"]
        if stage == "fine" and "fine" in self.graphs:
            return self.graphs["fine"]
        return self.graphs["coarse"]

    def field(self, points: np.ndarray, viewdirs: np.ndarray, *, stage: str = "fine") -> Tuple[np.ndarray, np.ndarray]:
        """Raw network outputs at ``points`` [N, 3] seen along unit ``viewdirs`` [N, 3]:
        (rgb [N, 3], sigma [N]) float32. ``stage`` picks "coarse" or "fine" for MLP bundles."""
        points = np.asarray(points, F32).reshape(-1, 3)
        viewdirs = np.asarray(viewdirs, F32).reshape(-1, 3)
        if len(points) != len(viewdirs):
            raise ValueError(f"{len(points)} points but {len(viewdirs)} viewdirs")
        return self._graph(stage)(points, viewdirs)

    @property
    def field_seconds(self) -> float:
        """Wall time spent in onnxruntime calls so far (all graphs)."""
        return sum(g.seconds for g in self.graphs.values())

    @property
    def samples_per_ray(self) -> int:
        """The most samples one ray sends to the field in one call: marching's MARCH_SEGMENT, or
        n_coarse + n_fine on the dense path (nerf-render's chunk limit)."""
        return R.MARCH_SEGMENT if self.grid is not None else self.n_coarse + self.n_fine

    @property
    def default_chunk(self) -> int:
        """Rays per batch unless told otherwise (nerf-render's ``default_chunk``): DEFAULT_CHUNK
        on the CPU, GPU_CHUNK on a GPU (a GPU wants large batches), fewer when a batch's samples
        would pass the points limit."""
        rays = DEFAULT_CHUNK if self.device == "cpu" else GPU_CHUNK
        return max(1, min(rays, MAX_POINTS_PER_CALL // max(self.samples_per_ray, 1)))

    def check_chunk(self, chunk: Optional[int], what: str = "chunk") -> int:
        """``chunk`` rays per batch (None: :attr:`default_chunk`) within the limits (ValueError
        naming ``what`` otherwise)."""
        return self.default_chunk if chunk is None else check_chunk(chunk, self.samples_per_ray, what)

    def _render_batch(self, o: np.ndarray, d: np.ndarray, view: np.ndarray, chunk: int, stages: R.Stages) -> R.Marched:
        """nerf-render's ``render_rays`` for (already NDC-warped) rays, ``chunk`` rays per batch:
        marched all together (each chunk's field calls as nerf-render makes them), or dense a
        chunk at a time."""
        min_t = float(R.MIN_TRANSMITTANCE) if self.skip_empty_space else None
        if self.grid is not None and self._gpu_loop is None and self.loop == "native":
            graph = self._graph("fine" if self.n_fine > 0 else "coarse")
            return _native.march_grid(graph, self.grid, o, d, view, self.near, self.far, max(self.march_steps, 1), min_t,
                                      self.white_background, chunk, stages)
        viewdirs = R.unit(view)
        if self.grid is not None:
            stage = "fine" if self.n_fine > 0 else "coarse"
            if self._gpu_loop is not None:
                return _joined([self._gpu_loop.march_grid(self._graph(stage), o[s:s + chunk], d[s:s + chunk], viewdirs[s:s + chunk],
                                                          self.near, self.far, max(self.march_steps, 1), min_t,
                                                          self.white_background, stages) for s in range(0, len(o), chunk)])
            return self._march_side_by_side(self._graph(stage), o, d, viewdirs, chunk, min_t, stages)
        return _joined([self._render_dense(o[s:s + chunk], d[s:s + chunk], viewdirs[s:s + chunk], min_t) for s in range(0, len(o), chunk)])

    def _march_side_by_side(self, graph: Graph, o: np.ndarray, d: np.ndarray, viewdirs: np.ndarray, chunk: int,
                            min_t: Optional[float], stages: R.Stages) -> R.Marched:
        """:func:`_render.march_grid` on the CPU as one loop per session of ``graph``, side by
        side: the rays' chunks dealt out in turn (so each loop gets rays from all over the
        frame), each loop marching, evaluating on its own session and compositing while the
        others' sessions evaluate (onnxruntime lets go of the GIL; the loops' numpy work, on
        arrays of some thousands of elements, holds it, so it overlaps the other loops'
        evaluation rather than their numpy work). A point's output does not depend on the others
        in its call, so the pixels are those of one loop. ``stages`` gets the loops' mean."""
        assert self.grid is not None
        n = len(o)
        loops = min(len(graph.sessions), -(-n // chunk))  # on a GPU one session: one loop
        steps = max(self.march_steps, 1)
        if loops <= 1:
            return R.march_grid(graph, self.grid, o, d, viewdirs, self.near, self.far, steps, min_t, self.white_background, chunk,
                                stages)
        assert graph.pool is not None
        deal = (np.arange(n) // chunk) % loops
        shares = [np.flatnonzero(deal == k) for k in range(loops)]
        parts = [R.Stages() for _ in shares]
        futures = [graph.pool.submit(R.march_grid, graph.on_session(k), self.grid, o[rays], d[rays], viewdirs[rays], self.near,
                                     self.far, steps, min_t, self.white_background, chunk, part)
                   for k, (rays, part) in enumerate(zip(shares, parts))]
        rgb, depth, acc = np.empty((n, 3), F32), np.empty(n, F32), np.empty(n, F32)
        for rays, future in zip(shares, futures):
            out = future.result()
            rgb[rays], depth[rays], acc[rays] = out.rgb, out.depth, out.acc
        stages.add_mean(parts)
        return R.Marched(rgb, depth, acc, None)

    def _render_dense(self, o: np.ndarray, d: np.ndarray, viewdirs: np.ndarray, min_t: Optional[float]) -> R.Marched:
        """Coarse (and fine) samples of one chunk of rays, without a grid."""
        n = self.n_coarse
        t = np.broadcast_to(R.stratified(self.near, self.far, n, self.lindisp), (len(o), n))
        seg = R.MARCH_SEGMENT if min_t is not None else n
        out = R.march_front_to_back(self._graph("coarse"), o, d, viewdirs, R.dense_packed(np.ascontiguousarray(t), d), min_t,
                                    self.white_background, seg)
        if self.n_fine == 0:
            return out
        assert out.weights is not None
        extra = R.importance(t, out.weights.reshape(len(o), n), self.n_fine)
        t_all = np.sort(np.concatenate([t, extra], axis=1), axis=1)
        seg = R.MARCH_SEGMENT if min_t is not None else t_all.shape[1]
        return R.march_front_to_back(self._graph("fine"), o, d, viewdirs, R.dense_packed(t_all, d), min_t,
                                     self.white_background, seg)

    def render_rays(self, origins: np.ndarray, directions: np.ndarray, *, chunk: Optional[int] = None) -> Rays:
        """Render world rays ``origins``, ``directions`` [N, 3] (directions not normalised: t is
        along them; NDC-warped first for a forward-facing bundle, as nerf-render does)."""
        chunk = self.check_chunk(chunk)
        o = np.asarray(origins, F32).reshape(-1, 3)
        d = np.asarray(directions, F32).reshape(-1, 3)
        out = self._render_world(o, d, chunk, R.Stages())
        return Rays(out.rgb, out.depth, out.acc)

    def _render_world(self, o: np.ndarray, d: np.ndarray, chunk: int, stages: R.Stages) -> R.Marched:
        start = time.perf_counter()
        view = d
        if self.ndc is not None:
            o, d = ndc_rays(self.ndc, o, d)
        stages.lap("rays", start)
        return self._render_batch(o, d, view, chunk, stages)

    def render(self, c2w: np.ndarray, width: Optional[int] = None, height: Optional[int] = None, *,
               chunk: Optional[int] = None) -> Frame:
        """Render the view from camera-to-world ``c2w`` [4, 4] (or 3×4) at the bundle's
        resolution, or at ``width`` (× ``height``, default keeping the aspect) with the camera
        rescaled as nerf-render's ``--width``/``--height``. ``chunk`` rays per batch (default
        :attr:`default_chunk`)."""
        chunk = self.check_chunk(chunk)
        c2w = check_pose(c2w, "c2w", "pose")
        cam = self.camera_at(width, height)
        stages = R.Stages()
        start, field_start = time.perf_counter(), self.field_seconds
        idx = np.arange(cam.width * cam.height)
        o, d = cam.rays(c2w, idx % cam.width, idx // cam.width)
        stages.lap("rays", start)
        out = self._render_world(o, d, chunk, stages)
        shape = (cam.height, cam.width)
        # Loops side by side each wait for their own calls: onnxruntime's time per loop.
        return Frame(out.rgb.reshape(shape + (3,)), out.depth.reshape(shape), out.acc.reshape(shape),
                     time.perf_counter() - start, (self.field_seconds - field_start) / stages.loops, stages)

    def __repr__(self) -> str:
        return (f"Bundle({self.path!r}, field_kind={self.field_kind!r}, camera={self.camera.width}×{self.camera.height}, "
                f"graphs={sorted(self.graphs)}, occupancy={'yes' if self.grid is not None else 'no'})")
