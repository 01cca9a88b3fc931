"""Fit identity, expressions and cameras to 2D iBUG-68 landmarks of one or more images.

Steps (each usable alone through the functions of this package):

1. linear pose: a scaled orthographic camera from the 2D points and the model's mean
   landmarks (:func:`~morphable.fitting.pose.estimate_affine_pose`);
2. jaw correspondences: each 2D jaw point takes the nearest point of the face's projected
   outline — the jaw line where it faces the camera, else the cheek's silhouette, at any
   height — and only its distance across the outline counts
   (:func:`~morphable.fitting.correspondences.slide_contours`); re-picked every round and
   every second nonlinear iteration;
3. closed-form solves for identity, then expression, under the Gaussian prior
   (:mod:`~morphable.fitting.linear`); steps 1 to 3 run ``n_linear`` times (once where
   no jaw point is given and step 4 follows: with nothing to re-pick, later rounds would
   only alternate pose and shape, which step 4 does jointly);
4. joint Levenberg-Marquardt over rotation (axis-angle increments, no gimbal lock),
   translation, scale (affine) or depth (perspective), expressions and identity, with
   analytic Jacobians, an optional Huber loss and a Schur complement that keeps a shared
   identity cheap for many frames.

Cost (per fit)::

    sum_frames sum_landmarks rho(|uv - y|^2 / s^2) + prior_weight |alpha|^2 + |delta|^2
        + expression_weight sum_frames |beta|^2,     s^2 = landmark_std_px^2 + (k model_std_mm)^2

with ``k`` the image scale in px/mm, so that the prior has its Bayesian weight for
``prior_weight = 1`` (for jaw points ``uv - y`` is its component across the outline; for
blendshape weights ``expression_weight`` is multiplied by :func:`expression_precision`, E / 6
for E blendshapes). Only the landmark rows of the model are evaluated, never the full mesh.
``landmark_std_px="auto"`` estimates the detector's noise from the residuals (MacKay's
evidence approximation: the normalised residuals of a fit add up to their degrees of freedom,
the observations minus the trace of the hat matrix) and refits.

Noise model. A landmark's 2D residual has three parts: the detector's noise
(``landmark_std_px``, new in every frame), the model's per-frame error (``model_std_mm``), and
the *definition* error (``definition_std_mm``): the annotation's lip corner or eyebrow is not
the model's landmark vertex, by the same 3D offset in every frame of a subject. With one
identity for several frames, treating that offset as independent per-frame noise counts N
frames as N looks at it, and the identity bends to fit it. So ``uv`` is the projection of
``m + A alpha + B beta + definition_std_mm * delta`` with one 3D offset ``delta_l ~ N(0, I)``
per fixed landmark, shared by the frames and estimated with the identity (in the same Schur
block): marginalising it gives each landmark's residuals across frames the covariance
``s^2 I + (k definition_std_mm)^2 1 1^T`` (per coordinate, affine, same pose). The offsets
grow and shrink with the face (times ``1 + g . alpha``, the face's size relative to the mean
to first order): landmarks fix a face's shape but not its size, which trades against the
camera's distance, and offsets of a fixed size in mm would be cheaper on a smaller face —
with them, shared fits came out 10-15 % smaller than the same frames fitted alone. A single
frame, or an independent fit per frame, cannot tell the offset from per-frame error; there
it only adds its variance: ``s^2 += (k definition_std_mm)^2``, exactly what marginalising it
gives. Sliding jaw points get no offset (they are defined by the outline they slide on). The
default ``definition_std_mm`` differs per landmark group (:data:`DEFINITION_STD_MM`: eyebrows
4.2 mm, nose base 1.6 mm...).
"""
from __future__ import annotations

import time

import numpy as np

from ..camera import Camera, cross
from ..errors import FitError, InputError
from ..landmarks import DEFINITION_GROUPS, as_landmarks
from ..threads import single_blas_thread
from .correspondences import (Correspondences, across_outline, landmark_bank, outline_points,
                              slide_contours)
from .linear import gram_hessian, project_rows, solve_expression, solve_identity
from .pose import estimate_affine_pose, project, projection_jacobian, rotate
from .result import FitResult

__all__ = ["fit_landmarks", "frame_model_std", "expression_precision", "DEFINITION_STD_MM",
           "MODEL_STD_MM", "DETECTED_MODEL_STD_MM", "BLENDSHAPES_REF"]

AUTO_ROUNDS = 1
"""Re-estimations of the landmark noise for ``landmark_std_px="auto"`` (each one refits)."""

AFFINE_DISTANCE_MM = 600.0
"""Camera distance reported for affine fits (the projection does not depend on it)."""


def _definition_profile() -> np.ndarray:
    d = np.empty(68)
    for group, mm in (("jaw", 2.0),    # distance across the outline; not measured: no SFM vertices
                      ("chin", 3.1), ("eyebrows", 4.2), ("nose ridge", 2.7), ("nose base", 1.6),
                      ("eyes", 2.3), ("mouth", 2.5)):
        d[DEFINITION_GROUPS[group]] = mm
    return d


