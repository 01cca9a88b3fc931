"""The data of one landmark fit: its fixed :class:`Problem` and its changing :class:`State`.

The stages of a fit (:mod:`~morphable.fitting.linear_stage`, :mod:`~morphable.fitting.nonlinear`,
:mod:`~morphable.fitting.noise_estimation`) are functions of the two. ``N`` frames fall in
``G`` groups that share an identity: one group for a shared identity, else one per frame.
"""
from __future__ import annotations

import numpy as np

from ..errors import FitError, InputError
from ..ibug68 import as_landmarks
from .noise import MISSING_STD_PX, expression_precision
from .options import FitOptions
from .rows import basis_rows, fixed_gram, size_direction

__all__ = ["Problem", "State", "as_frames", "group_index", "group_sum", "detector_looks"]


def detector_looks(detected, shared: bool) -> float:
    """How much more a shared identity's prior weighs because its frames' landmarks were
    detected ((N,) bool ``detected``): ``N / (annotated frames + 1)`` where any frame was
    detected, else 1 (and 1 for independent fits). A detector's errors are face-shaped (they
    come out of a shape regression), depend on the light and pose more than on the frame, and
    the views of a video triangulate them into depth: the detected frames of a shared fit are
    one look at the face's shape, not N (the frames' data weigh as much against the prior as
    one frame's; their poses and their per-frame noise still count in full). Measured on the
    Florence protocol with the face mesh (docs/fitting.md, "Fitting with per-point sigma")."""
    detected = np.asarray(detected, bool)
    if not shared or not detected.any():
        return 1.0
    return len(detected) / (np.count_nonzero(~detected) + 1.0)


def as_frames(landmarks, mask, image_size):
    """Validate a fit's data: ``landmarks`` (L, 2) or (N, L, 2) px (NaN rows missing),
    ``mask`` None or (L,) or (N, L) bool, ``image_size`` (W, H) or (N, 2) px -> ``y``
    (N, L, 2), ``given`` (N, L) bool, ``size`` (N, 2) float64. InputError if malformed."""
    y, given = as_landmarks(landmarks, "landmarks", n=None)
    if y.ndim == 2:
        y, given = y[None], given[None]
    if y.ndim != 3:
        raise InputError(f"landmarks: expected (L, 2) or (N, L, 2), got {np.shape(landmarks)}")
    N, L = y.shape[:2]
    if N == 0:
        raise InputError("landmarks: no frames given")
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape not in ((L,), (N, L)):
            raise InputError(f"mask: expected ({L},) or ({N}, {L}) booleans, got {m.shape}")
        given = given & np.broadcast_to(m, given.shape)
    size = np.asarray(image_size, dtype=np.float64)
    if size.shape == (2,):
        size = np.broadcast_to(size, (N, 2))
    if size.shape != (N, 2) or not np.all(np.isfinite(size)) or not np.all(size > 0):
        raise InputError(f"image_size: expected positive (W, H) or one per frame ({N}, 2), "
                         f"got {np.shape(image_size)}")
    return y, given, size


