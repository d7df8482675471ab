"""Checks on untrusted bundles, as ``nerf-render`` makes them (``bundle/src/scene.rs``,
``bundle/src/graph.rs``, ``core/src/io/limits.rs``): every value of ``scene.json`` is read here
with its type, range and presence checked, so the rest of the package reads only checked
values; errors are :class:`BundleError` naming the file and the field."""
from __future__ import annotations

import json
import math
import os
import stat
import unicodedata
from typing import Any, Dict, List, Optional, Tuple

import numpy as np

from ._limits import (MAX_CHUNK, MAX_FRAME_PIXELS, MAX_FRAMES, MAX_GRAPH_BYTES, MAX_GRID_RESOLUTION, MAX_IMAGE_SIDE,  # noqa: F401
                      MAX_JSON_BYTES, MAX_POINTS_PER_CALL, MAX_SAMPLES_PER_RAY, MAX_THREADS,
                      DEFAULT_MARCH_STEPS, READ_FORMATS)

__all__ = ["BundleError"]

F32 = np.float32
#: The scene.json format of a contracted field, and of it only (``SCENE_FORMAT_CONTRACTED``).
CONTRACTED_FORMAT = READ_FORMATS[2]
#: The contractions this version knows: scene.json's name → NERFOCC2's code.
CONTRACTIONS = {"linf": 1}
#: The half-size of the cube a contracted world fills (``CONTRACTED_HALF_SIZE``).
CONTRACTED_BOUND = F32(2)


class BundleError(Exception):
    """A bundle file breaks the contract or a limit; the message names the file and the problem."""


def bounded_file(path: str, max_bytes: int, field: Optional[str] = None) -> str:
    """``path`` if it is a regular file of at most ``max_bytes`` (checked before reading);
    ``field``: the scene.json key that named it, for the message."""
    named = f" (scene.json {field})" if field else ""
    try:
        st = os.stat(path)
    except OSError as e:
        raise BundleError(f"{path}{named}: cannot read: missing or not a regular file ({e.strerror})") from None
    if not stat.S_ISREG(st.st_mode):
        raise BundleError(f"{path}{named}: cannot read: not a regular file")
    if st.st_size > max_bytes:
        raise BundleError(f"{path}: {st.st_size} bytes is more than the limit of {max_bytes} for this file")
    return path


def plain_name(where: str, field: str, name: Any) -> str:
    """``name`` if it is a plain file name (not absolute, no "..", no separator)."""
    if not isinstance(name, str) or name in ("", ".", "..") or any(c in name for c in "/\\\0"):
        raise BundleError(f'{where}: {field}: {_show(name)} is not a plain file name inside the directory (no paths, no "..")')
    return name


def bundle_file(path: str, name: Any, field: str) -> str:
    """path/name for a file name read from scene.json: a plain name inside the bundle; a
    symbolic link must resolve inside the bundle."""
    where = os.path.join(path, "scene.json")
    full = os.path.join(path, plain_name(where, field, name))
    root, real = os.path.realpath(path), os.path.realpath(full)
    if os.path.commonpath([root, real]) != root:
        raise BundleError(f"{where}: {field}: {name!r} is a symbolic link to {real}, outside {path}")
    return full


# -- typed reads of JSON values -----------------------------------------------------------------

_ABSENT = object()


def _show(v: Any) -> str:
    """A value for a message, cut short (a name may be thousands of characters)."""
    text = repr(v)
    return text if len(text) <= 80 else text[:77] + "..."


def _kind(v: Any) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return f"the boolean {str(v).lower()}"
    if isinstance(v, (int, float)):
        return f"the number {_show(v)}"
    if isinstance(v, str):
        return f"the string {_show(v)}"
    return "an array" if isinstance(v, list) else "an object"