DEFINITION_STD_MM = _definition_profile()
"""(68,) default ``definition_std_mm``, mm per coordinate: how far a landmark's annotation
typically lies from the model's landmark vertex, per group (the eyebrows are the least well
defined): the per-coordinate RMS of the ICT FaceKit landmark vertices against SFM fits of the
same faces, 6 subjects, rounded (``python -m evaluation.landmark_definitions --synthetic-scan
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


class _Problem:
    """Fixed data of a fit: landmarks, weights, sizes and settings."""

    def __init__(self, bank, y, mask, principal, focal, perspective, K, E, shared, nonneg,
                 prior_weight, expression_weight, landmark_std_px, model_std_mm, robust, huber_k,
                 definition_std_mm=0.0):
        self.bank, self.y, self.mask, self.principal = bank, y, mask, principal
        # the given landmarks; ``y`` holds the jaw targets moved along the outline, ``tangent``
        # the outline's direction at each jaw point (0 elsewhere): only residuals across count
        self.y_obs = y
        self.tangent = np.zeros_like(y)
        self.focal, self.perspective, self.K, self.E = focal, perspective, K, E
        self.shared, self.nonneg = shared, nonneg
        self.prior_weight, self.expression_weight = prior_weight, expression_weight
        self.landmark_std_px = landmark_std_px
        self.model_std_mm = np.broadcast_to(np.asarray(model_std_mm, np.float64), (y.shape[0],))
        self.robust, self.huber_k = robust, huber_k
        self.N = y.shape[0]
        # a landmark's definition error is shared by every frame of a subject: with one
        # identity for several frames it gets its own coefficients (a 3D offset per landmark,
        # N(0, definition_std_mm^2) per coordinate), appended to the identity's; alone, a frame
        # cannot tell it from noise and it only widens the landmark's variance
        definition_std_mm = np.broadcast_to(np.asarray(definition_std_mm, np.float64), (y.shape[1],))
        self.offsets = bool(shared and self.N > 1 and np.any(definition_std_mm > 0))
        self.n_identity = K
        sliding = [int(j) for lms, _ in bank.polylines for j in lms]
        self.sliding_landmarks = np.asarray(sliding, dtype=np.int64)
        # sliding jaw points are defined by the outline they slide on: no offset
        self.offset_landmarks = np.setdiff1d(np.arange(y.shape[1]), sliding)
        self.D = 3 * len(self.offset_landmarks) if self.offsets else 0
        self.frame_def_std = np.zeros_like(definition_std_mm) if self.offsets else definition_std_mm
        self.definition_std_mm = definition_std_mm
        self.prior = np.r_[np.full(K, prior_weight), np.ones(self.D)]
        self.A, self.B, self.AT, self.BT = _basis_rows(bank, K, E)
        # one slice over the jaw (fixed points inside it are re-gathered unchanged): slices
        # copy much faster than index lists into the (N, 3, 68, K) rows. None where no frame
        # gives an outline point (51-point annotations, detectors that drop the jaw): then
        # nothing slides and the outline is never computed
        slides = bool(sliding) and bool(mask[:, sliding].any())
        self.sliding = slice(min(sliding), max(sliding) + 1) if slides else None
        # the Gram fast path needs one weight for all fixed landmarks of a frame: never so
        # with the Huber loss, offsets or a definition error that differs between landmarks
        fixed_std = self.frame_def_std[bank.fixed_row >= 0]
        uniform = fixed_std.size == 0 or np.all(fixed_std == fixed_std[0])
        self.gram = (_fixed_gram(bank, K, self.sliding)
                     if robust is None and K and not self.offsets and uniform else None)
        self.size_direction = _size_direction(bank, K) if self.offsets else None
        self.K = K + self.D          # the shared coefficients: identity, then offsets


def _basis_rows(bank, K, E):
    """The identity and expression rows of the first K and E modes, (R, 3, K) and (R, 3, E),
    and coordinate-major copies (3, R, K) and (3, R, E), cached per model: copying them is a
    good part of a small fit's time."""
    cache = bank.__dict__.setdefault("_basis_rows", {})
    if (K, E) not in cache:
        A = np.ascontiguousarray(bank.identity[:, :, :K])
        B = np.ascontiguousarray(bank.expression[:, :, :E])
        cache[K, E] = (A, B, np.ascontiguousarray(A.transpose(1, 0, 2)),
                       np.ascontiguousarray(B.transpose(1, 0, 2)))
    return cache[K, E]


def _size_direction(bank, K) -> np.ndarray:
    """(K,) how much each identity coefficient scales the face: the least-squares scale factor
    of the identity mode's landmark displacements about the mean landmarks' centroid."""
    rows = bank.fixed_row[bank.fixed_row >= 0]
    m = bank.mean[rows] - bank.mean[rows].mean(0)
    A = bank.identity[rows, :, :K] - bank.identity[rows, :, :K].mean(0)
    return np.einsum("li,lik->k", m, A) / (m * m).sum()


def _face_size(pb: _Problem, alpha) -> np.ndarray:
    """(G,) the face's size relative to the mean face, to first order in the identity."""
    # floored: an absurd identity must not turn the offsets inside out
    return np.maximum(1.0 + alpha[:, :pb.n_identity] @ pb.size_direction, 0.25)


def _coefficients(pb: _Problem, alpha) -> np.ndarray:
    """The shared coefficients (G, K) as they multiply the rows: the landmark offsets grow
    and shrink with the face (see the module docstring)."""
    if not pb.D:
        return alpha
    n = pb.n_identity
    return np.concatenate([alpha[:, :n], _face_size(pb, alpha)[:, None] * alpha[:, n:]], 1)


def _from_coefficients(pb: _Problem, c) -> np.ndarray:
    """The inverse of :func:`_coefficients`."""
    if not pb.D:
        return c
    n = pb.n_identity
    return np.concatenate([c[:, :n], c[:, n:] / _face_size(pb, c)[:, None]], 1)


def _shared_rows(pb: _Problem, st: _State) -> np.ndarray:
    """(N, 3, 68, K) derivatives of the landmark points by the shared coefficients: the identity
    rows plus the offsets' growth with the face, then the offset rows times the face's size."""
    A = st.rows[1]
    if not pb.D:
        return A
    n = pb.n_identity
    alpha = np.broadcast_to(st.alpha, (pb.N, pb.K))
    O = A[..., n:]
    N, _, L, D = O.shape
    shift = (O.reshape(N, 3 * L, D) @ alpha[:, n:, None]).reshape(N, 3, L, 1)
    out = np.empty(A.shape)
    out[..., :n] = A[..., :n] + shift * pb.size_direction
    out[..., n:] = O * _face_size(pb, alpha)[:, None, None, None]
    return out


