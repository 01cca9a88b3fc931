"""morphable: a geometry-first 3D morphable face model toolkit.

Importing the package loads numpy only; scipy, trimesh, open3d, pyvista and torch load
inside the functions that need them.

One call from photos (or videos, or image arrays) to a fitted face:
:func:`fit_images` (the steps: :mod:`morphable.pipeline`); a face through a video, one
identity and a pose and expression per frame: :func:`track_video`; every face of a video, shot
by shot, joined into people: :func:`track_footage` (:mod:`morphable.tracking`).

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
           "fit_landmarks", "FitResult", "fit_images", "ImageFit", "track_video", "track_footage"]

_LAZY = {"fit_landmarks": "fitting", "FitResult": "fitting", "fit_images": "pipeline",
         "ImageFit": "pipeline", "track_video": "tracking", "track_footage": "tracking"}


def __getattr__(name):
    # heavier subpackages load on first use, so that ``import morphable`` stays numpy-only
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
