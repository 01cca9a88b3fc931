"""Camera pose for landmark fitting: the linear affine estimate and the projection with its
Jacobian, vectorised over frames.

Conventions are those of :mod:`morphable.camera`: ``X_cam = R X + t``; affine
``u = c + k * D X_cam``, perspective ``u = c + k / d * D X_cam`` with ``D = [[1, 0, 0],
[0, -1, 0]]`` (image y down), ``d = -Z_cam`` the depth, ``k`` the scale (px/mm) or the focal
length (px).
"""
from __future__ import annotations

import numpy as np

from ..camera import axis_angle_to_matrix, cross
from ..errors import FitError

__all__ = ["estimate_affine_pose", "project", "projection_jacobian", "rotate"]

MIN_DEPTH_MM = 1e-3

_IMAGE_AXES = np.array([1.0, -1.0])      # camera x, y -> image x right, y down


def estimate_affine_pose(points3d, points2d, weights, principal, check: bool = True):
    """Scaled orthographic pose from 2D-3D correspondences (linear, eos / Hartley-Zisserman).

    A 2x4 affine camera is fitted by weighted least squares on centred coordinates, then
    its 2x3 part is replaced by the nearest scaled rotation.

    Parameters
    ----------
    points3d : (N, L, 3) mm, model points
    points2d : (N, L, 2) pixels
    weights : (N, L) >= 0 (0 = unused)
    principal : (N, 2) pixels
    check : bool
        Test the point sets for coincident or collinear points (callers that re-estimate
        with the same landmarks test once).

    Returns
    -------
    R : (N, 3, 3) rotations, t : (N, 3) mm (t_z = 0), scale : (N,) px/mm

    Raises
    ------
    FitError when a frame has fewer than 4 usable points or they are degenerate.
    """
    X = np.asarray(points3d, np.float64)
    y = np.asarray(points2d, np.float64)
    w = np.asarray(weights, np.float64)
    n_used = (w > 0).sum(1)
    if (n_used < 4).any():
        f = int(np.argmax(n_used < 4))
        raise FitError(f"frame {f}: {int(n_used[f])} usable landmarks, need at least 4 for a pose")
    wsum = w.sum(1)[:, None]
    mx = (w[..., None] * X).sum(1) / wsum                                  # (N, 3) centroids
    my = (w[..., None] * y).sum(1) / wsum                                  # (N, 2)
    Xc, yc = X - mx[:, None], y - my[:, None]
    # the weighted covariances: centred, the affine camera's translation is zero and y = M X
    # is solved for M (2x3) from them (a normalisation of either point set cancels in M)
    wX = (w[..., None] * Xc).transpose(0, 2, 1)
    Cxx, Cxy = wX @ Xc, wX @ yc
    if check:
        _check_spread((w[..., None] * yc).transpose(0, 2, 1) @ yc, "image")
        _check_spread(Cxx, "model")
    # coplanar model points (few landmarks) leave depth free: a tiny ridge keeps it defined
    d = np.einsum("nii->ni", Cxx)                                   # a view of the diagonal
    d += 1e-9 * d.sum(1, keepdims=True)
    M = np.linalg.solve(Cxx, Cxy).transpose(0, 2, 1) * _IMAGE_AXES[:, None]  # camera y up
    r12, scale = _nearest_scaled_rotation(M)
    R = np.concatenate([r12, cross(r12[:, 0], r12[:, 1])[:, None]], axis=1)
    if not (np.isfinite(R).all() and (scale > 0).all()):
        raise FitError("the affine pose estimate is degenerate (landmarks collinear?)")
    # the translation that maps the weighted centroids onto each other
    t = np.zeros((len(X), 3))
    t[:, :2] = (my - principal) * _IMAGE_AXES / scale[:, None] - (r12 @ mx[..., None])[..., 0]
    return R, t, scale


def _nearest_scaled_rotation(M):
    """M (N, 2, 3) -> the nearest two orthonormal rows (N, 2, 3) (the polar factor U V^T of
    its SVD) and the mean of its two singular values (N,), in closed form (an SVD's per-call
    cost is a tenth of the pose's): with A = M M^T (2 x 2) and d = sqrt(det A), s1 + s2 =
    sqrt(tr A + 2 d), and the factor is A^-1/2 M = ((tr A + d) I - A) M / (d (s1 + s2)).
    Not finite for a singular M."""
    A = M @ M.transpose(0, 2, 1)
    tr = A[:, 0, 0] + A[:, 1, 1]
    d = np.sqrt(np.maximum(A[:, 0, 0] * A[:, 1, 1] - A[:, 0, 1] * A[:, 1, 0], 0.0))
    s = np.sqrt(tr + 2 * d)
    return ((tr + d)[:, None, None] * M - A @ M) / (d * s)[:, None, None], s / 2


def _check_spread(cov, what):
    # the second principal spread must not vanish relative to the whole: the second invariant
    # of the weighted covariance cov (N, d, d) (the sum of its eigenvalues' pairwise products;
    # for 2D its determinant) against its squared trace, which brackets the eigenvalue ratio
    # within a factor 9 and needs no eigen-decomposition (no spread, NaN or inf: not above)
    tr = np.einsum("nii->n", cov)
    i2 = (tr ** 2 - (cov * cov).sum((1, 2))) / 2
    bad = ~(i2 > 1e-8 * tr ** 2)
    if bad.any():
        f = int(np.argmax(bad))
        raise FitError(f"frame {f}: the {what} landmark points are coincident or collinear")


def rotate(R, dw):
    """Left-multiply rotations (N, 3, 3) by ``exp([dw])``, dw (N, 3) radians (no gimbal lock)."""
    return axis_angle_to_matrix(dw) @ R


def project(X, R, t, k, principal, perspective: bool, jacobian: bool = True):
    """Project world points and (optionally) differentiate w.r.t. the camera-frame point.

    Parameters
    ----------
    X : (N, L, 3) mm; R : (N, 3, 3); t : (N, 3) mm; k : (N,) px/mm or focal px
    principal : (N, 2) px

    Returns
    -------
    uv : (N, L, 2) px, Xc : (N, L, 3) mm camera frame, J : (N, L, 2, 3) d uv / d Xc or None,
    depth : (N, L) mm (``-Z_cam``; inf for affine)
    """
    Xc = X @ R.transpose(0, 2, 1) + t[:, None]
    N, L = Xc.shape[:2]
    kk = k[:, None]
    if perspective:
        depth = -Xc[..., 2]
        safe = np.where(depth > MIN_DEPTH_MM, depth, MIN_DEPTH_MM)
        g = kk / safe
    else:
        depth = np.full((N, L), np.inf)
        g = kk
    uv = principal[:, None] + g[..., None] * Xc[..., :2] * _IMAGE_AXES
    J = projection_jacobian(Xc, k, perspective) if jacobian else None
    return uv, Xc, J, depth


def projection_jacobian(Xc, k, perspective: bool):
    """d uv / d Xc (N, L, 2, 3) at camera-frame points Xc (N, L, 3) mm, k (N,) px/mm or
    focal px (see :func:`project`)."""
    N, L = Xc.shape[:2]
    kk = k[:, None]
    J = np.zeros((N, L, 2, 3))
    if perspective:
        depth = -Xc[..., 2]
        safe = np.where(depth > MIN_DEPTH_MM, depth, MIN_DEPTH_MM)
        g = kk / safe
        J[..., 0, 2] = g * Xc[..., 0] / safe
        J[..., 1, 2] = -g * Xc[..., 1] / safe
    else:
        g = kk
    J[..., 0, 0] = g
    J[..., 1, 1] = -g
    return J
