"""The model rows of a fit's correspondences, and the points and residuals they give.

Only the landmark rows of the model (:class:`~morphable.fitting.correspondences.LandmarkBank`)
are evaluated, never the full mesh. Rows are gathered coordinate-major, (N, 3, L, k) for L
landmarks and ``k`` coefficients, so that projecting them is one matrix product per frame.
The shared coefficients are the identity's, then (with a shared identity and a definition
error) the landmark offsets of :mod:`~morphable.fitting.noise`, which scale with the face's
size.
``pb``, ``st``: a fit's :class:`~morphable.fitting.problem.Problem` and
:class:`~morphable.fitting.problem.State`.
"""
from __future__ import annotations

import weakref

import numpy as np

from .correspondences import across_outline
from .pose import project, projection_jacobian

__all__ = ["basis_rows", "size_direction", "fixed_gram", "face_size", "coefficients",
           "from_coefficients", "offset_rows", "shared_rows", "gather", "combine", "points",
           "residuals"]

# per landmark bank (so per model): arrays derived from its rows, built on a model's first fit
_BASIS_ROWS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()
_GRAMS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def basis_rows(bank, K, E):
    """The identity and expression rows of the first K and E modes, (R, 3, K) and (R, 3, E),
    and coordinate-major copies (3, R, K) and (3, R, E), cached per model: copying them is a
    good part of a small fit's time."""
    cache = _BASIS_ROWS.setdefault(bank, {})
    if (K, E) not in cache:
        A = np.ascontiguousarray(bank.identity[:, :, :K])
        B = np.ascontiguousarray(bank.expression[:, :, :E])
        cache[K, E] = (A, B, np.ascontiguousarray(A.transpose(1, 0, 2)),
                       np.ascontiguousarray(B.transpose(1, 0, 2)))
    return cache[K, E]


def size_direction(bank, K) -> np.ndarray:
    """(K,) how much each identity coefficient scales the face: the least-squares scale factor
    of the identity mode's landmark displacements about the mean landmarks' centroid."""
    rows = bank.fixed_row[bank.fixed_row >= 0]
    m = bank.mean[rows] - bank.mean[rows].mean(0)
    A = bank.identity[rows, :, :K] - bank.identity[rows, :, :K].mean(0)
    return np.einsum("li,lik->k", m, A) / (m * m).sum()


def fixed_gram(bank, K, sliding):
    """(fixed landmarks, sliding columns, G (3, 3, K, K)): Gram blocks of the identity rows of
    the fixed landmarks outside the ``sliding`` columns (a slice, indices or None;
    ``Problem.sliding``), cached per model, scheme and K (see ``linear.gram_hessian``);
    landmarks in neither never have a correspondence."""
    cache = _GRAMS.setdefault(bank, {})
    sliding = sliding if sliding is not None else slice(0, 0)
    moving = np.arange(len(bank.fixed_row))[sliding]
    key = (K, moving.tobytes())
    if key not in cache:
        fixed = np.flatnonzero(bank.fixed_row >= 0)
        fixed = fixed[~np.isin(fixed, moving)]
        Af = bank.identity[bank.fixed_row[fixed], :, :K]                  # (F, 3, K)
        G = np.einsum("lik,ljm->ijkm", Af, Af)
        cache[key] = (fixed, sliding, np.ascontiguousarray(G))
    return cache[key]


def face_size(pb, alpha) -> np.ndarray:
    """(G,) the face's size relative to the mean face, to first order in the identity."""
    # floored: an absurd identity must not turn the offsets inside out
    return np.maximum(1.0 + alpha[:, :pb.n_identity] @ pb.size_direction, 0.25)


def coefficients(pb, alpha) -> np.ndarray:
    """The shared coefficients (G, K) as they multiply the rows: the landmark offsets grow
    and shrink with the face (see :mod:`~morphable.fitting.noise`)."""
    if not pb.D:
        return alpha
    n = pb.n_identity
    return np.concatenate([alpha[:, :n], face_size(pb, alpha)[:, None] * alpha[:, n:]], 1)


