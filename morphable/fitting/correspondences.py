"""Which model point each landmark of a scheme corresponds to, and the model rows they need.

A fit's landmarks follow a :class:`~morphable.fitting.schemes.LandmarkScheme` (iBUG-68, the
face mesh's 478 points, any other). Its fixed landmarks are points of the model's surface,
barycentric combinations of a triangle's vertices: their mean, identity and expression rows
are combined once per model and scheme, so that a fit evaluates these rows only, never the
mesh (a landmark on a vertex, as iBUG-68's ``model.landmark_ids``, keeps the vertex's row).
Its outline landmarks (iBUG-68's jaw points, the face mesh's oval) lie on the face's visible
*outline*, the way a detector or annotator places them, at heights that vary from annotator
to annotator and from view to view. Each side of the face has a stack of horizontal
*outline lines* of vertices, one every ``OUTLINE_STEP_MM`` along the jaw line from 10 mm
above the height of the outer eye corners down to the chin; a line runs from the jaw line
(the model's ``contour_right``/``contour_left``, SFM; or the chain of the vertices of the
scheme's outline landmarks, top to chin, ICT) inwards to the midline; the scheme's chin
landmark is a fixed point that ends both sides' jaw line. In every frame each line
contributes one outline point: its jaw-line vertex where that faces the camera, else where
the line crosses the cheek's silhouette (interpolated between the two vertices around the
zero of the normal's camera component, as in 3DDFA's landmark marching; the mean shape's
normals, so the full mesh is never evaluated). An outline landmark then corresponds to the
outline point nearest to it in the image, and only its distance *across* the outline
counts: :func:`slide_contours` returns the outline's direction there, and the fit drops the
residual's component along it. This is eos' occluding-contour idea with a continuous
outline, on both sides of the face.

A correspondence is ``X = (1 - w) * X[a] + w * X[b]`` over two rows of a :class:`LandmarkBank`
(``a == b``, ``w == 0`` for fixed points), so sliding between vertices is continuous.
"""
from __future__ import annotations

import weakref
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .schemes import LandmarkScheme, fit_scheme

__all__ = ["LandmarkBank", "landmark_bank", "Correspondences", "slide_contours",
           "march_silhouette", "outline_lines", "outline_points", "chain_arc", "arc_lengths",
           "interpolate_arc", "horizontal_lines", "across_outline", "eye_corner_height",
           "nearest_vertices", "OUTLINE_STEP_MM"]

OUTLINE_STEP_MM = 2.0
"""Height between two outline lines (mean shape), mm."""


