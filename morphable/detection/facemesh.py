"""mediapipe's face mesh: 478 landmarks (468 mesh points + 10 iris points) of a face.

Needs ``mediapipe==0.10.14`` (its face detector and face-landmark models ship inside that
wheel; later versions do not), installed without its declared dependencies, and the
``facemesh`` extra (docs/detection.md says why). mediapipe and cv2 are imported on first use
only, and each model is loaded once per process.

Points are in mediapipe's own index order (the order of ``mediapipe.solutions.face_mesh`` and
of ``face_model_with_iris.obj``: 468-472 one iris, 473-477 the other), in the toolkit's pixel
convention: x right, y down, 0-based, the centre of the top-left pixel at (0, 0) — the
convention :func:`morphable.io.landmark_files.read_pts` gives (it subtracts 1 from the 1-based
``.pts`` values). mediapipe's normalised coordinates run from the image's left edge (0) to its
right edge (1), so a point is at ``x * W - 0.5``, ``y * H - 0.5``.

Faces: with ``face_detector="auto"`` the mesh runs on the whole photo (its own short-range
detector, one call, ~15-30 ms) and the largest face is kept; when it finds none, the
full-range face detector searches the photo, then in overlapping tiles (so that a face of
60 px in a 1.5 MP photo is found), and the mesh runs on an enlarged crop around the largest
box. ``"short-range"`` / ``"full-range"`` always take that detector's largest box; a given
``box`` skips detection.

>>> from morphable.io.landmark_files import read_pts
>>> pts = detect_landmarks("../shared/data/images/image_0010.png")
>>> truth = read_pts("../shared/data/images/image_0010.pts")      # annotated, 68 points
>>> error = np.linalg.norm(to_ibug68(pts) - truth, axis=1)         # px, on a face ~400 px wide
>>> pts.shape, bool(np.median(error[17:]) < 10)                    # the inner points
((478, 2), True)
"""
from __future__ import annotations

import atexit
import contextlib
import functools
import importlib
import importlib.util
import os
import sys
import threading
import warnings

import numpy as np

from ..errors import FitError, InputError
from .boxes import check_box, largest_first
from .boxes import iou as overlap
from .images import as_image

__all__ = ["FACE_DETECTORS", "N_POINTS", "FACEMESH_TO_IBUG68", "CROP_MARGIN", "CROP_PX",
           "MIN_FACE_FRACTION", "detect_faces", "detect_landmarks", "to_ibug68"]

N_POINTS = 478
FACE_DETECTORS = ("short-range", "full-range")
"""mediapipe's face detectors: short-range (faces within ~2 m, filling a good part of the
photo) and full-range (smaller faces; here also run in tiles)."""
MAX_FACES = 4
"""Faces the whole-photo mesh looks for, of which the largest is kept."""
CROP_MARGIN = 2.0
"""The mesh runs on a square crop this many times the face box's larger side, centred on it."""
CROP_PX = 256
"""... resampled to this many pixels a side: a small face is enlarged, a large one reduced."""
MIN_FACE_FRACTION = 40
"""Faces narrower than about 1/40 of the photo's longer side go unfound (measured: image_0010's
face scaled to 35 px in a 1500 x 1000 photo is found, at 25 px it is not)."""
TILE_LEVELS = (2, 3)
"""When the full-range detector finds no face in the whole photo, it searches overlapping
square tiles, first of 2/3 of the photo's longer side, then of 1/2 of it."""

