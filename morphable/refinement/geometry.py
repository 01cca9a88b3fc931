"""The fitted face in a crop camera, in torch: pose increments, projection, visibility, the
pixel views a renderer's appearance hooks take, and rendering (torch imported inside the
functions)."""
from __future__ import annotations

import dataclasses

import numpy as np

from ..camera import Camera

__all__ = ["rodrigues", "project_points", "face_visibility", "supersample_for", "PixelView",
           "surface_uv", "pixel_view", "render_face"]


def rodrigues(w):
    """(3,) axis-angle (rad) torch -> (3, 3), smooth at 0."""
    import torch

    theta2 = (w * w).sum()
    K = torch.zeros(3, 3, dtype=w.dtype)
    K[0, 1], K[0, 2], K[1, 2] = -w[2], w[1], -w[0]
    K = K - K.T
    # series forms near 0 keep the gradient finite at w = 0
    theta = torch.sqrt(theta2 + 1e-12)
    a = torch.where(theta2 > 1e-8, torch.sin(theta) / theta, 1 - theta2 / 6)
    b = torch.where(theta2 > 1e-8, (1 - torch.cos(theta)) / (theta2 + 1e-12), 0.5 - theta2 / 24)
    return torch.eye(3, dtype=w.dtype) + a * K + b * K @ K


def project_points(cam: Camera, X, R, t):
    """torch (N, 3) world mm -> (N, 2) pixels of ``cam`` with rotation R and translation t."""
    import torch

    Xc = X @ R.T + t
    if cam.kind == "affine":
        k = cam.scale
    else:
        k = cam.focal / (-Xc[:, 2]).clamp_min(1e-3)
    c = torch.as_tensor(cam.principal, dtype=X.dtype)
    return torch.stack([c[0] + k * Xc[:, 0], c[1] - k * Xc[:, 1]], -1)


def supersample_for(resolution: int) -> int:
    """Samples per pixel side of a crop's visibility: 2 below 128 px (a 64-px crop needs its
    silhouette anti-aliased), 1 from 128 px (each pixel then sees one surface point, which
    keeps the albedo's least squares per texel exact, and a step 4 x cheaper)."""
    return 2 if resolution < 128 else 1


def face_visibility(model, vertices, camera):
    """The :class:`morphable.raster.Visibility` of the face ``vertices`` (V, 3) mm of
    ``model`` in ``camera`` (:func:`supersample_for` its size)."""
    from ..raster import visibility

    return visibility(vertices, model.triangles, camera,
                      supersample=supersample_for(int(camera.image_size[0])))


@dataclasses.dataclass
class PixelView:
    """The face pixels of one crop, as a renderer's ``solve_appearance`` and
    ``view_appearance`` take them (:mod:`morphable.renderer_plugins`).

    resolution : R, the crop's side (px); pixels : (N,) int, flat indices into the R x R crop
    of the pixels at least half covered by the face; normals : (N, 3) camera-frame unit
    normals (None where only the pixels and UVs matter: ``view_appearance``); uv : (N, 2) the UV of the surface point each sees, or None (model without UVs);
    target : (N, 3) the crop's colours in [0, 1] and weight : (N,) their robust mask weight
    (None outside a fit); model : the MorphableModel.
    """

    resolution: int
    pixels: np.ndarray
    normals: np.ndarray | None
    uv: np.ndarray | None
    target: np.ndarray | None
    weight: np.ndarray | None
    model: object


def surface_uv(model, vis) -> np.ndarray | None:
    """(R, R, 2) the mean UV of the surface each pixel of ``vis`` sees (zero off the face),
    or None for a model without UVs."""
    from ..raster import interpolate

    if model.uv is None:
        return None
    tuv = model.triangles if model.triangle_uv is None else model.triangle_uv
    uv = vis.downsample(interpolate(vis, np.asarray(model.uv, dtype=np.float64), tuv))
    cover = vis.coverage()[..., None]
    return np.where(cover > 0, uv / np.maximum(cover, 1e-12), 0.0)


def pixel_view(model, vis, normal_map, uv_map, target=None, weight=None) -> PixelView:
    """The :class:`PixelView` of a crop: ``vis`` its visibility, ``normal_map`` (R, R, 3) or
    None (then the view's ``normals`` are None) and ``uv_map`` (R, R, 2) or None
    (:func:`surface_uv`) numpy, ``target`` (R, R, 3) and ``weight`` (R, R) numpy or None."""
    R = vis.image_shape[0]
    pixels = np.flatnonzero(vis.coverage().reshape(-1) > 0.5)

    def at(a, c):
        return None if a is None else np.asarray(a).reshape(R * R, c)[pixels]
    n = at(normal_map, 3)
    if n is not None:
        n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    w = at(weight, 1)
    return PixelView(R, pixels, n, at(uv_map, 2), at(target, 3), None if w is None else w[:, 0],
                     model)


def render_face(model, alpha, beta, camera, renderer, appearance):
    """The face (numpy coefficients) seen by ``camera``, rendered -> (R, R, 3) numpy in [0, 1];
    the appearance follows the view (the renderer's ``view_appearance``)."""
    import torch

    from ..raster import normal_map

    verts = model.vertices(alpha, beta)
    vis = face_visibility(model, verts, camera)
    n = normal_map(verts, model.triangles, vis=vis)
    app = renderer.view_appearance(appearance, pixel_view(model, vis, n, surface_uv(model, vis)))
    with torch.no_grad():
        img = renderer.render(torch.as_tensor(n, dtype=torch.float32).permute(2, 0, 1)[None], app)
    return img[0].permute(1, 2, 0).numpy()
