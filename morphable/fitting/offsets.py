"""The landmark offsets' part of a shared fit's normal equations, solved by their structure.

With a shared identity and a definition error, each fixed landmark has a 3D offset (three
coefficients after the identity's, :mod:`~morphable.fitting.noise`): 3 M coefficients for M
landmarks, ~1300 for the face mesh's 478 points. An offset moves one landmark along one
coordinate, so its derivatives are never materialised as columns, and the offsets' own block
of the normal equations is block-diagonal, one 3x3 block per landmark (its residuals in every
frame, plus the prior), as is the frames' (one Pf x Pf block per frame). The whole system is
solved as an arrow (:func:`solve_arrow`): the offsets are eliminated first, landmark by
landmark (batched 3x3 inverses), leaving a small dense system over the frames' parameters and
the identity (``N Pf + K``); or, where the frames' parameters outnumber the offsets' (many
frames), the frames are, leaving a dense system over the identity and the offsets (``K +
3 M``). The solutions are those of the whole system, so the fit (cost, damping, optimum) is the
same as with the dense columns.

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
    Huu (U, U), C (M, b, U), Hdd (M, b, b) (M blocks of size b), gu (U,), gd (M, b) -> xu
    (U,), xd (M, b). The blocks are eliminated first: a U x U solve and M b x b inverses."""
    Q, QC, R = _reduced(Huu, C, Hdd)
    xu = np.linalg.solve(R, gu - QC.reshape(-1, len(Huu)).T @ gd.reshape(-1))
    return xu, (Q @ gd[..., None])[..., 0] - QC @ xu


def arrow_inverse_diagonal(Huu, C, Hdd):
    """The diagonal of the inverse of the matrix of :func:`solve_arrow`: (U,), (M, b)."""
    Q, QC, R = _reduced(Huu, C, Hdd)
    Rinv = np.linalg.inv(R)
    QC = QC.reshape(-1, len(Huu))
    dd = np.diagonal(Q, axis1=1, axis2=2) + ((QC @ Rinv) * QC).sum(1).reshape(len(Q), -1)
    return np.diagonal(Rinv).copy(), dd


def _reduced(Huu, C, Hdd):
    # Q = Hdd^-1 per block, Q C (M, b, U), and the Schur complement of the blocks
    Q = np.linalg.inv(Hdd)
    QC = Q @ C
    U = len(Huu)
    return Q, QC, Huu - QC.reshape(-1, U).T @ C.reshape(-1, U)


def _block_diagonal(B):
    """(n, b, b) blocks -> the (n b, n b) block-diagonal matrix."""
    n, b, _ = B.shape
    D = np.zeros((n, b, n, b))
    D[np.arange(n), :, np.arange(n), :] = B
    return D.reshape(n * b, n * b)


def _arrow(Hff, Hfa, Haa, off, Hdd):
    """The whole system over the frames' parameters, the identity and the offsets (Hff
    (N, Pf, Pf), Hfa (N, Pf, K), Haa (K, K), the offsets' coupling ``off.C`` and blocks Hdd
    (M, 3, 3)) as an arrow for :func:`solve_arrow` -> (Huu, C, blocks, offsets_first): the
    blocks are the offsets' (the dense part the frames and the identity), or, where that is
    smaller, the frames' (the dense part the identity and the offsets)."""
    N, Pf, K = Hfa.shape
    M = len(Hdd)
    if N * Pf <= 3 * M:
        Hfa = Hfa.reshape(N * Pf, K)
        return np.block([[_block_diagonal(Hff), Hfa], [Hfa.T, Haa]]), off.C, Hdd, True
    Had = off.C[..., N * Pf:].reshape(3 * M, K)
    Hfd = off.C[..., :N * Pf].reshape(3 * M, N, Pf).transpose(1, 2, 0)      # (N, Pf, 3M)
    Hvv = np.block([[Haa, Had.T], [Had, _block_diagonal(Hdd)]])
    return Hvv, np.concatenate([Hfa, Hfd], -1), Hff, False


def _solve_whole(Hff, Hfa, Haa, off, Hdd, gf, ga, gd):
    """The whole system's solution (:func:`_arrow`; gf (N, Pf), ga (K,), gd (M, 3)) -> xf
    (N, Pf), xa (K,), xd (M, 3)."""
    N, Pf, K = Hfa.shape
    Huu, C, B, offsets_first = _arrow(Hff, Hfa, Haa, off, Hdd)
    if offsets_first:
        xu, xd = solve_arrow(Huu, C, B, np.r_[gf.reshape(-1), ga], gd)
        return xu[:N * Pf].reshape(N, Pf), xu[N * Pf:], xd
    xv, xf = solve_arrow(Huu, C, B, np.r_[ga, gd.reshape(-1)], gf)
    return xf, xv[:K], xv[K:].reshape(-1, 3)


def damped_step(Hd, Hfa, gf, Haa, ga, off: OffsetBlocks, mu: float):
    """A Levenberg-Marquardt step of a shared fit with offsets -> df (N, Pf), da (1, K + 3M).

    Damped as :func:`~morphable.fitting.nonlinear.lm_stage` damps a fit without offsets: the
    frames' blocks ``Hd`` (N, Pf, Pf) come damped, the shared coefficients get ``mu`` times
    their diagonal (+1e-9). Hfa (N, Pf, K), gf (N, Pf), Haa (1, K, K), ga (1, K): the frames'
    and identity's blocks."""
    K = Hfa.shape[2]
    M = len(off.Hdd)
    damp = mu * (np.r_[np.diagonal(Haa[0]), np.diagonal(off.Hdd, axis1=1, axis2=2).reshape(-1)]
                 + 1e-9)
    Hdd = off.Hdd + damp[K:].reshape(M, 3)[:, :, None] * np.eye(3)
    xf, xa, xd = _solve_whole(Hd, Hfa, Haa[0] + np.diag(damp[:K]), off, Hdd, gf, ga[0], off.gd)
    return -xf, -np.r_[xa, xd.reshape(-1)][None]


def posterior_variances(Hff, Hfa, Haa, off: OffsetBlocks):
    """The diagonal of the posterior covariance (the inverse of the whole system): frames'
    parameters (N, Pf), shared coefficients (K + 3M,)."""
    N, Pf, K = Hfa.shape
    Huu, C, B, offsets_first = _arrow(Hff, Hfa, Haa[0], off, off.Hdd)
    du, dd = arrow_inverse_diagonal(Huu, C, B)
    if offsets_first:
        return du[:N * Pf].reshape(N, Pf), np.r_[du[N * Pf:], dd.reshape(-1)]
    return dd, du


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
