"""Face and landmark detection in photos: two landmark detectors, each with its face detectors.

- ``landmark_detector="facemesh"`` (:mod:`.facemesh`): mediapipe's face mesh, 478 points;
  face detectors ``"short-range"`` / ``"full-range"`` (mediapipe's); the default when
  mediapipe is installed;
- ``landmark_detector="dlib"`` (:mod:`.dlib_detector`): dlib's 68 iBUG points; face
  detectors ``"hog"`` / ``"cnn"``;
- ``"auto"``: the face mesh when mediapipe can be imported, else dlib; ``face_detector="auto"``:
  the landmark detector's default (the face mesh's whole-photo search with the full-range
  fallback, dlib's HOG).

:mod:`.images` reads photos (grayscale, RGBA, 16-bit, EXIF-rotated -> upright RGB). Nothing
here imports mediapipe, cv2 or dlib until a detection runs.

>>> from morphable.detection import detect_landmarks                  # doctest: +SKIP
>>> detect_landmarks("image_0010.png").shape                          # doctest: +SKIP
(478, 2)
>>> detect_ibug68("image_0010.png", landmark_detector="dlib").shape   # doctest: +SKIP
(68, 2)
"""
from __future__ import annotations

import functools
import importlib.util

import numpy as np

from ..errors import InputError
from .images import as_image, image_size, read_image

__all__ = ["LANDMARK_DETECTORS", "FACE_DETECTORS", "resolve_detectors", "detect_landmarks",
           "detect_ibug68", "detect_faces", "describe", "read_image", "image_size", "as_image"]

LANDMARK_DETECTORS = ("auto", "facemesh", "dlib")
FACE_DETECTORS = {"facemesh": ("auto", "short-range", "full-range"), "dlib": ("auto", "hog", "cnn")}
"""The face detectors each landmark detector takes ("auto": its default)."""


@functools.lru_cache(maxsize=None)
def _facemesh_installed() -> bool:
    return importlib.util.find_spec("mediapipe") is not None


def resolve_detectors(landmark_detector: str = "auto", face_detector: str = "auto") -> tuple[str, str]:
    """The choice as given -> ``(landmark detector, face detector)`` as run: "auto" landmark
    detector resolved to "facemesh" or "dlib"; dlib's "auto" face detector to "hog" (the face
    mesh keeps "auto", its own strategy). InputError for an unknown name or a face detector
    of the other landmark detector."""
    if landmark_detector not in LANDMARK_DETECTORS:
        raise InputError(f"landmark detector: choose from {', '.join(LANDMARK_DETECTORS)}, "
                         f"got {landmark_detector!r}")
    if landmark_detector == "auto":
        landmark_detector = "facemesh" if _facemesh_installed() else "dlib"
    allowed = FACE_DETECTORS[landmark_detector]
    if face_detector not in allowed:
        other = next(k for k, v in FACE_DETECTORS.items() if face_detector in v) if any(
            face_detector in v for v in FACE_DETECTORS.values()) else None
        hint = f" ({face_detector} is {other}'s)" if other else ""
        raise InputError(f"face detector {face_detector!r} does not go with the {landmark_detector} "
                         f"landmark detector: choose from {', '.join(allowed)}{hint}")
    if landmark_detector == "dlib" and face_detector == "auto":
        face_detector = "hog"
    return landmark_detector, face_detector


def detect_landmarks(image, *, landmark_detector: str = "auto", face_detector: str = "auto",
                     box=None) -> np.ndarray:
    """Landmarks of the largest face in a photo (or of the face in ``box``).

    Parameters
    ----------
    image : path or (H, W, 3) array (see :func:`.images.as_image`)
    landmark_detector : {"auto", "facemesh", "dlib"}
    face_detector : "auto", or "short-range" / "full-range" (facemesh), "hog" / "cnn" (dlib)
    box : (left, top, right, bottom) pixels, optional; skips face detection

    Returns
    -------
    (478, 2) float64 (facemesh, mediapipe's order) or (68, 2) (dlib, iBUG order) pixels,
    0-based, x right, y down.

    Raises
    ------
    FitError when no face is found; InputError for a bad image, box or detector name.
    """
    landmarks, faces = resolve_detectors(landmark_detector, face_detector)
    if landmarks == "facemesh":
        from .facemesh import detect_landmarks as mesh
    else:
        from .dlib_detector import detect_landmarks as mesh
    return mesh(image, box=box, face_detector=faces)


def detect_ibug68(image, *, landmark_detector: str = "auto", face_detector: str = "auto",
                  box=None) -> np.ndarray:
    """:func:`detect_landmarks` as 68 iBUG points -> (68, 2) px: the face mesh's 478 through
    :data:`.facemesh.FACEMESH_TO_IBUG68` (a stopgap until the fitter takes the 478 points)."""
    pts = detect_landmarks(image, landmark_detector=landmark_detector,
                           face_detector=face_detector, box=box)
    if len(pts) == 68:
        return pts
    from .facemesh import to_ibug68

    return to_ibug68(pts)


def detect_faces(image, *, landmark_detector: str = "auto", face_detector: str = "auto") -> np.ndarray:
    """Face boxes of the landmark detector's face detector, largest first -> (F, 4) float64
    ``(left, top, right, bottom)`` px. The face mesh's "auto" is its full-range detector."""
    landmarks, faces = resolve_detectors(landmark_detector, face_detector)
    if landmarks == "facemesh":
        from .facemesh import detect_faces as boxes

        return boxes(image, face_detector="full-range" if faces == "auto" else faces)
    from .dlib_detector import detect_faces as boxes

    return boxes(image, face_detector=faces)


def describe(landmark_detector: str = "auto", face_detector: str = "auto") -> str:
    """The choice as run, for reports: e.g. ``"facemesh auto"``, ``"dlib hog"``."""
    return " ".join(resolve_detectors(landmark_detector, face_detector))
