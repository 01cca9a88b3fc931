"""Face profiling: a photo with its fit, turned to another head pose, with exact labels.

The idea of 3DDFA's face profiling (Zhu et al., CVPR 2016), on our rasteriser:

1. the head turns about a pivot :data:`PIVOT_BEHIND_MM` behind the centre of its 68 landmark
   points (model frame), by ``delta_yaw_deg`` about the camera's vertical axis and
   ``delta_pitch_deg`` about its horizontal axis (:func:`turned_camera`: the same mesh seen by
   a camera turned the other way, so the fit's identity and expression stay as they are);
2. the rest of the picture is warped by a piecewise-affine map of anchor points
   (:func:`warp_anchors`): the face's outline in the photo (the furthest face pixel in each of
   :data:`N_DIRECTIONS` directions from the face's centre) and the face's centre move with the
   head; rings of anchors around the outline (:data:`RINGS`: scale from the centre, share of
   the turn) stand for hair, ears and neck at the depth of their outline point and turn less
   the further out they lie; anchors on the image border stay;
3. the photo's own face is filled from its surroundings first (push-pull,
   :func:`morphable.texture.push_pull_fill`), so that what the warp carries out from under the
   new face at large turns shows hair or skin rather than a second face; the face is drawn over the warped picture through the fitted mesh at the new pose with the
   photo's own UV texture (:func:`morphable.texture.texture_from_views`, unlit: the photo's
   light stays in the texture), whose mirror fill colours the side the photo does not show.

Labels: the 68 iBUG and 478 face-mesh points as surface points of the model
(:func:`morphable.labels.label_schemes`), projected at the new pose (the 3D convention: hidden
points where they project), with visibility (:func:`morphable.labels.project_labels`).

Examples
--------
>>> from morphable import fit_images
>>> photo = "../shared/data/images/takeo.ppm"                              # 150 x 225 px
>>> fit = fit_images(photo, photo.replace(".ppm", ".pts")).fit
>>> out = profile_photo(photo, fit, 30.0, texture_size=128)                # turned by 30 degrees
>>> out["image"].shape, out["landmarks_px"]["68"].shape
((225, 150, 3), (68, 2))
>>> round(float(fit.euler_deg[0, 0])), round(float(out["camera"].euler_deg[0]))  # yaw before, after
(7, 37)
"""
from __future__ import annotations

import dataclasses

import numpy as np

from .errors import InputError

__all__ = ["profile_photo", "turned_camera", "head_pivot", "warp_anchors", "PIVOT_BEHIND_MM",
           "RINGS", "N_DIRECTIONS", "MAX_YAW_DEG", "MAX_PITCH_DEG"]

PIVOT_BEHIND_MM = 80.0
"""The head turns about a point this far behind the centre of its 68 landmarks (model frame,
along -z): about where the neck's axis meets the height of the eyes."""

N_DIRECTIONS = 36
"""Directions from the face's centre in which an outline anchor is placed."""

RINGS = ((1.3, 1.0), (1.7, 0.6), (2.4, 0.0))
"""Anchor rings around the outline: (distance from the face's centre as a multiple of the
outline point's, share of the head's turn they follow)."""

MAX_YAW_DEG = 90.0
MAX_PITCH_DEG = 60.0


def head_pivot(model, vertices) -> np.ndarray:
    """(3,) mm, model frame: the point the head turns about, :data:`PIVOT_BEHIND_MM` behind the
    centre of the defined iBUG-68 points of ``vertices`` (V, 3) mm."""
    from .fitting.schemes import ibug68_scheme

    P = ibug68_scheme(model).points(vertices)
    c = np.nanmean(P, axis=0)
    return c - np.array([0.0, 0.0, PIVOT_BEHIND_MM])


def turned_camera(camera, pivot, delta_yaw_deg: float, delta_pitch_deg: float = 0.0):
    """The camera that sees the scene turned by ``delta_yaw_deg`` (about the camera's vertical
    axis; positive: the camera's yaw grows) and ``delta_pitch_deg`` about ``pivot`` (3,) mm:
    ``turned.project(X) == camera.project(pivot + W (X - pivot))`` with ``W`` the turn in the
    world frame; the pivot projects where it did."""
    from .camera import euler_to_matrix

    Rd = euler_to_matrix(float(delta_yaw_deg), float(delta_pitch_deg), 0.0)
    R, t = camera.rotation, camera.translation
    c = np.asarray(pivot, dtype=np.float64)
    return dataclasses.replace(camera, rotation=Rd @ R, translation=R @ c + t - Rd @ R @ c)