@dataclass(eq=False)
class LandmarkBank:
    """The model rows landmark fitting touches, precomputed once per model and scheme.

    Attributes
    ----------
    scheme : LandmarkScheme, the L landmarks
    vertex_ids : (R,) int, the model vertex of each row (of a surface point's row: its
        triangle's vertex of the largest weight)
    mean : (R, 3) float64, mm
    identity : (R, 3, K) float64, mm per unit coefficient
    expression : (R, 3, E) float64
    fixed_row : (L,) int, row of each landmark's fixed point, -1 if none (or if it slides)
    polylines : list of (landmarks (J,), rows (C,)) — the outline landmarks of each side and
        that side's jaw line (top to chin)
    normals : (R, 3) unit normals of the mean shape at the rows
    outlines : list of (L, M) int rows, -1 padded, one per polyline: the side's outline lines
        from the top to the chin, each from the jaw line inwards (the last one is the chin)
    """

    scheme: LandmarkScheme
    vertex_ids: np.ndarray
    mean: np.ndarray
    identity: np.ndarray
    expression: np.ndarray
    fixed_row: np.ndarray
    polylines: list
    normals: np.ndarray
    outlines: list

    # the bank's derived index sets are made once (a fit reads them every time; read-only)
    @cached_property
    def usable(self) -> np.ndarray:
        """(L,) bool: landmarks that have a model correspondence."""
        ok = self.fixed_row >= 0
        for lms, _ in self.polylines:
            ok[lms] = True
        return _read_only(ok)

    @cached_property
    def sliding_landmarks(self) -> np.ndarray:
        """(J,) int: the outline landmarks, which slide along the outline (polyline order)."""
        return _read_only(np.array([int(j) for lms, _ in self.polylines for j in lms],
                                   dtype=np.int64))

    @cached_property
    def sliding_columns(self):
        """The :attr:`sliding_landmarks` as one slice over the jaw where they fill it but for
        the chin (iBUG-68's 0-16, the chin inside it re-gathered unchanged: slices copy much
        faster than index lists into the (N, 3, L, K) rows), else sorted indices; None
        without outline landmarks."""
        sliding = self.sliding_landmarks.tolist()
        if not sliding:
            return None
        lo, hi = min(sliding), max(sliding) + 1
        if set(range(lo, hi)) <= set(sliding) | {self.scheme.chin}:
            return slice(lo, hi)
        return _read_only(np.asarray(sorted(sliding), dtype=np.int64))

    @cached_property
    def fixed_landmarks(self) -> np.ndarray:
        """(M,) int: the landmarks that do not slide (sorted)."""
        fixed = np.ones(self.scheme.n, bool)
        fixed[self.sliding_landmarks] = False
        return _read_only(np.flatnonzero(fixed))

    # the polylines' outlines side by side: one pass over all of them per slide, not one each
    @cached_property
    def outline_rows(self) -> np.ndarray:
        """(T, M) int rows, -1 padded: every polyline's :attr:`outlines` in turn (T lines)."""
        width = max((o.shape[1] for o in self.outlines), default=1)
        return _read_only(np.concatenate(
            [np.pad(o, ((0, 0), (0, width - o.shape[1])), constant_values=-1)
             for o in self.outlines] or [np.zeros((0, width), np.int64)]))

    @cached_property
    def outline_normals(self) -> np.ndarray:
        """(T, M, 3) the mean shape's normals at the :attr:`outline_rows` (padding: any)."""
        return _read_only(self.normals[np.maximum(self.outline_rows, 0)])

    @cached_property
    def outline_segments(self) -> np.ndarray:
        """(J, T - 1) bool: the segments between consecutive :attr:`outline_rows` lines that
        lie on each :attr:`sliding_landmarks` landmark's own polyline."""
        line_of = np.concatenate([np.full(len(o), i) for i, o in enumerate(self.outlines)]
                                 or [np.zeros(0, int)])
        own = np.concatenate([np.full(len(lms), i) for i, (lms, _) in enumerate(self.polylines)]
                             or [np.zeros(0, int)])
        within = line_of[:-1] == line_of[1:]
        return _read_only((own[:, None] == line_of[None, :-1]) & within[None])


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


_BANKS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def nearest_vertices(scheme: LandmarkScheme) -> np.ndarray:
    """(L,) the model vertex of each landmark's largest barycentric weight, -1 where none."""
    v = scheme.vertices[np.arange(scheme.n), np.argmax(scheme.barycentric, 1)]
    return np.where(scheme.defined, v, -1)


def eye_corner_height(model, scheme: LandmarkScheme):
    """The mean shape's height (y, mm) of the scheme's outer eye corners (its points of
    iBUG 37 and 46), None where it lacks either."""
    corners = scheme.ibug68[[36, 45]]
    if (corners < 0).any():
        return None
    y = scheme.points(model.mean)[corners, 1]
    return float(y.mean()) if np.isfinite(y).all() else None


def _polylines(model, scheme: LandmarkScheme, slide: bool) -> list:
    if not slide:
        return []
    ids = nearest_vertices(scheme)
    chin = scheme.chin
    out = []
    for lms, contour in ((scheme.outline_right, model.contour_right),
                         (scheme.outline_left, model.contour_left)):
        lms = np.asarray(lms, dtype=np.int64)
        lms = lms[lms != chin]
        if lms.size == 0:
            continue
        chain = np.asarray(contour, dtype=np.int64)
        if chain.size == 0:
            # no contour candidates: slide along the model's own outline points (ICT)
            side = np.append(lms, chin) if chin >= 0 else lms
            if (ids[side] < 0).any():
                continue
            chain = ids[side]
        elif chin >= 0 and ids[chin] >= 0:
            chain = np.append(chain, ids[chin])
        if chain.size >= 2:
            out.append((lms, chain))
    return out


