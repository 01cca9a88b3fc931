"""Closed-form identity and expression solves under a fixed camera (Aldrian & Smith style).

With the camera fixed, a projected model point is linear in the coefficients:
``uv_l ~= q_l + P_l (m_l + A_l alpha + B_l beta)``, with ``P_l`` (2x3) the projection
(exact for the affine camera, the weak-perspective linearisation at the current depth for
the pinhole camera). Minimising ``sum_l w_l |uv_l - y_l|^2 + lambda |coeffs|^2`` is then a small
ridge regression, solved here for many frames at once.
"""
from __future__ import annotations

import numpy as np

from .rows import GRAM_PAIRS, upper_indices

__all__ = ["solve_identity", "solve_expression", "ridge_solve", "normal_blocks", "project_rows",
           "weighted_rows", "gram_hessian"]


def project_rows(P, rows):
    """``P @ rows`` per point in coordinate-major layout: P (N, 2, 3) shared by the points or
    (N, L, 2, 3), rows (N, 3, L, k) -> (N, 2, L, k). The shared case is one GEMM per frame."""
    N, _, L, k = rows.shape
    if P.ndim == 3:
        return (P @ rows.reshape(N, 3, L * k)).reshape(N, 2, L, k)
    out = np.empty((N, 2, L, k))
    for c in range(2):
        out[:, c] = P[:, :, c, 0, None] * rows[:, 0]
        for j in (1, 2):
            out[:, c] += P[:, :, c, j, None] * rows[:, j]
    return out


def ridge_solve(H, g, prior):
    """Solve ``(H + prior I) x = g`` for stacks (G, K, K), (G, K); finite even for prior 0."""
    K = H.shape[-1]
    if K == 0:
        return np.zeros(g.shape)
    tr = np.trace(H, axis1=-2, axis2=-1)[..., None, None]
    # a relative ridge of 1e-10 keeps an unregularised (prior 0) problem solvable
    A = H + (prior + 1e-10 * tr / K + 1e-12) * np.eye(K)
    return np.linalg.solve(A, g[..., None])[..., 0]


def weighted_rows(W, Phi):
    """``diag(sqrt(W)) Phi`` of coordinate-major rows Phi (N, 2, L, k) and weights W (N, L) ->
    Q (N, 2 L, k) (the x rows, then the y rows) and the square roots s (N, 2 L, 1): a normal
    equations' Hessian is ``Q^T Q`` (one symmetric product), its right side ``Q^T (s r)``."""
    N, _, L, k = Phi.shape
    s = np.sqrt(np.concatenate([W, W], 1))[..., None]
    return s * Phi.reshape(N, 2 * L, k), s


def gram_hessian(P, W, Q, gram, shift=None):
    """``Phi^T diag(W) Phi`` per frame, (N, k, k), for ``Phi = P @ rows`` (coordinate-major,
    (N, 2, L, k)) from its :func:`weighted_rows` ``Q`` (as (N, 2, L, k)), using precomputed
    Gram blocks of the landmarks whose rows never change.

    With a projection shared by all points (the affine camera) and one weight ``w_g`` for
    each group g of fixed landmarks of a frame (those of one definition error), their part is
    ``sum_g w_g sum_ij (P^T P)_ij G_gij`` with ``G_gij = sum_{l in g} A_l[i]^T A_l[j]``
    computed once per model: far fewer operations than the plain product. ``gram`` is
    :func:`~morphable.fitting.rows.fixed_gram`'s ``(fixed (F,), group (F,), first (g,),
    moving, G (g 6, k (k + 1) / 2), rows)``, the blocks packed
    (:class:`~morphable.fitting.rows.FixedGram`); frames that do not qualify (per-point
    projections, missing or differently weighted fixed landmarks) fall back to the plain product.
    ``moving`` (indices or a slice) covers every other landmark that can have a weight.
    ``shift``: None, or ``(s (L, 3) mm, d (k,))`` where the rows of ``Phi`` are the Gram's rows
    plus ``s_l d^T`` (a shared fit's landmark offsets growing with the face,
    :func:`~morphable.fitting.rows.shared_rows`): a rank-2 correction.
    """
    N, _, L, k = Q.shape
    if gram is None or P.ndim != 3:
        flat = Q.reshape(N, 2 * L, k)
        return flat.transpose(0, 2, 1) @ flat
    fixed, group, first, moving, G, rows = gram
    wf = W[:, fixed]
    wg = wf[:, first]                                               # (N, g)
    if not ((wg > 0).all() and (wf == wg[:, group]).all()):
        flat = Q.reshape(N, 2 * L, k)
        return flat.transpose(0, 2, 1) @ flat
    M = P.transpose(0, 2, 1) @ P                                    # (N, 3, 3)
    wM = (wg[:, :, None] * M[:, _PAIR_I, _PAIR_J][:, None]).reshape(N, -1)
    upper = wM @ G                                                  # (N, k (k + 1) / 2)
    iu, ju = upper_indices(k)
    H = np.empty((N, k, k))
    H[:, iu, ju] = upper
    H[:, ju, iu] = upper
    if shift is not None:
        # sum_l w_l (A_l + s_l d^T)^T M (A_l + s_l d^T) = Gram + u d^T + d u^T + c d d^T
        s, d = shift[0][fixed], shift[1]
        wMs = wf[..., None] * (s @ M)                               # (N, F, 3)
        u = wMs.transpose(0, 2, 1).reshape(N, -1) @ rows            # (N, k)
        c = (wMs * s).sum((1, 2))
        ud = u[:, :, None] * d
        H = H + ud + ud.transpose(0, 2, 1) + c[:, None, None] * np.outer(d, d)
    Qm = np.ascontiguousarray(Q[:, :, moving]).reshape(N, -1, k)
    return H + Qm.transpose(0, 2, 1) @ Qm