class _Reader:
    """Reads the values of one JSON document by type as serde reads them into the Rust
    structs: a required key must be there (null is a wrong type), a key with a default may be
    missing, an optional key may be missing or null."""

    def __init__(self, where: str) -> None:
        self.where = where

    def error(self, field: str, problem: str) -> BundleError:
        return BundleError(f"{self.where}: {field}: {problem}")

    def expected(self, field: str, what: str, v: Any) -> BundleError:
        return self.error(field, f"expected {what}, got {_kind(v)}")

    def get(self, obj: Dict[str, Any], key: str, prefix: str, presence: str = "required") -> Any:
        """``obj[key]``; ``presence`` "required", "default" (missing: ``_ABSENT``) or
        "optional" (missing or null: ``_ABSENT``)."""
        field = f"{prefix}.{key}" if prefix else key
        if key not in obj:
            if presence == "required":
                raise self.error(field, "missing")
            return _ABSENT
        v = obj[key]
        return _ABSENT if v is None and presence == "optional" else v

    def object(self, v: Any, field: str, keys: Optional[Tuple[str, ...]] = None) -> Dict[str, Any]:
        """A JSON object; ``keys``: the only keys allowed (serde's deny_unknown_fields)."""
        if not isinstance(v, dict):
            raise self.expected(field, "an object", v)
        if keys is not None:
            unknown = sorted(set(v) - set(keys))
            if unknown:
                raise self.error(field, f"unknown field {_show(unknown[0])}, expected one of {', '.join(keys)}")
        return v

    def f32(self, v: Any, field: str) -> float:
        """A number as the float32 Rust stores (a finite number past float32's range becomes
        infinite there, and is refused where finiteness is checked)."""
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise self.expected(field, "a number", v)
        try:
            x = float(v)
        except OverflowError:  # an integer beyond float64
            x = math.inf if v > 0 else -math.inf
        with np.errstate(over="ignore"):
            return float(F32(x))

    def uint(self, v: Any, field: str, bits: int = 64) -> int:
        """A non-negative integer of ``bits`` bits (usize, u32); 3.0 is not an integer."""
        if not isinstance(v, int) or isinstance(v, bool) or not 0 <= v < 2 ** bits:
            raise self.expected(field, f"an integer in 0..2^{bits}", v)
        return v

    def boolean(self, v: Any, field: str) -> bool:
        if not isinstance(v, bool):
            raise self.expected(field, "true or false", v)
        return v

    def string(self, v: Any, field: str) -> str:
        if not isinstance(v, str):
            raise self.expected(field, "a string", v)
        return v

    def array(self, v: Any, field: str, length: Optional[int] = None) -> List[Any]:
        if not isinstance(v, list):
            raise self.expected(field, "an array", v)
        if length is not None and len(v) != length:
            raise self.error(field, f"expected an array of {length}, got {len(v)} entries")
        return v

    def vector(self, v: Any, field: str, length: int) -> np.ndarray:
        """``length`` numbers as float32 (finiteness unchecked)."""
        return np.array([self.f32(x, f"{field}[{k}]") for k, x in enumerate(self.array(v, field, length))], F32)

    def matrix(self, v: Any, field: str, rows: int, cols: int) -> np.ndarray:
        """``rows`` arrays of ``cols`` numbers, as float32 [rows, cols] (finiteness unchecked)."""
        return np.stack([self.vector(row, f"{field}[{k}]", cols) for k, row in enumerate(self.array(v, field, rows))])


def _finite(v: float) -> bool:
    return math.isfinite(v)


def pinhole(cam: Dict[str, Any]) -> Dict[str, Any]:
    """scene.json's camera as the full model; bundles written before it have ``focal`` alone
    (fx = fy = focal, principal point at the centre, integer pixel centres); null is absent."""
    def opt(key: str, default: Any) -> Any:
        v = cam.get(key)
        return default if v is None else v

    fx = opt("fx", opt("focal", float("nan")))
    return {"width": cam["width"], "height": cam["height"], "fx": fx, "fy": opt("fy", fx),
            "cx": opt("cx", 0.5 * cam["width"]), "cy": opt("cy", 0.5 * cam["height"]),
            "pixel_center": opt("pixel_center", "integer"), "distortion": cam.get("distortion")}