def _offset_rows(pb: _Problem):
    """(N, 3, 68, D) coordinate-major rows of the landmark offsets: the i-th landmark of
    ``pb.offset_landmarks`` moves along coordinate a by ``definition_std_mm`` per unit of
    coefficient ``3 i + a``."""
    lms = pb.offset_landmarks
    O = np.zeros((3, pb.y.shape[1], pb.D))
    for a in range(3):
        O[a, lms, 3 * np.arange(len(lms)) + a] = pb.definition_std_mm[lms]
    return np.broadcast_to(O, (pb.N,) + O.shape)


def _fixed_gram(bank, K, jaw):
    """(fixed landmarks, jaw slice, G (3, 3, K, K)): Gram blocks of the identity rows of the
    fixed landmarks outside the jaw slice, cached per model and K (see
    ``linear.gram_hessian``); landmarks in neither never have a correspondence."""
    cache = bank.__dict__.setdefault("_gram", {})
    jaw = jaw if jaw is not None else slice(0, 0)
    key = (K, jaw.start, jaw.stop)
    if key not in cache:
        fixed = np.flatnonzero(bank.fixed_row >= 0)
        fixed = fixed[(fixed < jaw.start) | (fixed >= jaw.stop)]
        Af = bank.identity[bank.fixed_row[fixed], :, :K]                  # (F, 3, K)
        G = np.einsum("lik,ljm->ijkm", Af, Af)
        cache[key] = (fixed, jaw, np.ascontiguousarray(G))
    return cache[key]


class _State:
    """Cameras, coefficients, correspondences, and the model rows gathered for them.

    ``residuals`` caches :func:`_residuals` of all frames (None until computed; cleared when
    the correspondences or their targets move): a step's trial cost and the next iteration's
    normal equations need the same points."""

    def __init__(self, R, t, k, alpha, beta, corr, rows=None):
        self.R, self.t, self.k, self.alpha, self.beta, self.corr = R, t, k, alpha, beta, corr
        self.rows = rows
        self.residuals = None

    def copy(self):
        return _State(self.R.copy(), self.t.copy(), self.k.copy(), self.alpha.copy(),
                      self.beta.copy(), self.corr, self.rows)


def _gather(pb: _Problem, st: _State, sliding_only: bool = False):
    """Gather the mean (N, 68, 3) and the identity and expression rows (N, 3, 68, K|E) of the
    correspondences; after the first time only the sliding jaw landmarks are redone."""
    c = st.corr
    if sliding_only and st.rows is not None:
        if pb.sliding is not None:
            st.residuals = None
            c.gather_static(pb.bank.mean, pb.sliding, st.rows[0])
            # the offset columns (after the identity's) never change
            for src, dst in zip((pb.AT, pb.BT), (st.rows[1][..., :pb.n_identity], st.rows[2])):
                c.gather_coordinates(src, pb.sliding, dst)
        return
    # identity and expression rows coordinate-major, (N, 3, 68, k): projections are one GEMM
    A = c.gather_coordinates(pb.AT)
    if pb.D:
        A = np.concatenate([A, _offset_rows(pb)], -1)
    st.rows = (c.gather_static(pb.bank.mean), A, c.gather_coordinates(pb.BT))
    st.residuals = None


def _combine(rows, coeffs):
    """Coordinate-major rows (N, 3, L, k) times coefficients (N, k) -> (N, L, 3)."""
    N, _, L, k = rows.shape
    return (rows.reshape(N, 3 * L, k) @ coeffs[..., None]).reshape(N, 3, L).transpose(0, 2, 1)


def _points(pb: _Problem, st: _State, sel=slice(None)):
    """(n, 68, 3) model points of the correspondences of the frames ``sel``, mm."""
    m, A, B = (r[sel] for r in st.rows)
    X = m
    if pb.K:
        alpha = st.alpha if pb.shared else st.alpha[sel]
        X = X + _combine(A, np.broadcast_to(_coefficients(pb, alpha), (len(m), pb.K)))
    if pb.E:
        X = X + _combine(B, st.beta[sel])
    return X


def _model_variance(pb: _Problem, st: _State, depth=None):
    """(N, 68) px^2: the model's part of each landmark's variance, (k model_std_mm)^2 plus,
    where no offset carries it, (k definition_std_mm)^2 (k the image scale in px/mm)."""
    scale = st.k
    if pb.perspective and depth is not None:
        used = pb.mask & st.corr.defined
        d = np.where(used, depth, 0.0).sum(1) / np.maximum(used.sum(1), 1)
        scale = st.k / np.maximum(d, 1e-6)
    return scale[:, None] ** 2 * (pb.model_std_mm[:, None] ** 2 + pb.frame_def_std ** 2)


def _weights(pb: _Problem, st: _State, depth=None):
    """(N, 68) data weights 1/s^2 (0 for unused landmarks)."""
    s2 = np.asarray(pb.landmark_std_px)[..., None] ** 2 + _model_variance(pb, st, depth)
    return np.where(pb.mask & st.corr.defined, 1.0 / s2, 0.0)


