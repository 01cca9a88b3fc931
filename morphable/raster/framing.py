"""Cameras that frame a mesh: centre it and fit it into the image with a margin."""
from __future__ import annotations

import numpy as np

from ..camera import Camera, euler_to_matrix
from .visibility import check_mesh

__all__ = ["frame_mesh"]


def frame_mesh(vertices, image_size=(512, 512), yaw=0.0, pitch=0.0, roll=0.0,
               kind: str = "affine", margin: float = 0.05, distance_mm=None) -> Camera:
    """A camera looking at a mesh from the given angles, the mesh filling the image.

    Parameters
    ----------
    vertices : (V, 3) float, mm
    image_size : (W, H) pixels
    yaw, pitch, roll : degrees (see :mod:`morphable.camera`; yaw = 0 looks along -z, at the
        face of a model)
    kind : {"affine", "perspective"}
    margin : float
        Fraction of the image left free on each side.
    distance_mm : float or None
        Perspective: camera distance from the mesh's bounding-box centre (default three
        times the mesh's size).

    Returns
    -------
    Camera

    Examples
    --------
    >>> box = np.array([[-10., -20, -5], [10, 20, 5]])
    >>> cam = frame_mesh(box, (100, 100), margin=0.0)
    >>> cam.project(box).round(2)
    array([[24.5, 99.5],
           [74.5, -0.5]])
    """
    v, _ = check_mesh(vertices, np.zeros((1, 3), dtype=np.int64), what="mesh to frame")
    W, H = int(image_size[0]), int(image_size[1])
    R = euler_to_matrix(yaw, pitch, roll)
    centre = 0.5 * (v.min(0) + v.max(0))
    pc = (v - centre) @ R.T
    size = float(np.linalg.norm(v.max(0) - v.min(0))) or 1.0
    lo, hi = pc.min(0), pc.max(0)
    mid = 0.5 * (lo + hi)
    usable = np.array([W, H]) * (1 - 2 * margin)
    if kind == "perspective":
        dist = 3.0 * size if distance_mm is None else float(distance_mm)
        # fit the near face of the bounding box (the widest it can appear)
        near = dist - hi[2]
        ext = np.maximum(hi[:2] - mid[:2], mid[:2] - lo[:2]) * 2
        focal = float(np.min(usable / np.maximum(ext, 1e-9)) * near)
        t = -R @ centre + np.array([-mid[0], -mid[1], -dist])
        return Camera(kind="perspective", rotation=R, translation=t, focal=focal,
                      image_size=(W, H))
    ext = np.maximum(hi[:2] - lo[:2], 1e-9)
    scale = float(np.min(usable / ext))
    t = -R @ centre + np.array([-mid[0], -mid[1], -(size + 100.0)])
    return Camera(kind="affine", rotation=R, translation=t, scale=scale, image_size=(W, H))
