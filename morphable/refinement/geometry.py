"""The fitted face in a crop camera, in torch: pose increments, projection, visibility and
rendering (torch imported inside the functions)."""
from __future__ import annotations

from ..camera import Camera

__all__ = ["rodrigues", "project_points", "face_visibility", "render_face"]


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


def face_visibility(model, vertices, camera):
    """The :class:`morphable.raster.Visibility` of the face ``vertices`` (V, 3) mm of
    ``model`` in ``camera`` (2 x 2 samples per pixel)."""
    from ..raster import visibility

    return visibility(vertices, model.triangles, camera, supersample=2)


def render_face(model, alpha, beta, camera, renderer, appearance):
    """The face (numpy coefficients) seen by ``camera``, rendered -> (R, R, 3) numpy in [0, 1]."""
    import torch

    from ..raster import normal_map

    verts = model.vertices(alpha, beta)
    vis = face_visibility(model, verts, camera)
    n = torch.as_tensor(normal_map(verts, model.triangles, vis=vis), dtype=torch.float32)
    with torch.no_grad():
        img = renderer.render(n.permute(2, 0, 1)[None], appearance)
    return img[0].permute(1, 2, 0).numpy()
