"""Vertex colours from a photo a mesh is fitted to: texture extraction, one colour per vertex."""
from __future__ import annotations

import numpy as np

from ..errors import InputError
from .texture import as_texture
from .visibility import check_mesh, visibility

__all__ = ["vertex_colors"]


def vertex_colors(vertices, triangles, camera, image, symmetry=None, min_facing: float = 0.3,
                  depth_tol_mm: float = 2.0):
    """Sample a photo at a mesh's projected vertices -> (V, 3) colours in [0, 1], (V,) seen.

    A vertex is seen when it faces the camera (the cosine between its normal and the direction
    to the camera above ``min_facing``: grazing views smear the photo) and nothing lies in front
    of it (its depth within ``depth_tol_mm`` of the depth rendered at its pixel). An unseen
    vertex takes the colour of its mirror vertex (``symmetry``) when that one is seen, else
    the median colour of the seen vertices.

    Parameters
    ----------
    vertices : (V, 3) mm, the mesh as fitted to the photo (e.g. ``FitResult.vertices(0)``)
    triangles : (F, 3) int
    camera : morphable.camera.Camera of the fit; its ``image_size`` is the photo's
    image : (H, W, 3) photo (uint8 or float in [0, 1]) or a path
    symmetry : (V,) int or None, each vertex's mirror vertex (``MorphableModel.symmetry``; -1:
        none)
    min_facing : cosine threshold, in [0, 1)
    depth_tol_mm : occlusion tolerance, mm

    Raises
    ------
    InputError when the photo's size is not the camera's, or no vertex is seen.

    Examples
    --------
    >>> from morphable import fit_images, load_model
    >>> sfm = load_model("sfm")
    >>> photo = "../shared/data/images/image_0010.png"
    >>> res = fit_images(photo, photo.replace(".png", ".pts"), model=sfm).fit
    >>> colors, seen = vertex_colors(res.vertices(0), sfm.triangles, res.cameras[0], photo,
    ...                              sfm.symmetry)
    >>> colors.shape, bool(seen.mean() > 0.5)
    ((3448, 3), True)
    """
    from scipy.ndimage import map_coordinates

    from ..normals import vertex_normals

    v, t = check_mesh(vertices, triangles)
    img = as_texture(image)
    H, W = img.shape[:2]
    if (W, H) != tuple(int(s) for s in camera.image_size):
        raise InputError(f"image is {W}x{H}, the camera's is "
                         f"{camera.image_size[0]}x{camera.image_size[1]}")
    facing = np.einsum("vi,vi->v", vertex_normals(v, t), camera.view_directions(v))
    uv = camera.project(v)
    depth = camera.depth(v)
    inside = (np.isfinite(uv).all(1) & (uv[:, 0] > -0.5) & (uv[:, 0] < W - 0.5)
              & (uv[:, 1] > -0.5) & (uv[:, 1] < H - 0.5))
    seen = inside & (facing > min_facing)
    if seen.any():
        rendered = visibility(v, t, camera).depth
        ij = np.round(np.where(inside[:, None], uv, 0.0)[:, ::-1]).astype(np.int64)
        seen &= depth <= rendered[ij[:, 0], ij[:, 1]] + depth_tol_mm
    if not seen.any():
        raise InputError("no vertex of the mesh is seen by the camera")
    colors = np.stack([map_coordinates(img[..., k], [uv[seen, 1], uv[seen, 0]], order=1,
                                       mode="nearest") for k in range(3)], -1)
    out = np.empty((len(v), 3))
    out[seen] = colors
    if symmetry is not None:
        mirror = np.asarray(symmetry, dtype=np.int64)
        take = ~seen & (mirror >= 0) & seen[np.maximum(mirror, 0)]
        out[take] = out[mirror[take]]
        filled = seen | take
    else:
        filled = seen
    out[~filled] = np.median(colors, 0)
    return np.clip(out, 0.0, 1.0), seen