def from_coefficients(pb, c) -> np.ndarray:
    """The inverse of :func:`coefficients`."""
    if not pb.D:
        return c
    n = pb.n_identity
    return np.concatenate([c[:, :n], c[:, n:] / face_size(pb, c)[:, None]], 1)


def offset_rows(pb):
    """(N, 3, L, D) coordinate-major rows of the landmark offsets: the i-th landmark of
    ``pb.offset_landmarks`` moves along coordinate a by ``definition_std_mm`` per unit of
    coefficient ``3 i + a``."""
    lms = pb.offset_landmarks
    O = np.zeros((3, pb.y.shape[1], pb.D))
    for a in range(3):
        O[a, lms, 3 * np.arange(len(lms)) + a] = pb.definition_std_mm[lms]
    return np.broadcast_to(O, (pb.N,) + O.shape)


def shared_rows(pb, st) -> np.ndarray:
    """(N, 3, L, K) derivatives of the landmark points by the shared coefficients: the identity
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
    out[..., n:] = O * face_size(pb, alpha)[:, None, None, None]
    return out


def gather(pb, st, sliding_only: bool = False):
    """Gather the mean (N, L, 3) and the identity and expression rows (N, 3, L, K|E) of the
    correspondences; after the first time only the sliding outline landmarks are redone."""
    c = st.corr
    if sliding_only and st.rows is not None:
        if pb.sliding is not None:
            st.residuals = None
            c.gather_static(pb.bank.mean, pb.sliding, st.rows[0])
            # the offset columns (after the identity's) never change
            for src, dst in zip((pb.AT, pb.BT), (st.rows[1][..., :pb.n_identity], st.rows[2])):
                c.gather_coordinates(src, pb.sliding, dst)
        return
    # identity and expression rows coordinate-major, (N, 3, L, k): projections are one GEMM
    A = c.gather_coordinates(pb.AT)
    if pb.D:
        A = np.concatenate([A, offset_rows(pb)], -1)
    st.rows = (c.gather_static(pb.bank.mean), A, c.gather_coordinates(pb.BT))
    st.residuals = None


def combine(rows, coeffs):
    """Coordinate-major rows (N, 3, L, k) times coefficients (N, k) -> (N, L, 3)."""
    N, _, L, k = rows.shape
    return (rows.reshape(N, 3 * L, k) @ coeffs[..., None]).reshape(N, 3, L).transpose(0, 2, 1)


def points(pb, st, sel=slice(None)):
    """(n, L, 3) model points of the correspondences of the frames ``sel``, mm."""
    m, A, B = (r[sel] for r in st.rows)
    X = m
    if pb.K:
        alpha = st.alpha if pb.shared else st.alpha[sel]
        X = X + combine(A, np.broadcast_to(coefficients(pb, alpha), (len(m), pb.K)))
    if pb.E:
        X = X + combine(B, st.beta[sel])
    return X


def residuals(pb, st, jacobian: bool, sel=slice(None)):
    """Model points, projections, camera-frame points, d(uv)/d(Xc), depths, residuals (outline
    points: across the outline only) of the frames ``sel``."""
    every = isinstance(sel, slice) and sel == slice(None)
    if every and st.residuals is not None:
        X, uv, Xc, depth, r = st.residuals
    else:
        X = points(pb, st, sel)
        uv, Xc, _, depth = project(X, st.R[sel], st.t[sel], st.k[sel], pb.principal[sel],
                                   pb.perspective, False)
        r = across_outline(uv - pb.y[sel], pb.tangent[sel])
        if every:
            st.residuals = X, uv, Xc, depth, r
    J = projection_jacobian(Xc, st.k[sel], pb.perspective) if jacobian else None
    return X, uv, Xc, J, depth, r