def _check_camera(r: _Reader, v: Any) -> None:
    """``camera``: ``CameraDescription`` (``PinholeCamera`` flattened, ``convention``) and
    ``limits::check_camera``."""
    cam = r.object(v, "camera")
    w = r.uint(r.get(cam, "width", "camera"), "camera.width", 32)
    h = r.uint(r.get(cam, "height", "camera"), "camera.height", 32)
    for key in ("focal", "fx", "fy", "cx", "cy"):
        x = r.get(cam, key, "camera", "optional")
        if x is not _ABSENT:
            r.f32(x, f"camera.{key}")
    center = r.get(cam, "pixel_center", "camera", "optional")
    if center is not _ABSENT and center not in ("integer", "half_pixel"):
        raise r.error("camera.pixel_center", f'{_show(center)} is neither "integer" nor "half_pixel"')
    dist = r.get(cam, "distortion", "camera", "optional")
    if dist is not _ABSENT:
        dist = r.object(dist, "camera.distortion")
        for key in ("k1", "k2", "p1", "p2"):
            r.f32(r.get(dist, key, "camera.distortion"), f"camera.distortion.{key}")
    r.string(r.get(cam, "convention", "camera"), "camera.convention")
    if w == 0 or h == 0:
        raise r.error("camera", f"{w}×{h} pixels: both sides must be positive")
    if w > MAX_IMAGE_SIDE or h > MAX_IMAGE_SIDE:
        raise r.error("camera", f"{w}×{h} pixels: a side is more than the limit of {MAX_IMAGE_SIDE}")
    if w * h > MAX_FRAME_PIXELS:
        raise r.error("camera", f"{w}×{h} pixels is more than the limit of {MAX_FRAME_PIXELS} pixels per frame")
    full = pinhole(cam)
    for key in ("fx", "fy"):
        f = r.f32(full[key], f"camera.{key}")
        if not (_finite(f) and f > 0):
            raise r.error(f"camera.{key}", f"{f} is not a positive finite focal length")
    for key in ("cx", "cy"):
        if not _finite(r.f32(full[key], f"camera.{key}")):
            raise r.error(f"camera.{key}", f"{full[key]} is not a finite principal point")
    if dist is not _ABSENT and not all(_finite(r.f32(dist[k], "camera.distortion")) for k in ("k1", "k2", "p1", "p2")):
        raise r.error("camera.distortion", f"{_show(dist)} has a non-finite coefficient")


_NDC_KEYS = ("width", "height", "fx", "fy", "near")


def _check_sampling(r: _Reader, v: Any) -> Dict[str, Any]:
    """``sampling``: ``SamplingConfig`` (no other keys) and ``limits::check_sampling``."""
    s = r.object(v, "sampling", ("near", "far", "n_coarse", "n_fine", "lindisp", "ndc"))
    near = r.f32(r.get(s, "near", "sampling"), "sampling.near")
    far = r.f32(r.get(s, "far", "sampling"), "sampling.far")
    n_coarse = r.uint(r.get(s, "n_coarse", "sampling"), "sampling.n_coarse")
    n_fine = r.uint(r.get(s, "n_fine", "sampling"), "sampling.n_fine")
    r.boolean(r.get(s, "lindisp", "sampling"), "sampling.lindisp")
    ndc = r.get(s, "ndc", "sampling", "optional")
    if ndc is _ABSENT:
        if not (_finite(near) and _finite(far) and 0 < near < far):
            raise r.error("sampling", f"need finite 0 < near < far, got near {near} far {far}")
    else:
        ndc = r.object(ndc, "sampling.ndc", _NDC_KEYS)
        values = [r.f32(r.get(ndc, k, "sampling.ndc"), f"sampling.ndc.{k}") for k in _NDC_KEYS]
        if not (0 <= near < far <= 1):
            raise r.error("sampling", f"NDC rays need 0 <= near < far <= 1, got near {near} far {far}")
        if not all(_finite(x) and x > 0 for x in values):
            raise r.error("sampling.ndc", f"{_show(ndc)} needs positive finite width, height, fx, fy and near")
    if n_coarse == 0:
        raise r.error("sampling.n_coarse", "must be at least 1")
    if n_coarse + n_fine > MAX_SAMPLES_PER_RAY:
        raise r.error("sampling", f"n_coarse + n_fine = {n_coarse + n_fine} samples per ray is more than the limit of {MAX_SAMPLES_PER_RAY}")
    return s


def _check_encoding(r: _Reader, scene: Dict[str, Any], key: str) -> None:
    """``position_encoding``/``direction_encoding``: stated for other tools, typed as Rust reads them."""
    v = r.get(scene, key, "", "optional")
    if v is _ABSENT:
        return
    e = r.object(v, key)
    r.uint(r.get(e, "n_frequencies", key), f"{key}.n_frequencies")
    r.boolean(r.get(e, "include_input", key), f"{key}.include_input")
    for k, f in enumerate(r.array(r.get(e, "frequencies", key), f"{key}.frequencies")):
        r.f32(f, f"{key}.frequencies[{k}]")
    r.uint(r.get(e, "output_dim", key), f"{key}.output_dim")


