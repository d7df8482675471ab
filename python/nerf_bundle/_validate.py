"""Checks on untrusted bundles: the limits of ``core/src/io/limits.rs`` and the rules of
``nerf-render`` (ported from ``tests/python/render_rays.py``)."""
from __future__ import annotations

import json
import math
import os
import stat
from typing import Any, Dict, Optional, Tuple

import numpy as np

MAX_IMAGE_SIDE = 16_384
MAX_FRAME_PIXELS = 16_777_216
MAX_FRAMES = 10_000
MAX_SAMPLES_PER_RAY = 4_096
MAX_GRID_RESOLUTION = 512
MAX_JSON_BYTES = 67_108_864
MAX_GRAPH_BYTES = 2_147_483_648
MAX_THREADS = 1_024
#: The most samples one chunk may hold (rays × samples per ray), as nerf-render's --chunk check.
MAX_CHUNK_SAMPLES = 16_777_216

__all__ = ["BundleError"]


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
        raise BundleError(f'{where}: {field}: {name!r} is not a plain file name inside the directory (no paths, no "..")')
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


def pinhole(cam: Dict[str, Any]) -> Dict[str, Any]:
    """scene.json's camera as the full model; bundles written before it have ``focal`` alone
    (fx = fy = focal, principal point at the centre, integer pixel centres)."""
    fx = cam.get("fx", cam.get("focal", float("nan")))
    return {"width": cam["width"], "height": cam["height"], "fx": fx, "fy": cam.get("fy", fx),
            "cx": cam.get("cx", 0.5 * cam["width"]), "cy": cam.get("cy", 0.5 * cam["height"]),
            "pixel_center": cam.get("pixel_center", "integer"), "distortion": cam.get("distortion")}


def is_bounded(scene: Dict[str, Any]) -> bool:
    """A field defined inside its grid's box only: "bounded", or a version-1 hash-grid bundle."""
    return bool(scene.get("bounded", False)) or (scene.get("format") == "nerf-rs-scene-1" and scene.get("field", "mlp") == "ngp")


