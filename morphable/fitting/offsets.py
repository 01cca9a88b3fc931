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

Blocks of the offsets: ``Hdd`` (M, 3, 3), ``gd`` (M, 3), and the couplings to P other
parameters coordinate-major, (..., 3, M, P) (as the model rows: products with them are then
contiguous).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .linear import gram_hessian, project_rows
from .rows import face_size

__all__ = ["OffsetBlocks", "offset_normal", "solve_arrow",
           "arrow_inverse_diagonal", "damped_step", "posterior_variances",
           "solve_identity_offsets"]


class OffsetBlocks(NamedTuple):
    """The offsets' blocks of a shared fit's normal equations (priors included): ``Hfd``
    (N, 3, M, Pf) to each frame's parameters, ``Had`` (3, M, K) to the identity, ``Hdd``
    (M, 3, 3) their own, ``gd`` (M, 3) their gradient."""
    Hfd: np.ndarray
    Had: np.ndarray
    Hdd: np.ndarray
    gd: np.ndarray


def _blocks(pb, P, scale, W, r, J):
    """The offsets' Hdd (M, 3, 3), gd (M, 3) and coupling (N, 3, M, P) to the coordinate-major
    rows J (N, 2, L, P), per frame, for data weights W (N, L) and residuals or targets r
    (N, L, 2) px. An offset's Jacobian is the projection ``P`` ((N, 2, 3) shared by the points,
    or (N, L, 2, 3)) times ``scale`` (N,) times its ``offset_std``."""
    lms = pb.offset_landmarks
    N, M, Pj = len(W), len(lms), J.shape[-1]
    ws = W[:, lms] * (scale[:, None] * pb.offset_std)                       # (N, M)
    WJ = J[:, :, lms] * ws[:, None, :, None]                                # (N, 2, M, P)
    rl = r[:, lms]                                                          # (N, M, 2)
    s = scale[:, None] * pb.offset_std
    if P.ndim == 3:
        # one projection per frame: products with it are one GEMM per frame
        Hdd = ((ws * s).T @ (P.transpose(0, 2, 1) @ P).reshape(N, 9)).reshape(M, 3, 3)
        gd = ((ws[..., None] * rl) @ P).sum(0)
        return Hdd, gd, (P.transpose(0, 2, 1) @ WJ.reshape(N, 2, M * Pj)).reshape(N, 3, M, Pj)
    Pl = P[:, lms]                                                          # (N, M, 2, 3)
    Hdd = np.einsum("nm,nmca,nmcb->mab", ws * s, Pl, Pl)
    gd = np.einsum("nm,nmca,nmc->ma", ws, Pl, rl)
    Hfd = sum(Pl[:, :, c].transpose(0, 2, 1)[..., None] * WJ[:, c, None] for c in range(2))
    return Hdd, gd, Hfd


def _add_prior(pb, Hdd, gd, alpha):
    prior = pb.prior[pb.n_identity:].reshape(-1, 3)
    Hdd = Hdd + prior[:, :, None] * np.eye(3)
    return Hdd, gd + prior * alpha[0, pb.n_identity:].reshape(-1, 3)


def offset_normal(pb, st, JpR, W, r, Jf, Ja) -> OffsetBlocks:
    """The offsets' blocks at state ``st`` for the Levenberg-Marquardt: ``JpR`` the projection
    of the points' derivatives ((N, 2, 3) or (N, L, 2, 3)), W (N, L) the data weights, r
    (N, L, 2) px the residuals, Jf (N, 2, L, Pf) and Ja (N, 2, L, K) the frames' and the
    identity's Jacobian rows."""
    scale = np.broadcast_to(face_size(pb, st.alpha), (pb.N,))
    Hdd, gd, Hfd = _blocks(pb, JpR, scale, W, r, Jf)
    Hdd, gd = _add_prior(pb, Hdd, gd, st.alpha)
    Had = _blocks(pb, JpR, scale, W, r, Ja)[2].sum(0)
    return OffsetBlocks(Hfd, Had, Hdd, gd)


def solve_arrow(Huu, C, Hdd, gu, gd):
    """Solve ``[[Huu, C^T], [C, Hdd]] [xu, xd] = [gu, gd]`` with ``Hdd`` block-diagonal:
    Huu (U, U), C (3, M, U) (the coupling of landmark m's coordinate a is ``C[a, m]``), Hdd
    (M, 3, 3), gu (U,), gd (M, 3) -> xu (U,), xd (M, 3). The offsets are eliminated first: a
    U x U solve and M 3x3 inverses."""
    Q, QC, R = _reduced(Huu, C, Hdd)
    xu = np.linalg.solve(R, gu - QC.T @ gd.T.reshape(-1))
    v = gd - (C.reshape(len(QC), -1) @ xu).reshape(3, -1).T
    return xu, (Q @ v[..., None])[..., 0]


def arrow_inverse_diagonal(Huu, C, Hdd):
    """The diagonal of the inverse of the matrix of :func:`solve_arrow`: (U,), (M, 3)."""
    Q, QC, R = _reduced(Huu, C, Hdd)
    Rinv = np.linalg.inv(R)
    dd = np.diagonal(Q, axis1=1, axis2=2) + ((QC @ Rinv) * QC).sum(1).reshape(3, -1).T
    return np.diagonal(Rinv).copy(), dd


