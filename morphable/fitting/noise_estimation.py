"""``landmark_std_px="auto"``: the detector's noise estimated from a fit's own residuals.

MacKay's evidence approximation: at the right noise the normalised residuals of a fit add up
to their degrees of freedom, the observations minus the trace of the hat matrix (the number
of parameters the landmarks actually determine). The fit runs at 1 px, the noise is set so,
and the nonlinear stage refits (:data:`AUTO_ROUNDS` times).
"""
from __future__ import annotations

import numpy as np

from .noise import model_variance
from .nonlinear import normal_equations
from .offsets import posterior_variances
from .problem import Problem, State, group_index, group_sum
from .rows import residuals

__all__ = ["AUTO_ROUNDS", "effective_parameters", "estimate_landmark_std"]

AUTO_ROUNDS = 1
"""Re-estimations of the landmark noise for ``landmark_std_px="auto"`` (each one refits)."""


def effective_parameters(pb: Problem, st: State) -> np.ndarray:
    """(G,) the number of parameters the landmarks actually determine, per group of frames
    that share an identity: the trace of the fit's hat matrix (MacKay's gamma). A free
    parameter (pose) counts 1, a regularised one ``1 - prior * posterior variance``, one
    held at its bound 0; the posterior covariance comes from the Schur complement (with
    landmark offsets, from :func:`~morphable.fitting.offsets.posterior_variances`)."""
    ne = normal_equations(pb, st)
    Hff, Hfa, Haa, act, off = ne.Hff, ne.Hfa, ne.Haa, ne.act, ne.off
    E, K = pb.E, pb.K
    gamma = np.zeros(Haa.shape[0])
    if off is not None:
        var, shared = posterior_variances(Hff, Hfa, Haa, off)
        gamma += (1.0 - pb.prior * shared).sum()
    else:
        Hinv = np.linalg.inv(Hff)
        var = np.diagonal(Hinv, axis1=1, axis2=2).copy()
    if K and off is None:
        X1 = Hinv @ Hfa                                                      # (N, Pf, K)
        Saa = np.linalg.inv(Haa - group_sum(pb, Hfa.transpose(0, 2, 1) @ X1))    # (G, K, K)
        var += np.einsum("npk,nkl,npl->np", X1, Saa[group_index(pb)], X1)
        gamma += (1.0 - pb.prior * np.diagonal(Saa, axis1=1, axis2=2)).sum(1)
    prior_f = np.r_[np.zeros(Hff.shape[1] - E), np.full(E, pb.expression_weight)]
    return gamma + group_sum(pb, np.where(act, 0.0, 1.0 - prior_f * var).sum(1))


def estimate_landmark_std(pb: Problem, st: State, floor_px: float = 0.25) -> np.ndarray:
    """(N,) px: per group of frames, the landmark noise at which the normalised residuals add
    up to their degrees of freedom, ``sum r^2 / (sigma^2 + model variance) = n - gamma``
    (n residual coordinates, one per outline point as only its distance across the outline
    counts; gamma from :func:`effective_parameters`). Never below ``floor_px``."""
    _, _, _, _, depth, r = residuals(pb, st, False)
    used = pb.mask & st.corr.defined
    r2 = np.where(used, (r * r).sum(-1), 0.0)
    c = model_variance(pb, st, depth)
    n = 2 * used.sum(1) - used[:, pb.sliding_landmarks].sum(1)
    dof = group_sum(pb, n.astype(np.float64)) - effective_parameters(pb, st)

    def excess(s2):                     # decreasing in sigma^2 (s2: per group)
        return group_sum(pb, np.where(used, r2 / (s2[group_index(pb)][:, None] + c), 0.0).sum(1)) - dof
    lo = np.full(dof.shape, floor_px ** 2)
    hi = np.maximum(group_sum(pb, r2.sum(1)) / np.maximum(dof, 1.0), lo) * 4.0
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        up = excess(mid) > 0
        lo, hi = np.where(up, mid, lo), np.where(up, hi, mid)
    s2 = np.where((dof > 0) & (excess(np.full(dof.shape, floor_px ** 2)) > 0), 0.5 * (lo + hi),
                  floor_px ** 2)
    return np.sqrt(s2)[group_index(pb)]