def _effective_parameters(pb: _Problem, st: _State) -> np.ndarray:
    """(G,) the number of parameters the landmarks actually determine, per group of frames
    that share an identity: the trace of the fit's hat matrix (MacKay's gamma). A free
    parameter (pose) counts 1, a regularised one ``1 - prior * posterior variance``, one
    held at its bound 0; the posterior covariance comes from the Schur complement."""
    Hff, _, Hfa, Haa, _, _, act, _ = _normal_equations(pb, st)
    E, K = pb.E, pb.K
    Hinv = np.linalg.inv(Hff)
    var = np.diagonal(Hinv, axis1=1, axis2=2).copy()
    gamma = np.zeros(Haa.shape[0])
    if K:
        X1 = Hinv @ Hfa                                                      # (N, Pf, K)
        Saa = np.linalg.inv(Haa - _gsum(pb, Hfa.transpose(0, 2, 1) @ X1))    # (G, K, K)
        var += np.einsum("npk,nkl,npl->np", X1, Saa[_group_index(pb)], X1)
        gamma += (1.0 - pb.prior * np.diagonal(Saa, axis1=1, axis2=2)).sum(1)
    prior_f = np.r_[np.zeros(Hff.shape[1] - E), np.full(E, pb.expression_weight)]
    return gamma + _gsum(pb, np.where(act, 0.0, 1.0 - prior_f * var).sum(1))


def _group_index(pb: _Problem) -> np.ndarray:
    return np.zeros(pb.N, int) if pb.shared else np.arange(pb.N)


def _estimate_landmark_std(pb: _Problem, st: _State, floor_px: float = 0.25) -> np.ndarray:
    """(N,) px: per group of frames, the landmark noise at which the normalised residuals add
    up to their degrees of freedom, ``sum r^2 / (sigma^2 + model variance) = n - gamma``
    (n residual coordinates, one per jaw point as only its distance across the outline
    counts; gamma from :func:`_effective_parameters`). Never below ``floor_px``."""
    _, _, _, _, depth, r = _residuals(pb, st, False)
    used = pb.mask & st.corr.defined
    r2 = np.where(used, (r * r).sum(-1), 0.0)
    c = _model_variance(pb, st, depth)
    n = 2 * used.sum(1) - used[:, pb.sliding_landmarks].sum(1)
    dof = _gsum(pb, n.astype(np.float64)) - _effective_parameters(pb, st)

    def excess(s2):                     # decreasing in sigma^2 (s2: per group)
        return _gsum(pb, np.where(used, r2 / (s2[_group_index(pb)][:, None] + c), 0.0).sum(1)) - dof
    lo = np.full(dof.shape, floor_px ** 2)
    hi = np.maximum(_gsum(pb, r2.sum(1)) / np.maximum(dof, 1.0), lo) * 4.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        up = excess(mid) > 0
        lo, hi = np.where(up, mid, lo), np.where(up, hi, mid)
    s2 = np.where((dof > 0) & (excess(np.full(dof.shape, floor_px ** 2)) > 0), 0.5 * (lo + hi),
                  floor_px ** 2)
    return np.sqrt(s2)[_group_index(pb)]


def _slide(pb: _Problem, st: _State):
    """Re-pick the jaw correspondences on the current outline and move their targets along it
    (:func:`~morphable.fitting.correspondences.slide_contours`)."""
    bank = pb.bank
    if pb.sliding is None:
        return
    if pb.perspective:
        # a pinhole camera sees the outline where the surface turns away from its centre (the
        # direction taken to each line's start on the mean shape: a few mm do not change it)
        centre = -np.einsum("nji,nj->ni", st.R, st.t)
        view = []
        for lines in bank.outlines:
            v = centre[:, None] - bank.mean[lines[:, 0]][None]
            view.append(v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-9))
    else:
        view = st.R[:, 2]
    outlines = outline_points(bank, view)
    alpha = np.broadcast_to(st.alpha[:, :pb.n_identity], (pb.N, pb.n_identity))
    projected = []
    for a, b, w in outlines:
        X = [bank.mean[r] + np.einsum("nlik,nk->nli", pb.A[r], alpha)
             + (np.einsum("nlie,ne->nli", pb.B[r], st.beta) if pb.E else 0.0) for r in (a, b)]
        X = (1 - w[..., None]) * X[0] + w[..., None] * X[1]
        projected.append(project(X, st.R, st.t, st.k, pb.principal, pb.perspective, False)[0])
    pb.y, pb.tangent = slide_contours(bank, st.corr, outlines, projected, pb.y_obs, pb.mask)
    st.residuals = None


def _linear_stage(pb: _Problem, n_linear: int) -> _State:
    # the linear stage works with the affine camera; a pinhole fit starts from it
    perspective, pb.perspective = pb.perspective, False
    try:
        st = _affine_linear_stage(pb, n_linear)
    finally:
        pb.perspective = perspective
    if perspective:
        # the same image scale at the landmarks' centroid: its depth is f / s
        used = pb.mask & st.corr.defined
        z = (_points(pb, st) @ st.R.transpose(0, 2, 1))[..., 2]
        zc = np.where(used, z, 0.0).sum(1) / np.maximum(used.sum(1), 1)
        st.t = st.t.copy()
        st.t[:, 2] = -pb.focal / st.k - zc
        st.k = pb.focal.copy()
    return st


def _affine_linear_stage(pb: _Problem, n_linear: int) -> _State:
    N, K, E = pb.N, pb.K, pb.E
    G = 1 if pb.shared else N
    corr = Correspondences.fixed(pb.bank, N)
    alpha, beta = np.zeros((G, K)), np.zeros((N, E))
    W0 = np.where(pb.mask & corr.defined, 1.0, 0.0)     # the first pose: fixed landmarks only
    st = _State(None, None, None, alpha, beta, corr)
    _gather(pb, st)
    for it in range(max(n_linear, 1)):
        st.alpha, st.beta = alpha, beta
        R, t, s = estimate_affine_pose(_points(pb, st), pb.y, W0, pb.principal, check=it == 0)
        st.R, st.t, st.k = R, t, s
        _slide(pb, st)
        _gather(pb, st, sliding_only=True)
        W0 = np.where(pb.mask & corr.defined, 1.0, 0.0)
        if n_linear == 0:
            break
        W = _weights(pb, st)
        # exact affine projection: uv = c + s D (R X + t)
        P = s[:, None, None] * R[:, :2] * np.array([1.0, -1.0])[None, :, None]     # (N, 2, 3)
        q = pb.principal + s[:, None] * t[:, :2] * np.array([1.0, -1.0])
        m, Ag, Bg = st.rows
        base = pb.y - q[:, None] - m @ P.transpose(0, 2, 1)
        if K:
            expr = _combine(Bg, beta) @ P.transpose(0, 2, 1) if E else 0.0
            # the offsets are solved at the mean face's size here (the prior on c, not on
            # delta: a starting point the nonlinear stage corrects)
            c = solve_identity(P, base - expr, W, Ag, pb.prior, pb.shared, pb.gram)
            alpha = _from_coefficients(pb, c)
        if E:
            c = np.broadcast_to(_coefficients(pb, alpha), (N, K))
            ident = _combine(Ag, c) @ P.transpose(0, 2, 1)
            beta = solve_expression(P, base - ident, W, Bg, pb.expression_weight, pb.nonneg)
        st = _State(R, t, s, alpha, beta, corr, st.rows)
    return st


