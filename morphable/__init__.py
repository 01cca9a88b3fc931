"""morphable: a geometry-first 3D morphable face model toolkit.

Importing the package loads numpy only; scipy, trimesh, open3d, pyvista and torch load
inside the functions that need them.

Units: millimetres and degrees in every public interface. Image coordinates: x right,
y down, 0-based pixel centres. Model axes: x to the subject's left, y up, z towards a viewer.
"""
from .errors import FitError, InputError, MorphableError
from .io.registry import DEFAULT_MODEL, download, find_model, load_model
from .model import MorphableModel
from .normals import face_normals, vertex_normals

__version__ = "0.1.0"

__all__ = ["MorphableModel", "load_model", "find_model", "download", "DEFAULT_MODEL",
           "vertex_normals", "face_normals", "MorphableError", "InputError", "FitError",
           "fit_landmarks", "FitResult"]

_LAZY = {"fit_landmarks": "fitting", "FitResult": "fitting"}


def __getattr__(name):
    # heavier subpackages load on first use, so that ``import morphable`` stays numpy-only
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
