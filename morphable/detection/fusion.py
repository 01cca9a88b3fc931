"""Two detectors' readings of one face as one: :func:`fuse`.

The landmark network says how sure it is of each point (σ); the face mesh says nothing, but
where both read the same face, how far its points lie from the network's says how wrong it
is on that face: near-frontal faces, where the face mesh is the more precise, get most of
their points from it; faces it misreads (turned far away, hard light) get them from the
network. The fused points are the inverse-variance mean of the two, their σ the mean's.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from ..errors import InputError
from .result import Detection

__all__ = ["FLOOR", "other_std_px", "fuse"]

FLOOR = 0.5
"""The least σ the other detector gets, as a fraction of the measured detector's RMS σ: two
readings that agree closely are not both nearly exact."""


def other_std_px(measured: Detection, other: Detection, *, a: float = 0.5, b: float = 1.0) -> float:
    """The other detector's σ on this face, px (one for all its points):
    ``σ_o² = a mean(|d|²) - b mean(σ_m²)`` over the face's points, ``d`` the distance between a
    point's two readings, at least :data:`FLOOR` times the measured detector's RMS σ.

    The defaults are the estimate for independent errors: two independent readings of a point,
    each with an isotropic error (σ_m, σ_o per coordinate), lie ``|d|² = 2 (σ_m² + σ_o²)``
    apart on average. Of three rules compared on the validation sets (these coefficients,
    (1, 1) and (1/4, 1/2): ``python -m evaluation.bench_fusion``), each of the others did
    better on some sets and worse on others; this one lies between them and has the
    derivation (docs/landmark_net.md, "The network and the face mesh, fused").

    measured : a Detection with ``sigma_px`` (the landmark network's)
    other : a Detection of the same scheme and face without σ (the face mesh's)
    a, b : the rule's coefficients
    """
    d2 = float(np.mean(np.sum((measured.points - other.points) ** 2, axis=1)))
    s2 = float(np.mean(measured.sigma_px ** 2))
    return float(np.sqrt(max(a * d2 - b * s2, FLOOR ** 2 * s2)))


def _mean(a, sa, b, sb):
    wa, wb = 1.0 / sa ** 2, 1.0 / sb ** 2
    return (wa[:, None] * a + wb * b) / (wa + wb)[:, None], 1.0 / np.sqrt(wa + wb)


def fuse(measured: Detection, other: Detection) -> Detection:
    """One :class:`Detection` from two readings of the same face: each point the
    inverse-variance mean of the two, the measured detector's σ per point, the other's
    :func:`other_std_px`, and σ that of the mean (smaller than either).

    Parameters
    ----------
    measured : Detection with σ (``sigma_px`` and ``ibug68_sigma_px``): the landmark network's
    other : Detection without σ, same ``scheme`` and ``convention`` (the face mesh's)

    Returns
    -------
    Detection: points (P, 2) px and ibug68 (68, 2) px fused (the measured detector's own 68
    rows with the other's), their σ (px), the measured detector's score and box, ``detector``
    naming both, e.g. ``"network short-range + facemesh"``.

    >>> import numpy as np
    >>> a = Detection(np.zeros((68, 2)), np.full(68, 2.0), np.zeros((68, 2)), np.full(68, 2.0),
    ...               "ibug68", "3d", "network box")
    >>> b = dataclasses.replace(a, points=np.full((68, 2), 4.0), ibug68=np.full((68, 2), 4.0),
    ...                         sigma_px=None, ibug68_sigma_px=None, detector="facemesh")
    >>> f = fuse(a, b)                  # they disagree by 5.7 px: the face mesh's σ is 3.5 px
    >>> round(float(f.points[0, 0]), 2), round(float(f.sigma_px[0]), 2)
    (1.0, 1.73)
    """
    if measured.sigma_px is None or measured.ibug68_sigma_px is None or other.sigma_px is not None:
        raise InputError(f"fuse: {measured.detector} must give σ and {other.detector} none")
    if (measured.scheme, measured.convention) != (other.scheme, other.convention):
        raise InputError(f"fuse: {measured.detector} gives {measured.scheme} points "
                         f"({measured.convention} convention), {other.detector} gives "
                         f"{other.scheme} points ({other.convention}): not the same points")
    s = other_std_px(measured, other)
    points, sigma = _mean(measured.points, measured.sigma_px, other.points, s)
    ibug68, ibug68_sigma = _mean(measured.ibug68, measured.ibug68_sigma_px, other.ibug68, s)
    name = f"{measured.detector} + {other.detector.split()[0]}"
    return dataclasses.replace(measured, points=points, sigma_px=sigma, ibug68=ibug68,
                               ibug68_sigma_px=ibug68_sigma, detector=name)