def _check_poses(r: _Reader, v: Any) -> None:
    """``poses``: at most MAX_FRAMES test views (plain names) and orbit poses, each a finite
    4×4 matrix."""
    poses = r.object(v, "poses")
    test = r.array(r.get(poses, "test", "poses"), "poses.test")
    orbit = r.array(r.get(poses, "orbit", "poses"), "poses.orbit")
    for key, items in (("poses.test", test), ("poses.orbit", orbit)):
        if len(items) > MAX_FRAMES:
            raise r.error(key, f"{len(items)} poses is more than the limit of {MAX_FRAMES}")
    for k, p in enumerate(test):
        field = f"poses.test[{k}]"
        p = r.object(p, field)
        plain_name(r.where, f"{field}.name", r.string(r.get(p, "name", field), f"{field}.name"))
        pose_matrix(r, r.get(p, "transform_matrix", field), f"{field}.transform_matrix")
    for k, m in enumerate(orbit):
        pose_matrix(r, m, f"poses.orbit[{k}]")


def pose_matrix(r: _Reader, v: Any, field: str) -> np.ndarray:
    """A camera-to-world pose in scene.json: 4×4 numbers, finite as float32."""
    m = r.matrix(v, field, 4, 4)
    if not np.all(np.isfinite(m)):
        raise r.error(field, "has a non-finite entry")
    return m


def _check_placement(r: _Reader, scene: Dict[str, Any]) -> None:
    """``placement``: read by the package only for whether it records an orbit; typed as far as
    the capture format and the transform."""
    v = r.get(scene, "placement", "", "optional")
    if v is _ABSENT:
        return
    p = r.object(v, "placement")
    fmt = r.get(p, "format", "placement")
    if fmt not in ("blender", "instant_ngp", "llff"):
        raise r.error("placement.format", f'{_show(fmt)} is not "blender", "instant_ngp" or "llff"')
    t = r.object(r.get(p, "transform", "placement"), "placement.transform")
    r.f32(r.get(t, "scale", "placement.transform"), "placement.transform.scale")
    if r.get(t, "rotation", "placement.transform", "default") is not _ABSENT:
        r.matrix(t["rotation"], "placement.transform.rotation", 3, 3)
    r.vector(r.get(t, "translation", "placement.transform"), "placement.transform.translation", 3)
    near_far = r.get(p, "near_far", "placement", "optional")
    if near_far is not _ABSENT:
        r.vector(near_far, "placement.near_far", 2)
    orbit = r.get(p, "orbit", "placement", "optional")
    if orbit is not _ABSENT:
        r.object(orbit, "placement.orbit")


def _check_contraction(r: _Reader, scene: Dict[str, Any]) -> Optional[str]:
    """``contraction`` (a name of :data:`CONTRACTIONS`; missing or null: none) and
    ``contraction_definition`` (text for other readers)."""
    v = r.get(scene, "contraction", "", "optional")
    if v is not _ABSENT and not (isinstance(v, str) and v in CONTRACTIONS):
        raise r.error("contraction", f"{_show(v)} is not a contraction this version knows (expected one of "
                                     f"{', '.join(map(repr, CONTRACTIONS))})")
    text = r.get(scene, "contraction_definition", "", "optional")
    if text is not _ABSENT:
        r.string(text, "contraction_definition")
    return None if v is _ABSENT else v


def _check_appearance(r: _Reader, scene: Dict[str, Any]) -> None:
    """``appearance`` (optional): the per-image appearance code the graph renders with,
    ``{"fixed": "mean"}`` or ``{"fixed": "image", "image": NAME}`` (informational: the code is
    already color.0's bias inside the graph)."""
    v = r.get(scene, "appearance", "", "optional")
    if v is _ABSENT:
        return
    fixed = r.string(r.get(r.object(v, "appearance"), "fixed", "appearance"), "appearance.fixed")
    if fixed == "mean":
        r.object(v, "appearance", ("fixed",))
    elif fixed == "image":
        r.object(v, "appearance", ("fixed", "image"))
        r.string(r.get(v, "image", "appearance"), "appearance.image")
    else:
        raise r.error("appearance.fixed", f'{_show(fixed)} is not "mean" or "image"')


def contraction_of(scene: Dict[str, Any]) -> Optional[str]:
    """The (checked) scene's contraction, or None."""
    return scene.get("contraction")


