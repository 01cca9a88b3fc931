"""Face and 68-point landmark detection with dlib (the ``detect`` extra).

The models ship in the PyPI package ``face-recognition-models``; they are found on disk
without importing that package (its ``__init__`` needs ``pkg_resources``).

>>> pts = detect_landmarks("../shared/data/images/image_0010.png")  # doctest: +SKIP
>>> pts.shape  # doctest: +SKIP
(68, 2)
"""
from __future__ import annotations

import functools
import importlib.util
from pathlib import Path

import numpy as np

from ..errors import FitError, InputError

__all__ = ["read_image", "detect_faces", "detect_landmarks", "model_file"]


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
    raise InputError(f"detector: expected 'hog' or 'cnn', got {kind!r}")


@functools.lru_cache(maxsize=None)
def _predictor():
    return _dlib().shape_predictor(str(model_file("shape_predictor_68_face_landmarks.dat")))


def read_image(path) -> np.ndarray:
    """(H, W, 3) uint8 RGB image (PNG, JPEG, PPM...); InputError naming the file if unreadable."""
    from PIL import Image, UnidentifiedImageError

    try:
        with Image.open(path) as im:
            return np.asarray(im.convert("RGB"))
    except (OSError, UnidentifiedImageError, ValueError, Image.DecompressionBombError) as e:
        raise InputError(f"{path}: cannot read image ({e})") from None


def _as_image(image):
    if isinstance(image, (str, Path)):
        return read_image(image), str(image)
    a = np.asarray(image)
    if a.ndim == 2:
        a = np.repeat(a[..., None], 3, axis=-1)
    if a.ndim != 3 or a.shape[-1] not in (3, 4) or a.shape[0] == 0 or a.shape[1] == 0:
        raise InputError(f"image: expected (H, W, 3) pixels, got {a.shape}")
    if a.dtype != np.uint8:
        a = np.clip(a * (255.0 if a.dtype.kind == "f" and a.max() <= 1.0 else 1.0), 0, 255).astype(np.uint8)
    return np.ascontiguousarray(a[..., :3]), "image"


def detect_faces(image, *, detector: str = "hog", upsample: int = 1) -> np.ndarray:
    """Face boxes, largest first.

    Parameters
    ----------
    image : path or (H, W, 3) array
    detector : {"hog", "cnn"}
        dlib's HOG frontal detector (fast) or its CNN ``mmod`` detector (slower, more poses).
    upsample : int
        Times the image is upsampled before detection (finds smaller faces).

    Returns
    -------
    (F, 4) float array of boxes ``(left, top, right, bottom)`` in pixels.
    """
    img, _ = _as_image(image)
    found = _detector(detector)(img, int(upsample))
    rects = [getattr(d, "rect", d) for d in found]
    boxes = np.array([[r.left(), r.top(), r.right(), r.bottom()] for r in rects], dtype=np.float64).reshape(-1, 4)
    area = (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])
    return boxes[np.argsort(-area, kind="stable")]


def detect_landmarks(image, *, box=None, detector: str = "hog", upsample: int = 1) -> np.ndarray:
    """68 iBUG landmarks of the largest face (or of the face in ``box``).

    Parameters
    ----------
    image : path or (H, W, 3) array
    box : (left, top, right, bottom) pixels, optional; skips detection
    detector, upsample : see :func:`detect_faces`

    Returns
    -------
    (68, 2) float64 pixels, 0-based, x right, y down.

    Raises
    ------
    FitError when no face is found.
    """
    img, name = _as_image(image)
    if box is None:
        boxes = detect_faces(img, detector=detector, upsample=upsample)
        if len(boxes) == 0:
            raise FitError(f"{name}: no face found (try detector='cnn' or a larger upsample)")
        box = boxes[0]
    b = np.asarray(box, dtype=np.float64).reshape(-1)
    if b.shape != (4,) or not np.all(np.isfinite(b)) or b[2] <= b[0] or b[3] <= b[1]:
        raise InputError(f"box: expected (left, top, right, bottom) with right > left, bottom > top, got {box}")
    dlib = _dlib()
    rect = dlib.rectangle(*(int(round(v)) for v in b))
    shape = _predictor()(img, rect)
    return np.array([[shape.part(i).x, shape.part(i).y] for i in range(shape.num_parts)], dtype=np.float64)