def chain_arc(model, chain_ids, eye_y):
    """Mean-shape chain points (C, 3), their cumulative arc lengths (C,) and the arc position
    where the chain passes the height ``eye_y`` of the outer eye corners (0 if it starts
    lower, or for ``eye_y`` None; :func:`eye_corner_height`), mm."""
    mean = np.asarray(model.mean, dtype=np.float64)
    P = mean[chain_ids]
    arc = arc_lengths(P)
    start = 0.0
    if eye_y is not None:
        above = np.flatnonzero(P[:, 1] >= eye_y)
        if above.size and above[-1] + 1 < len(P):
            i = above[-1]
            f = (P[i, 1] - eye_y) / max(P[i, 1] - P[i + 1, 1], 1e-9)
            start = arc[i] + f * (arc[i + 1] - arc[i])
    return P, arc, start


def arc_lengths(P):
    """(C,) cumulative arc lengths of a polyline ``P`` (C, 3), from 0, mm."""
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))])


def interpolate_arc(P, arc, at):
    """Points (J, 3) at arc positions ``at`` (J,) of a polyline ``P`` (C, 3) whose cumulative
    arc lengths are ``arc`` (C,), mm."""
    return np.stack([np.interp(at, arc, P[:, k]) for k in range(3)], -1)


def horizontal_lines(model, points, chain_ids, height_mm: float = 3.0,
                     step_mm: float = 3.0) -> list:
    """Per point of the jaw line, the vertex ids of a horizontal line at its height on the
    mean shape, from the jaw line inwards to the midline: the chain vertex nearest to the
    point, then one vertex per ``step_mm`` of x nearer the midline (the closest in height,
    the front-most on ties)."""
    mean = np.asarray(model.mean, dtype=np.float64)
    ids = np.asarray(model.segments.get("face", np.arange(len(mean))), dtype=np.int64)
    q = mean[ids]
    out = []
    for p in points:
        side = np.sign(p[0]) or 1.0
        start = chain_ids[np.argmin(np.linalg.norm(mean[chain_ids] - p, axis=1))]
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


def outline_lines(model, chain_ids, eye_y, step_mm: float = OUTLINE_STEP_MM) -> np.ndarray:
    """(L, M) vertex ids, -1 padded: horizontal lines every ``step_mm`` of arc along the jaw
    line, from 10 mm above the outer eye corners' height ``eye_y`` (:func:`chain_arc`) down
    to the chin (the last line is the chin vertex alone)."""
    P, arc, start = chain_arc(model, chain_ids, eye_y)
    at = np.arange(max(start - 10.0, 0.0), arc[-1] - 0.5 * step_mm, step_mm)
    lines = horizontal_lines(model, interpolate_arc(P, arc, at), chain_ids) + [chain_ids[-1:]]
    out = np.full((len(lines), max(len(v) for v in lines)), -1, dtype=np.int64)
    for i, v in enumerate(lines):
        out[i, :len(v)] = v
    return out


def landmark_bank(model, scheme: LandmarkScheme | None = None, slide: bool = True) -> LandmarkBank:
    """The (cached) :class:`LandmarkBank` of ``model`` for ``scheme`` (None: iBUG-68);
    ``slide=False`` uses fixed points only."""
    scheme = fit_scheme(model, 68) if scheme is None else scheme
    per_scheme = _BANKS.setdefault(model, weakref.WeakKeyDictionary()).setdefault(scheme, {})
    if slide in per_scheme:
        return per_scheme[slide]
    L = scheme.n
    lines = _polylines(model, scheme, slide)
    sliding = np.zeros(L, bool)
    for lms, _ in lines:
        sliding[lms] = True
    # a point on one vertex keeps the vertex's row; others get a row of their own
    one_vertex = scheme.defined & ((scheme.barycentric == 1.0).any(1)
                                   | (scheme.vertices == scheme.vertices[:, :1]).all(1))
    fixed = np.where(sliding | ~one_vertex, -1, nearest_vertices(scheme))
    surface = np.flatnonzero(scheme.defined & ~one_vertex & ~sliding)
    chains = [c for _, c in lines]
    eye_y = eye_corner_height(model, scheme)
    outline_ids = [outline_lines(model, c, eye_y) for _, c in lines]
    rows = np.unique(np.concatenate([fixed[fixed >= 0], *chains, *[o[o >= 0] for o in outline_ids]]))
    lookup = np.full(model.n_vertices, -1, dtype=np.int64)
    lookup[rows] = np.arange(len(rows))
    fixed_row = np.where(fixed >= 0, lookup[np.maximum(fixed, 0)], -1)
    fixed_row[surface] = len(rows) + np.arange(len(surface))
    polylines = [(lms, lookup[c]) for lms, c in lines]
    outlines = [np.where(o >= 0, lookup[np.maximum(o, 0)], -1) for o in outline_ids]
    from ..normals import vertex_normals

    tri, bary = scheme.vertices[surface], scheme.barycentric[surface]       # (S, 3)

    def with_surface(data):
        """Per-vertex data (V, ...) -> rows (R, ...) float64: the vertices', then the surface
        points' barycentric combinations."""
        point = np.einsum("sj...,sj->s...", data[tri].astype(np.float64), bary)
        return np.concatenate([data[rows].astype(np.float64), point])

    normals = with_surface(vertex_normals(model.mean.astype(np.float64), model.triangles))
    n = normals[len(rows):]
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    bank = LandmarkBank(
        scheme=scheme,
        vertex_ids=np.concatenate([rows, nearest_vertices(scheme)[surface]]),
        mean=with_surface(np.asarray(model.mean)),
        identity=np.ascontiguousarray(
            with_surface(np.asarray(model.identity_basis).transpose(1, 2, 0))),
        expression=np.ascontiguousarray(
            with_surface(np.asarray(model.expression_basis).transpose(1, 2, 0))),
        fixed_row=fixed_row,
        polylines=polylines,
        normals=normals,
        outlines=outlines,
    )
    per_scheme[slide] = bank
    return bank