def _residuals(pb: _Problem, st: _State, jacobian: bool, sel=slice(None)):
    """Model points, projections, camera-frame points, d(uv)/d(Xc), depths, residuals (jaw
    points: across the outline only) of the frames ``sel``."""
    every = isinstance(sel, slice) and sel == slice(None)
    if every and st.residuals is not None:
        X, uv, Xc, depth, r = st.residuals
    else:
        X = _points(pb, st, sel)
        uv, Xc, _, depth = project(X, st.R[sel], st.t[sel], st.k[sel], pb.principal[sel],
                                   pb.perspective, False)
        r = across_outline(uv - pb.y[sel], pb.tangent[sel])
        if every:
            st.residuals = X, uv, Xc, depth, r
    J = projection_jacobian(Xc, st.k[sel], pb.perspective) if jacobian else None
    return X, uv, Xc, J, depth, r


def _across_rows(pb: _Problem, J):
    """The same projection for coordinate-major Jacobian rows (N, 2, 68, P), in place, on the
    jaw slice only."""
    if pb.sliding is None:
        return J
    t = pb.tangent[:, pb.sliding].transpose(0, 2, 1)[..., None]      # (N, 2, J, 1)
    Js = J[:, :, pb.sliding]
    J[:, :, pb.sliding] = Js - t * (t * Js).sum(1, keepdims=True)
    return J


def _data_cost(pb, st, W, r, depth, sel=slice(None)):
    """(n,) per-frame costs of the frames ``sel`` (W, r, depth: theirs)."""
    c = (W * (r * r).sum(-1)).sum(1)
    if pb.perspective:
        bad = ((W > 0) & (depth <= 1e-3)).any(1)
        c = np.where(bad, np.inf, c)
    if pb.E:
        c = c + pb.expression_weight * (st.beta[sel] ** 2).sum(1)
    return c


def _group_cost(pb, st, frame_cost, sel=slice(None)):
    """Group costs from the per-frame costs of the frames ``sel`` (all frames for a shared
    identity)."""
    g = frame_cost.sum(0, keepdims=True) if pb.shared else frame_cost
    if pb.K:
        alpha = st.alpha if pb.shared else st.alpha[sel]
        g = g + (pb.prior * alpha ** 2).sum(1)
    return g


def _robust(pb, W, r):
    if pb.robust is None:
        return W
    e = np.sqrt(W * (r * r).sum(-1))
    return W * np.where(e > pb.huber_k, pb.huber_k / np.maximum(e, 1e-300), 1.0)


def _normal_equations(pb: _Problem, st: _State):
    """Gauss-Newton blocks at the current state, priors included: per frame Hff (N, Pf, Pf)
    and gf over rotation, translation, scale (affine) and expressions; Hfa (N, Pf, K) to the
    shared coefficients; Haa (G, K, K) and ga over them; the data weights W (N, 68), the group
    costs (G,) and the expression bound's active set (N, Pf)."""
    N, K, E = pb.N, pb.K, pb.E
    n_t, n_rho = (3, 0) if pb.perspective else (2, 1)
    Pf = 3 + n_t + n_rho + E
    act = np.zeros((N, Pf), bool)
    X, uv, Xc, Jp, depth, r = _residuals(pb, st, True)
    W = _robust(pb, _weights(pb, st, depth), r)
    cost0 = _group_cost(pb, st, _data_cost(pb, st, W, r, depth))
    # Jacobian rows coordinate-major: the 68 x residuals, then the 68 y residuals
    RX = Xc - st.t[:, None]
    blocks = [cross(RX[:, :, None, :], Jp), Jp[..., :n_t]]
    if n_rho:
        blocks.append((uv - pb.principal[:, None])[..., None])     # d uv / d log(scale)
    blocks = [np.concatenate(blocks, -1).transpose(0, 2, 1, 3)]
    # the affine Jacobian is the same for every point: one GEMM per frame
    JpR = Jp[:, 0] @ st.R if not pb.perspective else Jp @ st.R[:, None]
    if E:
        blocks.append(project_rows(JpR, st.rows[2]))
    Jf = _across_rows(pb, np.concatenate(blocks, -1)).reshape(N, 136, Pf)
    Ja4 = _across_rows(pb, project_rows(JpR, _shared_rows(pb, st)))    # (N, 2, 68, K)
    Ja = Ja4.reshape(N, 136, K)
    w2 = np.concatenate([W, W], 1)[..., None]
    rr = r.transpose(0, 2, 1).reshape(N, 136)
    WJf, WJa = w2 * Jf, w2 * Ja
    Hff = Jf.transpose(0, 2, 1) @ WJf
    gf = (WJf.transpose(0, 2, 1) @ rr[..., None])[..., 0]
    if E:
        Hff[:, 3 + n_t + n_rho:, 3 + n_t + n_rho:] += pb.expression_weight * np.eye(E)
        gf[:, 3 + n_t + n_rho:] += pb.expression_weight * st.beta
    Hfa = Jf.transpose(0, 2, 1) @ WJa
    if E and pb.nonneg:
        # blendshape weights held at 0 by the bound leave this step (projected Newton)
        o = 3 + n_t + n_rho
        act[:, o:] = (st.beta <= 0) & (gf[:, o:] > 0)
        if act.any():
            keep = ~act
            Hff = np.where(keep[:, :, None] & keep[:, None, :], Hff, 0.0) + act[:, :, None] * np.eye(Pf)
            gf = np.where(keep, gf, 0.0)
            Hfa = np.where(keep[:, :, None], Hfa, 0.0)
    Haa = gram_hessian(JpR, W, Ja4, pb.gram)
    ga = (WJa.transpose(0, 2, 1) @ rr[..., None])[..., 0]
    if pb.shared:
        Haa, ga = Haa.sum(0, keepdims=True), ga.sum(0, keepdims=True)
    Haa[:, np.arange(K), np.arange(K)] += pb.prior
    ga = ga + pb.prior * st.alpha
    return Hff, gf, Hfa, Haa, ga, W, act, cost0