class Problem:
    """Fixed data of a fit: landmarks, weights, sizes and settings.

    Made from the model, its landmark rows for the scheme of the landmarks
    (:func:`~morphable.fitting.correspondences.landmark_bank`), the validated settings and
    the frames of :func:`as_frames` (``y`` (N, L, 2) px, ``given`` (N, L) bool, ``size``
    (N, 2) px); checks the settings against them (InputError) and raises FitError for a
    frame with fewer than 4 usable landmarks (given, defined on the model and with a noise
    below :data:`~morphable.fitting.noise.MISSING_STD_PX`). ``mask`` (N, L) holds the usable
    ones, ``landmark_var`` (N, L) px^2 their landmark noise's variance (``point_std``: one of
    their own per point, else one number for all). ``sliding`` are the landmarks whose rows are re-gathered
    when the outline moves (the outline landmarks; None where no frame gives one): a slice
    where they are consecutive, but for the chin (iBUG-68's 0-16), else indices.
    """

    def __init__(self, model, bank, options: FitOptions, y, given, size):
        N, L = y.shape[:2]
        model_std_mm = options.frame_model_std(N)
        K, E = options.modes(model)
        focal = options.focal(size)
        std = options.landmark_std(N, L)
        self.point_std = options.point_std is not None
        mask = given & bank.usable[None]
        if self.point_std:
            # a point nobody is sure of is a missing point (not a tiny weight: the count of
            # usable points, the first pose and the noise estimate must not count it)
            mask &= std < MISSING_STD_PX
        if (mask.sum(1) < 4).any():
            f = int(np.argmax(mask.sum(1) < 4))
            raise FitError(f"frame {f}: {int(mask[f].sum())} usable landmarks "
                           f"(given and defined on model {model.name}), need at least 4")
        self.model, self.options, self.given, self.size = model, options, given, size
        self.bank, self.y, self.mask, self.principal = bank, y, mask, (size - 1) / 2.0
        # the given landmarks; ``y`` holds the outline targets moved along the outline,
        # ``tangent`` the outline's direction at each outline point (0 elsewhere): only
        # residuals across count
        self.y_obs = y
        self.tangent = np.zeros_like(y)
        self.focal, self.perspective, self.K, self.E = focal, options.perspective, K, E
        self.shared, self.nonneg = options.shared_identity, model.expression_kind == "blendshapes"
        self.prior_weight = float(options.prior_weight)
        self.expression_weight = float(options.expression_weight) * expression_precision(model)
        self.landmark_std_px = options.start_std_px
        self.landmark_var = np.where(mask, std, 1.0) ** 2
        self.model_std_mm = model_std_mm
        self.robust, self.huber_k = options.robust, float(options.huber_k)
        self.N = N
        # a landmark's definition error is shared by every frame of a subject: with one
        # identity for several frames it gets its own coefficients (a 3D offset per landmark,
        # N(0, definition_std_mm^2) per coordinate), appended to the identity's; alone, a frame
        # cannot tell it from noise and it only widens the landmark's variance
        definition_std_mm = options.landmark_definition_std(bank.scheme)
        self.offsets = bool(self.shared and self.N > 1 and np.any(definition_std_mm > 0))
        self.n_identity = K
        self.sliding_landmarks = bank.sliding_landmarks
        # sliding outline points are defined by the outline they slide on: no offset
        self.offset_landmarks = bank.fixed_landmarks
        self.D = 3 * len(self.offset_landmarks) if self.offsets else 0
        self.frame_def_std = np.zeros_like(definition_std_mm) if self.offsets else definition_std_mm
        self.definition_std_mm = definition_std_mm
        # (N, L) mm^2: the model's part of each landmark's variance before the image scale
        # (:func:`~morphable.fitting.noise.model_variance`), the same in every iteration
        self.model_var_mm2 = model_std_mm[:, None] ** 2 + self.frame_def_std ** 2
        # (M,) mm per unit of offset coefficient, of the landmarks ``offset_landmarks``
        self.offset_std = definition_std_mm[self.offset_landmarks] if self.offsets else np.zeros(0)
        self.prior = np.ones(K + self.D)
        self.prior[:K] = self.prior_weight * detector_looks(options.frame_detected(N), self.shared)
        # the Gaussian prior's centre in the same coordinates (offsets stay centred at 0)
        self.prior_mean = np.zeros(K + self.D)
        if options.identity_prior_mean is not None:
            mean = options.identity_prior_mean
            if len(mean) < K:
                raise InputError(f"identity_prior_mean: {len(mean)} coefficients, the fit uses {K}")
            self.prior_mean[:K] = mean[:K]
        if options.identity_prior_std is not None:
            std = options.identity_prior_std
            if len(std) < K:
                raise InputError(f"identity_prior_std: {len(std)} values, the fit uses {K}")
            self.prior[:K] /= std[:K] ** 2
        self.A, self.B, self.AT, self.BT = basis_rows(bank, K, E)
        # None where no frame gives an outline point (51-point annotations, detectors that
        # drop the jaw): then nothing slides and the outline is never computed
        slides = len(self.sliding_landmarks) and mask[:, self.sliding_landmarks].any()
        self.sliding = bank.sliding_columns if slides else None
        # the Gram fast path needs one weight for each group of fixed landmarks of a frame
        # (those of one definition error): never so with the Huber loss
        self.gram = (fixed_gram(bank, K, self.sliding, self.frame_def_std)
                     if self.robust is None and K else None)
        self.size_direction = size_direction(bank, K) if self.offsets else None
        self.K = K + self.D          # the shared coefficients: identity, then offsets


    def set_landmark_std(self, std):
        """Set one landmark noise per frame, (N,) px, for all points (``"auto"``)."""
        self.landmark_std_px = std
        self.landmark_var = np.broadcast_to((np.asarray(std) ** 2)[:, None], self.mask.shape)


class State:
    """Cameras, coefficients, correspondences, and the model rows gathered for them.

    ``residuals`` caches :func:`~morphable.fitting.rows.residuals` of all frames (None until
    computed; cleared when the correspondences or their targets move): a step's trial cost and
    the next iteration's normal equations need the same points."""

    def __init__(self, R, t, k, alpha, beta, corr, rows=None):
        self.R, self.t, self.k, self.alpha, self.beta, self.corr = R, t, k, alpha, beta, corr
        self.rows = rows
        self.residuals = None

    def copy(self):
        return State(self.R.copy(), self.t.copy(), self.k.copy(), self.alpha.copy(),
                      self.beta.copy(), self.corr, self.rows)


def group_index(pb: Problem) -> np.ndarray:
    """(N,) the group of frames (one shared identity) each frame belongs to."""
    return np.zeros(pb.N, int) if pb.shared else np.arange(pb.N)


def group_sum(pb: Problem, x):
    """Per-frame values (N, ...) summed over each group of frames -> (G, ...)."""
    return x.sum(0, keepdims=True) if pb.shared else x
