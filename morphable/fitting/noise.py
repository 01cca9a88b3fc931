"""The noise model of a landmark fit: the defaults of its noise settings and the data weights.

A landmark's 2D residual has three parts: the detector's noise
(``landmark_std_px``, new in every frame), the model's per-frame error (``model_std_mm``), and
the *definition* error (``definition_std_mm``): the annotation's lip corner or eyebrow is not
the model's landmark vertex, by the same 3D offset in every frame of a subject. With one
identity for several frames, treating that offset as independent per-frame noise counts N
frames as N looks at it, and the identity bends to fit it. So ``uv`` is the projection of
``m + A alpha + B beta + definition_std_mm * delta`` with one 3D offset ``delta_l ~ N(0, I)``
per fixed landmark, shared by the frames and estimated with the identity
(:mod:`~morphable.fitting.offsets`): marginalising it gives each landmark's residuals across
frames the covariance ``s^2 I + (k definition_std_mm)^2 1 1^T`` (per coordinate, affine, same
pose). The offsets grow and shrink with the face (times ``1 + g . alpha``, the face's size
relative to the mean to first order): landmarks fix a face's shape but not its size, which
trades against the camera's distance, and offsets of a fixed size in mm would be cheaper on
a smaller face — with them, shared fits came out 10-15 % smaller than the same frames fitted
alone. A single frame, or an independent fit per frame, cannot tell the offset from per-frame
error; there it only adds its variance: ``s^2 += (k definition_std_mm)^2``, exactly what
marginalising it gives. Sliding outline points get no offset (they are defined by the
outline they slide on). The default ``definition_std_mm`` is the landmark scheme's
(:attr:`~morphable.fitting.schemes.LandmarkScheme.definition_std_mm`); for iBUG-68 it differs
per landmark group (:data:`DEFINITION_STD_MM`: eyebrows 4.2 mm, nose base 1.6 mm...).

A fit's data weight of a landmark is ``1 / s^2`` with ``s^2 = landmark_std_px^2 + (k
model_std_mm)^2`` (plus ``(k definition_std_mm)^2`` where no offset carries the definition
error), ``k`` the image scale in px/mm: :func:`weights` (``pb``, ``st``: a fit's
:class:`~morphable.fitting.problem.Problem` and :class:`~morphable.fitting.problem.State`).
``landmark_std_px`` is one number for all points, or its own for each point and frame (a
detector that says how sure it is of each point): then each point's residual has its own
``s^2``, the model's and definition errors added as for one number. A point whose noise is
:data:`MISSING_STD_PX` or more (``inf`` included) is a missing point.
"""
from __future__ import annotations

import numpy as np

from ..ibug68 import DEFINITION_GROUPS

__all__ = ["DEFINITION_STD_MM", "MODEL_STD_MM", "DETECTED_MODEL_STD_MM", "BLENDSHAPES_REF",
           "MISSING_STD_PX", "expression_precision", "frame_model_std", "model_variance",
           "weights", "pose_weights", "effective_std"]


def _definition_profile() -> np.ndarray:
    d = np.empty(68)
    for group, mm in (("jaw", 2.0),    # distance across the outline; not measured: no SFM vertices
                      ("chin", 3.1), ("eyebrows", 4.2), ("nose ridge", 2.7), ("nose base", 1.6),
                      ("eyes", 2.3), ("mouth", 2.5)):
        d[DEFINITION_GROUPS[group]] = mm
    return d


DEFINITION_STD_MM = _definition_profile()
"""(68,) iBUG-68's ``definition_std_mm``, mm per coordinate: how far a landmark's annotation
typically lies from the model's landmark vertex, per group (the eyebrows are the least well
defined): the per-coordinate RMS of the ICT FaceKit landmark vertices against SFM fits of the
same faces, 6 subjects, rounded (``python -m evaluation.definition_error --synthetic-scan
ict --n-scans 6``)."""

MODEL_STD_MM = 1.5
"""Default ``model_std_mm``: the model's per-frame landmark error for annotated landmarks, mm."""

DETECTED_MODEL_STD_MM = 10.0
"""``model_std_mm`` for frames whose landmarks a detector found (dlib), mm. A detector's errors
are face-shaped (they come out of a shape regression) and much the same in the frames of a
video, so the identity takes them for the face's shape: they say less about the shape than
independent errors of their size (dlib on rendered faces: about 3 mm per coordinate for the
inner points and 5 mm for the jaw, half of it shared by a video's frames). Chosen on rendered
validation subjects wearing photos' colours (SFM and ICT FaceKit, 8 each, ``python -m
evaluation.florence --synthetic-scan ict --detect --appearance ...``): 8-12 mm did best, 1.5 mm
(:data:`MODEL_STD_MM`, for annotated landmarks) worst; the held-out scan was not used."""


