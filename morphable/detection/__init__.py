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
- ``landmark_detector="fused"``: the network, then the face mesh in the network's box, the
  two readings fused by their uncertainty (:func:`.fusion.fuse`: the network's σ per point, the
  face mesh's from how far it lies from the network); the network alone where the face mesh
  finds no face there, the face mesh alone where the network finds none; the network's face
  detectors;
- ``"auto"``: "fused" where mediapipe is installed and the network's plugin can run (torch and
  its weights), else the face mesh, else the network, else dlib (docs/landmark_net.md: the
  fused points fit better than either's alone on the held-out faces and on AFLW2000-3D);
  ``face_detector="auto"``: the landmark detector's default (the face mesh's whole-photo
  search with the full-range fallback, dlib's HOG, the network's mediapipe boxes then its
  window search).

:func:`detect` gives a :class:`~.result.Detection` (points, σ per point where the detector
predicts one, the 68 iBUG points, the convention, the face score and box) of the largest face;
:func:`detect_all` one for every face of a photo, left to right; :func:`detect_in_boxes` the
faces in given boxes (a video's boxes carried from its previous frame);
:func:`detect_landmarks` and :func:`detect_ibug68` its points alone. :mod:`.images` reads
photos (grayscale, RGBA, 16-bit, EXIF-rotated -> upright RGB). Nothing here imports
mediapipe, cv2, dlib, torch or a plugin until a detection runs (or ``"auto"`` asks a plugin
whether it can run).

>>> from morphable.detection import detect, detect_ibug68
>>> photo = "../shared/data/images/image_0010.png"
>>> found = detect(photo)         # "auto": the network and the face mesh fused (all extras installed)
>>> found.detector, found.points.shape, found.sigma_px.shape, found.ibug68.shape
('network short-range + facemesh', (478, 2), (478,), (68, 2))
>>> detect_ibug68(photo, landmark_detector="dlib").shape
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
           "detect_ibug68", "detect_faces", "detect_all", "detect_in_boxes", "face_box", "SAME_FACE_IOU",
           "QUICK_FACE_DETECTORS", "QUICKEST_FACE_DETECTORS", "TILES", "describe", "landmark_count", "Detection", "landmark_noise",
           "read_image", "image_size", "as_image"]

LANDMARK_DETECTORS = ("auto", "fused", "facemesh", "dlib", "network")
"""The landmark detectors by name ("network": the neural plugin's, when installed; "fused":
the network and the face mesh together)."""
_NETWORK_FACES = ("auto", "short-range", "full-range", "hog", "cnn", "windows")
FACE_DETECTORS = {"facemesh": ("auto", "short-range", "full-range"), "dlib": ("auto", "hog", "cnn"),
                  "network": _NETWORK_FACES, "fused": _NETWORK_FACES}
"""The face detectors each landmark detector takes ("auto": its default; "fused": the
network's, which finds the face). A plugin other than the network lists its own (its class's
``FACE_DETECTORS``)."""
QUICK_FACE_DETECTORS = {"facemesh": "full-range", "network": "full-range", "fused": "full-range",
                        "dlib": "hog"}
"""Per landmark detector, a quick face detector that finds small faces: mediapipe's full-range
detector (5 ms on a 640 x 480 frame with faces; 70 ms without, in its own tiles, where "auto"
ends in the network's window search, about 1.2 s) and dlib's HOG. :func:`detect_all`'s tiles
and a video's searches between full ones (:mod:`morphable.tracking.footage`) use it."""
QUICKEST_FACE_DETECTORS = {"facemesh": "short-range", "network": "short-range", "fused": "short-range",
                           "dlib": "hog"}