def is_bounded(scene: Dict[str, Any]) -> bool:
    """A field defined inside its grid's box only: "bounded", or a version-1 hash-grid bundle."""
    return scene.get("bounded") is True or (scene.get("format") == READ_FORMATS[0] and scene.get("field", "mlp") == "ngp")


def graph_files(scene: Dict[str, Any]) -> Dict[str, Tuple[str, Any]]:
    """{role: (scene.json key, file)}, in role order: "graphs" by role, or (when "graphs" is
    empty) nerf-rs-scene-1's "networks"."""
    nets = scene.get("networks")
    if not scene.get("graphs") and nets is not None:
        first = "field" if is_bounded(scene) else "coarse"
        files = {first: ("networks.coarse", nets["coarse"])}
        if nets.get("fine") is not None:
            files["fine"] = ("networks.fine", nets["fine"])
        return files
    graphs = scene.get("graphs") or {}
    return {role: (f"graphs.{role}", graphs[role]) for role in ("field", "coarse", "fine") if role in graphs}


def _check_graphs(r: _Reader, scene: Dict[str, Any], n_fine: int) -> None:
    """``graphs`` (role → file) or ``networks``: the roles the sampling needs, plain file names."""
    graphs = r.get(scene, "graphs", "", "default")
    if graphs is not _ABSENT:
        for role, name in r.object(graphs, "graphs").items():
            if role not in ("field", "coarse", "fine"):
                raise r.error("graphs", f'unknown role {_show(role)}, expected "field", "coarse" or "fine"')
            r.string(name, f"graphs.{role}")
    nets = r.get(scene, "networks", "", "optional")
    if nets is not _ABSENT:
        nets = r.object(nets, "networks")
        r.string(r.get(nets, "coarse", "networks"), "networks.coarse")
        fine = r.get(nets, "fine", "networks", "optional")
        if fine is not _ABSENT:
            r.string(fine, "networks.fine")
    files = graph_files(scene)
    roles = list(files)
    wanted = ["field"] if roles[:1] == ["field"] else ["coarse", "fine"] if n_fine > 0 else ["coarse"]
    if roles != wanted or (wanted == ["field"] and n_fine > 0):
        key = "networks" if nets is not _ABSENT and not scene.get("graphs") else "graphs"
        raise r.error(key, f"graphs [{', '.join(roles)}] with sampling.n_fine {n_fine}: need [field] (n_fine 0), "
                           "[coarse] (n_fine 0) or [coarse, fine] (n_fine > 0)")
    for key, name in files.values():
        plain_name(r.where, key, name)


def check_scene(scene: Any, where: str) -> None:
    """Every field of scene.json as ``SceneDescription`` reads it, and the limits
    ``SceneDescription::check`` applies, before anything is allocated or opened."""
    r = _Reader(where)
    if not isinstance(scene, dict):
        raise BundleError(f"{where}: not a scene description: the top level is {_kind(scene)}, not a JSON object")
    fmt = r.string(r.get(scene, "format", ""), "format")
    if fmt not in READ_FORMATS:
        raise r.error("format", f"{_show(fmt)}, expected one of {list(READ_FORMATS)}")
    _check_camera(r, r.get(scene, "camera", ""))
    s = _check_sampling(r, r.get(scene, "sampling", ""))
    r.boolean(r.get(scene, "white_background", ""), "white_background")
    if r.get(scene, "field", "", "default") is not _ABSENT:
        r.string(scene["field"], "field")
    if r.get(scene, "bounded", "", "default") is not _ABSENT:
        r.boolean(scene["bounded"], "bounded")
    for key in ("position_encoding", "direction_encoding"):
        _check_encoding(r, scene, key)
    steps = r.get(scene, "march_steps", "", "default")
    steps = DEFAULT_MARCH_STEPS if steps is _ABSENT else r.uint(steps, "march_steps")
    _check_poses(r, r.get(scene, "poses", ""))
    occ = r.get(scene, "occupancy", "", "optional")
    if occ is not _ABSENT:
        occ = r.object(occ, "occupancy")
        r.string(r.get(occ, "file", "occupancy"), "occupancy.file")
        r.uint(r.get(occ, "resolution", "occupancy"), "occupancy.resolution")
        r.f32(r.get(occ, "bound", "occupancy"), "occupancy.bound")
    _check_placement(r, scene)
    _check_graphs(r, scene, s["n_fine"])
    contraction = _check_contraction(r, scene)
    _check_appearance(r, scene)
    # The checks after reading, in SceneDescription::check's order.
    if (contraction is not None) != (fmt == CONTRACTED_FORMAT):
        raise r.error("contraction", f"{_show(contraction)} with format {_show(fmt)}: a contracted field is "
                                     f"{_show(CONTRACTED_FORMAT)}, and only it")
    if is_bounded(scene) and occ is _ABSENT:
        raise r.error("occupancy", "a bounded field is defined inside its box only and marched through its occupancy grid: the bundle needs one")
    if steps == 0:
        raise r.error("march_steps", "must be at least 1 (got 0 steps)")
    if steps > MAX_SAMPLES_PER_RAY:
        raise r.error("march_steps", f"{steps} steps is more than the limit of {MAX_SAMPLES_PER_RAY}")
    appearance = scene.get("appearance")
    if isinstance(appearance, dict) and appearance.get("fixed") == "image":
        image = appearance["image"]
        if not image or len(image.encode()) > 255 or any(unicodedata.category(c) == "Cc" for c in image):
            raise r.error("appearance.image", f"{_show(image)} is not an image name")
    if occ is not _ABSENT:
        plain_name(where, "occupancy.file", occ["file"])
        res = occ["resolution"]
        if not 1 <= res <= MAX_GRID_RESOLUTION:
            raise r.error("occupancy.resolution", f"{res} cells per axis is outside 1..{MAX_GRID_RESOLUTION}"
                          if res == 0 else f"{res} cells per axis is more than the limit of {MAX_GRID_RESOLUTION}")
        bound = r.f32(occ["bound"], "occupancy.bound")
        if not (_finite(bound) and bound > 0):
            raise r.error("occupancy.bound", f"{bound} is not a positive finite bound")


