"""Face and landmark detection in photos: landmark detectors, each with its face detectors.

- ``landmark_detector="facemesh"`` (:mod:`.facemesh`): mediapipe's face mesh, 478 points;
  face detectors ``"short-range"`` / ``"full-range"`` (mediapipe's);
- ``landmark_detector="dlib"`` (:mod:`.dlib_detector`): dlib's 68 iBUG points; face
  detectors ``"hog"`` / ``"cnn"``;
- ``landmark_detector="network"``: the landmark network of the neural plugin (546 surface
  points, a σ each, a face score), found through the entry-point group
  ``morphable.landmark_detectors`` (:mod:`.plugins`; any other plugin registered there is
  taken by its name too); face detectors ``"short-range"`` / ``"full-range"`` / ``"hog"`` /
  ``"cnn"`` (whichever is installed), ``"windows"`` (the network's own face score over a grid
  of candidate windows), ``"auto"`` (mediapipe's short-range then full-range detector, else
  dlib's HOG, then the windows when they find no face);
- ``"auto"``: the face mesh when mediapipe can be imported, and for a face it does not find
  the network when its plugin is installed and can run (torch and its weights); else the
  network; else dlib (the committed network is less accurate than the face mesh on
  near-frontal photos but finds nearly every face: docs/landmark_net.md has the figures that keep it
  second); ``face_detector="auto"``: the
  landmark detector's default (the face mesh's whole-photo search with the full-range
  fallback, dlib's HOG).

:func:`detect` gives a :class:`~.result.Detection` (points, σ per point where the detector
predicts one, the 68 iBUG points, the convention, the face score and box);
:func:`detect_landmarks` and :func:`detect_ibug68` its points alone. :mod:`.images` reads
photos (grayscale, RGBA, 16-bit, EXIF-rotated -> upright RGB). Nothing here imports
mediapipe, cv2, dlib, torch or a plugin until a detection runs (or ``"auto"`` asks a plugin
whether it can run).

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

from ..errors import FitError, InputError
from . import plugins
from .boxes import check_box
from .images import as_image, image_size, read_image
from .result import FACE_PROBABILITY, Detection, landmark_noise

__all__ = ["LANDMARK_DETECTORS", "FACE_DETECTORS", "resolve_detectors", "detect", "detect_landmarks",
           "detect_ibug68", "detect_faces", "describe", "landmark_count", "Detection", "landmark_noise",
           "read_image", "image_size", "as_image"]

LANDMARK_DETECTORS = ("auto", "facemesh", "dlib", "network")
"""The landmark detectors by name ("network": the neural plugin's, when installed)."""
FACE_DETECTORS = {"facemesh": ("auto", "short-range", "full-range"), "dlib": ("auto", "hog", "cnn"),
                  "network": ("auto", "short-range", "full-range", "hog", "cnn", "windows")}
"""The face detectors each landmark detector takes ("auto": its default). A plugin other than
the network lists its own (its class's ``FACE_DETECTORS``)."""
BUILTIN = ("facemesh", "dlib")


@functools.lru_cache(maxsize=None)
def _facemesh_installed() -> bool:
    return importlib.util.find_spec("mediapipe") is not None


@functools.lru_cache(maxsize=None)
def _network_ready() -> bool:
    """Whether the network plugin is installed and says it can run (torch, weights); its module
    is imported for that, not torch."""
    if "network" not in plugins.entry_points():
        return False
    try:
        return plugins.detector_class("network").unavailable() is None
    except InputError:
        return False


def _face_detectors(landmark_detector: str) -> tuple:
    if landmark_detector in FACE_DETECTORS:
        return FACE_DETECTORS[landmark_detector]
    return tuple(plugins.detector_class(landmark_detector).FACE_DETECTORS)


def resolve_detectors(landmark_detector: str = "auto", face_detector: str = "auto") -> tuple[str, str]:
    """The choice as given -> ``(landmark detector, face detector)`` as run: "auto" landmark
    detector resolved to "facemesh" (mediapipe installed), else "network" (plugin installed,
    torch and weights present), else "dlib"; dlib's "auto" face detector to "hog" (the
    face mesh and the network keep "auto", their own strategy). InputError for an unknown name,
    a plugin that is not installed, or a face detector of another landmark detector."""
    if landmark_detector not in LANDMARK_DETECTORS and landmark_detector not in plugins.entry_points():
        raise InputError(f"landmark detector: choose from {', '.join(LANDMARK_DETECTORS)}, "
                         f"got {landmark_detector!r}")
    if landmark_detector == "auto":
        landmark_detector = ("facemesh" if _facemesh_installed() else
                             "network" if _network_ready() else "dlib")
    if landmark_detector not in BUILTIN:
        plugins.detector_class(landmark_detector)  # not installed: its one line, now
    allowed = _face_detectors(landmark_detector)
    if face_detector not in allowed:
        other = next((k for k in BUILTIN if face_detector in FACE_DETECTORS[k]), None)
        hint = f" ({face_detector} is {other}'s)" if other else ""
        raise InputError(f"face detector {face_detector!r} does not go with the {landmark_detector} "
                         f"landmark detector: choose from {', '.join(allowed)}{hint}")
    if landmark_detector == "dlib" and face_detector == "auto":
        face_detector = "hog"
    return landmark_detector, face_detector


def detect(image, *, landmark_detector: str = "auto", face_detector: str = "auto", box=None) -> Detection:
    """The landmarks of the largest face in a photo (or of the face in ``box``), with what the
    detector knows of them.

    Parameters
    ----------
    image : path or (H, W, 3) array (see :func:`.images.as_image`)
    landmark_detector : "auto", "facemesh", "dlib", "network" or another installed plugin's name
    face_detector : "auto" or one of ``FACE_DETECTORS[landmark detector]``
    box : (left, top, right, bottom) px, optional; skips face detection (a video's previous
        frame's :attr:`Detection.box`, for instance)

    Returns
    -------
    :class:`~.result.Detection`: the face mesh's 478 points (3D convention, no σ), dlib's 68
    (2D convention, no σ), the network's 478 face-mesh rows with their σ and its own 68 iBUG
    rows (3D convention, score, box). With "auto", a face the face mesh does not find is
    looked for by the network where it can run (:attr:`Detection.detector` says which found
    it; in a given box, only where the network scores it a face, :data:`FACE_PROBABILITY`):
    the face mesh misses faces turned far away, which the network finds.

    Raises
    ------
    FitError when no face is found; InputError for a bad image, box or detector name.
    """
    landmarks, faces = resolve_detectors(landmark_detector, face_detector)
    try:
        return _detect(image, landmarks, faces, box)
    except FitError as e:
        if not (landmark_detector == "auto" and landmarks == "facemesh" and _network_ready()):
            raise
        missed = e
    # the face mesh's face detectors are the network's too; in a given box the network reads
    # points whatever the box holds, so its face score decides (a video's carried box on a
    # frame without the face)
    try:
        found = _detect(image, "network", faces, box)
    except FitError as e:
        raise FitError(f"{e}; nor by the face mesh") from None
    if found.score is not None and found.score < FACE_PROBABILITY:
        raise missed
    return found


def _detect(image, landmarks: str, faces: str, box) -> Detection:
    """:func:`detect` with the detectors resolved, without the "auto" fallback."""
    if landmarks in BUILTIN:
        if landmarks == "facemesh":
            from .facemesh import detect_landmarks as mesh
            from .facemesh import to_ibug68

            pts = mesh(image, box=box, face_detector=faces)
            return Detection(pts, None, to_ibug68(pts), None, "facemesh478", "3d",
                             describe(landmarks, faces))
        from .dlib_detector import detect_landmarks as mesh

        pts = mesh(image, box=box, face_detector=faces)
        return Detection(pts, None, pts, None, "ibug68", "2d", describe(landmarks, faces))
    img, _ = as_image(image)
    return plugins.detector(landmarks).detect(img, box=None if box is None else check_box(box),
                                              face_detector=faces, name=_name(image))


def _name(image) -> str:
    return "image" if not isinstance(image, (str, bytes)) and not hasattr(image, "__fspath__") else str(image)


def detect_landmarks(image, *, landmark_detector: str = "auto", face_detector: str = "auto",
                     box=None) -> np.ndarray:
    """Landmarks of the largest face in a photo (or of the face in ``box``): :func:`detect`'s
    points.

    Parameters
    ----------
    image : path or (H, W, 3) array (see :func:`.images.as_image`)
    landmark_detector : {"auto", "facemesh", "dlib", "network"} or a plugin's name
    face_detector : "auto" or one of ``FACE_DETECTORS[landmark detector]``
    box : (left, top, right, bottom) pixels, optional; skips face detection

    Returns
    -------
    (478, 2) float64 (facemesh, the network: mediapipe's order) or (68, 2) (dlib, iBUG order)
    pixels, 0-based, x right, y down.

    Raises
    ------
    FitError when no face is found; InputError for a bad image, box or detector name.
    """
    return detect(image, landmark_detector=landmark_detector, face_detector=face_detector,
                  box=box).points


def detect_ibug68(image, *, landmark_detector: str = "auto", face_detector: str = "auto",
                  box=None) -> np.ndarray:
    """:func:`detect`'s 68 iBUG points -> (68, 2) px: dlib's own, the network's own 68 rows,
    the face mesh's 478 through :data:`.facemesh.FACEMESH_TO_IBUG68`."""
    return detect(image, landmark_detector=landmark_detector, face_detector=face_detector,
                  box=box).ibug68


def detect_faces(image, *, landmark_detector: str = "auto", face_detector: str = "auto") -> np.ndarray:
    """Face boxes of the landmark detector's face detector, largest first -> (F, 4) float64
    ``(left, top, right, bottom)`` px. The face mesh's "auto" is its full-range detector; the
    network's, the face detector it would use (its windows when that finds none)."""
    landmarks, faces = resolve_detectors(landmark_detector, face_detector)
    if landmarks == "facemesh":
        from .facemesh import detect_faces as boxes

        return boxes(image, face_detector="full-range" if faces == "auto" else faces)
    if landmarks == "dlib":
        from .dlib_detector import detect_faces as boxes

        return boxes(image, face_detector=faces)
    return plugins.detector(landmarks).detect_faces(as_image(image)[0], face_detector=faces)


def describe(landmark_detector: str = "auto", face_detector: str = "auto") -> str:
    """The choice as run, for reports: e.g. ``"facemesh auto"``, ``"dlib hog"``, ``"network auto"``."""
    return " ".join(resolve_detectors(landmark_detector, face_detector))


def landmark_count(landmark_detector: str = "auto", face_detector: str = "auto") -> int:
    """Rows :func:`detect_landmarks` gives with that choice: 68 (dlib) or 478 (the others)."""
    return 68 if resolve_detectors(landmark_detector, face_detector)[0] == "dlib" else 478