"""Per landmark detector, its quickest face detector: mediapipe's short-range detector (2-3 ms
on a 640 x 480 frame, with or without a face; it misses faces under about 100 px there) and
dlib's HOG. A video's frames without a tracked face and a photo's count of faces use it."""
BUILTIN = ("facemesh", "dlib")
SAME_FACE_IOU = 0.5
"""Two detections whose :func:`face_box` overlap by this IoU or more are one face read twice
(two face detectors' boxes, or two boxes of a video, on the same face)."""
FUSED = "fused"


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
    detector resolved to "fused" (mediapipe installed and the network's plugin ready: torch
    and weights present), else "facemesh", else "network", else "dlib"; dlib's "auto" face
    detector to "hog" (the others keep "auto", their own strategy). InputError for an unknown
    name, a plugin that is not installed, "fused" without mediapipe, or a face detector of
    another landmark detector."""
    if landmark_detector not in LANDMARK_DETECTORS and landmark_detector not in plugins.entry_points():
        raise InputError(f"landmark detector: choose from {', '.join(LANDMARK_DETECTORS)}, "
                         f"got {landmark_detector!r}")
    if landmark_detector == "auto":
        mesh, network = _facemesh_installed(), _network_ready()
        landmark_detector = (FUSED if mesh and network else "facemesh" if mesh else
                             "network" if network else "dlib")
    if landmark_detector == FUSED and not _facemesh_installed():
        raise InputError("landmark detector 'fused' needs mediapipe (pip install mediapipe) "
                         "besides the network")
    if landmark_detector not in BUILTIN:
        # not installed: its one line, now
        plugins.detector_class("network" if landmark_detector == FUSED else landmark_detector)
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
    landmark_detector : "auto", "fused", "facemesh", "dlib", "network" or another installed
        plugin's name
    face_detector : "auto" or one of ``FACE_DETECTORS[landmark detector]``
    box : (left, top, right, bottom) px, optional; skips face detection (a video's previous
        frame's :attr:`Detection.box`, for instance)

    Returns
    -------
    :class:`~.result.Detection`: the face mesh's 478 points (3D convention, no σ), dlib's 68
    (2D convention, no σ), the network's 478 face-mesh rows with their σ and its own 68 iBUG
    rows (3D convention, score, box), "fused" the two fused with their σ
    (:attr:`Detection.detector` says which ran: e.g. ``"network short-range + facemesh"``, or
    ``"network windows"`` where the face mesh found no face in the network's box).

    Raises
    ------
    FitError when no face is found; InputError for a bad image, box or detector name.
    """
    landmarks, faces = resolve_detectors(landmark_detector, face_detector)
    if landmarks == FUSED:
        return _fused(image, faces, box)
    return _detect(image, landmarks, faces, box)


def _fused(image, faces: str, box) -> Detection:
    """The "fused" detector: the network finds the face and reads it, the face mesh reads it in
    the same box, :func:`.fusion.fuse` makes one reading of the two. A face the network does
    not find (or, in a given box, does not score a face: a video's carried box on a frame
    without the face) is the face mesh's alone: the face mesh has its own face check."""
    from .fusion import fuse

    img, name = as_image(image)          # decoded once for both detectors
    mesh_faces = faces if faces in FACE_DETECTORS["facemesh"] else "auto"
    try:
        found = _detect(img, "network", faces, box, name)
    except FitError as e:
        missed = e
    else:
        if box is None or found.score is None or found.score >= FACE_PROBABILITY:
            try:
                mesh = _detect(img, "facemesh", mesh_faces, found.box if box is None else box)
            except FitError:
                return found
            return fuse(found, mesh)
        missed = FitError(f"{name}: the landmark network scores the box {found.score:.2f} "
                          f"as a face (a face needs {FACE_PROBABILITY})")
    try:
        return _detect(img, "facemesh", mesh_faces, box)
    except FitError:
        raise FitError(f"{missed}; nor by the face mesh") from None


def _detect(image, landmarks: str, faces: str, box, name: str | None = None) -> Detection:
    """:func:`detect` with the detectors resolved, one detector (``name``: the photo's, for
    messages, where ``image`` is its decoded array)."""
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
                                              face_detector=faces, name=name or _name(image))


def _name(image) -> str:
    return "image" if not isinstance(image, (str, bytes)) and not hasattr(image, "__fspath__") else str(image)


