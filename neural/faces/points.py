"""The landmark network's point set and its face framing, shared by every landmark pack, the
trainer and the detector.

The network predicts :data:`N_POINTS` = 546 points, each a fixed point of the model's surface
in the 3D convention (a hidden point where it projects):

- rows 0-477: mediapipe's 478 face-mesh points in mediapipe's order (468 mesh points, then the
  right and the left iris, 5 points each), the ``facemesh478`` scheme of
  :mod:`morphable.fitting.schemes`;
- rows 478-545 (:data:`IBUG_ROWS`): the 68 iBUG points in iBUG order.

A pack labels any subset of them (``labelled`` rows; e.g. AFLW's 21 points map to 19 rows).

Pixels: x right, y down, 0-based pixel centres. A face box is ``(x0, y0, x1, y1)`` px, square.

>>> import numpy as np
>>> int(mirror_index()[IBUG_ROWS][36]) - IBUG_START   # right outer eye corner <-> left
45
"""
from __future__ import annotations

import numpy as np

from morphable.fitting.schemes import DATA_DIR
from morphable.ibug68 import MIRROR as IBUG_MIRROR

__all__ = ["N_FACEMESH", "N_IBUG", "IBUG_START", "N_POINTS", "IBUG_ROWS", "FACEMESH_ROWS",
           "BOX_SCALE", "BOX_LIFT", "mirror_index", "face_box", "box_from_points", "box_side"]

N_FACEMESH = 478
N_IBUG = 68
IBUG_START = N_FACEMESH
N_POINTS = N_FACEMESH + N_IBUG
"""The network's points: the 478 face-mesh rows, then the 68 iBUG rows."""
FACEMESH_ROWS = np.arange(N_FACEMESH)
IBUG_ROWS = np.arange(IBUG_START, N_POINTS)
"""(68,) int: the rows of the 68 iBUG points."""

BOX_SCALE = 1.4
"""Side of the face box over the larger side of the 68 points' bounding box."""
BOX_LIFT = 0.1
"""Upward shift of the box centre, in units of the 68 points' larger side (the points stop at
the brows; the box takes some forehead)."""

_SCHEME = DATA_DIR / "facemesh478_sfm.npz"


def mirror_index() -> np.ndarray:
    """(546,) int: the row of each point's mirror image (for horizontally flipped crops): the
    face-mesh scheme's own ``mirror`` (the same for every model: it is mediapipe's topology)
    and iBUG's :data:`morphable.ibug68.MIRROR`. Read from the committed sidecar, no model
    needed (the GPU machine has no ``../shared``)."""
    with np.load(_SCHEME) as f:
        mesh = f["mirror"].astype(np.int64)
    return np.concatenate([mesh, IBUG_MIRROR + IBUG_START])


def face_box(points68) -> np.ndarray:
    """The framing box of a face from its 68 iBUG points (3D convention; NaN rows ignored).

    Parameters
    ----------
    points68 : (..., 68, 2) px

    Returns
    -------
    (..., 4) float64 ``(x0, y0, x1, y1)`` px: a square of side :data:`BOX_SCALE` x the larger
    side of the points' bounding box, centred on it, lifted by :data:`BOX_LIFT` x that side.

    >>> face_box(np.array([[0.0, 0.0], [100.0, 80.0]] * 34)).round(1)
    array([-20., -40., 120., 100.])
    """
    p = np.asarray(points68, dtype=np.float64)
    lo, hi = np.nanmin(p, axis=-2), np.nanmax(p, axis=-2)
    return box_from_points(lo, hi)


def box_from_points(lo, hi) -> np.ndarray:
    """:func:`face_box` from the 68 points' bounding box corners ``lo``, ``hi`` (..., 2) px."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    size = np.max(hi - lo, axis=-1)
    cx = (lo[..., 0] + hi[..., 0]) / 2
    cy = (lo[..., 1] + hi[..., 1]) / 2 - BOX_LIFT * size
    half = BOX_SCALE * size / 2
    return np.stack([cx - half, cy - half, cx + half, cy + half], axis=-1)


def box_side(boxes):
    """The side of boxes (..., 4) ``(x0, y0, x1, y1)`` px -> (...,) px: the mean of width and
    height (a square's side; numpy arrays or tensors)."""
    return ((boxes[..., 2] - boxes[..., 0]) + (boxes[..., 3] - boxes[..., 1])) / 2