@dataclass
class Correspondences:
    """Per-frame landmark -> model point: ``(1 - w) * row a + w * row b``; ``a`` -1 = none.

    a, b : (N, L) int rows of the bank; w : (N, L) float in [0, 1].
    """

    a: np.ndarray
    b: np.ndarray
    w: np.ndarray

    @classmethod
    def fixed(cls, bank: LandmarkBank, n_frames: int) -> "Correspondences":
        """Each landmark at its fixed point (``bank.fixed_row``) in each of ``n_frames`` frames."""
        a = np.broadcast_to(bank.fixed_row, (n_frames, len(bank.fixed_row))).copy()
        return cls(a, a.copy(), np.zeros(a.shape))

    @property
    def defined(self) -> np.ndarray:
        return self.a >= 0

    def gather(self, rows: np.ndarray) -> np.ndarray:
        """Interpolate per-frame row data ``(N or 1, R, ...)`` -> ``(N, L, ...)`` (0 where undefined)."""
        N = self.a.shape[0]
        rows = np.broadcast_to(rows, (N,) + rows.shape[1:])
        a, b = np.maximum(self.a, 0), np.maximum(self.b, 0)
        idx = np.arange(N)[:, None]
        w = self.w.reshape(self.w.shape + (1,) * (rows.ndim - 2))
        out = (1 - w) * rows[idx, a] + w * rows[idx, b]
        return np.where(self.defined.reshape(w.shape), out, 0.0)

    def gather_static(self, rows: np.ndarray, cols=None, out=None) -> np.ndarray:
        """Interpolate frame-independent row data ``(R, ...)`` -> ``(N, L, ...)``, 0 where
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
        """Like :meth:`gather_static` for coordinate-major rows ``(3, R, k)`` -> ``(N, 3, L, k)``
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
        """(N, L) the nearest model vertex of each correspondence, -1 where none."""
        r = np.where(self.w < 0.5, self.a, self.b)
        return np.where(self.defined, bank.vertex_ids[np.maximum(r, 0)], -1)


def march_silhouette(lines, normals, view):
    """Where marching lines cross the silhouette: between the last vertex facing away and the
    first facing the camera, at the zero of the interpolated normal's view component.

    Parameters
    ----------
    lines : (J, M) int, -1 padded (any ids: rows or vertex ids)
    normals : (J, M, 3) unit normals of the line vertices
    view : (N, 3) the third row of each rotation (camera z in model coordinates), or (N, J, 3)
        one direction towards the camera per line (a pinhole camera)

    Returns
    -------
    a, b : (N, J) ids from ``lines``; w : (N, J) in [0, 1], the point ``(1 - w) a + w b``
    """
    J, M = lines.shape
    view = np.asarray(view, dtype=np.float64)
    if view.ndim == 2:
        nz = (normals.reshape(J * M, 3) @ view.T).T.reshape(-1, J, M)    # (N, J, M)
    else:
        nz = np.einsum("jmk,njk->njm", normals, view)
    valid = (lines >= 0)[None]
    front = (nz >= 0) & valid
    last = valid.sum(-1) - 1                                       # (1, J)
    k = np.where(front.any(-1), np.argmax(front, -1), last)        # first facing vertex
    km = np.maximum(k - 1, 0)
    n_idx, j_idx = np.arange(nz.shape[0])[:, None], np.arange(J)
    z1, z0 = nz[n_idx, j_idx, k], nz[n_idx, j_idx, km]
    w = np.where(k > 0, np.minimum(np.maximum(-z0 / np.maximum(z1 - z0, 1e-12), 0.0), 1.0), 0.0)
    return lines[j_idx, km], lines[j_idx, k], w


