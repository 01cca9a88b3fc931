"""The model rows of a fit's correspondences, and the points and residuals they give.

Only the landmark rows of the model (:class:`~morphable.fitting.correspondences.LandmarkBank`)
are evaluated, never the full mesh. Rows are gathered coordinate-major, (N, 3, L, k) for L
landmarks and ``k`` coefficients, so that projecting them is one matrix product per frame.
The shared coefficients are the identity's, then (with a shared identity and a definition
error) the landmark offsets of :mod:`~morphable.fitting.noise`, which scale with the face's
size. The rows hold the identity's only: an offset moves one landmark along one coordinate,
and its derivatives are used by that structure (:mod:`~morphable.fitting.offsets`).
``pb``, ``st``: a fit's :class:`~morphable.fitting.problem.Problem` and
:class:`~morphable.fitting.problem.State`.
"""
from __future__ import annotations

import weakref
from functools import lru_cache
from typing import NamedTuple

import numpy as np

from .correspondences import Correspondences, across_outline
from .pose import project, projection_jacobian

__all__ = ["basis_rows", "size_direction", "MAX_GRAM_GROUPS", "MIN_GRAM_LANDMARKS", "GRAM_PAIRS",
           "upper_indices", "FixedGram",
           "fixed_gram", "face_size",
           "from_coefficients", "offsets", "shared_rows", "fixed_rows", "gather", "combine", "identity_points",
           "points", "residuals"]

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


MAX_GRAM_GROUPS = 16
"""Most weight groups of :func:`fixed_gram` (each holds 9 K x K blocks): the calibrated
face-mesh sidecars have 15 definition errors (0.5 mm steps)."""

MIN_GRAM_LANDMARKS = 100
"""Fewest fixed landmarks for :func:`fixed_gram`: below, the plain product is as fast (SFM,
per-frame fits: iBUG-68's 51 fixed points ran 0.5-1.4 ms slower with the Gram blocks, the face
mesh's ~450 10-17 % faster)."""


GRAM_PAIRS = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))
"""The coordinate pairs (i, j), i <= j, of :class:`FixedGram`'s packed blocks."""


@lru_cache(maxsize=8)
def upper_indices(k: int):
    """``np.triu_indices(k)`` (read-only, cached): the order in which :class:`FixedGram`
    packs each symmetric k x k block, and ``linear.gram_hessian`` unpacks it."""
    iu, ju = np.triu_indices(k)
    iu.flags.writeable = ju.flags.writeable = False
    return iu, ju


class FixedGram(NamedTuple):
    """Gram blocks of the identity rows of the fixed landmarks (see ``linear.gram_hessian``):
    ``fixed`` (F,) the landmarks, ``group`` (F,) their weight group, ``first`` (g,) the first
    of each group, ``moving`` the sliding columns (a slice or indices), ``G`` (g 6, K (K + 1)
    / 2) the blocks ``G_ij = sum_l A_l[i]^T A_l[j]`` of each group for the :data:`GRAM_PAIRS`,
    ``G_ij + G_ji`` off the diagonal (the weights ``(P^T P)_ij`` are symmetric), each
    symmetric and kept as its upper triangle (row-major, ``np.triu_indices``): a third of the
    nine full blocks, which a fit re-reads from memory at every Hessian; ``rows`` (3 F, K) the
    fixed landmarks' rows, coordinate-major."""
    fixed: np.ndarray
    group: np.ndarray
    first: np.ndarray
    moving: object
    G: np.ndarray
    rows: np.ndarray


def fixed_gram(bank, K, sliding, std):
    """The :class:`FixedGram` of the fixed landmarks outside the ``sliding`` columns (a slice,
    indices or None; ``Problem.sliding``), one block per group of landmarks with the same
    ``std`` (L,) (their definition error: in a frame they have one weight), cached per model,
    scheme, K and groups; landmarks in neither never have a correspondence. None for fewer
    than :data:`MIN_GRAM_LANDMARKS` fixed landmarks or more than :data:`MAX_GRAM_GROUPS`
    groups."""
    if np.count_nonzero(bank.fixed_row >= 0) < MIN_GRAM_LANDMARKS:     # too few in any case
        return None
    cache = _GRAMS.setdefault(bank, {})
    sliding = sliding if sliding is not None else slice(0, 0)
    moving = np.arange(len(bank.fixed_row))[sliding]
    fixed = bank.fixed_row >= 0
    fixed[moving] = False
    fixed = np.flatnonzero(fixed)
    if len(fixed) < MIN_GRAM_LANDMARKS:
        return None
    values, first, group = np.unique(std[fixed], return_index=True, return_inverse=True)
    if len(values) > MAX_GRAM_GROUPS:
        return None
    key = (K, moving.tobytes(), group.tobytes())
    if key not in cache:
        Af = bank.identity[bank.fixed_row[fixed], :, :K]                  # (F, 3, K)
        iu, ju = upper_indices(K)
        G = []
        for g in range(len(values)):
            full = np.einsum("lik,ljm->ijkm", Af[group == g], Af[group == g])
            G += [(full[i, j] if i == j else full[i, j] + full[j, i])[iu, ju]
                  for i, j in GRAM_PAIRS]
        cache[key] = FixedGram(fixed, group, first, sliding, np.stack(G),
                               np.ascontiguousarray(Af.transpose(1, 0, 2)).reshape(-1, K))
    return cache[key]


