"""The iBUG-68 landmark scheme: groups, the inner-51 subset, left/right mirroring, and the
mapping of menpo label groups to iBUG order.

Landmark numbers here are 0-based (iBUG point 1 is index 0). "Right" and "left" are the
subject's: the jaw starts at the subject's right ear, which appears on the image's left.
"""
from __future__ import annotations

import numpy as np

from .errors import InputError

__all__ = ["N_LANDMARKS", "GROUPS", "DEFINITION_GROUPS", "INNER", "JAW", "MIRROR", "MENPO_LABELS",
           "from_menpo_labels", "as_landmarks"]

N_LANDMARKS = 68

GROUPS = {
    "jaw": np.arange(0, 17),
    "right_eyebrow": np.arange(17, 22),
    "left_eyebrow": np.arange(22, 27),
    "nose": np.arange(27, 36),
    "right_eye": np.arange(36, 42),
    "left_eye": np.arange(42, 48),
    "mouth": np.arange(48, 68),
}
"""Each iBUG-68 group's points (0-based indices); sides are the subject's."""
JAW = GROUPS["jaw"]
DEFINITION_GROUPS = {
    "jaw": np.r_[0:8, 9:17],
    "chin": np.array([8]),
    "eyebrows": np.arange(17, 27),
    "nose ridge": np.arange(27, 31),
    "nose base": np.arange(31, 36),
    "eyes": np.arange(36, 48),
    "mouth": np.arange(48, 68),
}
"""Landmark groups by how well their annotation is defined (the size of the definition error,
:data:`morphable.fitting.noise.DEFINITION_STD_MM`): the chin apart from the jaw, the
nose's ridge apart from its base, both sides together."""
INNER = np.arange(17, 68)
"""The 51 inner points (iBUG 18-68), used when the jaw outline is unreliable."""

MENPO_LABELS = {
    "chin": "jaw", "jaw": "jaw",
    "leyebrow": "right_eyebrow", "left_eyebrow": "right_eyebrow",
    "reyebrow": "left_eyebrow", "right_eyebrow": "left_eyebrow",
    "nose": "nose",
    "leye": "right_eye", "left_eye": "right_eye",
    "reye": "left_eye", "right_eye": "left_eye",
    "mouth": "mouth",
}
"""menpo's iBUG-68 label -> the iBUG group (:data:`GROUPS`) it names. menpo names sides as
seen in the image: its ``leye`` is the subject's right eye."""


def _mirror() -> np.ndarray:
    m = np.arange(N_LANDMARKS)
    pairs = [(0, 16), (1, 15), (2, 14), (3, 13), (4, 12), (5, 11), (6, 10), (7, 9),
             (17, 26), (18, 25), (19, 24), (20, 23), (21, 22),
             (31, 35), (32, 34),
             (36, 45), (37, 44), (38, 43), (39, 42), (40, 47), (41, 46),
             (48, 54), (49, 53), (50, 52), (55, 59), (56, 58), (60, 64), (61, 63), (65, 67)]
    for a, b in pairs:
        m[a], m[b] = b, a
    return m


MIRROR = _mirror()
"""Permutation that maps each landmark to its mirror image (for flipped images)."""


def from_menpo_labels(points, labels: dict, source: str = "landmarks") -> np.ndarray:
    """Reorder menpo-labelled points (``chin``, ``leye``, ...) into iBUG-68 order.

    Parameters
    ----------
    points : (68, D) array
    labels : dict of label name -> point indices, as returned by ``read_ljson``

    Returns
    -------
    (68, D) array in iBUG order.
    """
    points = np.asarray(points)
    out = np.full((N_LANDMARKS, points.shape[1]), np.nan)
    seen = set()
    for name, idx in labels.items():
        group = MENPO_LABELS.get(name)
        if group is None:
            raise InputError(f"{source}: unknown landmark label {name!r}")
        target = GROUPS[group]
        if len(idx) != len(target):
            raise InputError(f"{source}: label {name!r} has {len(idx)} points, iBUG {group} has "
                             f"{len(target)}")
        out[target] = points[idx]
        seen.add(group)
    if seen != set(GROUPS):
        raise InputError(f"{source}: missing landmark groups {sorted(set(GROUPS) - seen)}")
    return out


def as_landmarks(landmarks, source: str = "landmarks", dim: int = 2,
                 n: int | None = N_LANDMARKS) -> tuple[np.ndarray, np.ndarray]:
    """Validate landmarks and split them into values and a visibility mask.

    Parameters
    ----------
    landmarks : (..., n, dim) array-like; NaN rows mark missing points
    dim : 2 or 3
    n : the number of landmarks, 68; None: any number

    Returns
    -------
    points : (..., n, dim) float64 with NaN rows replaced by 0
    mask : (..., n) bool, True where a point is given
    """
    a = np.asarray(landmarks, dtype=np.float64)
    if a.ndim < 2 or a.shape[-1] != dim or (n is not None and a.shape[-2] != n):
        raise InputError(f"{source}: expected (..., {'L' if n is None else n}, {dim}) landmarks, "
                         f"got {a.shape}")
    if np.isinf(a).any():
        raise InputError(f"{source}: landmarks contain inf")
    nan = np.isnan(a)
    mask = ~nan.any(-1)
    if (nan.any(-1) & ~nan.all(-1)).any():
        raise InputError(f"{source}: a landmark has some coordinates NaN and others not")
    return np.where(nan, 0.0, a), mask