def _load_json(text: str, where: str) -> Any:
    """JSON as serde_json reads it: no NaN or Infinity literals, no key twice in an object.
    Nesting deeper than the parser's recursion allows is refused (serde_json stops at 128
    levels in the fields it reads, which then have the wrong type anyway)."""
    def no_constant(name: str) -> Any:
        raise ValueError(f"{name} is not a JSON number")

    def no_duplicates(pairs: List[Tuple[str, Any]]) -> Dict[str, Any]:
        obj = dict(pairs)
        if len(obj) != len(pairs):
            seen: set = set()
            key = next(k for k, _ in pairs if k in seen or seen.add(k))
            raise ValueError(f"duplicate key {_show(key)}")
        return obj

    try:
        return json.loads(text, parse_constant=no_constant, object_pairs_hook=no_duplicates)
    except RecursionError:
        raise BundleError(f"{where}: not valid JSON: arrays or objects nested too deeply") from None
    except ValueError as e:
        raise BundleError(f"{where}: not valid JSON: {e}") from None


def read_scene(path: str) -> Dict[str, Any]:
    """Read and check ``path/scene.json``."""
    if not os.path.isdir(path):
        raise BundleError(f"{path}: no such bundle directory")
    where = bounded_file(os.path.join(path, "scene.json"), MAX_JSON_BYTES)
    try:
        with open(where, "rb") as f:
            text = f.read().decode("utf-8")
    except OSError as e:
        raise BundleError(f"{where}: cannot read: {e.strerror}") from None
    except UnicodeDecodeError as e:
        raise BundleError(f"{where}: not UTF-8 text: {e}") from None
    scene = _load_json(text, where)
    check_scene(scene, where)
    return scene


def read_grid(path: str) -> Tuple[np.ndarray, np.float32, np.float32, Optional[str]]:
    """occupancy.bin: the header (resolution, bound and threshold checked; NERFOCC2's
    contraction known, its bound 2) before the cells. Returns (density [R, R, R] float32, bound,
    threshold, contraction or None)."""
    bounded_file(path, MAX_GRAPH_BYTES)
    with open(path, "rb") as f:
        header = f.read(24)
        magic = header[:8]
        size = 24 if magic == b"NERFOCC2" else 20
        if len(header) < size or magic not in (b"NERFOCC1", b"NERFOCC2"):
            raise BundleError(f"{path}: not an occupancy grid (missing NERFOCC1 or NERFOCC2 header; truncated?)")
        res = int(np.frombuffer(header[8:12], "<u4")[0])
        bound, threshold = np.frombuffer(header[12:20], "<f4")
        if not 1 <= res <= MAX_GRID_RESOLUTION:
            raise BundleError(f"{path}: header resolution: {res} cells per axis is outside 1..{MAX_GRID_RESOLUTION}"
                              if res == 0 else f"{path}: header resolution: {res} cells per axis is more than the limit of {MAX_GRID_RESOLUTION}")
        if not (np.isfinite(bound) and bound > 0 and np.isfinite(threshold)):
            raise BundleError(f"{path}: bad header: resolution {res}, bound {bound}, threshold {threshold} "
                              "(need a positive finite bound and a finite threshold)")
        contraction = _grid_contraction(path, header, bound) if size == 24 else None
        want = size + 4 * res ** 3
        have = os.path.getsize(path)
        if have != want:
            raise BundleError(f"{path}: {have} bytes, expected {want} for a {res}³ grid (truncated?)")
        f.seek(size)
        density = np.frombuffer(f.read(want - size), "<f4")
        if density.size != res ** 3:
            raise BundleError(f"{path}: {size + 4 * density.size} bytes, expected {want} for a {res}³ grid (truncated?)")
    return density.reshape(res, res, res), F32(bound), F32(threshold), contraction


