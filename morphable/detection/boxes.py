"""Face boxes ``(left, top, right, bottom)`` in pixels: checking a given one, ordering found
ones, their overlap."""
from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["check_box", "largest_first", "iou"]


def check_box(box) -> np.ndarray:
    """A user's box -> (4,) float64 ``(left, top, right, bottom)``; InputError unless finite
    with right > left and bottom > top."""
    b = np.asarray(box, dtype=np.float64).reshape(-1)
    if b.shape != (4,) or not np.all(np.isfinite(b)) or b[2] <= b[0] or b[3] <= b[1]:
        raise InputError(f"box: expected (left, top, right, bottom) with right > left, bottom > top, got {box}")
    return b


def largest_first(boxes) -> np.ndarray:
    """(F, 4) boxes -> the same rows, largest area first (ties keep their order)."""
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    return b[np.argsort(-area, kind="stable")]


def iou(boxes, box) -> np.ndarray:
    """Intersection over union of ``boxes`` (F, 4+) with one ``box`` (4+,), ``(left, top, right,
    bottom)`` px (further columns, e.g. scores, are ignored) -> (F,)."""
    a = np.asarray(boxes, dtype=np.float64).reshape(-1, np.shape(box)[-1])
    b = np.asarray(box, dtype=np.float64)
    w = np.clip(np.minimum(a[:, 2], b[2]) - np.maximum(a[:, 0], b[0]), 0.0, None)
    h = np.clip(np.minimum(a[:, 3], b[3]) - np.maximum(a[:, 1], b[1]), 0.0, None)
    union = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1]) + (b[2] - b[0]) * (b[3] - b[1]) - w * h
    return w * h / union
