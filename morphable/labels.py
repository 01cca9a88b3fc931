"""Labels of a fitted or synthetic face: points of the model's surface projected into an image,
with visibility.

The labelled point sets are the 68 iBUG points and mediapipe's 478 face-mesh points, as points
of the model's surface (:mod:`morphable.fitting.schemes`). iBUG-68 rows the model has no fixed
vertex for (SFM: the 17 jaw points and two inner-mouth points) take the face-mesh scheme's
counterpart point, a fixed surface point near the jaw line; rows with no point at all stay
undefined (``defined`` False, NaN positions, never silently).

Examples
--------
>>> import morphable
>>> from morphable.camera import Camera
>>> sfm = morphable.load_model("sfm")
>>> schemes = label_schemes(sfm)
>>> lab = project_labels(sfm.mean, sfm.triangles, Camera.looking_at_face((256, 256)), schemes)
>>> lab["points68"].shape, int(lab["visible478"].sum()) > 300
((68, 2), True)
"""
from __future__ import annotations

import numpy as np

__all__ = ["label_schemes", "project_labels", "VIEW_OFFSET_MM"]

VIEW_OFFSET_MM = 0.01
"""A label's visibility ray starts this far from its surface point towards the camera."""


def label_schemes(model) -> dict:
    """The labelled point sets of ``model``: {"68": iBUG-68, "478": face mesh} as
    :class:`morphable.fitting.schemes.LandmarkScheme`. The iBUG rows the model has no vertex
    for take the face-mesh scheme's counterpart point (see the module's notes)."""
    from .fitting.schemes import ibug68_3d_scheme, load_scheme

    mesh = load_scheme(model, "facemesh478")      # the labels need it: InputError if missing
    return {"68": ibug68_3d_scheme(model), "478": mesh}


def project_labels(vertices, triangles, camera, schemes, offset_mm: float = VIEW_OFFSET_MM) -> dict:
    """Each scheme's surface points projected by ``camera``, with visibility.

    Parameters
    ----------
    vertices : (V, 3) float, mm, the mesh in the camera's world frame
    triangles : (F, 3) int
    camera : :class:`morphable.camera.Camera`
    schemes : {key: LandmarkScheme} (:func:`label_schemes`)
    offset_mm : float, mm: the visibility ray starts this far off the point

    Returns
    -------
    dict: for each key ``k``, ``points{k}`` (L, 2) float32 px (x right, y down, 0-based pixel
    centres; hidden points where they project: the 3D convention; NaN rows for points the
    scheme does not define or behind a perspective camera) and ``visible{k}`` (L,) bool: the
    point's normal faces the camera, a ray from it towards the camera hits no triangle
    (:func:`morphable.raster.visibility.points_in_view`) and it projects inside the image.
    """
    from .normals import vertex_normals
    from .raster.visibility import points_in_view

    vertices = np.asarray(vertices, dtype=np.float64)
    normals = vertex_normals(vertices, triangles)
    W, H = camera.image_size
    out = {}
    for key, scheme in schemes.items():
        P = scheme.points(vertices)
        N = scheme.points(normals)
        N /= np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-12)
        with np.errstate(invalid="ignore"):
            xy = camera.project(P)
            inside = ((xy > -0.5) & (xy < np.array([W, H]) - 0.5)).all(1)
        out[f"points{key}"] = xy.astype(np.float32)
        out[f"visible{key}"] = points_in_view(vertices, triangles, camera, P, N,
                                              offset_mm=offset_mm) & inside
    return out
