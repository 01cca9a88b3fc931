"""Which model point each iBUG-68 landmark corresponds to, and the model rows they need.

Inner landmarks map to fixed vertices (``model.landmark_ids``). Jaw landmarks slide: each
one corresponds to the point of a jaw *polyline* (a chain of candidate vertices from the top
of the face to the chin) whose projection is closest to the 2D point, re-picked at every
iteration as eos does. The polylines are the model's ``contour_right``/``contour_left``
(SFM) with the chin vertex appended; a model without contours but with fixed jaw vertices
(ICT) uses the chain of its jaw landmark vertices, so the jaw points can slide along the jaw
line between them.

Where the jaw line is self-occluded (its normal at the landmark's expected place turns away
from the camera) a detector puts the jaw point on the face's visible outline instead. The
correspondence then *marches* (as in 3DDFA's landmark marching) along a horizontal line of
vertices at the landmark's height, from the jaw line towards the face's midline, to where the
surface starts facing the camera (interpolated between the two vertices around the zero of
the normal's z): the silhouette of the cheek at that height. The test uses the
mean shape's normals rotated by the current pose, so it never evaluates the full mesh.

A correspondence is ``X = (1 - w) * X[a] + w * X[b]`` over two rows of a :class:`LandmarkBank`
(``a == b``, ``w == 0`` for fixed points), so sliding between vertices is continuous.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

__all__ = ["LandmarkBank", "landmark_bank", "Correspondences", "slide_contours", "march_lines",
           "march_silhouette", "expected_jaw_points"]

_RIGHT_JAW = np.arange(0, 8)
_LEFT_JAW = np.arange(9, 17)
_CHIN = 8


@dataclass(eq=False)
class LandmarkBank:
    """The model rows landmark fitting touches, precomputed once per model.

    Attributes
    ----------
    vertex_ids : (R,) int, the model vertices of the rows
    mean : (R, 3) float64, mm
    identity : (R, 3, K) float64, mm per unit coefficient
    expression : (R, 3, E) float64
    fixed_row : (68,) int, row of each landmark's fixed vertex, -1 if none (or if it slides)
    polylines : list of (landmarks (J,), rows (C,)) — the jaw landmarks that slide on a chain
    normals : (R, 3) unit normals of the mean shape at the rows
    marches : list of (J, M) int rows, -1 padded: per sliding landmark, its horizontal line
        of vertices from the jaw line inwards (one per polyline)
    jaw_normals : list of (J, 3) mean-shape normals where each sliding landmark is expected
        on its chain (evenly spaced from the top to the chin), for the self-occlusion test
    """

    vertex_ids: np.ndarray
    mean: np.ndarray
    identity: np.ndarray
    expression: np.ndarray
    fixed_row: np.ndarray
    polylines: list
    normals: np.ndarray
    marches: list
    jaw_normals: list

    @property
    def usable(self) -> np.ndarray:
        """(68,) bool: landmarks that have a model correspondence."""
        ok = self.fixed_row >= 0
        for lms, _ in self.polylines:
            ok[lms] = True
        return ok


_BANKS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _polylines(model, slide: bool) -> list:
    ids = np.asarray(model.landmark_ids)
    if not slide:
        return []
    out = []
    for lms, contour in ((_RIGHT_JAW, model.contour_right), (_LEFT_JAW, model.contour_left)):
        chain = np.asarray(contour, dtype=np.int64)
        if chain.size == 0:
            # no contour candidates: slide along the model's own jaw vertices (ICT)
            side = np.append(lms, _CHIN) if lms[0] == 0 else np.append(lms[::-1], _CHIN)
            if (ids[side] < 0).any():
                continue
            chain = ids[side]
        elif ids[_CHIN] >= 0:
            chain = np.append(chain, ids[_CHIN])
        if chain.size >= 2:
            out.append((lms, chain))
    return out


def expected_jaw_points(model, lms, chain_ids):
    """Mean-shape points (J, 3) of the sliding landmarks on their chain, their arc positions
    (J,) and the chain's cumulative arc lengths (C,), mm.

    iBUG jaw point 1 (17) sits at the height of the outer eye corner: the landmarks are
    evenly spaced by arc length from where the chain passes that height (its top if lower)
    down to the chin (8)."""
    mean = np.asarray(model.mean, dtype=np.float64)
    P = mean[chain_ids]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])
    start = 0.0
    corners = np.asarray(model.landmark_ids)[[36, 45]]
    if (corners >= 0).all():
        eye_y = mean[corners, 1].mean()
        above = np.flatnonzero(P[:, 1] >= eye_y)
        if above.size and above[-1] + 1 < len(P):
            i = above[-1]
            f = (P[i, 1] - eye_y) / max(P[i, 1] - P[i + 1, 1], 1e-9)
            start = arc[i] + f * (arc[i + 1] - arc[i])
    frac = (lms if lms[0] < 8 else 16 - lms) / 8.0
    at = start + frac * (arc[-1] - start)
    return np.stack([np.interp(at, arc, P[:, k]) for k in range(3)], -1), at, arc


def march_lines(model, lms, chain_ids, height_mm: float = 3.0, step_mm: float = 3.0) -> list:
    """Per sliding landmark, the vertex ids of a horizontal line at its height on the mean
    shape, ordered from the jaw line inwards to the midline: the chain vertex nearest to the
    landmark's expected place, then one vertex per ``step_mm`` of x nearer the midline (the
    closest in height, the front-most on ties)."""
    mean = np.asarray(model.mean, dtype=np.float64)
    ids = np.asarray(model.segments.get("face", np.arange(len(mean))), dtype=np.int64)
    pts, _, _ = expected_jaw_points(model, lms, chain_ids)
    out = []
    for p in pts:
        side = np.sign(p[0]) or 1.0
        start = chain_ids[np.argmin(np.linalg.norm(mean[chain_ids] - p, axis=1))]
        q = mean[ids]
        # starting at the jaw line keeps the march continuous where the jaw turns away
        sel = (np.abs(q[:, 1] - p[1]) < height_mm) & (side * q[:, 0] >= 0) & (
            side * q[:, 0] <= side * mean[start, 0] - 0.5 * step_mm)
        cand, qc = ids[sel], q[sel]
        bins = np.floor(side * qc[:, 0] / step_mm).astype(np.int64)
        line = [start]
        for b in sorted(set(bins.tolist()), reverse=True):
            k = np.flatnonzero(bins == b)
            k = k[np.lexsort((-qc[k, 2], np.abs(qc[k, 1] - p[1])))][0]
            line.append(cand[k])
        out.append(np.asarray(line, dtype=np.int64))
    return out


def landmark_bank(model, slide: bool = True) -> LandmarkBank:
    """The (cached) :class:`LandmarkBank` of ``model``; ``slide=False`` uses fixed jaw vertices only."""
    per_model = _BANKS.setdefault(model, {})
    if slide in per_model:
        return per_model[slide]
    ids = np.asarray(model.landmark_ids, dtype=np.int64)
    lines = _polylines(model, slide)
    sliding = np.zeros(68, bool)
    for lms, _ in lines:
        sliding[lms] = True
    fixed = np.where(sliding, -1, ids)
    chains = [c for _, c in lines]
    march_ids = [march_lines(model, lms, c) for lms, c in lines]
    rows = np.unique(np.concatenate([fixed[fixed >= 0], *chains, *[v for m in march_ids for v in m]]))
    lookup = dict(zip(rows.tolist(), range(len(rows))))
    fixed_row = np.array([lookup.get(int(v), -1) if v >= 0 else -1 for v in fixed], dtype=np.int64)
    polylines = [(lms, np.array([lookup[int(v)] for v in c], dtype=np.int64)) for lms, c in lines]
    marches = []
    for m in march_ids:
        M = max(len(v) for v in m)
        arr = np.full((len(m), M), -1, dtype=np.int64)
        for i, v in enumerate(m):
            arr[i, :len(v)] = [lookup[int(x)] for x in v]
        marches.append(arr)
    from ..normals import vertex_normals

    normals = vertex_normals(model.mean.astype(np.float64), model.triangles)[rows]
    jaw_normals = []
    for lms, c in polylines:
        _, at, arc = expected_jaw_points(model, lms, rows[c])
        nj = np.stack([np.interp(at, arc, normals[c][:, k]) for k in range(3)], -1)
        jaw_normals.append(nj / np.maximum(np.linalg.norm(nj, axis=1, keepdims=True), 1e-12))
    bank = LandmarkBank(
        vertex_ids=rows,
        mean=model.mean[rows].astype(np.float64),
        identity=np.ascontiguousarray(model.identity_basis[:, rows].astype(np.float64).transpose(1, 2, 0)),
        expression=np.ascontiguousarray(
            model.expression_basis[:, rows].astype(np.float64).transpose(1, 2, 0)),
        fixed_row=fixed_row,
        polylines=polylines,
        normals=normals,
        marches=marches,
        jaw_normals=jaw_normals,
    )
    per_model[slide] = bank
    return bank


@dataclass
class Correspondences:
    """Per-frame landmark -> model point: ``(1 - w) * row a + w * row b``; ``a`` -1 = none.

    a, b : (N, 68) int rows of the bank; w : (N, 68) float in [0, 1].
    """

    a: np.ndarray
    b: np.ndarray
    w: np.ndarray

    @classmethod
    def fixed(cls, bank: LandmarkBank, n_frames: int) -> "Correspondences":
        a = np.broadcast_to(bank.fixed_row, (n_frames, 68)).copy()
        return cls(a, a.copy(), np.zeros((n_frames, 68)))

    @property
    def defined(self) -> np.ndarray:
        return self.a >= 0

    def gather(self, rows: np.ndarray) -> np.ndarray:
        """Interpolate per-frame row data ``(N or 1, R, ...)`` -> ``(N, 68, ...)`` (0 where undefined)."""
        N = self.a.shape[0]
        rows = np.broadcast_to(rows, (N,) + rows.shape[1:])
        a, b = np.maximum(self.a, 0), np.maximum(self.b, 0)
        idx = np.arange(N)[:, None]
        w = self.w.reshape(self.w.shape + (1,) * (rows.ndim - 2))
        out = (1 - w) * rows[idx, a] + w * rows[idx, b]
        return np.where(self.defined.reshape(w.shape), out, 0.0)

    def gather_static(self, rows: np.ndarray, cols=None, out=None) -> np.ndarray:
        """Interpolate frame-independent row data ``(R, ...)`` -> ``(N, 68, ...)``, 0 where
        undefined; with ``cols`` only those landmarks are (re)computed into ``out``."""
        a, b, w = self.a, self.b, self.w
        if cols is not None:
            a, b, w = a[:, cols], b[:, cols], w[:, cols]
        ok = a >= 0
        a0 = np.maximum(a, 0)
        res = rows[a0]
        moving = w != 0
        if moving.any():
            # interpolate only the (few) correspondences between two vertices
            n, j = np.nonzero(moving)
            wm = w[n, j].reshape((-1,) + (1,) * (rows.ndim - 1))
            res[n, j] = (1 - wm) * res[n, j] + wm * rows[b[n, j]]
        if not ok.all():
            res[~ok] = 0.0
        if cols is None:
            return res
        out[:, cols] = res
        return out

    def gather_coordinates(self, rows: np.ndarray, cols=None, out=None) -> np.ndarray:
        """Like :meth:`gather_static` for coordinate-major rows ``(3, R, k)`` -> ``(N, 3, 68, k)``
        (all three coordinates in one pass); with ``cols`` only those landmarks, into ``out``."""
        a, b, w = self.a, self.b, self.w
        if cols is not None:
            a, b, w = a[:, cols], b[:, cols], w[:, cols]
        res = rows[:, np.maximum(a, 0)]                      # (3, N, J, k)
        moving = w != 0
        if moving.any():
            n, j = np.nonzero(moving)
            wm = w[n, j][None, :, None]
            res[:, n, j] = (1 - wm) * res[:, n, j] + wm * rows[:, b[n, j]]
        bad = a < 0
        if bad.any():
            res[:, bad] = 0.0
        res = res.transpose(1, 0, 2, 3)
        if cols is None:
            return np.ascontiguousarray(res)
        out[:, :, cols] = res
        return out

    def vertex_ids(self, bank: LandmarkBank) -> np.ndarray:
        """(N, 68) the nearest model vertex of each correspondence, -1 where none."""
        r = np.where(self.w < 0.5, self.a, self.b)
        return np.where(self.defined, bank.vertex_ids[np.maximum(r, 0)], -1)


def march_silhouette(lines, normals, view):
    """Where marching lines cross the silhouette: between the last vertex facing away and the
    first facing the camera, at the zero of the interpolated normal's z.

    Parameters
    ----------
    lines : (J, M) int, -1 padded (any ids: rows or vertex ids)
    normals : (J, M, 3) unit normals of the line vertices
    view : (N, 3) the third row of each rotation (camera z in model coordinates)

    Returns
    -------
    a, b : (N, J) ids from ``lines``; w : (N, J) in [0, 1], the point ``(1 - w) a + w b``
    """
    J, M = lines.shape
    nz = (normals.reshape(J * M, 3) @ view.T).T.reshape(-1, J, M)    # (N, J, M)
    valid = (lines >= 0)[None]
    front = (nz >= 0) & valid
    last = valid.sum(-1) - 1                                       # (1, J)
    k = np.where(front.any(-1), np.argmax(front, -1), last)        # first facing vertex
    km = np.maximum(k - 1, 0)
    n_idx, j_idx = np.ogrid[:nz.shape[0], :J]
    z1, z0 = nz[n_idx, j_idx, k], nz[n_idx, j_idx, km]
    w = np.where(k > 0, np.clip(-z0 / np.maximum(z1 - z0, 1e-12), 0.0, 1.0), 0.0)
    return lines[j_idx, km], lines[j_idx, k], w


def slide_contours(bank: LandmarkBank, corr: Correspondences, projected_chains, landmarks, mask,
                   rotation=None) -> None:
    """Re-pick the sliding jaw correspondences in place.

    Parameters
    ----------
    projected_chains : list of (N, C, 2) pixels, each polyline's rows projected with the current fit
    landmarks : (N, 68, 2) pixels
    mask : (N, 68) bool, given landmarks (others keep no correspondence)
    rotation : (N, 3, 3) or None
        Current rotations; with them, jaw points whose jaw line faces away from the camera
        march to the silhouette (see the module docstring).
    """
    for (lms, chain), p, jn, march in zip(bank.polylines, projected_chains, bank.jaw_normals,
                                          bank.marches):
        p0, d = p[:, :-1], p[:, 1:] - p[:, :-1]       # (N, S, 2)
        y = landmarks[:, lms]                         # (N, J, 2)
        rel = y[:, :, None, :] - p0[:, None]          # (N, J, S, 2)
        dd = np.einsum("nsk,nsk->ns", d, d)[:, None]
        t = np.clip(np.einsum("njsk,nsk->njs", rel, d) / np.maximum(dd, 1e-12), 0.0, 1.0)
        err = rel - t[..., None] * d[:, None]
        seg = np.argmin(np.einsum("njsk,njsk->njs", err, err), axis=-1)   # (N, J)
        n_idx, j_idx = np.ogrid[:len(seg), :len(lms)]
        tt = t[n_idx, j_idx, seg]
        given = mask[:, lms]
        a = np.where(given, chain[seg], -1)
        b = np.where(given, chain[seg + 1], -1)
        w = np.where(given, tt, 0.0)
        if rotation is not None and march.size:
            hidden = given & ((rotation[:, 2] @ jn.T) < 0)                # (N, J)
            if hidden.any():
                pa, pb_, pw = march_silhouette(march, bank.normals[np.maximum(march, 0)],
                                               rotation[:, 2])
                a = np.where(hidden, pa, a)
                b = np.where(hidden, pb_, b)
                w = np.where(hidden, pw, w)
        corr.a[:, lms], corr.b[:, lms], corr.w[:, lms] = a, b, w
