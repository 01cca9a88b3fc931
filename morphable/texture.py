"""UV textures from photos: the colour each photo shows at each texel's surface point.

A texel of the model's UV layout is a point on the surface (a triangle and barycentrics). In
every frame of a fit that point is projected into the photo; its colour there counts with the
weight ``cos(normal, direction to the camera)`` when nothing of the mesh lies between it and
the camera (a ray cast towards the camera, open3d) and the surface faces the camera at least
``min_facing``. Frames blend by these weights. Texels no frame sees take the colour at their
mirror point (the point across the model's plane of symmetry) where a frame sees that one, and
the rest is filled by push-pull (a pyramid of weighted averages), so the texture has no holes
and no NaN; ``confidence`` says which texels were observed.

UV convention as :mod:`morphable.raster.texture`: texel ``(i, j)`` of an S x S map has its
centre at ``u = (j + 0.5) / S``, ``v = 1 - (i + 0.5) / S`` (row 0 is the top, v up).

Examples
--------
>>> import tempfile
>>> from morphable import fit_images
>>> photo = "../shared/data/images/image_0010.png"
>>> res = fit_images(photo, photo.replace(".png", ".pts")).fit
>>> tex = extract_texture(res, [photo], size=256)
>>> tex.image.shape, round(float(tex.observed[tex.layout].mean()), 2)     # the face's texels seen
((256, 256, 3), 0.74)
>>> save_texture(tex, f"{tempfile.mkdtemp()}/face.png").name
'face.png'
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .errors import InputError

__all__ = ["PhotoTexture", "extract_texture", "texture_from_views", "texture_layout",
           "mirror_texels", "push_pull_fill", "save_texture", "MIN_FACING", "MIRROR_TOL_MM"]

MIN_FACING = 0.2
"""Smallest cosine between a surface normal and the direction to the camera at which a photo
colours a texel (78 degrees): nearer the silhouette a pixel spans a long strip of surface and
mixes in the background."""

MIRROR_TOL_MM = 1.0
"""A model is taken as mirror-symmetric when the mirror images of its textured vertices lie
within this distance (median, mm) of its mean surface; a texel's own mirror point must lie
within 2 x this."""


@dataclass
class PhotoTexture:
    """A texture extracted from photos.

    Attributes
    ----------
    image : (S, S, 3) float32 in [0, 1], filled everywhere (no NaN)
    confidence : (S, S) float32 in [0, 1]: the largest ``cos(normal, view)`` of the frames
        that see the texel's surface point; 0 where none does
    mirrored : (S, S) bool, texels coloured from their mirror point (not observed themselves)
    layout : (S, S) bool, texels on the textured triangles of the UV layout
    uv : (T, 2) float, triangle_uv : (F, 3) int
        The UV layout that goes with ``image`` for every triangle of the model (write these
        with the mesh; triangles outside the layout point at one filled texel)
    runtime_ms : float, wall time of the extraction
    """

    image: np.ndarray
    confidence: np.ndarray
    mirrored: np.ndarray
    layout: np.ndarray
    uv: np.ndarray
    triangle_uv: np.ndarray
    runtime_ms: float = 0.0

    @property
    def observed(self) -> np.ndarray:
        """(S, S) bool: texels some frame sees."""
        return self.confidence > 0


def texture_layout(model, size: int = 512):
    """The UV layout a single S x S texture of ``model`` uses.

    The model's own UVs, restricted to the triangles one map holds
    (:func:`morphable.raster.normal_maps.layout_faces`: ICT's face, not its eyes, mouth interior
    or back of the head, which sit in other UV tiles or overlap the face's) whose UVs lie in
    the unit square. Every other triangle gets the UV of one texel outside the layout, so that
    a renderer draws it in the texture's fill colour.

    Parameters
    ----------
    model : MorphableModel with UVs
    size : int, texels per side

    Returns
    -------
    uv : (T + 1, 2) float, triangle_uv : (F, 3) int, textured : (F,) bool

    Raises
    ------
    InputError when the model has no UVs, or none of its triangles lies in the unit square.
    """
    from .raster.normal_maps import layout_faces

    if getattr(model, "uv", None) is None:
        raise InputError(f"{getattr(model, 'source', '') or model.name}: the model has no UV "
                         "coordinates, so it cannot take a texture")
    uv = np.asarray(model.uv, dtype=np.float64)
    tuv = model.triangles if model.triangle_uv is None else np.asarray(model.triangle_uv)
    corners = uv[tuv]                                                     # (F, 3, 2)
    textured = layout_faces(model) & ((corners >= 0) & (corners <= 1)).all((1, 2))
    if not textured.any():
        raise InputError(f"{model.name}: no triangle has UVs in [0, 1]")
    spare = _spare_texel(corners[textured], size)
    out_uv = np.vstack([uv, spare[None]])
    out_tuv = np.where(textured[:, None], tuv, len(uv)).astype(np.int64)
    return out_uv, out_tuv, textured


def _spare_texel(corners, size):
    """(2,) UV of a texel centre that no textured triangle's bounding box covers (the UV
    square's corners first)."""
    lo, hi = corners.min(1), corners.max(1)                               # (F, 2)
    c = (np.arange(size) + 0.5) / size
    for u, v in [(c[0], c[-1]), (c[-1], c[-1]), (c[0], c[0]), (c[-1], c[0])]:
        p = np.array([u, v])
        if not ((lo <= p) & (p <= hi)).all(1).any():
            return p
    # a layout filling the whole square: the untextured triangles take its first texel
    return np.array([c[0], c[-1]])


def mirror_texels(model, table, textured, tol_mm: float = MIRROR_TOL_MM):
    """Each texel's mirror point on the model's mean surface.

    The plane of symmetry is ``x = c`` in model coordinates (x runs across the face): ``c``
    from the model's symmetric vertex pairs (``model.symmetry``) where it has them, else the
    middle of the textured vertices' x range. The model counts as symmetric when its mirrored
    textured vertices lie within ``tol_mm`` (median) of its mean surface.

    Parameters
    ----------
    model : MorphableModel
    table : Visibility of the UV layout (:func:`morphable.raster.uv_visibility`)
    textured : (F,) bool, the triangles the mirror point may lie on

    Returns
    -------
    Visibility on the same texel grid whose samples are the mirror points of ``table``'s
    (texels whose mirror point lies further than ``2 * tol_mm`` from the surface are left
    out), or None when the model is not symmetric.
    """
    from .raster.visibility import Visibility, closest_points

    mean = np.asarray(model.mean, dtype=np.float64)
    tri = np.asarray(model.triangles)
    ids = np.unique(tri[textured])
    sym = getattr(model, "symmetry", None)
    if sym is not None and (np.asarray(sym) >= 0).any():
        ok = np.asarray(sym) >= 0
        c = float(np.median((mean[ok, 0] + mean[sym[ok], 0]) / 2))
    else:
        c = float((mean[ids, 0].min() + mean[ids, 0].max()) / 2)
    flip = np.array([-1.0, 1.0, 1.0])
    sub = np.flatnonzero(textured)
    _, _, d = closest_points(mean, tri[sub], (mean[ids] - [c, 0, 0]) * flip + [c, 0, 0])
    if not np.median(d) <= tol_mm:
        return None
    points = np.einsum("nk,nkc->nc", table.weights, mean[table.corners()])
    t, b, d = closest_points(mean, tri[sub], (points - [c, 0, 0]) * flip + [c, 0, 0])
    keep = d <= 2 * tol_mm
    return Visibility.from_samples(table.shape, table.pixels[keep], sub[t[keep]], b[keep],
                                   np.zeros(int(keep.sum())), tri)


def _view_samples(vertices, triangles, normals, camera, photo, samples, min_facing):
    """Colour (N, 3) and weight (N,) of a photo at the surface points of ``samples`` (a
    Visibility over the UV grid): ``cos(normal, view)`` where the point faces the camera by at
    least ``min_facing``, projects inside the photo and nothing lies in front of it, else 0."""
    from .raster import interpolate, sample_texture
    from .raster.visibility import points_in_view

    p = interpolate(samples, vertices, foreground=True)
    n = interpolate(samples, normals, foreground=True)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    d = camera.view_directions(p)
    cos = np.einsum("nc,nc->n", n, d)
    xy = camera.project(p)
    H, W = photo.shape[:2]
    with np.errstate(invalid="ignore"):
        ok = ((cos >= min_facing) & (xy[:, 0] > -0.5) & (xy[:, 0] < W - 0.5)
              & (xy[:, 1] > -0.5) & (xy[:, 1] < H - 0.5))
    k = np.flatnonzero(ok)
    # a ray from just off the surface towards the camera: any hit before the camera hides it
    ok[k] = points_in_view(vertices, triangles, camera, p[k], n[k])
    weight = np.where(ok, cos, 0.0)
    k = np.flatnonzero(ok)
    colour = np.zeros((len(p), 3))
    uv = np.stack([(xy[k, 0] + 0.5) / W, 1.0 - (xy[k, 1] + 0.5) / H], 1)
    colour[k] = sample_texture(photo, uv)
    return colour, weight


def _read_photo(image, i: int, camera) -> np.ndarray:
    """(H, W, 3) float32 in [0, 1] of the camera's size, read upright like the fit's photo."""
    from .detection.images import as_image
    from .raster import as_texture

    photo, name = as_image(image)
    photo = as_texture(photo)
    W, H = (int(s) for s in camera.image_size)
    if photo.shape[:2] != (H, W):
        raise InputError(f"{name}: image is {photo.shape[1]}x{photo.shape[0]}, frame {i} of the "
                         f"fit is {W}x{H}")
    return photo


def texture_from_views(model, vertices, cameras, images, size: int = 512, *,
                       min_facing: float = MIN_FACING, mirror: bool = True) -> PhotoTexture:
    """A UV texture of ``model`` from photos of its fitted meshes.

    Parameters
    ----------
    model : MorphableModel with UVs (its UV layout and triangles)
    vertices : (N, V, 3) float, mm: the mesh as fitted in each frame (world frame)
    cameras : N :class:`morphable.camera.Camera`, each of its photo's size
    images : N photos: paths or (H, W, 3) arrays (uint8, or float in [0, 1])
    size : int, texels per side of the square texture
    min_facing : float in [0, 1), the smallest cosine between the normal and the direction to
        the camera at which a photo colours a surface point
    mirror : bool, colour unobserved texels from their mirror point where the model is
        symmetric

    Returns
    -------
    PhotoTexture

    Raises
    ------
    InputError for a model without UVs, a count of images other than of frames, a photo of
    another size than its camera's, or when no frame sees any texel.

    Examples
    --------
    >>> import morphable
    >>> from morphable.camera import Camera
    >>> sfm = morphable.load_model("sfm")
    >>> grey = np.full((240, 240, 3), 128, dtype=np.uint8)
    >>> cam = Camera.looking_at_face(image_size=(240, 240))
    >>> tex = texture_from_views(sfm, sfm.mean[None], [cam], [grey], size=64)
    >>> tex.image.shape, bool(np.isfinite(tex.image).all()), round(float(tex.image.mean()), 3)
    ((64, 64, 3), True, 0.502)
    """
    from .normals import vertex_normals
    from .raster import uv_visibility
    from .raster.visibility import array_key, check_mesh

    t0 = time.perf_counter()
    cameras = list(cameras)
    images = list(images)
    vertices = np.asarray(vertices, dtype=np.float64)
    if vertices.ndim == 2:
        vertices = vertices[None]
    if len(images) != len(cameras) or len(vertices) != len(cameras):
        raise InputError(f"{len(images)} images for a fit of {len(cameras)} frames"
                         if len(images) != len(cameras) else
                         f"{len(vertices)} meshes for {len(cameras)} cameras")
    if not 0 <= min_facing < 1:
        raise InputError(f"min_facing must be in [0, 1), got {min_facing}")
    uv, tuv, textured = texture_layout(model, size)
    # the untextured triangles' UVs are one point: no texel lands on them
    table = uv_visibility(model.triangles, uv, tuv, size)
    twin = None
    if mirror:  # kept with the (cached) texel table: the same model and size find it again
        twin = table.cached(("mirror", array_key(model.mean, textured)),
                            lambda: mirror_texels(model, table, textured))
    photos = [_read_photo(im, i, cam) for i, (im, cam) in enumerate(zip(images, cameras))]

    n_tex = size * size
    acc = np.zeros((2, n_tex, 3))
    wsum = np.zeros((2, n_tex))
    best = np.zeros(n_tex)
    for v, cam, photo in zip(vertices, cameras, photos):
        v, t = check_mesh(v, model.triangles)
        normals = vertex_normals(v, t)
        for k, samples in enumerate((table, twin)):
            if samples is None:
                continue
            colour, w = _view_samples(v, t, normals, cam, photo, samples, min_facing)
            acc[k, samples.pixels] += w[:, None] * colour
            wsum[k, samples.pixels] += w
            if k == 0:
                best[samples.pixels] = np.maximum(best[samples.pixels], w)
    seen = wsum[0] > 0
    if not seen.any():
        raise InputError("no frame sees any texel of the face (check the fit's cameras)")
    mirrored = ~seen & (wsum[1] > 0)
    colour = np.zeros((n_tex, 3))
    colour[seen] = acc[0, seen] / wsum[0, seen, None]
    colour[mirrored] = acc[1, mirrored] / wsum[1, mirrored, None]
    known = (seen | mirrored).astype(np.float64)
    image = push_pull_fill(colour.reshape(size, size, 3), known.reshape(size, size))
    # the untextured triangles' texel (ICT: eyes, mouth, back of the head): the face's median
    # colour rather than whatever the photo shows next to the layout (often hair)
    i, j = int((1 - uv[-1, 1]) * size), int(uv[-1, 0] * size)
    if not table.mask[i, j]:
        image[i, j] = np.median(colour[seen], 0)
    return PhotoTexture(image=np.clip(image, 0, 1).astype(np.float32),
                        confidence=best.reshape(size, size).astype(np.float32),
                        mirrored=mirrored.reshape(size, size), layout=table.mask.copy(),
                        uv=uv, triangle_uv=tuv, runtime_ms=1e3 * (time.perf_counter() - t0))


def extract_texture(result, images, size: int = 512, *, min_facing: float = MIN_FACING,
                    mirror: bool = True) -> PhotoTexture:
    """A UV texture from the photos of a fit (:func:`texture_from_views` on each frame's mesh
    and camera).

    Parameters
    ----------
    result : FitResult (:mod:`morphable.fitting`) of a model with UVs
    images : its N frames' photos, in order: paths or (H, W, 3) arrays
    size, min_facing, mirror : see :func:`texture_from_views`

    Returns
    -------
    PhotoTexture
    """
    images = list(images)
    if len(images) != result.n_frames:
        raise InputError(f"{len(images)} images for a fit of {result.n_frames} frames")
    return texture_from_views(result.model, result.vertices(dtype=np.float64), result.cameras,
                              images, size, min_facing=min_facing, mirror=mirror)


def push_pull_fill(image, weight) -> np.ndarray:
    """Fill the texels of low weight from their neighbourhood (push-pull, Gortler et al. 1996).

    The image is averaged down a pyramid of halvings with ``weight``; each level is then
    completed from the level below it (upsampled bilinearly): ``out = w * image + (1 - w) *
    coarser`` with ``w = clip(weight, 0, 1)``. Texels of weight 1 keep their value.

    Parameters
    ----------
    image : (H, W, C) float
    weight : (H, W) float >= 0 (e.g. 1 where known, 0 in holes); values of texels with
        weight 0 are ignored (they may be NaN)

    Returns
    -------
    (H, W, C) float64, finite everywhere

    Raises
    ------
    InputError when every weight is 0 (nothing to fill from).

    Examples
    --------
    >>> img = np.zeros((4, 4, 1)); img[0, 0] = 1.0
    >>> w = np.zeros((4, 4)); w[0, 0] = 1.0
    >>> float(push_pull_fill(img, w)[..., 0].min())
    1.0
    """
    c = np.asarray(image, dtype=np.float64)
    w = np.clip(np.asarray(weight, dtype=np.float64), 0.0, 1.0)
    if c.ndim != 3 or w.shape != c.shape[:2]:
        raise InputError(f"push_pull_fill: image (H, W, C) and weight (H, W) expected, got "
                         f"{c.shape} and {w.shape}")
    if not w.any():
        raise InputError("push_pull_fill: every weight is 0, nothing to fill from")
    premultiplied = np.where(w[..., None] > 0, c, 0.0) * w[..., None]
    return _pull(premultiplied, w)


def _pull(pc, w):
    """Filled colours of a premultiplied level ``pc`` (H, W, C) with weights ``w`` (H, W)."""
    H, W = w.shape
    if H == 1 and W == 1 or w.min() >= 1:
        return pc / np.maximum(w, 1e-12)[..., None]
    # halve, padding odd sides with weight 0
    h2, w2 = (H + 1) // 2, (W + 1) // 2
    P = np.zeros((2 * h2, 2 * w2) + pc.shape[2:])
    Q = np.zeros((2 * h2, 2 * w2))
    P[:H, :W], Q[:H, :W] = pc, w
    sp = P.reshape(h2, 2, w2, 2, -1).sum((1, 3))
    sw = Q.reshape(h2, 2, w2, 2).sum((1, 3))
    cw = np.minimum(sw, 1.0)
    coarse = _pull(sp / np.maximum(sw, 1e-12)[..., None] * cw[..., None], cw)
    up = _upsample(coarse, H, W)
    return pc + (1.0 - w)[..., None] * up


def _upsample(a, H, W):
    """Bilinear upsampling of (h, w, C) to (H, W, C), texel centres aligned (2x)."""
    h, w = a.shape[:2]
    y = np.clip((np.arange(H) + 0.5) / 2 - 0.5, 0, h - 1)
    x = np.clip((np.arange(W) + 0.5) / 2 - 0.5, 0, w - 1)
    y0, x0 = np.floor(y).astype(int), np.floor(x).astype(int)
    y1, x1 = np.minimum(y0 + 1, h - 1), np.minimum(x0 + 1, w - 1)
    fy, fx = (y - y0)[:, None, None], (x - x0)[None, :, None]
    top = a[y0][:, x0] * (1 - fx) + a[y0][:, x1] * fx
    bottom = a[y1][:, x0] * (1 - fx) + a[y1][:, x1] * fx
    return top * (1 - fy) + bottom * fy


def save_texture(texture, path, confidence_path=None):
    """Write ``texture.image`` as an 8-bit RGB PNG (atomically), and its confidence as an
    8-bit grey PNG (0-255 for cosine 0-1) when ``confidence_path`` is given. Returns ``path``."""
    from pathlib import Path

    from .raster import save_image_png

    save_image_png(path, texture.image)
    if confidence_path is not None:
        save_image_png(confidence_path, np.repeat(texture.confidence[..., None], 3, -1))
    return Path(path)
