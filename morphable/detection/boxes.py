"""Face boxes ``(left, top, right, bottom)`` in pixels: checking a given one, ordering found ones."""
from __future__ import annotations

import numpy as np

from ..errors import InputError

__all__ = ["check_box", "largest_first"]


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
