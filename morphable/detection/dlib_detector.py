"""dlib's face detectors (HOG, CNN) and its 68-point iBUG shape predictor (the ``detect`` extra).

The models ship in the PyPI package ``face-recognition-models``; they are found on disk
without importing that package (its ``__init__`` needs ``pkg_resources``). Use it through
:func:`morphable.detection.detect_landmarks` (``landmark_detector="dlib"``).

>>> from morphable.io.landmark_files import read_pts
>>> pts = detect_landmarks("../shared/data/images/image_0010.png")
>>> truth = read_pts("../shared/data/images/image_0010.pts")      # px, a face ~400 px wide
>>> pts.shape, bool(np.median(np.linalg.norm(pts - truth, axis=1)[17:]) < 10)
((68, 2), True)
"""
from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

import numpy as np

from ..errors import FitError, InputError
from .images import as_image
from .boxes import check_box, largest_first

__all__ = ["FACE_DETECTORS", "detect_faces", "detect_landmarks", "model_file"]

FACE_DETECTORS = ("hog", "cnn")
"""dlib's face detectors: the HOG frontal detector (fast) and the CNN ``mmod`` one (slower, more poses)."""


def model_file(name: str) -> Path:
    """Path of a model file of ``face-recognition-models`` (InputError when not installed)."""
    spec = importlib.util.find_spec("face_recognition_models")
    if spec is None or not spec.submodule_search_locations:
        raise InputError("face detection needs the 'detect' extra: pip install face-recognition-models dlib-bin")
    path = Path(list(spec.submodule_search_locations)[0]) / "models" / name
    if not path.is_file():
        raise InputError(f"{path}: detector model file is missing")
    return path


def _dlib():
    try:
        import dlib
    except ImportError:
        raise InputError("face detection needs the 'detect' extra: pip install dlib-bin") from None
    return dlib


@functools.lru_cache(maxsize=None)
def _detector(kind: str):
    dlib = _dlib()
    if kind == "hog":
        return dlib.get_frontal_face_detector()
    if kind == "cnn":
        return dlib.cnn_face_detection_model_v1(str(model_file("mmod_human_face_detector.dat")))
    raise InputError(f"face detector: dlib has 'hog' or 'cnn', got {kind!r}")


@functools.lru_cache(maxsize=None)
def _predictor():
    return _dlib().shape_predictor(str(model_file("shape_predictor_68_face_landmarks.dat")))


def detect_faces(image, *, face_detector: str = "hog", upsample: int = 1) -> np.ndarray:
    """Face boxes, largest first.

    Parameters
    ----------
    image : path or (H, W, 3) array
    face_detector : {"hog", "cnn"}
        dlib's HOG frontal detector (fast) or its CNN ``mmod`` detector (slower, more poses).
    upsample : int
        Times the image is upsampled before detection (finds smaller faces).

    Returns
    -------
    (F, 4) float array of boxes ``(left, top, right, bottom)`` in pixels.
    """
    img, _ = as_image(image)
    found = _detector(face_detector)(img, int(upsample))
    rects = [getattr(d, "rect", d) for d in found]
    return largest_first([[r.left(), r.top(), r.right(), r.bottom()] for r in rects])


def detect_landmarks(image, *, box=None, face_detector: str = "hog", upsample: int = 1) -> np.ndarray:
    """68 iBUG landmarks of the largest face (or of the face in ``box``).

    Parameters
    ----------
    image : path or (H, W, 3) array
    box : (left, top, right, bottom) pixels, optional; skips detection
    face_detector, upsample : see :func:`detect_faces`

    Returns
    -------
    (68, 2) float64 pixels, 0-based, x right, y down.

    Raises
    ------
    FitError when no face is found.
    """
    img, name = as_image(image)
    if box is None:
        boxes = detect_faces(img, face_detector=face_detector, upsample=upsample)
        if len(boxes) == 0:
            raise FitError(f"{name}: no face found by dlib {face_detector} (try the cnn face detector)")
        box = boxes[0]
    b = check_box(box)
    dlib = _dlib()
    rect = dlib.rectangle(*(int(round(v)) for v in b))
    shape = _predictor()(img, rect)
    return np.array([[shape.part(i).x, shape.part(i).y] for i in range(shape.num_parts)], dtype=np.float64)
