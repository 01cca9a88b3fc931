"""The landmark offsets' part of a shared fit's normal equations, solved by their structure.

With a shared identity and a definition error, each fixed landmark has a 3D offset (three
coefficients after the identity's, :mod:`~morphable.fitting.noise`): 3 M coefficients for M
landmarks, ~1300 for the face mesh's 478 points. An offset moves one landmark along one
coordinate, so its derivatives are never materialised as columns, and the offsets' own block
of the normal equations is block-diagonal, one 3x3 block per landmark (its residuals in every
frame, plus the prior). The offsets are eliminated first, landmark by landmark (batched 3x3
inverses); what is left is a small dense system over the frames' parameters and the identity
(``N Pf + K``): :func:`solve_arrow`. The solutions are those of the whole system, so the fit
(cost, damping, optimum) is the same as with the dense columns.

Blocks of the offsets: ``Hdd`` (M, 3, 3), ``gd`` (M, 3), and the coupling ``C`` (M, 3, U) to
U other parameters (row ``C[m, a]``: landmark m's offset along coordinate a).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .linear import normal_blocks
from .rows import face_size

__all__ = ["OffsetBlocks", "offset_normal", "solve_arrow", "arrow_inverse_diagonal",
           "damped_step", "posterior_variances", "solve_identity_offsets"]


class OffsetBlocks(NamedTuple):
    """The offsets' blocks of a shared fit's normal equations (priors included): ``C``
    (M, 3, N Pf + K) the coupling to the frames' parameters (frame by frame) and then the
    identity, ``Hdd`` (M, 3, 3) their own, ``gd`` (M, 3) their gradient."""
    C: np.ndarray
    Hdd: np.ndarray
    gd: np.ndarray


def _offset_blocks(pb, P, scale, W, r, S):
    """The offsets' Hdd (M, 3, 3), gd (M, 3) and coupling (M, 3, K) to the identity.

    An offset's Jacobian is the projection ``P`` ((N, 2, 3) shared by the points, or
    (N, L, 2, 3)) times ``scale`` (N,) times its ``offset_std``; W (N, L) the data weights, r
    (N, L, 2) px the residuals (or targets), S (3, L, K) the identity's rows (unprojected):
    the same in every frame at the offset landmarks, which are fixed points (only the
    outline's rows move), so that the coupling is a 3x3 sum over the frames times the rows."""
    lms = pb.offset_landmarks
    N, M = len(W), len(lms)
    s = scale[:, None] * pb.offset_std                                      # (N, M)
    ws, rl = W[:, lms] * s, r[:, lms]
    if P.ndim == 3:
        PP = (P.transpose(0, 2, 1) @ P).reshape(N, 9)
        T, Hdd = ((ws.T @ PP).reshape(M, 3, 3), ((ws * s).T @ PP).reshape(M, 3, 3))
        gd = ((ws[..., None] * rl) @ P).sum(0)
    else:
        Pl = P[:, lms]                                                      # (N, M, 2, 3)
        PP = Pl.transpose(0, 1, 3, 2) @ Pl
        T, Hdd = (np.einsum("nm,nmab->mab", w, PP) for w in (ws, ws * s))
        gd = np.einsum("nm,nmca,nmc->ma", ws, Pl, rl)
    return Hdd, gd, T @ S[:, lms].transpose(1, 0, 2)


def _frame_coupling(pb, P, scale, W, J):
    """(M, 3, N Pf) the offsets' coupling to the frames' parameters, from their coordinate-major
    Jacobian rows J (N, 2, L, Pf) (P, scale, W as in :func:`_offset_blocks`)."""
    lms = pb.offset_landmarks
    N, M, Pf = len(W), len(lms), J.shape[-1]
    # per landmark and frame: (3, 2) @ (2, Pf)
    Pw = P[:, None] if P.ndim == 3 else P[:, lms]                           # (N, 1|M, 2, 3)
    Pw = Pw * (W[:, lms] * (scale[:, None] * pb.offset_std))[..., None, None]
    H = Pw.transpose(1, 0, 3, 2) @ J[:, :, lms].transpose(2, 0, 1, 3)        # (M, N, 3, Pf)
    return H.transpose(0, 2, 1, 3).reshape(M, 3, N * Pf)


def _add_prior(pb, Hdd, gd, alpha):
    prior = pb.prior[pb.n_identity:].reshape(-1, 3)
    Hdd = Hdd + prior[:, :, None] * np.eye(3)
    return Hdd, gd + prior * alpha[0, pb.n_identity:].reshape(-1, 3)


def offset_normal(pb, st, JpR, W, r, Jf, S) -> OffsetBlocks:
    """The offsets' blocks at state ``st`` for the Levenberg-Marquardt: ``JpR`` the projection
    of the points' derivatives ((N, 2, 3) or (N, L, 2, 3)), W (N, L) the data weights, r
    (N, L, 2) px the residuals, Jf (N, 2, L, Pf) the frames' Jacobian rows, S (3, L, K) the
    identity's derivatives of the points (:func:`~morphable.fitting.rows.shared_rows`, any
    frame)."""
    scale = np.broadcast_to(face_size(pb, st.alpha), (pb.N,))
    Hdd, gd, Had = _offset_blocks(pb, JpR, scale, W, r, S)
    Hdd, gd = _add_prior(pb, Hdd, gd, st.alpha)
    return OffsetBlocks(np.concatenate([_frame_coupling(pb, JpR, scale, W, Jf), Had], -1), Hdd, gd)


def solve_arrow(Huu, C, Hdd, gu, gd):
    """Solve ``[[Huu, C^T], [C, Hdd]] [xu, xd] = [gu, gd]`` with ``Hdd`` block-diagonal:
    Huu (U, U), C (M, 3, U), Hdd (M, 3, 3), gu (U,), gd (M, 3) -> xu (U,), xd (M, 3). The
    offsets are eliminated first: a U x U solve and M 3x3 inverses."""
    Q, QC, R = _reduced(Huu, C, Hdd)
    xu = np.linalg.solve(R, gu - QC.reshape(-1, len(Huu)).T @ gd.reshape(-1))
    return xu, (Q @ gd[..., None])[..., 0] - QC @ xu


def arrow_inverse_diagonal(Huu, C, Hdd):
    """The diagonal of the inverse of the matrix of :func:`solve_arrow`: (U,), (M, 3)."""
    Q, QC, R = _reduced(Huu, C, Hdd)
    Rinv = np.linalg.inv(R)
    QC = QC.reshape(-1, len(Huu))
    dd = np.diagonal(Q, axis1=1, axis2=2) + ((QC @ Rinv) * QC).sum(1).reshape(-1, 3)
    return np.diagonal(Rinv).copy(), dd


def _reduced(Huu, C, Hdd):
    # Q = Hdd^-1 per landmark, Q C (M, 3, U), and the Schur complement of the offsets' block
    Q = np.linalg.inv(Hdd)
    QC = Q @ C
    U = len(Huu)
    return Q, QC, Huu - QC.reshape(-1, U).T @ C.reshape(-1, U)


def _frame_system(Hff, Hfa, Haa):
    """The frames' and identity's block of the whole system, (N Pf + K) square."""
    N, Pf, K = Hfa.shape
    F = np.zeros((N, Pf, N, Pf))
    F[np.arange(N), :, np.arange(N), :] = Hff
    Hfa = Hfa.reshape(N * Pf, K)
    return np.block([[F.reshape(N * Pf, N * Pf), Hfa], [Hfa.T, Haa]])


def damped_step(Hd, Hfa, gf, Haa, ga, off: OffsetBlocks, mu: float):
    """A Levenberg-Marquardt step of a shared fit with offsets -> df (N, Pf), da (1, K + 3M).

    Damped as :func:`~morphable.fitting.nonlinear.lm_stage` damps a fit without offsets: the
    frames' blocks ``Hd`` (N, Pf, Pf) come damped, the shared coefficients get ``mu`` times
    the diagonal of their Schur complement (+1e-9). Hfa (N, Pf, K), gf (N, Pf), Haa (1, K, K),
    ga (1, K): the frames' and identity's blocks."""
    N, Pf, K = Hfa.shape
    M = len(off.Hdd)
    Hfd = off.C[..., :N * Pf].reshape(3 * M, N, Pf).transpose(1, 2, 0)     # (N, Pf, 3M)
    Hfs = np.concatenate([Hfa, Hfd], -1)
    schur = (np.r_[np.diagonal(Haa[0]), np.diagonal(off.Hdd, axis1=1, axis2=2).reshape(-1)]
             - (Hfs * np.linalg.solve(Hd, Hfs)).sum((0, 1)))
    damp = mu * (schur + 1e-9)
    Huu = _frame_system(Hd, Hfa, Haa[0] + np.diag(damp[:K]))
    Hdd = off.Hdd + damp[K:].reshape(M, 3)[:, :, None] * np.eye(3)
    xu, xd = solve_arrow(Huu, off.C, Hdd, np.r_[gf.reshape(-1), ga[0]], off.gd)
    return -xu[:N * Pf].reshape(N, Pf), -np.r_[xu[N * Pf:], xd.reshape(-1)][None]


def posterior_variances(Hff, Hfa, Haa, off: OffsetBlocks):
    """The diagonal of the posterior covariance (the inverse of the whole system): frames'
    parameters (N, Pf), shared coefficients (K + 3M,)."""
    N, Pf, _ = Hfa.shape
    du, dd = arrow_inverse_diagonal(_frame_system(Hff, Hfa, Haa[0]), off.C, off.Hdd)
    return du[:N * Pf].reshape(N, Pf), np.r_[du[N * Pf:], dd.reshape(-1)]


def solve_identity_offsets(pb, P, target, W, A) -> np.ndarray:
    """The shared identity and offsets (1, K + 3M) from ``P (A alpha + offsets) ~= target``,
    the offsets at the mean face's size: :func:`~morphable.fitting.linear.solve_identity`
    (shared, the same ridge) with the offsets' columns used by their structure.

    P (N, 2, 3) the projection, target (N, L, 2) px, W (N, L) weights, A (N, 3, L, K) the
    identity rows (coordinate-major, the same in every frame at the offset landmarks)."""
    N, _, L, K = A.shape
    Haa, ga = (x.sum(0) for x in normal_blocks(P, W, A, target, pb.gram))
    Hdd, gd, Had = _offset_blocks(pb, P, np.ones(N), W, target, A[0])
    # the ridge of ridge_solve over all K + 3M coefficients
    n = K + Hdd.shape[0] * 3
    ridge = 1e-10 * (np.trace(Haa) + np.trace(Hdd, axis1=1, axis2=2).sum()) / n + 1e-12
    prior = pb.prior + ridge
    xa, xd = solve_arrow(Haa + np.diag(prior[:K]), Had, Hdd + prior[K:].reshape(-1, 3)[:, :, None]
                         * np.eye(3), ga, gd)
    return np.r_[xa, xd.reshape(-1)][None]