def detect_landmarks(image, *, landmark_detector: str = "auto", face_detector: str = "auto",
                     box=None) -> np.ndarray:
    """Landmarks of the largest face in a photo (or of the face in ``box``): :func:`detect`'s
    points.

    Parameters
    ----------
    image : path or (H, W, 3) array (see :func:`.images.as_image`)
    landmark_detector : {"auto", "fused", "facemesh", "dlib", "network"} or a plugin's name
    face_detector : "auto" or one of ``FACE_DETECTORS[landmark detector]``
    box : (left, top, right, bottom) pixels, optional; skips face detection

    Returns
    -------
    (478, 2) float64 (facemesh, the network, fused: mediapipe's order) or (68, 2) (dlib, iBUG order)
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
    network's (and "fused"'s), the face detector it would use (its windows when that finds
    none)."""
    landmarks, faces = resolve_detectors(landmark_detector, face_detector)
    if landmarks == "facemesh":
        from .facemesh import detect_faces as boxes

        return boxes(image, face_detector="full-range" if faces == "auto" else faces)
    if landmarks == "dlib":
        from .dlib_detector import detect_faces as boxes

        return boxes(image, face_detector=faces)
    network = "network" if landmarks == FUSED else landmarks
    return plugins.detector(network).detect_faces(as_image(image)[0], face_detector=faces)


def face_box(detection: Detection) -> np.ndarray:
    """A detection's face box -> (4,) float64 ``(left, top, right, bottom)`` px: the
    detector's own (:attr:`Detection.box`, which :func:`detect`'s ``box=`` reads) where it
    gives one, else the extent of its 68 iBUG points (what dlib's and the face mesh's ``box=``
    read roughly)."""
    if detection.box is not None:
        return np.asarray(detection.box, dtype=np.float64)
    return np.concatenate([detection.ibug68.min(0), detection.ibug68.max(0)])


def detect_in_boxes(image, boxes, *, landmark_detector: str = "auto",
                    face_detector: str = "auto", min_score: float | None = FACE_PROBABILITY) -> list:
    """The face in each of ``boxes``: :func:`detect` with ``box=`` for each.

    Parameters
    ----------
    image : path or (H, W, 3) array (decoded once for all boxes)
    boxes : (B, 4) px ``(left, top, right, bottom)``, e.g. :func:`face_box` of a video's
        previous frame's detections
    landmark_detector, face_detector : see :func:`detect`
    min_score : a reading whose face score (:attr:`Detection.score`, where the detector gives
        one) is below this is no face (default :data:`~.result.FACE_PROBABILITY`); None keeps
        every reading, for the caller to judge

    Returns
    -------
    list of B :class:`~.result.Detection` or None: None where the box holds no face (the
    detector finds none there, or scores its crop below ``min_score``, or the box lies outside
    the image).
    """
    img, name = as_image(image)
    out = []
    for b in np.asarray(boxes, dtype=np.float64).reshape(-1, 4):
        try:
            found = detect(img, landmark_detector=landmark_detector, face_detector=face_detector,
                           box=b)
        except (FitError, InputError):
            # a carried box that has left the picture or shrunk below what a detector reads
            # holds no face to read, which is what the caller asks
            found = None
        if found is not None and found.score is not None and min_score is not None and found.score < min_score:
            found = None
        out.append(found)
    return out


TILES = ((2, 2 / 3), (3, 1 / 2))
""":func:`detect_all`'s tiles: ``(n, side)``, n x n overlapping squares of ``side`` x the
photo's longer side, spread edge to edge. On the first 20 AFW photos with two faces or more
(61 faces annotated, 26-70 px wide ones among them; research use only) the face detectors'
whole-photo pass finds 52 of them, with the tiles all 61 (0.5 s a photo on the 2 shared cores;
``python -m evaluation.bench_footage --group 20``), and 13 faces AFW does not annotate."""