def _outline(vis, surface, centre):
    """Per direction the face pixel furthest from ``centre`` (2,) px: (K, 2) px and their
    surface points (K, 3) mm (directions with no face pixel left out)."""
    W = vis.image_shape[1]
    xy = np.stack([vis.pixels % W, vis.pixels // W], 1).astype(np.float64)
    d = xy - centre
    r = np.linalg.norm(d, axis=1)
    k = np.floor((np.arctan2(d[:, 1], d[:, 0]) + np.pi) / (2 * np.pi) * N_DIRECTIONS).astype(int)
    k = np.clip(k, 0, N_DIRECTIONS - 1)
    order = np.lexsort((r, k))                      # by direction, then radius
    last = np.r_[k[order][1:] != k[order][:-1], True]
    pick = order[last]
    return xy[pick], surface[pick]


def warp_anchors(vertices, triangles, camera, pivot, delta_yaw_deg, delta_pitch_deg=0.0) -> tuple:
    """Anchor points of the background warp: ``(src (A, 2), dst (A, 2))`` px, where each
    anchor lies in the photo and where it goes at the new pose (see the module's notes).

    Parameters
    ----------
    vertices : (V, 3) mm, the fitted mesh in ``camera``'s world frame
    triangles : (F, 3) int
    camera : Camera of the photo
    pivot : (3,) mm, :func:`head_pivot`
    delta_yaw_deg, delta_pitch_deg : the turn, degrees
    """
    from .raster import interpolate, visibility

    vis = visibility(vertices, triangles, camera)
    if not len(vis.pixels):
        raise InputError("the fitted face does not show in its photo (check the fit's camera)")
    surface = interpolate(vis, vertices, foreground=True)          # (P, 3) mm
    W, H = camera.image_size
    xy = np.stack([vis.pixels % W, vis.pixels // W], 1).astype(np.float64)
    centre_px = xy.mean(0)
    j = int(np.argmin(np.linalg.norm(xy - centre_px, axis=1)))
    p_out, X_out = _outline(vis, surface, centre_px)
    src, dst = [xy[j:j + 1], p_out], []
    turned = turned_camera(camera, pivot, delta_yaw_deg, delta_pitch_deg)
    dst.append(turned.project(np.vstack([surface[j:j + 1], X_out])))
    k = camera.px_per_mm(X_out)[:, None]                           # (K, 1) px/mm
    for scale, share in RINGS:
        q = centre_px + scale * (p_out - centre_px)
        # the ring point at its outline point's depth: the offset in the camera's image plane
        off = np.stack([(q - p_out)[:, 0], -(q - p_out)[:, 1], np.zeros(len(q))], 1) / k
        X = X_out + off @ camera.rotation
        src.append(q)
        dst.append(turned_camera(camera, pivot, share * delta_yaw_deg, share * delta_pitch_deg).project(X))
    # the image border stays
    n = 8
    t = np.linspace(0, 1, n, endpoint=False)
    x0, y0, x1, y1 = -0.5, -0.5, W - 0.5, H - 0.5
    border = np.concatenate([np.stack([x0 + t * (x1 - x0), np.full(n, y0)], 1),
                             np.stack([np.full(n, x1), y0 + t * (y1 - y0)], 1),
                             np.stack([x1 - t * (x1 - x0), np.full(n, y1)], 1),
                             np.stack([np.full(n, x0), y1 - t * (y1 - y0)], 1)])
    src.append(border)
    dst.append(border)
    src, dst = np.vstack(src), np.vstack(dst)
    ok = np.isfinite(dst).all(1) & np.isfinite(src).all(1)
    return src[ok], dst[ok]


def _warp(photo, src, dst):
    """(H, W, 3) float photo warped so that the ``src`` anchors (A, 2) px land on ``dst``
    (A, 2) px: piecewise affine over a Delaunay triangulation of ``dst`` (scipy), each output
    pixel read bilinearly at its triangle's affine image in the photo; pixels outside every
    triangle read the nearest border pixel."""
    from scipy.ndimage import map_coordinates
    from scipy.spatial import Delaunay

    if np.allclose(src, dst):
        return photo.copy()
    H, W = photo.shape[:2]
    tri = Delaunay(dst)
    gx, gy = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    q = np.stack([gx.ravel(), gy.ravel()], 1)
    s = tri.find_simplex(q)
    inside = s >= 0
    T = tri.transform[s[inside]]                                   # (n, 3, 2)
    b = np.einsum("nij,nj->ni", T[:, :2], q[inside] - T[:, 2])
    bary = np.concatenate([b, 1 - b.sum(1, keepdims=True)], 1)     # (n, 3)
    at = q.copy()
    at[inside] = np.einsum("nk,nkc->nc", bary, src[tri.simplices[s[inside]]])
    coords = [np.clip(at[:, 1], 0, H - 1), np.clip(at[:, 0], 0, W - 1)]
    out = np.stack([map_coordinates(photo[..., c], coords, order=1, mode="nearest")
                    for c in range(photo.shape[2])], -1)
    return out.reshape(H, W, -1)


def profile_photo(image, fit, delta_yaw_deg: float, delta_pitch_deg: float = 0.0, *, frame: int = 0,
                  texture=None, texture_size: int = 512, supersample: int = 2) -> dict:
    """A photo turned to another head pose through its fit (see the module's notes).

    Parameters
    ----------
    image : path or (H, W, 3) array: the photo of frame ``frame`` of ``fit``
    fit : FitResult (:mod:`morphable.fitting`) of a model with UVs
    delta_yaw_deg : float in [-90, 90], degrees: the turn about the camera's vertical axis
        (positive: the fit's yaw grows)
    delta_pitch_deg : float in [-60, 60], degrees: the turn about the camera's horizontal axis
    frame : int, the fit's frame the photo is
    texture : PhotoTexture of this frame (:func:`morphable.texture.texture_from_views`) to
        reuse; default: extracted from the photo at ``texture_size`` texels
    supersample : antialiasing samples per pixel along each axis for the face

    Returns
    -------
    dict: ``image`` (H, W, 3) uint8; ``landmarks_px`` {"68": (68, 2), "478": (478, 2)} float
    px at the new pose (0-based pixel centres; hidden points where they project; NaN rows for
    iBUG points the model does not define); ``visible`` {"68": (68,), "478": (478,)} bool;
    ``defined68`` (68,) bool; ``fit``: ``fit`` with ``cameras[frame]`` turned (identity and
    expression unchanged; its landmark fields are still the photo's); ``camera`` the turned
    Camera; ``face_mask`` (H, W) float in [0, 1], the face's coverage at the new pose;
    ``anchors`` (src (A, 2), dst (A, 2)) px of the background warp.

    Raises
    ------
    InputError for a turn out of range, a frame the fit does not have, a photo of another size
    than the frame's camera, or a model without UVs.
    """
    from .detection.images import as_image
    from .labels import label_schemes, project_labels
    from .raster import render, visibility
    from .texture import texture_from_views

    dy, dp = float(delta_yaw_deg), float(delta_pitch_deg)
    if not (np.isfinite(dy) and abs(dy) <= MAX_YAW_DEG):
        raise InputError(f"yaw turn must be within +-{MAX_YAW_DEG:.0f} degrees, got {delta_yaw_deg}")
    if not (np.isfinite(dp) and abs(dp) <= MAX_PITCH_DEG):
        raise InputError(f"pitch turn must be within +-{MAX_PITCH_DEG:.0f} degrees, got {delta_pitch_deg}")
    if not 0 <= int(frame) < fit.n_frames:
        raise InputError(f"frame {frame}: the fit has {fit.n_frames} frame(s)")
    photo, name = as_image(image)
    cam = fit.cameras[frame]
    W, H = cam.image_size
    if photo.shape[:2] != (H, W):
        raise InputError(f"{name}: image is {photo.shape[1]}x{photo.shape[0]}, frame {frame} of "
                         f"the fit is {W}x{H}")
    model = fit.model
    v = fit.vertices(frame, dtype=np.float64)
    if texture is None:
        texture = texture_from_views(model, v[None], [cam], [photo], size=texture_size)
    pivot = head_pivot(model, v)
    new_cam = turned_camera(cam, pivot, dy, dp)
    src, dst = warp_anchors(v, model.triangles, cam, pivot, dy, dp)
    source = photo.astype(np.float64) / 255
    if not np.allclose(src, dst):
        # the photo's own face is drawn again at the new pose: where the warp would carry it
        # out from under the new face (the far side at large turns) it shows its surroundings
        from .texture import push_pull_fill

        old = visibility(v, model.triangles, cam).coverage()
        source = push_pull_fill(source, 1.0 - old)
    background = _warp(source, src, dst)
    vis = visibility(v, model.triangles, new_cam, supersample=supersample)
    img = render(v, model.triangles, texture=(texture.uv, texture.triangle_uv, texture.image),
                 light=np.eye(9)[0], background=np.clip(background, 0, 1), vis=vis)
    labels = project_labels(v, model.triangles, new_cam, label_schemes(model))
    schemes_68_defined = np.isfinite(labels["points68"]).all(1)
    cameras = list(fit.cameras)
    cameras[frame] = new_cam
    return {"image": np.round(np.clip(img, 0, 1) * 255).astype(np.uint8),
            "landmarks_px": {k: labels[f"points{k}"].astype(np.float64) for k in ("68", "478")},
            "visible": {k: labels[f"visible{k}"] for k in ("68", "478")},
            "defined68": schemes_68_defined,
            "fit": dataclasses.replace(fit, cameras=cameras), "camera": new_cam,
            "face_mask": vis.coverage(), "anchors": (src, dst)}
