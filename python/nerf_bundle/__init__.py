"""Render nerf-rs scene bundles (``scene.json`` + ONNX graphs + ``occupancy.bin``) with numpy
and onnxruntime, with the same checks and the same pixels (to 1e-4) as ``nerf-render``.

>>> import nerf_bundle
>>> bundle = nerf_bundle.Bundle.open("models/spheres")
>>> frame = bundle.render(bundle.poses("test")[0], width=64)
>>> frame.rgb.shape
(64, 64, 3)
"""
from ._validate import BundleError
from .bundle import Bundle, Frame, Rays
from .camera import Camera

__all__ = ["Bundle", "BundleError", "Camera", "Frame", "Rays"]
__version__ = "0.1.0"