def _tile_boxes(img: np.ndarray, landmark_detector: str, face_detector: str) -> list:
    """The face boxes of :data:`TILES` (each tile's own face detection), in photo px."""
    H, W = img.shape[:2]
    out = []
    for n, frac in TILES:
        side = int(round(frac * max(W, H)))
        for y in np.linspace(0, max(0, H - side), n).astype(int):
            for x in np.linspace(0, max(0, W - side), n).astype(int):
                tile = np.ascontiguousarray(img[y:y + side, x:x + side])
                for b in detect_faces(tile, landmark_detector=landmark_detector, face_detector=face_detector):
                    out.append(b + [x, y, x, y])
    return out


def detect_all(image, *, landmark_detector: str = "auto", face_detector: str = "auto", skip=None,
               tiles: bool = False) -> list:
    """Every face of a photo, ordered left to right.

    The face detector's boxes (:func:`detect_faces`), each read by the landmark detector
    (:func:`detect_in_boxes`); a box without a face is dropped, and two readings of one face
    (:data:`SAME_FACE_IOU`) kept once, the first (the larger box's).

    Parameters
    ----------
    image : path or (H, W, 3) array
    landmark_detector, face_detector : see :func:`detect`
    skip : (S, 4) px boxes, optional: faces known already (a video's tracked faces); a face
        box overlapping one of them by :data:`SAME_FACE_IOU` is neither read nor returned
    tiles : bool, also search overlapping tiles (:data:`TILES`) with the landmark detector's
        :data:`QUICK_FACE_DETECTORS` face detector (``face_detector="auto"``; else the one
        chosen): the small faces of a group photo, which a pass over the whole photo misses

    Returns
    -------
    list of :class:`~.result.Detection`, by the centre of their :func:`face_box` from left to
    right (an empty list: no face).

    >>> from morphable.io.landmark_files import read_pts
    >>> faces = detect_all("../shared/data/images/breakingbad.jpg")    # two men, the right one annotated
    >>> truth = read_pts("../shared/data/images/breakingbad.pts")      # a face ~360 px wide
    >>> [bool(np.median(np.linalg.norm(f.ibug68 - truth, axis=1)) < 15) for f in faces]
    [False, True]
    """
    from .boxes import iou

    img, name = as_image(image)
    known = [np.asarray(b, dtype=np.float64) for b in (() if skip is None else np.reshape(skip, (-1, 4)))]

    def seen(box, among) -> bool:
        return bool(among) and float(iou(np.array(among), box).max()) >= SAME_FACE_IOU

    boxes = list(detect_faces(img, landmark_detector=landmark_detector, face_detector=face_detector))
    if tiles:
        quick = face_detector
        if face_detector == "auto":
            quick = QUICK_FACE_DETECTORS.get(resolve_detectors(landmark_detector)[0], "auto")
        for b in _tile_boxes(img, landmark_detector, quick):
            if not seen(b, boxes):        # a face of the whole photo's pass found again
                boxes.append(b)
    boxes = [b for b in boxes if not seen(b, known)]
    kept, kept_boxes = [], []
    for found in detect_in_boxes(img, boxes, landmark_detector=landmark_detector,
                                 face_detector=face_detector):
        if found is None or seen(face_box(found), kept_boxes + known):
            continue
        kept.append(found)
        kept_boxes.append(face_box(found))
    order = np.argsort([(b[0] + b[2]) / 2 for b in kept_boxes], kind="stable")
    return [kept[i] for i in order]


def describe(landmark_detector: str = "auto", face_detector: str = "auto") -> str:
    """The choice as run, for reports: e.g. ``"facemesh auto"``, ``"dlib hog"``, ``"network auto"``."""
    return " ".join(resolve_detectors(landmark_detector, face_detector))


def landmark_count(landmark_detector: str = "auto", face_detector: str = "auto") -> int:
    """Rows :func:`detect_landmarks` gives with that choice: 68 (dlib) or 478 (the others)."""
    return 68 if resolve_detectors(landmark_detector, face_detector)[0] == "dlib" else 478