# The mapping of the 478 points to iBUG-68, a stopgap until the fitter takes the 478 points
# (the surface correspondence of issue 24 supersedes it). Derived, not copied: on the 4
# annotated photos of ../shared/data/images and the first 30 300-W afw photos, the mean
# distance (normalised by sqrt(w*h) of the annotation's box) between each iBUG point and each
# mesh point, and per iBUG point the mesh point with the smallest one; jaw points (iBUG 1-17)
# choose among the face-oval points only. Command: ``python -m evaluation.facemesh_ibug68
# --n-300w 30`` (34 photos; the chosen points' mean distance: median 2.5 %, at most 8.7 %, iBUG 15).
FACEMESH_TO_IBUG68 = np.array([
    127, 234, 132, 58, 172, 136, 149, 148, 152, 400, 378, 365,
    397, 288, 323, 454, 356, 70, 63, 105, 66, 55, 336, 296,
    334, 293, 300, 168, 197, 195, 4, 75, 97, 2, 326, 460,
    7, 159, 157, 133, 153, 144, 382, 385, 387, 263, 373, 380,
    76, 73, 72, 11, 302, 304, 291, 405, 314, 17, 84, 181,
    96, 82, 13, 312, 308, 316, 14, 87,
], dtype=np.int64)
"""(68,) int64: the face-mesh point taken for each iBUG-68 point (derived by
``python -m evaluation.facemesh_ibug68 --n-300w 30``)."""

_lock = threading.Lock()  # mediapipe's graphs take one image at a time


@contextlib.contextmanager
def _stderr_to(fd: int):
    """File descriptor 2 pointed at ``fd`` (taken over: closed here) and Python's warnings
    off, both given back on leaving."""
    sys.stderr.flush()
    saved = os.dup(2)
    os.dup2(fd, 2)
    os.close(fd)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            yield
    finally:
        os.dup2(saved, 2)
        os.close(saved)


def _quiet():
    """mediapipe's C++ code logs set-up lines (TFLite delegate, feedback manager) straight to
    file descriptor 2, and protobuf warns when results are read: a CLI must answer in one
    line, so stderr is closed while mediapipe works."""
    return _stderr_to(os.open(os.devnull, os.O_WRONLY))


def _silence_stderr_at_exit():
    """fd 2 to /dev/null once the program is done: mediapipe's graphs also log from their own
    threads and destructors while the process ends, after a command has given its one line."""
    sys.stderr.flush()
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 2)
    os.close(null)


def _bare_package(name: str):
    """The package ``name`` in ``sys.modules`` as a bare package, its folder without its
    ``__init__``, where nothing imported it yet; its ``__init__`` runs on the first look-up of a
    name it lacks (``mediapipe.solutions``, ``mediapipe.__version__``), so that other code of
    the process finds the package whole.

    mediapipe's ``__init__`` imports every solution, the drawing utilities (matplotlib's
    pyplot with them) and the tasks API, none of which the face mesh uses: ``/usr/bin/time
    python -c "import mediapipe"`` took 1.2 s and 140 MB here, the two solutions alone 0.3 s
    and 55 MB (``evaluation.bench_startup --profile`` times them in a fit)."""
    import types

    if name in sys.modules:
        return
    spec = importlib.util.find_spec(name)
    if spec is None:
        raise ImportError(f"No module named {name!r}")
    package = types.ModuleType(name)
    package.__path__, package.__spec__, package.__file__ = list(spec.submodule_search_locations), spec, spec.origin
    package.__loader__, package.__package__ = spec.loader, name

    def whole(attr):
        del package.__getattr__
        spec.loader.exec_module(package)
        return getattr(package, attr)

    package.__getattr__ = whole
    sys.modules[name] = package


@functools.lru_cache(maxsize=None)
def _solutions():
    try:
        with _quiet():
            _bare_package("mediapipe")
            _bare_package("mediapipe.python.solutions")
            # import_module, not "from ... import": that asks the bare package for the names first
            face_detection = importlib.import_module("mediapipe.python.solutions.face_detection")
            face_mesh = importlib.import_module("mediapipe.python.solutions.face_mesh")
    except ImportError as e:
        raise InputError("the face mesh needs mediapipe: pip install -e '.[facemesh]' and "
                         f"pip install --no-deps mediapipe==0.10.14 ({e})") from None
    atexit.register(_silence_stderr_at_exit)
    return face_detection, face_mesh


OPEN_WAIT_S = 2.0
"""The longest a new graph is waited for to finish opening (see ``_opened``)."""


