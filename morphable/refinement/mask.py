"""Which pixels a photometric fit may explain: a robust weight per pixel, estimated from the
image and the current residual, never drawn by hand.

A pixel's weight in [0, 1] is the product of

- **clipping**: 0 where the photo is saturated (a channel >= :data:`CLIP_HIGH`) or black (every
  channel <= :data:`CLIP_LOW`): a clipped pixel carries no shading;
- **colour**: a Geman-McClure weight ``1 / (1 + (d / c)^2)^2`` of the distance ``d`` of its
  chromaticity (r, g over r + g + b) from the face's median, with ``c`` = 3 x the robust
  (MAD) spread of ``d`` over the face: hair, glasses, microphones and hands rarely have the
  colour of the skin around them (on the face pixels only; the background keeps 1);
- **residual**: the same Geman-McClure weight of the colour residual ``|render - photo|``
  with ``c`` = 3 x its MAD scale over the face: whatever the model does not explain (an
  occluder the albedo cannot follow, the mouth interior, a cast shadow) is down-weighted.
  The fit re-estimates the weights as it goes (iteratively reweighted least squares).

:func:`mask_coverage` is the share of the face the weights keep; a frame under
:data:`MIN_COVERAGE` falls back to its landmark fit.

Examples
--------
>>> photo = np.full((8, 8, 3), 0.5); photo[:, :2] = (0.1, 0.1, 0.9)      # a blue occluder
>>> face = np.ones((8, 8))
>>> w = pixel_weights(photo, np.full((8, 8, 3), 0.5), face)
>>> float(w[0, 0]) < 0.05, float(w[0, 5])
(True, 1.0)
"""
from __future__ import annotations

import numpy as np

__all__ = ["pixel_weights", "mask_coverage", "MIN_COVERAGE", "CLIP_LOW", "CLIP_HIGH"]

MIN_COVERAGE = 0.05
"""A frame whose mask keeps less than this share of its face pixels is not fitted
photometrically (issue 54: "a frame the mask leaves nearly empty")."""

CLIP_LOW = 0.02
"""A pixel whose every channel is at most this (of 1) is black: no shading to read."""

CLIP_HIGH = 0.98
"""A pixel with a channel at least this (of 1) is saturated."""

_SCALE_FLOOR = 0.01  # intensity: below this MAD the image is flat (e.g. grey), not noise-free


def _geman_mcclure(d, c):
    return 1.0 / (1.0 + (d / c) ** 2) ** 2


def _mad_scale(d) -> float:
    return max(1.4826 * float(np.median(d)) if d.size else 0.0, _SCALE_FLOOR)


def pixel_weights(photo, rendered, face, region=None) -> np.ndarray:
    """Robust weight of each pixel of a crop.

    Parameters
    ----------
    photo, rendered : (R, R, 3) float in [0, 1], the crop and the current render
    face : (R, R) float in [0, 1], the fitted face's coverage
    region : (R, R) float, the pixels the renderer compares (its ``photometric_mask``);
        default ``face``

    Returns
    -------
    (R, R) float64 weights in [0, 1], zero outside ``region``.
    """
    photo = np.nan_to_num(np.asarray(photo, dtype=np.float64))
    rendered = np.nan_to_num(np.asarray(rendered, dtype=np.float64))
    face = np.asarray(face, dtype=np.float64)
    region = face if region is None else np.asarray(region, dtype=np.float64)
    top = photo.max(-1)
    unclipped = (top < CLIP_HIGH) & (top > CLIP_LOW)
    on_face = (face > 0.5) & unclipped
    chroma = photo[..., :2] / np.maximum(photo.sum(-1, keepdims=True), 1e-6)
    colour = np.ones(face.shape)
    if on_face.any():
        d = np.linalg.norm(chroma - np.median(chroma[on_face], 0), axis=-1)
        colour = np.where(face > 0.5, _geman_mcclure(d, 3 * _mad_scale(d[on_face])), 1.0)
    r = np.linalg.norm(rendered - photo, axis=-1)
    residual = _geman_mcclure(r, 3 * _mad_scale(r[on_face]))
    return region * unclipped * colour * residual


def mask_coverage(weights, face) -> float:
    """The share of the face (``face`` (R, R) coverage) that ``weights`` (R, R) keep, in
    [0, 1] (0 for a face of no pixels)."""
    face = np.asarray(face, dtype=np.float64)
    total = float(face.sum())
    return float((np.asarray(weights) * face).sum() / total) if total > 0 else 0.0