def outline_points(bank: LandmarkBank, view) -> tuple:
    """The outline point of every outline line of every polyline in each frame
    (:func:`march_silhouette` of ``bank.outline_rows``): ``(a, b, w)`` arrays (N, T) of bank
    rows, polyline by polyline. ``view``: (N, 3) camera z axes in model coordinates, or
    (N, T, 3) directions from each line towards a pinhole camera."""
    return march_silhouette(bank.outline_rows, bank.outline_normals, view)


def across_outline(residuals, tangents):
    """Residuals (..., 2) without their component along the outline: ``tangents`` (..., 2) are
    unit for outline points (from :func:`slide_contours`) and 0 for the others."""
    return residuals - tangents * (residuals * tangents).sum(-1, keepdims=True)


def slide_contours(bank: LandmarkBank, corr: Correspondences, outline, projected, landmarks,
                   mask):
    """Re-pick the outline correspondences in place: each outline landmark takes the nearest point
    of its side's projected outline, and its target moves along the outline to that point.

    Parameters
    ----------
    outline : ``(a, b, w)`` (N, T) from :func:`outline_points`, T outline lines
    projected : (N, T, 2) pixels, those outline points projected with the fit
    landmarks : (N, L, 2) pixels
    mask : (N, L) bool, given landmarks (others keep no correspondence)

    Returns
    -------
    targets : (N, L, 2) ``landmarks`` with each given outline point moved along the outline to
        its outline point, the nearer end of the nearest outline segment of its polyline (a
        correspondence interpolates two rows; the lines are ``OUTLINE_STEP_MM`` apart)
    tangents : (N, L, 2) unit directions of those segments at the given outline points, 0
        elsewhere: a fit counts only the residual across them
    """
    a, b, w = outline
    lms = bank.sliding_landmarks
    targets = np.array(landmarks, dtype=np.float64, copy=True)
    tangents = np.zeros_like(targets)
    # x and y apart: (N, J, S) arrays whose inner loops run over the S segments, not over 2
    ux, uy = projected[..., 0], projected[..., 1]                   # (N, T)
    dx, dy = ux[:, 1:] - ux[:, :-1], uy[:, 1:] - uy[:, :-1]         # (N, S), S = T - 1
    yx, yy = landmarks[:, lms, 0, None], landmarks[:, lms, 1, None]  # (N, J, 1)
    rx, ry = yx - ux[:, None, :-1], yy - uy[:, None, :-1]           # (N, J, S)
    dd = np.maximum(dx * dx + dy * dy, 1e-12)[:, None]
    t = np.minimum(np.maximum((rx * dx[:, None] + ry * dy[:, None]) / dd, 0.0), 1.0)
    ex, ey = rx - t * dx[:, None], ry - t * dy[:, None]
    dist = np.where(bank.outline_segments, ex * ex + ey * ey, np.inf)
    seg = np.argmin(dist, axis=-1)                                  # (N, J)
    n_idx, j_idx = np.arange(len(seg))[:, None], np.arange(len(lms))
    e = seg + (t[n_idx, j_idx, seg] > 0.5)
    given = mask[:, lms]
    corr.a[:, lms] = np.where(given, a[n_idx, e], -1)
    corr.b[:, lms] = np.where(given, b[n_idx, e], -1)
    corr.w[:, lms] = np.where(given, w[n_idx, e], 0.0)
    tau = np.stack([dx[n_idx, seg], dy[n_idx, seg]], -1)           # (N, J, 2)
    tau /= np.maximum(np.sqrt((tau * tau).sum(-1, keepdims=True)), 1e-12)
    y = landmarks[:, lms]
    along = ((projected[n_idx, e] - y) * tau).sum(-1, keepdims=True) * tau
    targets[:, lms] = np.where(given[..., None], y + along, y)
    tangents[:, lms] = np.where(given[..., None], tau, 0.0)
    return targets, tangents