def _reduced(Huu, C, Hdd):
    # Q = Hdd^-1 per landmark, the rows Q C (3 M, U), and the Schur complement of the
    # offsets' block
    Q = np.linalg.inv(Hdd)
    QC = sum(Q[:, :, b].T[..., None] * C[b] for b in range(3))              # (3, M, U)
    QC = QC.reshape(-1, len(Huu))
    return Q, QC, Huu - QC.T @ C.reshape(len(QC), -1)


def _frame_system(Hff, Hfa, Haa, off):
    """The frames' and identity's block of the whole system (N Pf + K square) and its coupling
    to the offsets (3, M, N Pf + K)."""
    N, Pf, K = Hfa.shape
    F = np.zeros((N, Pf, N, Pf))
    F[np.arange(N), :, np.arange(N), :] = Hff
    Hfa = Hfa.reshape(N * Pf, K)
    Huu = np.block([[F.reshape(N * Pf, N * Pf), Hfa], [Hfa.T, Haa]])
    _, _, M, _ = off.Hfd.shape
    Hfd = off.Hfd.transpose(1, 2, 0, 3).reshape(3, M, N * Pf)
    return Huu, np.concatenate([Hfd, off.Had], -1)


def damped_step(Hd, Hfa, gf, Haa, ga, off: OffsetBlocks, mu: float):
    """A Levenberg-Marquardt step of a shared fit with offsets -> df (N, Pf), da (1, K + 3M).

    Damped as :func:`~morphable.fitting.nonlinear.lm_stage` damps a fit without offsets: the
    frames' blocks ``Hd`` (N, Pf, Pf) come damped, the shared coefficients get ``mu`` times
    the diagonal of their Schur complement (+1e-9). Hfa (N, Pf, K), gf (N, Pf), Haa (1, K, K),
    ga (1, K): the frames' and identity's blocks."""
    N, Pf, K = Hfa.shape
    # the offsets' columns in the coordinate-major order of the couplings (3, M)
    Hfs = np.concatenate([Hfa, off.Hfd.reshape(N, -1, Pf).transpose(0, 2, 1)], -1)
    schur = (np.r_[np.diagonal(Haa[0]), np.diagonal(off.Hdd, axis1=1, axis2=2).T.reshape(-1)]
             - (Hfs * np.linalg.solve(Hd, Hfs)).sum((0, 1)))
    damp = mu * (schur + 1e-9)
    Huu, C = _frame_system(Hd, Hfa, Haa[0] + np.diag(damp[:K]), off)
    Hdd = off.Hdd + damp[K:].reshape(3, -1).T[:, :, None] * np.eye(3)
    xu, xd = solve_arrow(Huu, C, Hdd, np.r_[gf.reshape(-1), ga[0]], off.gd)
    return -xu[:N * Pf].reshape(N, Pf), -np.r_[xu[N * Pf:], xd.reshape(-1)][None]


def posterior_variances(Hff, Hfa, Haa, off: OffsetBlocks):
    """The diagonal of the posterior covariance (the inverse of the whole system): frames'
    parameters (N, Pf), shared coefficients (K + 3M,)."""
    N, Pf, _ = Hfa.shape
    du, dd = arrow_inverse_diagonal(*_frame_system(Hff, Hfa, Haa[0], off), off.Hdd)
    return du[:N * Pf].reshape(N, Pf), np.r_[du[N * Pf:], dd.reshape(-1)]


def solve_identity_offsets(pb, P, target, W, A) -> np.ndarray:
    """The shared identity and offsets (1, K + 3M) from ``P (A alpha + offsets) ~= target``,
    the offsets at the mean face's size: :func:`~morphable.fitting.linear.solve_identity`
    (shared, the same ridge) with the offsets' columns used by their structure.

    P (N, 2, 3) the projection, target (N, L, 2) px, W (N, L) weights, A (N, 3, L, K) the
    identity rows (coordinate-major)."""
    N, _, L, K = A.shape
    Phi = project_rows(P, A)                                           # (N, 2, L, K)
    W2 = np.concatenate([W, W], 1)[..., None]
    flat, t = Phi.reshape(N, 2 * L, K), target.transpose(0, 2, 1).reshape(N, 2 * L, 1)
    Haa = gram_hessian(P, W, Phi, None).sum(0)
    ga = ((W2 * flat).transpose(0, 2, 1) @ t)[..., 0].sum(0)
    Hdd, gd, Had = _blocks(pb, P, np.ones(N), W, target, Phi)
    Had = Had.sum(0)
    # the ridge of ridge_solve over all K + 3M coefficients
    n = K + Hdd.shape[0] * 3
    ridge = 1e-10 * (np.trace(Haa) + np.trace(Hdd, axis1=1, axis2=2).sum()) / n + 1e-12
    prior = pb.prior + ridge
    xa, xd = solve_arrow(Haa + np.diag(prior[:K]), Had, Hdd + prior[K:].reshape(-1, 3)[:, :, None]
                         * np.eye(3), ga, gd)
    return np.r_[xa, xd.reshape(-1)][None]