def face_size(pb, alpha) -> np.ndarray:
    """(G,) the face's size relative to the mean face, to first order in the identity."""
    # floored: an absurd identity must not turn the offsets inside out
    return np.maximum(1.0 + alpha[:, :pb.n_identity] @ pb.size_direction, 0.25)


def from_coefficients(pb, c) -> np.ndarray:
    """The shared coefficients (G, K) from the coefficients as they multiply the points, the
    offsets at the face's size (``face_size`` times the offsets'; see
    :mod:`~morphable.fitting.noise`)."""
    if not pb.D:
        return c
    n = pb.n_identity
    return np.concatenate([c[:, :n], c[:, n:] / face_size(pb, c)[:, None]], 1)


def offsets(pb, alpha) -> np.ndarray:
    """(G, L, 3) mm: the landmark offsets at the mean face's size, ``definition_std_mm`` times
    the offset coefficients (the i-th landmark of ``pb.offset_landmarks`` moves along coordinate
    a by coefficient ``3 i + a``); 0 for landmarks without one."""
    out = np.zeros((len(alpha), pb.y.shape[1], 3))
    out[:, pb.offset_landmarks] = (pb.offset_std[:, None]
                                   * alpha[:, pb.n_identity:].reshape(len(alpha), -1, 3))
    return out


def shared_rows(pb, st) -> np.ndarray:
    """(N, 3, L, K) derivatives of the landmark points by the identity coefficients: the
    identity rows plus the offsets' growth with the face. The offsets' own derivatives are
    ``face_size * offset_std`` along their coordinate, never materialised
    (:mod:`~morphable.fitting.offsets`)."""
    A = st.rows[1]
    if not pb.D:
        return A
    shift = np.broadcast_to(offsets(pb, st.alpha), (pb.N,) + A.shape[2:3] + (3,))
    return A + shift.transpose(0, 2, 1)[..., None] * pb.size_direction


def fixed_rows(pb, n_frames: int):
    """The mean (N, L, 3) and the identity and expression rows (N, 3, L, K|E) at the bank's
    fixed correspondences (:meth:`~morphable.fitting.correspondences.Correspondences.fixed`;
    0 for landmarks without one), where a fit starts: copies of rows gathered once per model,
    scheme and modes (gathering them was a twentieth of a 51-point fit's time). Where nothing
    slides (``pb.sliding`` None) the rows never change: read-only views of the cached rows."""
    cache = _BASIS_ROWS.setdefault(pb.bank, {})
    key = ("fixed", pb.AT.shape[-1], pb.BT.shape[-1])
    if key not in cache:
        c = Correspondences.fixed(pb.bank, 1)
        cache[key] = (c.gather_static(pb.bank.mean), c.gather_coordinates(pb.AT),
                      c.gather_coordinates(pb.BT))
        for x in cache[key]:
            x.flags.writeable = False
    if pb.sliding is None:
        return tuple(x if n_frames == 1 else np.broadcast_to(x, (n_frames,) + x.shape[1:])
                     for x in cache[key])
    return tuple(np.repeat(x, n_frames, 0) for x in cache[key])


def gather(pb, st):
    """Gather the rows of the sliding outline landmarks anew, into ``st.rows`` (those of
    :func:`fixed_rows`; the fixed landmarks' do not change)."""
    if pb.sliding is None:
        return
    c = st.corr
    st.residuals = None
    c.gather_static(pb.bank.mean, pb.sliding, st.rows[0])
    for src, dst in zip((pb.AT, pb.BT), (st.rows[1], st.rows[2])):
        c.gather_coordinates(src, pb.sliding, dst)


def combine(rows, coeffs):
    """Coordinate-major rows (N, 3, L, k) times coefficients (N, k), or (1, k) shared by the
    frames, -> (N, L, 3)."""
    N, _, L, k = rows.shape
    return (rows.reshape(N, 3 * L, k) @ coeffs[..., None]).reshape(N, 3, L).transpose(0, 2, 1)


def identity_points(pb, A, alpha) -> np.ndarray:
    """(n, L, 3) mm: what the shared coefficients ``alpha`` (G, K) add to the points of
    identity rows ``A`` (n, 3, L, K_identity): the identity's part and the offsets."""
    if not pb.D:
        return combine(A, alpha)
    n = pb.n_identity
    X = combine(A, alpha[:, :n])
    return X + face_size(pb, alpha)[:, None, None] * offsets(pb, alpha)


def points(pb, st, sel=slice(None)):
    """(n, L, 3) model points of the correspondences of the frames ``sel``, mm."""
    m, A, B = (r[sel] for r in st.rows)
    X = m
    if pb.K:
        X = X + identity_points(pb, A, st.alpha if pb.shared else st.alpha[sel])
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
        r = uv - pb.y[sel]
        if pb.sliding is not None:
            r = across_outline(r, pb.tangent[sel])
        if every:
            st.residuals = X, uv, Xc, depth, r
    J = projection_jacobian(Xc, st.k[sel], pb.perspective) if jacobian else None
    return X, uv, Xc, J, depth, r