def _grid_contraction(path: str, header: bytes, bound: np.float32) -> str:
    """NERFOCC2's contraction word (a name of :data:`CONTRACTIONS`); its grid covers ±2."""
    code = int(np.frombuffer(header[20:24], "<u4")[0])
    names = {c: name for name, c in CONTRACTIONS.items()}
    if code not in names:
        raise BundleError(f"{path}: unknown contraction {code} in the NERFOCC2 header (this version knows "
                          f"{', '.join(f'{c}: {n}' for c, n in names.items())})")
    if bound != CONTRACTED_BOUND:
        raise BundleError(f"{path}: a contracted grid covers [-2, 2]^3, the header says bound {bound}")
    return names[code]


def check_grid_matches(scene_path: str, scene: Dict[str, Any], grid_path: str, res: int, bound: np.float32,
                       contraction: Optional[str]) -> None:
    """The grid file covers what scene.json says, contracted as it says (``read_occupancy``)."""
    occ = scene["occupancy"]
    if res != occ["resolution"] or bound != F32(occ["bound"]):
        raise BundleError(f"{scene_path}: occupancy: the grid file is {res}³ over ±{bound}, scene.json says "
                          f"{occ['resolution']}³ over ±{F32(occ['bound'])}")
    if contraction != contraction_of(scene):
        def said(c: Optional[str]) -> str:
            return "none" if c is None else repr(c)
        raise BundleError(f"{scene_path}: occupancy: the grid file {grid_path}'s contraction is {said(contraction)}, "
                          f"scene.json's {said(contraction_of(scene))}")


def check_pose(matrix: Any, where: str, field: str) -> np.ndarray:
    """A 4×4 (or 3×4) camera-to-world matrix, finite as float32, as float32 [4, 4]."""
    try:
        m = np.array(matrix, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        raise BundleError(f"{where}: {field}: not a numeric matrix") from None
    if m.shape not in ((4, 4), (3, 4)):
        raise BundleError(f"{where}: {field}: shape {m.shape} is not 4×4 or 3×4")
    with np.errstate(over="ignore"):
        m = m.astype(F32)
    if not np.all(np.isfinite(m)):
        raise BundleError(f"{where}: {field} has a non-finite entry")
    if m.shape == (3, 4):
        m = np.vstack([m, np.array([[0, 0, 0, 1]], F32)])
    return m


def check_count(n: Any, limit: int, what: str, unit: str) -> int:
    """An option value in 1..limit."""
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool):
        raise ValueError(f"{what}: {n!r} is not an integer")
    if n < 1:
        raise ValueError(f"{what}: must be at least 1")
    if n > limit:
        raise ValueError(f"{what}: {n} {unit} is more than the limit of {limit}")
    return int(n)


def check_chunk(chunk: Any, samples_per_ray: int, what: str = "chunk") -> int:
    """Rays per network call: at most MAX_CHUNK, and at most MAX_POINTS_PER_CALL points with
    ``samples_per_ray`` (``limits::check_chunk``)."""
    chunk = check_count(chunk, MAX_CHUNK, what, "rays")
    points = chunk * max(samples_per_ray, 1)
    if points > MAX_POINTS_PER_CALL:
        raise ValueError(f"{what}: {chunk} rays × {samples_per_ray} samples = {points} points per network call "
                         f"is more than the limit of {MAX_POINTS_PER_CALL}")
    return chunk
