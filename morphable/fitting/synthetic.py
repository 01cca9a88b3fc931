"""Synthetic 2D landmarks of a model face, placed the way a 68-point detector places them
(for tests, benchmarks and the evaluation of fitting).

Fixed landmarks are the projections of their vertices. Jaw points lie on the face's outline
at fixed heights: on the jaw line, spaced evenly from the height of the outer eye corners
down to the chin and generally between vertices; where the jaw line faces away from the
camera (normals of the actual mesh) a point marches along its horizontal line of vertices to
the first one that faces the camera — the cheek's silhouette, interpolated at the zero of
the normal's z. The fit (:mod:`morphable.fitting.correspondences`) takes them as points of
the outline at any height.
"""
from __future__ import annotations

import numpy as np

from .correspondences import (interpolate_arc, jaw_arc_positions, landmark_bank, march_lines,
                              march_silhouette)

__all__ = ["simulate_landmarks"]


def simulate_landmarks(model, camera, identity=None, expression=None, vertices=None) -> np.ndarray:
    """Detector-like iBUG-68 landmarks of a model face seen by ``camera``.

    Parameters
    ----------
    model : MorphableModel
    camera : morphable.camera.Camera
    identity, expression : coefficient vectors (see ``MorphableModel.vertices``)
    vertices : (V, 3) mm, optional; overrides the coefficients

    Returns
    -------
    (68, 2) float64 pixels, NaN where the model defines no landmark.

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
    lms = np.full((68, 2), np.nan)
    fixed = model.landmark_ids >= 0
    lms[fixed] = camera.project(verts[model.landmark_ids[fixed]])
    normals = vertex_normals(verts, model.triangles) @ camera.rotation.T
    bank = landmark_bank(model)
    for side, chain in bank.polylines:
        chain_ids = bank.vertex_ids[chain]
        P, arc, at = jaw_arc_positions(model, side, chain_ids, verts)
        facing = np.interp(at, arc, normals[chain_ids, 2])
        view = np.array([[0.0, 0.0, 1.0]])         # normals are already in the camera frame
        for j, p, nz, line in zip(side, interpolate_arc(P, arc, at), facing,
                                  march_lines(model, side, chain_ids)):
            if nz < 0:
                i0, i1, w = (x[0, 0] for x in march_silhouette(line[None], normals[line][None], view))
                p = (1 - w) * verts[i0] + w * verts[i1]
            lms[j] = camera.project(p[None])[0]
    return lms