def _opened(make, models: int):
    """The graph ``make()`` builds, once its calculators have opened, with stderr away meanwhile.

    A new graph opens its calculators on its own threads after the constructor returns, each
    of its ``models`` TFLite models logging one "inference_feedback_manager" line to file
    descriptor 2 when it loads; a blank image does not wait for them all (the face mesh's
    landmark model only runs on a face). So stderr goes to a pipe from before the graph is
    built until those lines have come (or :data:`OPEN_WAIT_S` has passed): a line after that
    would break a command's one-line answer."""
    import time

    read, write = os.pipe()
    try:
        with _lock, _stderr_to(write):
            graph = make()
            graph.process(np.zeros((32, 32, 3), np.uint8))
            os.set_blocking(read, False)
            seen, end = b"", time.monotonic() + OPEN_WAIT_S
            while seen.count(b"inference_feedback_manager") < models and time.monotonic() < end:
                try:
                    seen += os.read(read, 1 << 16)
                except BlockingIOError:
                    time.sleep(0.01)
    finally:
        os.close(read)
    return graph


@functools.lru_cache(maxsize=None)
def _mesh():
    # face detection, face landmarks
    return _opened(lambda: _solutions()[1].FaceMesh(static_image_mode=True, refine_landmarks=True,
                                                    max_num_faces=MAX_FACES), models=2)


@functools.lru_cache(maxsize=None)
def _detector(kind: str):
    if kind not in FACE_DETECTORS:
        raise InputError(f"face detector: the face mesh has {' or '.join(FACE_DETECTORS)}, got {kind!r}")
    return _opened(lambda: _solutions()[0].FaceDetection(model_selection=FACE_DETECTORS.index(kind)),
                   models=1)


def _process(graph, img: np.ndarray):
    with _lock, _quiet():
        return graph.process(img)


def _boxes(img: np.ndarray, kind: str) -> np.ndarray:
    """(F, 5) ``(left, top, right, bottom, score)`` px of the faces a detector finds in one image."""
    H, W = img.shape[:2]
    found = _process(_detector(kind), img).detections or []
    out = []
    for d in found:
        b = d.location_data.relative_bounding_box
        x0, y0 = b.xmin * W - 0.5, b.ymin * H - 0.5
        out.append([x0, y0, x0 + b.width * W, y0 + b.height * H, d.score[0]])
    return np.array(out, dtype=np.float64).reshape(-1, 5)