def _lm_stage(pb: _Problem, st: _State, n_iter: int, slide_every: int = 2):
    N, K, E = pb.N, pb.K, pb.E
    G = 1 if pb.shared else N
    n_t = 3 if pb.perspective else 2
    n_rho = 0 if pb.perspective else 1
    Pf = 3 + n_t + n_rho + E
    mu = np.full(G, 1e-3)
    gidx = _group_index(pb)
    iters = 0
    # a group that has converged stops moving, so that fitting frames together or alone
    # gives the same result
    active = np.ones(G, bool)
    for it in range(n_iter):
        if it % slide_every == 0 and it:
            _slide(pb, st)
            _gather(pb, st, sliding_only=True)
        Hff, gf, Hfa, Haa, ga, W, _, cost0 = _normal_equations(pb, st)
        accepted = ~active
        stepped = np.zeros(G, bool)
        gain = np.zeros(G)
        for attempt in range(4):          # retry rejected groups with more damping
            # independent frames: solve only the active ones still rejected
            sel = slice(None) if pb.shared else np.flatnonzero(~accepted)
            gs = slice(None) if pb.shared else sel
            Hs, Hfs, gfs = Hff[sel], Hfa[sel], gf[sel]
            m_f = mu[gidx[sel]][:, None]
            Hd = Hs + m_f[..., None] * (np.eye(Pf) * (np.diagonal(Hs, axis1=1, axis2=2)[:, None, :] + 1e-9))
            sol = np.linalg.solve(Hd, np.concatenate([Hfs, gfs[..., None]], -1))
            X1, x2 = sol[..., :K], sol[..., K]
            df = np.zeros((N, Pf))
            da = np.zeros((G, K))
            if K:
                Sa = Haa[gs] - _gsum(pb, Hfs.transpose(0, 2, 1) @ X1)
                ba = ga[gs] - _gsum(pb, (x2[:, None, :] @ Hfs)[:, 0])
                Sa = Sa + mu[gs, None, None] * (
                    np.eye(K) * (np.diagonal(Sa, axis1=1, axis2=2)[:, None, :] + 1e-9))
                da[gs] = -np.linalg.solve(Sa, ba[..., None])[..., 0]
                df[sel] = -(x2 + (X1 @ da[gidx[sel]][..., None])[..., 0])
            else:
                df[sel] = -x2
            new = _apply(pb, st, df, da, n_t, n_rho)
            cost1 = np.full(G, np.inf)
            cost1[gs] = _subset_cost(pb, new, W, sel)
            ok = np.isfinite(cost1) & (cost1 <= cost0) & ~accepted
            gain = np.where(ok, cost0 - cost1, gain)
            if ok.any():
                st = _merge(pb, st, new, ok[gidx], ok)
                accepted |= ok
                stepped |= ok
                mu = np.where(ok, np.maximum(mu / 3, 1e-9), mu)
            mu = np.where(~accepted, mu * 8, mu)
            if accepted.all():
                break
        iters += 1
        # a group stops when no damping gave it a better step, or when it has converged
        active &= stepped & (gain > 1e-6 * np.maximum(cost0, 1e-12)) & (mu <= 1e8)
        if not active.any():
            break
    return st, iters


def _subset_cost(pb, st, W, sel):
    """Group costs of the frames ``sel`` (all frames for a shared identity)."""
    _, _, _, _, depth, r = _residuals(pb, st, False, sel)
    return _group_cost(pb, st, _data_cost(pb, st, W[sel], r, depth, sel), sel)


def _gsum(pb, x):
    return x.sum(0, keepdims=True) if pb.shared else x


def _apply(pb, st, df, da, n_t, n_rho):
    t = st.t.copy()
    t[:, :n_t] += df[:, 3:3 + n_t]
    k = st.k * np.exp(np.clip(df[:, 3 + n_t], -2.0, 2.0)) if n_rho else st.k
    o = 3 + n_t + n_rho
    beta = st.beta
    if pb.E:
        beta = st.beta + df[:, o:]
        if pb.nonneg:
            beta = np.maximum(beta, 0.0)
    alpha = st.alpha + da if pb.K else st.alpha
    return _State(rotate(st.R, df[:, :3]), t, k, alpha, beta, st.corr, st.rows)


def _merge(pb, old, new, frames_ok, groups_ok):
    if frames_ok.all() and groups_ok.all():
        return new
    f = frames_ok
    return _State(np.where(f[:, None, None], new.R, old.R), np.where(f[:, None], new.t, old.t),
                  np.where(f, new.k, old.k), np.where(groups_ok[:, None], new.alpha, old.alpha),
                  np.where(f[:, None], new.beta, old.beta), old.corr, old.rows)


