"""The linear stage of a landmark fit: pose, outline correspondences, identity and expression.

Each round estimates a scaled orthographic camera from the 2D points and the current model
points (:func:`~morphable.fitting.pose.estimate_affine_pose`; the first from the fixed
landmarks of the mean face), re-picks the outline correspondences
(:mod:`~morphable.fitting.sliding`) and solves for the identity, then the expression, in
closed form under the Gaussian prior (:mod:`~morphable.fitting.linear`).
"""
from __future__ import annotations

import numpy as np

from .correspondences import Correspondences
from .linear import solve_expression, solve_identity
from .noise import pose_weights, weights
from .pose import estimate_affine_pose
from .problem import Problem, State
from .offsets import solve_identity_offsets
from .rows import combine, fixed_rows, from_coefficients, identity_points, points
from .sliding import slide

__all__ = ["linear_stage"]


def linear_stage(pb: Problem, n_linear: int) -> State:
    """The start of a fit: ``n_linear`` rounds (at least one pose) of the affine pose, the outline
    correspondences and the identity and expression solves; a pinhole fit then takes the
    affine fit's image scale at the landmarks' centroid."""
    # the linear stage works with the affine camera; a pinhole fit starts from it
    perspective, pb.perspective = pb.perspective, False
    try:
        st = _affine_linear_stage(pb, n_linear)
    finally:
        pb.perspective = perspective
    if perspective:
        # the same image scale at the landmarks' centroid: its depth is f / s
        used = pb.mask & st.corr.defined
        z = (points(pb, st) @ st.R.transpose(0, 2, 1))[..., 2]
        zc = np.where(used, z, 0.0).sum(1) / np.maximum(used.sum(1), 1)
        st.t = st.t.copy()
        st.t[:, 2] = -pb.focal / st.k - zc
        st.k = pb.focal.copy()
    return st


def _affine_linear_stage(pb: Problem, n_linear: int) -> State:
    N, K, E = pb.N, pb.K, pb.E
    G = 1 if pb.shared else N
    corr = Correspondences.fixed(pb.bank, N)
    alpha, beta = np.zeros((G, K)), np.zeros((N, E))
    W0 = pose_weights(pb, corr.defined)     # the first pose: fixed landmarks only
    st = State(None, None, None, alpha, beta, corr, fixed_rows(pb, N))
    for it in range(max(n_linear, 1)):
        st.alpha, st.beta = alpha, beta
        R, t, s = estimate_affine_pose(points(pb, st), pb.y, W0, pb.principal, check=it == 0)
        st.R, st.t, st.k = R, t, s
        slide(pb, st)
        W0 = pose_weights(pb, corr.defined)
        if n_linear == 0:
            break
        W = weights(pb, st)
        # exact affine projection: uv = c + s D (R X + t)
        P = s[:, None, None] * R[:, :2] * np.array([1.0, -1.0])[None, :, None]     # (N, 2, 3)
        q = pb.principal + s[:, None] * t[:, :2] * np.array([1.0, -1.0])
        m, Ag, Bg = st.rows
        base = pb.y - q[:, None] - m @ P.transpose(0, 2, 1)
        if K:
            expr = combine(Bg, beta) @ P.transpose(0, 2, 1) if E else 0.0
            # the offsets are solved at the mean face's size here (the prior on c, not on
            # delta: a starting point the nonlinear stage corrects)
            # solved as the step from the prior's mean, whose own prior is centred at 0
            mean = pb.prior_mean[None, :pb.n_identity]
            target = base - expr - combine(Ag, mean) @ P.transpose(0, 2, 1)
            c = (solve_identity_offsets(pb, P, target, W, Ag) if pb.D else
                 solve_identity(P, target, W, Ag, pb.prior, pb.shared, pb.gram))
            c[:, :pb.n_identity] += mean
            alpha = from_coefficients(pb, c)
        if E:
            ident = identity_points(pb, Ag, alpha) @ P.transpose(0, 2, 1)
            beta = solve_expression(P, base - ident, W, Bg, pb.expression_weight, pb.nonneg)
        st = State(R, t, s, alpha, beta, corr, st.rows)
    return st