def _tiles(W: int, H: int, level: int):
    """Overlapping square tiles ``(x0, y0, x1, y1)`` of side 2/(level+1) of the longer side,
    half a tile apart, covering the photo: a face up to half a tile wide lies whole in one."""
    side = max(1, round(2 * max(W, H) / (level + 1)))
    step = max(1, side // 2)

    def starts(n):
        if n <= side:
            return [0]
        return sorted(set(range(0, n - side, step)) | {n - side})

    return [(x, y, min(x + side, W), min(y + side, H)) for y in starts(H) for x in starts(W)]


def _suppress(boxes: np.ndarray, iou: float = 0.3) -> np.ndarray:
    """Boxes ``(F, 5)`` found twice (overlapping tiles) -> the higher-scored of each group."""
    keep = []
    for b in boxes[np.argsort(-boxes[:, 4], kind="stable")]:
        if not keep or not (overlap(np.array(keep), b) > iou).any():
            keep.append(b)
    return np.array(keep).reshape(-1, 5)


def detect_faces(image, *, face_detector: str = "full-range") -> np.ndarray:
    """Face boxes of mediapipe's face detector, largest first.

    Parameters
    ----------
    image : path or (H, W, 3) array
    face_detector : {"short-range", "full-range"}
        The full-range detector also searches overlapping tiles when the whole photo shows
        none (faces down to about 1/:data:`MIN_FACE_FRACTION` of the photo's longer side).

    Returns
    -------
    (F, 4) float64 boxes ``(left, top, right, bottom)`` in pixels.
    """
    img, _ = as_image(image)
    _detector(face_detector)  # an unknown name fails before any work
    boxes = _boxes(img, face_detector)
    if len(boxes) == 0 and face_detector == "full-range":
        H, W = img.shape[:2]
        for level in TILE_LEVELS:
            found = []
            for x0, y0, x1, y1 in _tiles(W, H, level):
                b = _boxes(np.ascontiguousarray(img[y0:y1, x0:x1]), face_detector)
                found.append(b + [x0, y0, x0, y0, 0.0])
            boxes = _suppress(np.concatenate(found))
            if len(boxes):
                break
    return largest_first(boxes[:, :4])


def _points(face, W: int, H: int) -> np.ndarray:
    """One face of mediapipe's result -> (478, 2) px (see the module's pixel convention)."""
    p = np.array([(q.x, q.y) for q in face.landmark], dtype=np.float64)
    return p * [W, H] - 0.5


def _largest(faces, W: int, H: int) -> np.ndarray | None:
    if not faces:
        return None
    pts = [_points(f, W, H) for f in faces]
    return max(pts, key=lambda p: float(np.prod(p.max(0) - p.min(0))))


def _mesh_in_box(img: np.ndarray, box: np.ndarray) -> np.ndarray | None:
    """The mesh on a CROP_PX square crop around ``box`` -> (478, 2) px of the photo, or None."""
    from PIL import Image

    cx, cy = (box[0] + box[2]) / 2 + 0.5, (box[1] + box[3]) / 2 + 0.5  # pixel-edge coordinates
    half = CROP_MARGIN * max(box[2] - box[0], box[3] - box[1]) / 2
    extent = (cx - half, cy - half, cx + half, cy + half)
    crop = Image.fromarray(img).transform((CROP_PX, CROP_PX), Image.Transform.EXTENT, extent,
                                          resample=Image.Resampling.BILINEAR)
    faces = _process(_mesh(), np.asarray(crop)).multi_face_landmarks
    if not faces:
        return None
    # several faces in the crop: the one nearest its centre is the box's
    pts = [_points(f, CROP_PX, CROP_PX) for f in faces]
    p = min(pts, key=lambda q: float(np.sum((q.mean(0) - CROP_PX / 2) ** 2)))
    scale = 2 * half / CROP_PX
    return (p + 0.5) * scale + [extent[0], extent[1]] - 0.5


def detect_landmarks(image, *, box=None, face_detector: str = "auto") -> np.ndarray:
    """478 face-mesh landmarks of the largest face (or of the face in ``box``).

    Parameters
    ----------
    image : path or (H, W, 3) array
    box : (left, top, right, bottom) pixels, optional; skips detection
    face_detector : {"auto", "short-range", "full-range"}, see the module's docstring

    Returns
    -------
    (478, 2) float64 pixels, 0-based, x right, y down, in mediapipe's index order.

    Raises
    ------
    FitError when no face is found.
    """
    img, name = as_image(image)
    if face_detector not in ("auto",) + FACE_DETECTORS:
        raise InputError(f"face detector: the face mesh has auto, {', '.join(FACE_DETECTORS)}; got {face_detector!r}")
    if box is not None:
        pts = _mesh_in_box(img, check_box(box))
    else:
        pts = None
        if face_detector == "auto":
            H, W = img.shape[:2]
            pts = _largest(_process(_mesh(), img).multi_face_landmarks, W, H)
        if pts is None:
            boxes = detect_faces(img, face_detector="full-range" if face_detector == "auto" else face_detector)
            pts = _mesh_in_box(img, boxes[0]) if len(boxes) else None
    if pts is None:
        raise FitError(f"{name}: no face found by the face mesh (faces narrower than about "
                       f"1/{MIN_FACE_FRACTION} of the photo's longer side are not found)")
    return pts


def to_ibug68(points) -> np.ndarray:
    """(..., 478, 2) face-mesh points -> (..., 68, 2) at :data:`FACEMESH_TO_IBUG68`."""
    p = np.asarray(points, dtype=np.float64)
    if p.shape[-2:] != (N_POINTS, 2):
        raise InputError(f"face-mesh points: expected (478, 2), got {p.shape}")
    return p[..., FACEMESH_TO_IBUG68, :]