MISSING_STD_PX = 1e6
"""A landmark whose noise (``landmark_std_px``, px) is this or more is a missing point: its
weight would be below 1e-12 of a 1 px point's, and leaving it out keeps a frame's count of
usable points, the first pose and the noise estimate honest (no image is a million px wide)."""

BLENDSHAPES_REF = 6
"""Blendshapes of the model whose expression prior weight 1 was chosen on (the SFM's six)."""


def expression_precision(model) -> float:
    """The expression prior's weight per coefficient at ``expression_weight=1``: 1 for
    expression coefficients in standard deviations (PCA), ``E / 6`` for a model of ``E``
    blendshape weights. A face's expression is split over however many blendshapes the model
    has, so each weight of a finer set carries less of it: the prior holds the sum of squares
    of a frame's weights about constant (SFM, 6 blendshapes: 1; ICT FaceKit, 53: 8.8). Chosen
    on validation subjects with and without expressions (SFM and ICT FaceKit subjects fitted
    with ICT FaceKit, ``expression_weight`` 1 / 3 / 9 / 30: 9 did best on the expressive ones,
    1 worst everywhere; SFM fits hardly change between 0.3 and 9)."""
    if model.expression_kind == "blendshapes" and model.n_expression:
        return model.n_expression / BLENDSHAPES_REF
    return 1.0


def frame_model_std(detected) -> np.ndarray:
    """(N,) ``model_std_mm`` per frame, mm: :data:`DETECTED_MODEL_STD_MM` where ``detected``
    ((N,) bool: a detector found the frame's landmarks), else :data:`MODEL_STD_MM`."""
    return np.where(np.asarray(detected, dtype=bool), DETECTED_MODEL_STD_MM, MODEL_STD_MM)


def model_variance(pb, st, depth=None):
    """(N, L) px^2: the model's part of each landmark's variance, (k model_std_mm)^2 plus,
    where no offset carries it, (k definition_std_mm)^2 (k the image scale in px/mm)."""
    scale = st.k
    if pb.perspective and depth is not None:
        used = pb.mask & st.corr.defined
        d = np.where(used, depth, 0.0).sum(1) / np.maximum(used.sum(1), 1)
        scale = st.k / np.maximum(d, 1e-6)
    return scale[:, None] ** 2 * pb.model_var_mm2


def weights(pb, st, depth=None):
    """(N, L) data weights 1/s^2 (0 for unused landmarks)."""
    s2 = pb.landmark_var + model_variance(pb, st, depth)
    return np.where(pb.mask & st.corr.defined, 1.0 / s2, 0.0)


def pose_weights(pb, defined) -> np.ndarray:
    """(N, L) weights of the linear affine pose (:func:`~morphable.fitting.pose.estimate_affine_pose`)
    over the usable landmarks with a correspondence (``defined`` (N, L) bool): 1 where all
    points have the same noise; with per-point noise ``2 m / (s^2 + m)``, ``m`` the frame's
    median ``s^2``. The image scale is not known yet, so the model's error cannot be added:
    the median stands in for it, so that a precise point counts at most twice and a point
    ten times less sure about 1/50 (not 1/100 of it, as ``1 / s^2`` alone would)."""
    used = pb.mask & defined
    if not pb.point_std:
        return np.where(used, 1.0, 0.0)
    v = np.where(used, pb.landmark_var, np.nan)
    with np.errstate(all="ignore"):
        m = np.nanmedian(v, axis=1, keepdims=True)
    return np.where(used, 2 * m / (pb.landmark_var + m), 0.0)


def effective_std(var, used) -> np.ndarray:
    """(N,) px: per frame, the one noise that gives the used points (``used`` (N, L) bool)
    the same total weight as their own noise (variances ``var`` (N, L) px^2):
    ``1 / sqrt(mean(1 / var))``; 0 for a frame without used points."""
    n = used.sum(1)
    with np.errstate(divide="ignore"):
        mean_w = np.where(used, 1.0 / var, 0.0).sum(1) / np.maximum(n, 1)
    return np.where(n > 0, 1.0 / np.sqrt(np.maximum(mean_w, 1e-300)), 0.0)