def _finite(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def check_scene(scene: Dict[str, Any], where: str) -> None:
    """The limits nerf-render applies (SceneDescription::check), before anything is allocated."""
    cam, s = pinhole(scene["camera"]), scene["sampling"]
    w, h = cam["width"], cam["height"]
    if not (isinstance(w, int) and isinstance(h, int)):
        raise BundleError(f"{where}: camera: width and height must be integers, got {w!r}×{h!r}")
    if not (0 < w <= MAX_IMAGE_SIDE and 0 < h <= MAX_IMAGE_SIDE and w * h <= MAX_FRAME_PIXELS):
        raise BundleError(f"{where}: camera: {w}×{h} pixels is outside the limits ({MAX_IMAGE_SIDE} per side, {MAX_FRAME_PIXELS} per frame): the limit of {MAX_IMAGE_SIDE}")
    for key in ("fx", "fy"):
        if not (_finite(cam[key]) and cam[key] > 0):
            raise BundleError(f"{where}: camera.{key}: {cam[key]} is not a positive finite focal length")
    for key in ("cx", "cy"):
        if not _finite(cam[key]):
            raise BundleError(f"{where}: camera.{key}: {cam[key]} is not a finite principal point")
    if cam["pixel_center"] not in ("integer", "half_pixel"):
        raise BundleError(f"{where}: camera.pixel_center: {cam['pixel_center']!r} is neither \"integer\" nor \"half_pixel\"")
    if cam["distortion"] is not None and not all(_finite(cam["distortion"][k]) for k in ("k1", "k2", "p1", "p2")):
        raise BundleError(f"{where}: camera.distortion: {cam['distortion']} has a non-finite coefficient")
    for key in ("near", "far"):
        if not _finite(s[key]):
            raise BundleError(f"{where}: sampling.{key}: {s[key]!r} is not a finite number (need finite 0 < near < far)")
    if s.get("ndc") is not None:
        ndc = s["ndc"]
        if not (0 <= s["near"] < s["far"] <= 1):
            raise BundleError(f"{where}: sampling: NDC rays need 0 <= near < far <= 1, got near {s['near']} far {s['far']}")
        if not all(_finite(ndc[k]) and ndc[k] > 0 for k in ("width", "height", "fx", "fy", "near")):
            raise BundleError(f"{where}: sampling.ndc: {ndc} needs positive finite width, height, fx, fy and near")
    elif not (0 < s["near"] < s["far"]):
        raise BundleError(f"{where}: sampling: need finite 0 < near < far, got near {s['near']} far {s['far']}")
    n_coarse, n_fine = s["n_coarse"], s["n_fine"]
    if not (isinstance(n_coarse, int) and isinstance(n_fine, int)):
        raise BundleError(f"{where}: sampling: n_coarse and n_fine must be integers")
    if not (1 <= n_coarse and 0 <= n_fine and n_coarse + n_fine <= MAX_SAMPLES_PER_RAY):
        raise BundleError(f"{where}: sampling: n_coarse + n_fine = {n_coarse + n_fine} samples per ray is outside 1..{MAX_SAMPLES_PER_RAY}")
    if n_fine > 0 and n_coarse < 3:
        raise BundleError(f"{where}: sampling: hierarchical sampling needs n_coarse >= 3, got {n_coarse}")
    for key in ("test", "orbit"):
        if len(scene["poses"][key]) > MAX_FRAMES:
            raise BundleError(f"{where}: poses.{key}: {len(scene['poses'][key])} poses is more than the limit of {MAX_FRAMES}")
    for k, p in enumerate(scene["poses"]["test"]):
        plain_name(where, f"poses.test[{k}].name", p["name"])
    steps = scene.get("march_steps", 256)
    if not (isinstance(steps, int) and 1 <= steps <= MAX_SAMPLES_PER_RAY):
        raise BundleError(f"{where}: march_steps: {steps} is outside 1..{MAX_SAMPLES_PER_RAY}")
    if is_bounded(scene) and not scene.get("occupancy"):
        raise BundleError(f"{where}: occupancy: a bounded field is defined inside its box only and marched through its occupancy grid: the bundle needs one")
    occ = scene.get("occupancy")
    if occ:
        if not (isinstance(occ["resolution"], int) and 1 <= occ["resolution"] <= MAX_GRID_RESOLUTION):
            raise BundleError(f"{where}: occupancy.resolution: {occ['resolution']} cells per axis is outside 1..{MAX_GRID_RESOLUTION}")
        if not (_finite(occ["bound"]) and occ["bound"] > 0):
            raise BundleError(f"{where}: occupancy.bound: {occ['bound']} is not a positive finite number")


def graph_files(scene: Dict[str, Any]) -> Dict[str, Tuple[str, Any]]:
    """{role: (scene.json key, file)}: "graphs" by role, or nerf-rs-scene-1's "networks"."""
    if scene.get("graphs"):
        files = {role: (f"graphs.{role}", name) for role, name in scene["graphs"].items()}
    else:
        nets = scene["networks"]
        first = "field" if is_bounded(scene) else "coarse"
        files = {first: ("networks.coarse", nets["coarse"])}
        if nets.get("fine"):
            files["fine"] = ("networks.fine", nets["fine"])
    if "field" not in files and "coarse" not in files:
        raise BundleError("scene.json: graphs: needs a \"field\" graph or \"coarse\" (+ \"fine\") graphs")
    return files


def read_scene(path: str) -> Dict[str, Any]:
    """Read and check ``path/scene.json``."""
    if not os.path.isdir(path):
        raise BundleError(f"{path}: no such bundle directory")
    where = bounded_file(os.path.join(path, "scene.json"), MAX_JSON_BYTES)
    try:
        with open(where, encoding="utf-8") as f:
            scene = json.load(f)
        if not isinstance(scene, dict):
            raise TypeError("scene.json is not a JSON object")
        check_scene(scene, where)
        graph_files(scene)
    except KeyError as e:
        raise BundleError(f"{where}: missing field `{e.args[0]}`") from None
    except BundleError as e:
        if str(e).startswith("scene.json:"):
            raise BundleError(f"{where}: {str(e)[len('scene.json: '):]}") from None
        raise
    except (TypeError, ValueError, AttributeError, IndexError) as e:
        raise BundleError(f"{where}: missing or malformed field: {e}") from None
    return scene


def read_grid(path: str) -> Tuple[np.ndarray, np.float32, np.float32]:
    """occupancy.bin: the header (resolution checked against the limit) before the cells.
    Returns (density [R, R, R] float32, bound, threshold)."""
    bounded_file(path, MAX_GRAPH_BYTES)
    with open(path, "rb") as f:
        header = f.read(20)
        if len(header) < 20 or header[:8] != b"NERFOCC1":
            raise BundleError(f"{path}: not an occupancy grid (missing NERFOCC1 header; truncated?)")
        res = int(np.frombuffer(header[8:12], "<u4")[0])
        bound, threshold = np.frombuffer(header[12:20], "<f4")
        if not 1 <= res <= MAX_GRID_RESOLUTION:
            raise BundleError(f"{path}: header resolution: {res} cells per axis is outside 1..{MAX_GRID_RESOLUTION}")
        want = 20 + 4 * res ** 3
        size = os.path.getsize(path)
        if size != want:
            raise BundleError(f"{path}: {size} bytes, expected {want} for a {res}³ grid (truncated?)")
        density = np.frombuffer(f.read(want - 20), "<f4").reshape(res, res, res)
    return density, np.float32(bound), np.float32(threshold)


def check_pose(matrix: Any, where: str, field: str) -> np.ndarray:
    """A 4×4 (or 3×4) finite camera-to-world matrix as float32 [4, 4]."""
    try:
        m = np.array(matrix, dtype=np.float64)
    except (TypeError, ValueError):
        raise BundleError(f"{where}: {field}: not a numeric matrix") from None
    if m.shape not in ((4, 4), (3, 4)):
        raise BundleError(f"{where}: {field}: shape {m.shape} is not 4×4 or 3×4")
    if not np.all(np.isfinite(m)):
        raise BundleError(f"{where}: {field} has a non-finite entry")
    if m.shape == (3, 4):
        m = np.vstack([m, [0, 0, 0, 1]])
    return m.astype(np.float32)


def check_count(n: Any, limit: int, what: str, unit: str) -> int:
    """An option value in 1..limit."""
    if not isinstance(n, (int, np.integer)) or isinstance(n, bool):
        raise ValueError(f"{what}: {n!r} is not an integer")
    if n < 1:
        raise ValueError(f"{what}: must be at least 1")
    if n > limit:
        raise ValueError(f"{what}: {n} {unit} is more than the limit of {limit}")
    return int(n)