_PAIR_I, _PAIR_J = np.array(GRAM_PAIRS).T


def normal_blocks(P, W, basis, residual, gram=None):
    """Per-frame normal equations of ``P basis x = residual``: (N, k, k), (N, k) (P, W, basis
    and gram as in :func:`solve_identity`, residual (N, L, 2) px)."""
    N, L = W.shape
    Phi = project_rows(P, basis)                                 # (N, 2, L, k): x rows, y rows
    Q, s = weighted_rows(W, Phi)
    g = (Q.transpose(0, 2, 1) @ (s * residual.transpose(0, 2, 1).reshape(N, 2 * L, 1)))[..., 0]
    return gram_hessian(P, W, Q.reshape(Phi.shape), gram), g


def solve_identity(P, target, W, A, prior, shared: bool, gram=None):
    """Identity coefficients from ``P A alpha ~= target``.

    Parameters
    ----------
    P : (N, L, 2, 3) projection of each point, or (N, 2, 3) shared by all points
    target : (N, L, 2) px, the image point minus everything but the identity term
    W : (N, L) weights (1/px^2)
    A : (N, 3, L, K) identity rows (coordinate-major)
    prior : float, weight of ``|alpha|^2``; shared : one identity for all frames
    gram : optional precomputed Gram blocks, see :func:`gram_hessian`

    Returns
    -------
    (1, K) if shared else (N, K) coefficients in std units.
    """
    H, g = normal_blocks(P, W, A, target, gram)
    if shared:
        H, g = H.sum(0, keepdims=True), g.sum(0, keepdims=True)
    return ridge_solve(H, g, prior)


def solve_expression(P, target, W, B, prior, nonnegative: bool):
    """Per-frame expression coefficients from ``P B beta ~= target`` (ridge).

    ``nonnegative`` (blendshapes) clamps negative weights to 0 and re-solves the others, up
    to E passes (a one-way active set: close to NNLS, which the nonlinear stage then refines
    with its projected steps).

    Returns (N, E).
    """
    H, g = normal_blocks(P, W, B, target)
    E = H.shape[-1]
    beta = ridge_solve(H, g, prior)
    if not nonnegative or E == 0:
        return beta
    free = np.ones(beta.shape, bool)
    for _ in range(E):
        neg = free & (beta < 0)
        if not neg.any():
            break
        free &= ~neg
        # drop clamped modes: identity rows/cols and zero right-hand side
        F = free[:, :, None] & free[:, None, :]
        Hf = np.where(F, H, 0.0) + np.where(~free, 1.0, 0.0)[:, :, None] * np.eye(E)
        beta = ridge_solve(Hf, np.where(free, g, 0.0), prior)
        beta = np.where(free, beta, 0.0)
    return np.maximum(beta, 0.0)
