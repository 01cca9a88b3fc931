"""Synthetic 2D landmarks of a model face, placed the way a detector places them (for tests,
benchmarks and the evaluation of fitting), for any landmark scheme (default iBUG-68).

Fixed landmarks are the projections of their surface points. Outline points (iBUG-68's jaw)
lie on the face's outline at fixed heights: on the jaw line, spaced evenly (in the scheme's
order, top to chin) from the height of the outer eye corners down to the chin and generally
between vertices; where the jaw line faces away from the camera (normals of the actual mesh)
a point marches along its horizontal line of vertices to the first one that faces the
camera — the cheek's silhouette, interpolated at the zero of the normal's z. The fit
(:mod:`morphable.fitting.correspondences`) takes them as points of the outline at any height.
"""
from __future__ import annotations

import weakref

import numpy as np

from .correspondences import (arc_lengths, chain_arc, eye_corner_height, horizontal_lines,
                              interpolate_arc, landmark_bank, march_silhouette)
from .schemes import fit_scheme

__all__ = ["simulate_landmarks", "jaw_arc_positions", "expected_jaw_points", "march_lines"]


def simulate_landmarks(model, camera, identity=None, expression=None, vertices=None,
                       scheme=None, march: bool = True) -> np.ndarray:
    """Detector-like landmarks of a model face seen by ``camera``.

    Parameters
    ----------
    model : MorphableModel
    camera : morphable.camera.Camera
    identity, expression : coefficient vectors (see ``MorphableModel.vertices``)
    vertices : (V, 3) mm, optional; overrides the coefficients
    scheme : LandmarkScheme, optional; None: iBUG-68
    march : bool
        True: outline points facing away march to the cheek's silhouette (where a 2D
        annotator or detector puts them, 300-W); False: they stay on the jaw line, hidden or
        not (projected 3D landmarks, as AFLW2000-3D's ground truth and 3DDFA's output).

    Returns
    -------
    (L, 2) float64 pixels, NaN where the model defines no landmark.

    Examples
    --------
    >>> from morphable import load_model
    >>> from morphable.camera import Camera
    >>> m = load_model("sfm")
    >>> lms = simulate_landmarks(m, Camera.looking_at_face(yaw=30))
    >>> lms.shape, int(np.isnan(lms[:, 0]).sum())     # SFM has no inner mouth corners
    ((68, 2), 2)
    """
    from ..normals import vertex_normals

    verts = model.vertices(identity, expression) if vertices is None else np.asarray(vertices, np.float64)
    scheme = fit_scheme(model, 68) if scheme is None else scheme
    lms = np.full((scheme.n, 2), np.nan)
    fixed = scheme.defined
    lms[fixed] = camera.project(scheme.points(verts)[fixed])
    normals = vertex_normals(verts, model.triangles) @ camera.rotation.T
    bank = landmark_bank(model, scheme)
    eye_y = eye_corner_height(model, scheme)
    view = np.array([[0.0, 0.0, 1.0]])             # normals are already in the camera frame
    for side, chain in bank.polylines:
        chain_ids = bank.vertex_ids[chain]
        P, arc, at = jaw_arc_positions(model, side, chain_ids, verts, eye_y)
        facing = np.interp(at, arc, normals[chain_ids, 2])
        points = interpolate_arc(P, arc, at)
        away = np.flatnonzero(facing < 0) if march else np.zeros(0, dtype=np.int64)
        if away.size:
            lines = _padded_march_lines(model, side, chain_ids, eye_y)[away]     # (J, M)
            i0, i1, w = (x[0] for x in march_silhouette(lines, normals[lines], view))
            points[away] = (1 - w)[:, None] * verts[i0] + w[:, None] * verts[i1]
        lms[side] = camera.project(points)
    return lms


_MEAN_SHAPE = weakref.WeakKeyDictionary()
"""Per model: what depends on its mean shape alone (:func:`expected_jaw_points`, the march
lines), made once: a track's frames share one model."""


def _cached(model, key, make):
    per_model = _MEAN_SHAPE.setdefault(model, {})
    if key not in per_model:
        per_model[key] = make()
    return per_model[key]


def _padded_march_lines(model, lms, chain_ids, eye_y) -> np.ndarray:
    """:func:`march_lines` as one (J, M) array of vertex ids, -1 padded, cached per model."""
    def make():
        lines = march_lines(model, lms, chain_ids, eye_y)
        out = np.full((len(lines), max(len(v) for v in lines)), -1, dtype=np.int64)
        for i, v in enumerate(lines):
            out[i, :len(v)] = v
        return out

    return _cached(model, ("march", tuple(np.ravel(lms).tolist()),
                           tuple(np.ravel(chain_ids).tolist()), eye_y), make)


def jaw_arc_positions(model, lms, chain_ids, vertices, eye_y):
    """A face's jaw line and where its sliding landmarks sit on it: the chain's points (C, 3)
    in ``vertices``, their cumulative arc lengths (C,) and the landmarks' arc positions (J,),
    mm — :func:`expected_jaw_points` rescaled to this face's jaw line."""
    _, at, mean_arc = expected_jaw_points(model, lms, chain_ids, eye_y)
    P = np.asarray(vertices, dtype=np.float64)[chain_ids]
    arc = arc_lengths(P)
    return P, arc, at / mean_arc[-1] * arc[-1]


def expected_jaw_points(model, lms, chain_ids, eye_y):
    """Mean-shape points (J, 3) of the sliding landmarks ``lms`` (top to chin) on their
    chain, their arc positions (J,) and the chain's cumulative arc lengths (C,), mm.

    The first (iBUG jaw point 1 or 17) sits at the height ``eye_y`` of the outer eye corners
    (:func:`~morphable.fitting.correspondences.eye_corner_height`): the landmarks are evenly
    spaced by arc length from where the chain passes that height (its top if lower) down to
    the chin (iBUG 9), which ends the chain."""
    def make():
        P, arc, start = chain_arc(model, chain_ids, eye_y)
        frac = np.arange(len(lms)) / len(lms)
        at = start + frac * (arc[-1] - start)
        return interpolate_arc(P, arc, at), at, arc

    # cached per model (the mean shape's alone); copies, as callers may change them
    return tuple(x.copy() for x in _cached(model, ("jaw", tuple(np.ravel(lms).tolist()),
                                                   tuple(np.ravel(chain_ids).tolist()), eye_y), make))


def march_lines(model, lms, chain_ids, eye_y, height_mm: float = 3.0,
                step_mm: float = 3.0) -> list:
    """Per sliding landmark, its horizontal line of vertices (jaw line inwards) at the height
    where the landmark is expected on the mean shape (:func:`expected_jaw_points`)."""
    pts, _, _ = expected_jaw_points(model, lms, chain_ids, eye_y)
    return horizontal_lines(model, pts, chain_ids, height_mm, step_mm)
