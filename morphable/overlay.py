"""Overlays: the input photo with the fitted mesh and the landmarks drawn on top.

The mesh is drawn with the fit's own camera through :mod:`morphable.raster` (ray-cast
visibility), either shaded and alpha-blended over the photo or as the wireframe of its
visible triangles. Landmarks: the given/detected ones as green crosses, the projections of
the fitted model points as red discs (drawn last, so a red pixel marks a fitted position).

Examples
--------
>>> from morphable import load_model
>>> from morphable.fitting import fit_landmarks
>>> from morphable.io.landmark_files import read_pts
>>> photo = "../shared/data/images/image_0010.png"
>>> landmarks = read_pts(photo.replace(".png", ".pts"))
>>> res = fit_landmarks(load_model("sfm"), landmarks[None], [[1280, 1024]])
>>> img = draw_overlay(photo, res, mesh="wireframe")
>>> img.shape, img.dtype
((1024, 1280, 3), dtype('uint8'))
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from .errors import InputError

__all__ = ["draw_overlay", "label_faces", "save_overlay", "write_overlays", "overlay_paths", "check_overlay_path", "face_box", "MESH_STYLES", "GIVEN_COLOR",
           "FITTED_COLOR"]

MESH_STYLES = ("shaded", "wireframe", None)
GIVEN_COLOR = (0, 220, 0)
"""RGB of the given (or detected) landmarks: crosses."""
FITTED_COLOR = (255, 0, 0)
"""RGB of the fitted landmarks (projected model points): discs."""


def _photo(image) -> np.ndarray:
    """Path or array -> (H, W, 3) float32 in [0, 1]; a file is read as the detectors read it
    (upright by its EXIF orientation, 16-bit scaled), so that its landmarks land on it."""
    from .raster import as_texture

    if isinstance(image, (str, bytes)) or hasattr(image, "__fspath__"):
        from .detection.images import read_image

        image = read_image(image)
    else:
        a = np.asarray(image)
        if a.ndim not in (2, 3) or (a.ndim == 3 and a.shape[2] not in (3, 4)) or a.size == 0:
            raise InputError(f"image must be (H, W), (H, W, 3) or (H, W, 4), got shape {a.shape}")
        if a.dtype.kind not in "uif" or (a.dtype.kind == "f" and not np.isfinite(a).all()):
            raise InputError(f"image must hold finite numbers, got {a.dtype} with NaN/inf or objects")
    return as_texture(image)


def _frame_index(result, frame: int) -> int:
    n = result.n_frames
    if not isinstance(frame, (int, np.integer)) or not -n <= frame < n:
        raise InputError(f"frame {frame!r}: the fit has {n} frame(s)")
    return int(frame) % n


def _window(cam, vertices):
    """The camera restricted to the pixels the mesh can cover -> (camera, (x0, y0, x1, y1)),
    or None when the mesh projects outside the image. Rendering the window instead of the
    whole photo keeps the cost proportional to the face, not to the photo."""
    from dataclasses import replace

    W, H = cam.image_size
    if cam.kind == "perspective" and (cam.depth(vertices) <= 0).any():
        return cam, (0, 0, W, H)  # points at or behind the camera: no finite bound
    p = cam.project(vertices)
    x0, y0 = np.maximum(np.floor(p.min(0)).astype(int) - 2, 0)
    x1, y1 = np.minimum(np.ceil(p.max(0)).astype(int) + 3, [W, H])
    if x1 <= x0 or y1 <= y0:
        return None
    sub = replace(cam, image_size=(int(x1 - x0), int(y1 - y0)), principal=cam.principal - [x0, y0])
    return sub, (int(x0), int(y0), int(x1), int(y1))


def _visible_edges(triangles, vis) -> np.ndarray:
    """(M, 2) vertex-id pairs of the edges of the triangles seen by at least one sample."""
    seen = np.unique(vis.triangle_id[vis.mask])
    t = triangles[seen]
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    return np.unique(np.sort(e, axis=1), axis=0)


def _pixels(points, W, H, margin):
    """Finite points (N, 2) within ``margin`` of the image -> rounded integer pixels."""
    p = np.asarray(points, dtype=np.float64)
    p = p[np.isfinite(p).all(1)]
    p = p[(p[:, 0] > -margin) & (p[:, 0] < W + margin) & (p[:, 1] > -margin) & (p[:, 1] < H + margin)]
    return [(int(x), int(y)) for x, y in np.round(p)]


def draw_overlay(image, result, frame: int = 0, *, mesh: str | None = "shaded",
                 alpha: float = 0.6, mesh_color=(0.75, 0.75, 0.75), landmarks: bool = True,
                 radius: int | None = None, supersample: int = 2,
                 crop: float | None = None) -> np.ndarray:
    """Draw a fit over its photo.

    Parameters
    ----------
    image : (H, W, 3) or (H, W) uint8/float image, or a path
        The photo of ``frame``; its size must be the camera's ``image_size``.
    result : morphable.fitting.FitResult
    frame : int
        Which frame of a multi-frame fit (its mesh, camera and landmarks).
    mesh : "shaded", "wireframe" or None
        Shaded: Lambertian grey mesh blended with weight ``alpha``; wireframe: the edges of
        the visible triangles (anti-aliased lines, opacity ``alpha``); None: landmarks only.
    alpha : float in [0, 1]
    mesh_color : (3,) float in [0, 1], albedo of the shaded mesh / colour of the wireframe
    landmarks : bool
        Draw the given landmarks (green crosses) and the fitted ones (red discs).
    radius : int or None
        Landmark size in pixels; default ``max(2, min(W, H) // 250)``, and half that (at
        least 1) for dense sets (more than 68 points, e.g. the face mesh's 478).
    supersample : int
        Samples per pixel along each axis for the shaded mesh's edges.
    crop : float or None
        Cut the result to the face: the box of the projected mesh and the landmarks, widened
        by this fraction of its size on each side (e.g. 0.2). None: the whole image, pixel
        for pixel aligned with the photo.

    Returns
    -------
    (H, W, 3) uint8, or the (h, w, 3) crop

    Raises
    ------
    InputError
        Image size different from the camera's, a bad ``frame``, ``mesh`` or ``alpha``.
    """
    from PIL import Image, ImageDraw

    from .raster import render, visibility

    i = _frame_index(result, frame)
    if mesh not in MESH_STYLES:
        raise InputError(f"mesh={mesh!r}: choose from shaded, wireframe or None")
    if not 0.0 <= float(alpha) <= 1.0:
        raise InputError(f"alpha={alpha}: must be in [0, 1]")
    if crop is not None and not (np.isfinite(crop) and crop >= 0):
        raise InputError(f"crop={crop}: must be a margin fraction >= 0 or None")
    photo = _photo(image).astype(np.float64)
    H, W = photo.shape[:2]
    cam = result.cameras[i]
    if tuple(cam.image_size) != (W, H):
        raise InputError(f"image is {W}x{H}, the fit's camera of frame {i} is "
                         f"{cam.image_size[0]}x{cam.image_size[1]}")
    color = np.asarray(mesh_color, dtype=np.float64)
    if color.shape != (3,) or not np.isfinite(color).all():
        raise InputError(f"mesh_color must be 3 numbers in [0, 1], got {mesh_color}")
    out = photo
    vertices = np.asarray(result.vertices(i), dtype=np.float64)
    window = _window(cam, vertices) if mesh is not None else None
    if window is not None:
        sub, (x0, y0, x1, y1) = window
        triangles = np.asarray(result.model.triangles)
        if mesh == "shaded":
            vis = visibility(vertices, triangles, sub, supersample=max(1, int(supersample)))
            # black background: the render is the mesh premultiplied by its pixel coverage
            shaded = render(vertices, triangles, vis=vis, colors=color, background=(0.0, 0.0, 0.0))
            cover = alpha * vis.coverage()[..., None]
            out = photo.copy()
            out[y0:y1, x0:x1] = photo[y0:y1, x0:x1] * (1.0 - cover) + alpha * shaded
        out = Image.fromarray(np.round(255 * np.clip(out, 0, 1)).astype(np.uint8))
        if mesh == "wireframe":
            vis = visibility(vertices, triangles, sub)
            uv = cam.project(vertices)
            layer = Image.new("RGBA", out.size, (0, 0, 0, 0))
            draw = ImageDraw.Draw(layer)
            rgba = tuple(int(round(255 * c)) for c in np.clip(color, 0, 1)) + (int(round(255 * alpha)),)
            for a, b in _visible_edges(triangles, vis):  # PIL pixel indices = our pixel centres
                draw.line([tuple(uv[a]), tuple(uv[b])], fill=rgba, width=1)
            out = Image.alpha_composite(out.convert("RGBA"), layer).convert("RGB")
    else:  # no mesh, or a mesh outside the image
        out = Image.fromarray(np.round(255 * np.clip(out, 0, 1)).astype(np.uint8))
    if landmarks:
        r = int(radius) if radius is not None else max(2, min(W, H) // 250)
        if radius is None and len(result.landmarks[i]) > 68:  # 478 crosses would hide the face
            r = max(1, r // 2)
        draw = ImageDraw.Draw(out)
        # marks centred on the nearest pixel (pixel centres sit at integer coordinates)
        for x, y in _pixels(result.landmarks[i], W, H, r):
            draw.line([(x - r, y - r), (x + r, y + r)], fill=GIVEN_COLOR, width=max(1, r // 2))
            draw.line([(x - r, y + r), (x + r, y - r)], fill=GIVEN_COLOR, width=max(1, r // 2))
        for x, y in _pixels(result.fitted_landmarks[i], W, H, r):
            draw.ellipse([x - r, y - r, x + r, y + r], fill=FITTED_COLOR)
    out = np.asarray(out)
    if crop is not None:
        x0, y0, x1, y1 = face_box(result, i, margin=float(crop))
        out = out[y0:y1, x0:x1]
    return out


def face_box(result, frame: int = 0, margin: float = 0.2) -> tuple:
    """Pixel box ``(x0, y0, x1, y1)`` (x1, y1 exclusive) around the projected mesh and the
    landmarks of a frame, widened by ``margin`` times its size per side, clipped to the image.
    """
    i = _frame_index(result, frame)
    cam = result.cameras[i]
    W, H = (int(v) for v in cam.image_size)
    pts = np.concatenate([cam.project(np.asarray(result.vertices(i), dtype=np.float64)),
                          result.landmarks[i], result.fitted_landmarks[i]])
    pts = pts[np.isfinite(pts).all(1)]
    if cam.kind == "perspective":  # points behind the camera project anywhere
        pts = pts[(pts[:, 0] > -W) & (pts[:, 0] < 2 * W) & (pts[:, 1] > -H) & (pts[:, 1] < 2 * H)]
    if len(pts) == 0:
        return 0, 0, W, H
    lo, hi = pts.min(0), pts.max(0)
    pad = margin * (hi - lo).max()
    x0, y0 = np.clip(np.floor(lo - pad), 0, [W - 1, H - 1]).astype(int)
    x1, y1 = np.clip(np.ceil(hi + pad) + 1, [x0 + 1, y0 + 1], [W, H]).astype(int)
    return int(x0), int(y0), int(x1), int(y1)


_FORMATS = {".png": "PNG", ".jpg": "JPEG", ".jpeg": "JPEG"}


def check_overlay_path(path) -> Path:
    """Raise InputError unless ``path`` ends in .png/.jpg/.jpeg in an existing folder."""
    path = Path(path)
    if path.suffix.lower() not in _FORMATS:
        raise InputError(f"{path}: overlay must be a .png or .jpg file")
    if not path.resolve().parent.is_dir():
        raise InputError(f"{path}: folder {path.resolve().parent} does not exist")
    return path


def save_overlay(path, image, result, frame: int = 0, **kwargs) -> Path:
    """:func:`draw_overlay` written to a .png/.jpg at ``path`` (atomically) -> the path."""
    from PIL import Image

    from .io.atomic import atomic_path

    path = check_overlay_path(path)
    img = draw_overlay(image, result, frame, **kwargs)
    with atomic_path(path) as tmp:
        Image.fromarray(img).save(tmp, format=_FORMATS[path.suffix.lower()])
    return path


def write_overlays(path, result, images, **kwargs) -> list:
    """One overlay per frame: ``path`` itself for a single image, else ``stem_<i>.suffix``.

    ``images``: the N photos (paths or arrays) of the fit's frames. Returns the paths written.
    """
    images = list(images)
    if len(images) != result.n_frames:
        raise InputError(f"{len(images)} images for a fit of {result.n_frames} frames")
    return [save_overlay(p, im, result, i, **kwargs)
            for i, (p, im) in enumerate(zip(overlay_paths(path, len(images)), images))]


def overlay_paths(path, n_frames: int) -> list:
    """The files :func:`write_overlays` writes for a fit of ``n_frames`` frames: ``path``
    itself for one, else ``stem_<i>.suffix``."""
    path = Path(path)
    if n_frames == 1:
        return [path]
    return [path.with_name(f"{path.stem}_{i}{path.suffix}") for i in range(n_frames)]


def label_faces(image, boxes, labels, color=(255, 255, 0)) -> np.ndarray:
    """Write each label at the top-left corner of its box (a face's number on a photo or frame
    with several faces).

    Parameters
    ----------
    image : (H, W, 3) uint8
    boxes : (N, 4) px ``(left, top, right, bottom)``
    labels : N str
    color : (3,) int 0-255

    Returns
    -------
    (H, W, 3) uint8, a copy.
    """
    from PIL import Image, ImageDraw, ImageFont

    out = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8))
    draw = ImageDraw.Draw(out)
    H = out.size[1]
    try:
        font = ImageFont.load_default(size=max(12, H // 30))
    except TypeError:                 # Pillow before 10.1 has one size
        font = ImageFont.load_default()
    for b, text in zip(np.asarray(boxes, dtype=np.float64).reshape(-1, 4), labels):
        x, y = float(b[0]), max(0.0, float(b[1]) - max(12, H // 30) - 2)
        draw.text((x, y), str(text), fill=tuple(int(c) for c in color), font=font,
                  stroke_width=2, stroke_fill=(0, 0, 0))
    return np.asarray(out)