def _as_frames(landmarks, mask, image_size):
    y, given = as_landmarks(landmarks, "landmarks")
    if y.ndim == 2:
        y, given = y[None], given[None]
    if y.ndim != 3:
        raise InputError(f"landmarks: expected (68, 2) or (N, 68, 2), got {np.shape(landmarks)}")
    N = y.shape[0]
    if N == 0:
        raise InputError("landmarks: no frames given")
    if mask is not None:
        m = np.asarray(mask, dtype=bool)
        if m.shape not in ((68,), (N, 68)):
            raise InputError(f"mask: expected (68,) or ({N}, 68) booleans, got {m.shape}")
        given = given & np.broadcast_to(m, given.shape)
    size = np.asarray(image_size, dtype=np.float64)
    if size.shape == (2,):
        size = np.broadcast_to(size, (N, 2))
    if size.shape != (N, 2) or not np.all(np.isfinite(size)) or not np.all(size > 0):
        raise InputError(f"image_size: expected positive (W, H) or one per frame ({N}, 2), "
                         f"got {np.shape(image_size)}")
    return y, given, size


@single_blas_thread()
def fit_landmarks(model, landmarks, image_size, *, camera: str = "affine", mask=None,
                  n_iterations: int = 4, n_linear: int = 3, n_identity=None, n_expression=None,
                  prior_weight: float = 1.0, expression_weight: float = 1.0, robust=None,
                  huber_k: float = 1.345, shared_identity: bool = True,
                  landmark_std_px=1.0, model_std_mm=MODEL_STD_MM,
                  definition_std_mm=DEFINITION_STD_MM, focal_px=None,
                  contour: str = "slide", dtype=np.float64) -> FitResult:
    """Fit a morphable model to 2D iBUG-68 landmarks of one or more images.

    Parameters
    ----------
    model : MorphableModel or str
        A model with an iBUG-68 mapping (``landmark_ids``); a name is loaded with ``load_model``.
    landmarks : (68, 2) or (N, 68, 2) array-like, pixels
        0-based image coordinates (x right, y down); NaN rows are missing points.
    image_size : (W, H) or (N, 2), pixels
    camera : {"affine", "perspective"}
        Scaled orthographic or pinhole camera (fixed focal ``focal_px``, default ``max(W, H)``).
    mask : (68,) or (N, 68) bool, optional
        False excludes a landmark (in addition to NaN rows).
    n_iterations : int
        Levenberg-Marquardt iterations after the linear stage (0 = linear fit only).
    n_linear : int
        Rounds of pose / jaw / identity / expression linear solves (at most one where no
        frame gives a jaw point and ``n_iterations > 0``).
    n_identity, n_expression : int or None
        Fit only the first modes (None = all).
    prior_weight, expression_weight : float >= 0
        Weights of ``|alpha|^2`` and ``|beta|^2`` (1 = the Gaussian prior at its Bayesian
        weight; for blendshapes, ``|beta|^2`` is weighted by :func:`expression_precision`
        too); 0 is allowed and stays finite (a tiny ridge remains).
    robust : None or "huber"
        Huber loss on the normalised landmark residuals (threshold ``huber_k``).
    shared_identity : bool
        True: one identity for all frames. False: every frame is fitted on its own (batch mode,
        vectorised); ``identity`` is then the average of the per-frame identities.
    landmark_std_px : float or "auto"
        Noise of the 2D points (px). "auto" estimates it from the fit's own residuals (fit at
        1 px, set the noise so that the normalised residuals add up to their degrees of
        freedom, refit), one value per shared identity; it costs about 60 % more time. The
        noise used is ``FitResult.landmark_std_px``.
    model_std_mm : float or (N,) array
        The model's per-frame landmark error (mm), or per frame; for landmarks a detector
        found, :data:`DETECTED_MODEL_STD_MM` (``morphable fit`` uses it for detected frames).
    definition_std_mm : float or (68,) array
        Standard deviation (mm, per coordinate) of each landmark's definition error, one 3D
        offset shared by all frames of a subject (see the module docstring); 0 = none.
        Default :data:`DEFINITION_STD_MM`, largest for the eyebrows.
    contour : {"slide", "fixed"}
        "slide": jaw points correspond to the face's outline, re-picked at every iteration
        (:mod:`~morphable.fitting.correspondences`); "fixed": to fixed vertices, if any.
    dtype : numpy dtype of the returned meshes (the fit itself runs in float64)

    Returns
    -------
    FitResult

    Raises
    ------
    FitError when the landmarks cannot determine a fit (fewer than 4 usable points,
    collinear or coincident points, a non-finite result). InputError for malformed input.

    Examples
    --------
    >>> from morphable import load_model
    >>> from morphable.camera import Camera
    >>> model = load_model("sfm")
    >>> cam = Camera.looking_at_face(image_size=(512, 512), yaw=20)
    >>> lms = cam.project(model.landmark_positions())      # NaN rows for the jaw contour
    >>> res = fit_landmarks(model, lms, (512, 512))
    >>> bool(res.landmark_rmse_px[0] < 1.0), round(float(res.euler_deg[0, 0]))
    (True, 20)
    """
    t0 = time.perf_counter()
    if isinstance(model, str):
        from ..io.registry import load_model

        model = load_model(model)
    if camera not in ("affine", "perspective"):
        raise InputError(f"camera: expected 'affine' or 'perspective', got {camera!r}")
    if contour not in ("slide", "fixed"):
        raise InputError(f"contour: expected 'slide' or 'fixed', got {contour!r}")
    if robust not in (None, "huber"):
        raise InputError(f"robust: expected None or 'huber', got {robust!r}")
    auto_std = isinstance(landmark_std_px, str)
    if auto_std and landmark_std_px != "auto":
        raise InputError(f"landmark_std_px: expected a number or 'auto', got {landmark_std_px!r}")
    definition_std_mm = np.asarray(definition_std_mm, dtype=np.float64)
    if definition_std_mm.shape not in ((), (68,)):
        raise InputError(f"definition_std_mm: expected a number or 68 numbers, got shape "
                         f"{definition_std_mm.shape}")
    for name, v in (("prior_weight", prior_weight), ("expression_weight", expression_weight),
                    ("landmark_std_px", 1.0 if auto_std else landmark_std_px),
                    ("model_std_mm", model_std_mm), ("definition_std_mm", definition_std_mm),
                    ("huber_k", huber_k)):
        if not (np.all(np.isfinite(v)) and np.all(np.asarray(v) >= 0)):
            raise InputError(f"{name}: must be finite and >= 0, got {v}")
    y, given, size = _as_frames(landmarks, mask, image_size)
    N = y.shape[0]
    model_std_mm = np.asarray(model_std_mm, dtype=np.float64)
    if model_std_mm.shape not in ((), (N,)):
        raise InputError(f"model_std_mm: expected a number or one per frame ({N}), got shape "
                         f"{model_std_mm.shape}")
    if not auto_std and landmark_std_px == 0 and np.any(model_std_mm == 0):
        raise InputError("landmark_std_px and model_std_mm cannot both be 0")
    K = model.n_identity if n_identity is None else int(n_identity)
    E = model.n_expression if n_expression is None else int(n_expression)
    if not (0 <= K <= model.n_identity) or not (0 <= E <= model.n_expression):
        raise InputError(f"n_identity/n_expression must be in [0, {model.n_identity}] / "
                         f"[0, {model.n_expression}], got {K} / {E}")
    principal = (size - 1) / 2.0
    perspective = camera == "perspective"
    if focal_px is None:
        focal = size.max(1)
    else:
        focal = np.broadcast_to(np.asarray(focal_px, dtype=np.float64), (N,)).copy()
        if not (np.all(np.isfinite(focal)) and np.all(focal > 0)):
            raise InputError(f"focal_px: must be positive, got {focal_px}")
    # the model's landmark rows are prepared once per model and process: not part of a fit's time
    t_bank = time.perf_counter()
    bank = landmark_bank(model, slide=contour == "slide")
    t0 += time.perf_counter() - t_bank
    usable = given & bank.usable[None]
    if (usable.sum(1) < 4).any():
        f = int(np.argmax(usable.sum(1) < 4))
        raise FitError(f"frame {f}: {int(usable[f].sum())} usable landmarks "
                       f"(given and defined on model {model.name}), need at least 4")
    pb = _Problem(bank, y, usable, principal, focal, perspective, K, E, shared_identity,
                  model.expression_kind == "blendshapes", float(prior_weight),
                  float(expression_weight) * expression_precision(model),
                  1.0 if auto_std else float(landmark_std_px),
                  model_std_mm, robust, float(huber_k), definition_std_mm)
    with np.errstate(all="ignore"):
        # with no jaw point to re-pick, later linear rounds would only alternate pose and
        # shape, which the nonlinear stage does jointly (same accuracy, a third less time)
        rounds = n_linear if pb.sliding is not None or not n_iterations else min(n_linear, 1)
        st = _linear_stage(pb, rounds)
        st, iters = _lm_stage(pb, st, n_iterations)
        for _ in range(AUTO_ROUNDS if auto_std else 0):
            _slide(pb, st)
            _gather(pb, st, sliding_only=True)
            pb.landmark_std_px = _estimate_landmark_std(pb, st)
            st, more = _lm_stage(pb, st, n_iterations)
            iters += more
        _slide(pb, st)
        _gather(pb, st, sliding_only=True)
        _, uv, _, _, depth, r = _residuals(pb, st, False)
    used = usable & st.corr.defined
    d2 = (r ** 2).sum(-1)
    rmse = np.sqrt(np.where(used, d2, 0.0).sum(1) / np.maximum(used.sum(1), 1))
    finite = all(np.all(np.isfinite(a)) for a in (st.R, st.t, st.k, st.alpha, st.beta, rmse))
    if not finite:
        raise FitError("the fit did not converge to finite values (degenerate landmarks?)")
    if perspective and np.any(used & ~(depth > 0)):
        raise FitError("the perspective fit put landmarks behind the camera")
    cams = []
    for i in range(N):
        W_, H_ = (int(round(v)) for v in size[i])
        t = st.t[i].copy()
        if not perspective:
            t[2] = -AFFINE_DISTANCE_MM
        cams.append(Camera(kind=camera, rotation=st.R[i], translation=t,
                           scale=float(st.k[i]) if not perspective else 1.0,
                           focal=float(st.k[i]) if perspective else 1.0,
                           image_size=(W_, H_), principal=principal[i]))
    frame_alpha = np.broadcast_to(st.alpha[:, :K], (N, K)).copy()
    # jaw points: the foot of the landmark on the fitted outline (the target moved along it)
    fitted = np.where(used[..., None], y + r, np.nan)
    res = FitResult(model=model, identity=frame_alpha.mean(0), frame_identity=frame_alpha,
                    expression=st.beta.copy(), cameras=cams, landmark_rmse_px=rmse,
                    landmarks=np.where(given[..., None], y, np.nan), fitted_landmarks=fitted,
                    landmark_vertices=np.where(used, st.corr.vertex_ids(bank), -1),
                    shared_identity=bool(shared_identity), iterations=iters,
                    cost=(np.where(used, d2, 0.0)).sum(1), dtype=np.dtype(dtype),
                    landmark_std_px=np.broadcast_to(pb.landmark_std_px, (N,)).astype(np.float64),
                    model_std_mm=pb.model_std_mm.astype(np.float64))
    res.runtime_ms = (time.perf_counter() - t0) * 1e3
    return res
