"""What a fit reads: pictures (photos, video frames, arrays) and their landmarks, from files or
detected.

- :func:`pictures` — photos, videos and (H, W, 3) arrays as :class:`Picture` objects; a video
  gives ``video_frames`` frames spread uniformly; a photo's header alone is read (its size),
  so a huge photo with a landmark file costs nothing;
- :func:`read_landmark_file` — iBUG ``.pts`` or menpo ``.ljson`` 68-point files, or 478
  face-mesh points (``.npy``, ``.json``), checked against the picture;
- :func:`check_landmarks` — a landmark array, checked as a file's points are;
- :func:`detect_points` — a picture's landmarks found by the detectors of
  :mod:`morphable.detection`.

Every problem with an input is an :class:`~morphable.errors.InputError` naming the file (an
array: ``<array I>``, its position among the inputs).
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["Picture", "pictures", "read_landmark_file", "check_landmarks", "detect_points", "check_detect_size",
           "MAX_DETECT_MEGAPIXELS", "OUTSIDE_MARGIN"]

MAX_DETECT_MEGAPIXELS = 40.0
"""Largest image (in millions of pixels) handed to the face detector: dlib's HOG pyramid on a
larger image takes minutes and gigabytes; such images need landmarks given or downscaling."""

OUTSIDE_MARGIN = 0.1
"""Landmarks may lie outside the image by this fraction of its width/height (faces cut by the
border are annotated that way); further out, the file does not belong to the image."""


@dataclass(frozen=True, eq=False)
class Picture:
    """One picture of a fit: a photo, an array's pixels or a video's frame.

    Attributes
    ----------
    label : str
        How reports and messages name it: the photo's path, ``"clip.mp4#14"`` for a video's
        frame, ``"<array 0>"`` for the first of the inputs when it is an array.
    image : path or (H, W, 3) uint8 RGB array
        A photo's path (decoded only when its pixels are needed), else the pixels.
    size : (W, H) int, pixels
    frame : :class:`~morphable.video.VideoFrame` or None
        The video frame it is (its video, index and time), None for a photo or an array.
    """

    label: str
    image: object
    size: tuple
    frame: object = None

    def pixels(self) -> np.ndarray:
        """(H, W, 3) uint8 RGB: the photo read now (upright, 8-bit), or the pixels held."""
        from ..detection.images import read_image

        return read_image(self.image) if isinstance(self.image, Path) else self.image


def pictures(item, index: int = 0, video_frames: int = 5) -> list:
    """The :class:`Picture` objects of one input.

    Parameters
    ----------
    item : a photo's path; a video's path (:func:`morphable.video.is_video`: by its suffix);
        a :class:`~morphable.video.VideoFrame`; or an (H, W, 3) / (H, W) array, uint8, uint16
        or float (see :func:`morphable.detection.images.as_image`)
    index : int, the item's position among the inputs (names an array: ``<array INDEX>``)
    video_frames : int >= 1, frames spread uniformly over a video
        (:func:`morphable.video.sample_frames`; all of a shorter one)

    Returns
    -------
    list of Picture: one for a photo, an array or a frame; a video's sampled frames.
    """
    from ..video import is_video, sample_frames

    if hasattr(item, "image") and hasattr(item, "label"):      # a VideoFrame already decoded
        return [Picture(item.label, item.image, item.size, item)]
    if is_video(item):
        return [Picture(f.label, f.image, f.size, f) for f in sample_frames(item, video_frames)]
    if isinstance(item, (str, Path)):
        from ..detection.images import image_size

        path = Path(item)
        return [Picture(str(path), path, image_size(path))]
    if isinstance(item, np.ndarray):
        from ..detection.images import as_image

        pixels, label = as_image(item, f"<array {index}>")
        return [Picture(label, pixels, (pixels.shape[1], pixels.shape[0]))]
    raise InputError(f"input {index}: expected a photo or video path or an (H, W, 3) array, "
                     f"got {type(item).__name__}")


def read_landmark_file(path, size=None) -> np.ndarray:
    """Landmarks from a file, checked against an image size.

    Parameters
    ----------
    path : one of
        ``.pts`` — 68 iBUG points, 1-based pixels;
        ``.ljson`` — menpo, 68 points in iBUG order or labelled;
        ``.npy`` — a (478, 2) array of face-mesh points (mediapipe's order), 0-based pixels;
        ``.json`` — 478 face-mesh points as a list of ``[x, y]`` or ``{"landmarks": [...]}``,
        0-based pixels.
    size : (W, H) pixels, optional; landmarks further than ``OUTSIDE_MARGIN`` outside are refused

    Returns
    -------
    (68, 2) or (478, 2) float64 pixels, 0-based, x right, y down; NaN rows for missing
    points (.ljson only).
    """
    from ..detection.facemesh import N_POINTS
    from ..ibug68 import MENPO_LABELS, from_menpo_labels
    from ..io.landmark_files import read_ljson, read_pts

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such landmark file")
    suffix = path.suffix.lower()
    if suffix in (".npy", ".json"):
        pts = _read_facemesh_points(path)
        if pts.shape != (N_POINTS, 2):
            raise InputError(f"{path}: expected {N_POINTS} x 2 face-mesh landmarks, got shape {pts.shape}")
        if not np.isfinite(pts).all():
            raise InputError(f"{path}: coordinates contain NaN or inf")
    elif suffix == ".ljson":
        pts, labels = read_ljson(path)
        if pts.shape[1] != 2:
            raise InputError(f"{path}: expected 2D landmarks, got {pts.shape[1]}D points")
        if len(pts) == 68 and labels and set(labels) <= set(MENPO_LABELS):
            pts = from_menpo_labels(pts, labels, str(path))
    else:
        pts = read_pts(path)
    if suffix not in (".npy", ".json") and pts.shape != (68, 2):
        raise InputError(f"{path}: expected 68 iBUG landmarks, got {len(pts)}")
    if size is not None:
        _check_inside(pts, size, path)
    return pts


def check_landmarks(points, size=None, name: str = "landmarks") -> np.ndarray:
    """A landmark array checked as :func:`read_landmark_file` checks a file's points.

    Parameters
    ----------
    points : (68, 2) iBUG or (478, 2) face-mesh points, 0-based pixels, x right, y down
    size : (W, H) pixels, optional; points further than ``OUTSIDE_MARGIN`` outside are refused
    name : str, names the points in messages

    Returns
    -------
    (68, 2) or (478, 2) float64 pixels.
    """
    from ..detection.facemesh import N_POINTS

    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{name}: expected an array of numbers") from None
    if pts.shape not in ((68, 2), (N_POINTS, 2)):
        raise InputError(f"{name}: expected 68 or {N_POINTS} x 2 landmarks, got shape {pts.shape}")
    if not np.isfinite(pts).all():
        raise InputError(f"{name}: coordinates contain NaN or inf")
    if size is not None:
        _check_inside(pts, size, name)
    return pts


def _check_inside(pts, size, name) -> None:
    W, H = size
    lo = -0.5 - OUTSIDE_MARGIN * np.array([W, H])
    hi = np.array([W, H]) - 0.5 + OUTSIDE_MARGIN * np.array([W, H])
    with np.errstate(invalid="ignore"):
        out = np.flatnonzero(((pts < lo) | (pts > hi)).any(1))
    if out.size:
        i = int(out[0])
        raise InputError(f"{name}: landmark {i + 1} at ({pts[i, 0]:.1f}, {pts[i, 1]:.1f}) px "
                         f"is outside the {W}x{H} image")


def _read_facemesh_points(path: Path) -> np.ndarray:
    """A ``.npy`` array or a ``.json`` list (bare or under ``"landmarks"``) -> float64 array
    of whatever shape it holds; InputError naming the file when it is not numbers."""
    try:
        if path.suffix.lower() == ".npy":
            data = np.load(path, allow_pickle=False)
        else:
            data = json.loads(path.read_text())
            if isinstance(data, dict):
                if "landmarks" not in data:
                    raise InputError(f"{path}: expected a list of [x, y] or {{\"landmarks\": [...]}}")
                data = data["landmarks"]
        return np.asarray(data, dtype=np.float64)
    except (OSError, ValueError, TypeError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read landmarks ({str(e).splitlines()[0] if str(e) else type(e).__name__})") from None


def check_detect_size(picture: Picture) -> None:
    """InputError naming a picture larger than :data:`MAX_DETECT_MEGAPIXELS` (face detection
    on it would take minutes and gigabytes)."""
    W, H = picture.size
    mp = W * H / 1e6
    if mp > MAX_DETECT_MEGAPIXELS:
        raise InputError(f"{picture.label}: {W}x{H} is {mp:.1f} megapixels, more than the "
                         f"{MAX_DETECT_MEGAPIXELS:.0f} megapixels face detection takes; downscale it or give landmarks")


def detect_points(picture: Picture, landmark_detector: str = "auto", face_detector: str = "auto"):
    """The :class:`~morphable.detection.result.Detection` of a picture's largest face (its
    points, and its σ where the detector gives one).

    Parameters
    ----------
    picture : Picture
    landmark_detector, face_detector : see :func:`morphable.detection.detect`

    Raises
    ------
    InputError for a picture larger than :data:`MAX_DETECT_MEGAPIXELS`; FitError when no face
    is found.
    """
    from ..detection import detect

    check_detect_size(picture)
    return detect(picture.image, landmark_detector=landmark_detector, face_detector=face_detector)
