"""Shaded images: Lambertian surfaces with vertex colours or a texture, under SH or
directional light, with optional cast shadows, over a background colour or image.

Smooth shading: normals are vertex normals interpolated per sample (camera frame), lights are
given in the camera frame (they move with the camera, which suits turntable videos).
"""
from __future__ import annotations

import numpy as np

from ..arrays import is_torch
from ..errors import InputError
from .interpolate import interpolate
from .normal_maps import sample_normals
from .shading import DirectionalLight, shade_directional, shade_sh
from .texture import as_texture, sample_texture
from .visibility import cast, check_mesh, scene, visibility

__all__ = ["render", "DEFAULT_LIGHT", "DEFAULT_AMBIENT"]

DEFAULT_LIGHT = DirectionalLight(direction=(0.4, 0.5, 1.0), color=(0.75, 0.75, 0.75))
"""The light of :func:`render` when none is given (camera frame, +z towards the viewer)."""
DEFAULT_AMBIENT = 0.3
_GREY = (0.75, 0.75, 0.75)


def _is_sh(light) -> bool:
    if light is None or isinstance(light, DirectionalLight):
        return False
    if is_torch(light):
        return True
    if isinstance(light, (list, tuple)) and light and isinstance(light[0], DirectionalLight):
        return False
    a = np.asarray(light)
    if a.dtype.kind not in "fiu" or a.shape[-2:] != (9, 3) and a.shape != (9,):
        raise InputError("light must be SH coefficients (9,) / (9, 3), a DirectionalLight or "
                         f"a list of them, got {type(light).__name__} {getattr(a, 'shape', '')}")
    return True


def _background(background, vis, like):
    """(Hs, Ws, 3) background samples, numpy float."""
    Hs, Ws = vis.shape
    s = vis.supersample
    path_like = isinstance(background, (str, bytes)) or hasattr(background, "__fspath__")
    b = None if path_like else np.asarray(background)
    if b is not None and b.ndim <= 1:
        try:
            b = np.asarray(b, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise InputError(f"background must be a colour or an image, got {background!r}") from None
        if b.size != 3 or not np.isfinite(b).all():
            raise InputError(f"background colour must be 3 numbers in [0, 1], got {background}")
        return np.broadcast_to(b.astype(like), (Hs, Ws, 3))
    img = as_texture(background)
    if img.shape[:2] != vis.image_shape:
        raise InputError(f"background image is {img.shape[1]}x{img.shape[0]}, the camera image "
                         f"{vis.image_shape[1]}x{vis.image_shape[0]}")
    return np.repeat(np.repeat(img, s, 0), s, 1).astype(like)


def _shadow_mask(v, t, vis, light_dirs_world, normals_world):
    """(L, N) float: 1 where foreground sample n sees light l (no occluder towards it);
    ``normals_world`` (N, 3) are the samples' normals."""
    sc = scene(v, t)
    p = interpolate(vis, v, foreground=True)
    ng = normals_world
    eps = 1e-3 * float(np.linalg.norm(v.max(0) - v.min(0)))
    out = np.ones((len(light_dirs_world), len(p)))
    for i, d in enumerate(light_dirs_world):
        # start a little off the surface on the lit side to avoid hitting the own triangle
        side = np.where((ng @ d)[:, None] >= 0, ng, -ng)
        origins = p + eps * (side + d)
        t_hit, _, _ = cast(sc, np.concatenate([origins, np.broadcast_to(d, origins.shape)], -1))
        out[i] = ~np.isfinite(t_hit)
    return out


def render(vertices, triangles, camera=None, colors=None, texture=None, light=None,
           ambient=DEFAULT_AMBIENT, background=(1.0, 1.0, 1.0), shadows: bool = False,
           supersample: int = 1, vis=None, weighting: str = "area"):
    """Render a Lambertian mesh.

    Parameters
    ----------
    vertices : (V, 3) float, mm (or torch (V, 3), see Notes)
    triangles : (F, 3) int
    camera : morphable.camera.Camera (or None when ``vis`` is given)
    colors : (V, 3) float in [0, 1] or uint8, or (3,) one colour; default light grey
    texture : (uv (T, 2), triangle_uv (F, 3) or None, image (h, w, 3) or a path), optional
        Albedo from a texture through UVs (v up); takes precedence over ``colors``. A torch
        image (h, w, 3) in [0, 1] gets gradients (torch vertices).
    light : None, SH coefficients (9,) / (9, 3), a DirectionalLight or a list of them
        Directions in the camera frame (+z towards the viewer). None: one light from the
        upper right front (:data:`DEFAULT_LIGHT`) plus ``ambient``.
    ambient : float or (3,)
        Added to directional lights (ignored for SH, whose first coefficient is ambient).
    background : (3,) colour in [0, 1], or an (H, W, 3) image / path of the camera's size
    shadows : bool
        Cast shadows of directional lights (one shadow ray per lit sample).
    supersample : int
        Antialiasing: samples per pixel along each axis, box-filtered.
    vis : Visibility or None
        Reuse a visibility (its supersampling applies).

    Returns
    -------
    (H, W, 3) float in [0, 1] (numpy; torch in, torch out).

    Notes
    -----
    Torch vertices (and torch ``colors``, texture image or SH ``light``) give a
    differentiable image with the visibility fixed: the classical differentiable renderer.
    Cast shadows are numpy-only.

    Examples
    --------
    >>> from morphable.camera import Camera
    >>> sq = np.array([[-50., -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]])
    >>> img = render(sq, [[0, 1, 2], [0, 2, 3]], Camera.looking_at_face((32, 32)),
    ...              colors=(1.0, 0.5, 0.5), light=[1, 0, 0, 0, 0, 0, 0, 0, 0], background=(0, 0, 0))
    >>> img[16, 16], img[0, 0]
    (array([1. , 0.5, 0.5]), array([0., 0., 0.]))
    """
    torch_in = is_torch(vertices)
    if vis is None:
        if camera is None:
            raise InputError("render needs a camera or a visibility")
        v_np = vertices.detach().cpu().numpy() if torch_in else vertices
        v_np, t = check_mesh(v_np, triangles)
        vis = visibility(v_np, t, camera, supersample)
    else:
        v_np, t = check_mesh(vertices.detach().cpu().numpy() if torch_in else vertices, triangles)
    like = np.float64 if torch_in else np.result_type(v_np.dtype, np.float32)
    if torch_in:
        import torch

        if vertices.ndim != 2:
            raise InputError("render takes one mesh (V, 3); batch with a loop or use "
                             "interpolate/shade_sh directly")
        tri = torch.as_tensor(t, device=vertices.device)
        # shading runs on the foreground samples only; the background is composited after
        n = sample_normals(vertices, tri, vis, foreground=True)

        def as_xp(a):
            return torch.as_tensor(np.array(a), dtype=vertices.dtype, device=vertices.device)
    else:
        n = sample_normals(v_np, t, vis, foreground=True)

        def as_xp(a):
            return np.asarray(a, dtype=like)

    # albedo per sample
    if texture is not None:
        try:
            uv, tuv, image = texture
        except (TypeError, ValueError):
            raise InputError("texture must be (uv, triangle_uv, image)") from None
        uv = np.asarray(uv, dtype=np.float64)
        tuv = t if tuv is None else np.asarray(tuv, dtype=np.int64)
        if uv.ndim != 2 or uv.shape[1] != 2 or tuv.shape != t.shape or tuv.max() >= len(uv):
            raise InputError(f"texture uv must be (T, 2) with triangle_uv {t.shape} ids into it")
        if not np.isfinite(uv).all():
            raise InputError("texture uv contain NaN or inf")
        uv_samples = interpolate(vis, uv, tuv, foreground=True)
        if is_torch(image):  # a differentiable texture (torch (h, w, 3) in [0, 1])
            albedo = sample_texture(image, as_xp(uv_samples))
        else:
            albedo = as_xp(sample_texture(as_texture(image), uv_samples))
    elif colors is None:
        albedo = as_xp(_GREY)
    elif is_torch(colors):
        albedo = interpolate(vis, colors, foreground=True) if colors.ndim == 2 else colors
    else:
        c = np.asarray(colors)
        c = c / 255.0 if c.dtype == np.uint8 else c.astype(np.float64)
        if not np.isfinite(c).all():
            raise InputError("colors contain NaN or inf")
        if c.shape == (3,):
            albedo = as_xp(c)
        elif c.ndim == 2 and c.shape[0] == len(v_np) and c.shape[1] in (3, 4):
            albedo = as_xp(interpolate(vis, c[:, :3], foreground=True))
        else:
            raise InputError(f"colors must be (V, 3) per vertex or (3,), got {c.shape}")

    if _is_sh(light):
        shaded = shade_sh(n, albedo, light)
    else:
        lights = [DEFAULT_LIGHT] if light is None else (
            [light] if isinstance(light, DirectionalLight) else list(light))
        visible = None
        if shadows:
            if torch_in:
                raise InputError("shadows are numpy-only")
            R = vis.camera.rotation
            nw = sample_normals(v_np, t, vis, frame="world", foreground=True)
            visible = _shadow_mask(v_np, t, vis, [R.T @ lt.direction for lt in lights], nw)
        shaded = shade_directional(n, albedo, lights, ambient, visible)
    bg = _background(background, vis, like).reshape(-1, 3)
    if torch_in:
        samples = as_xp(bg).index_copy(0, torch.as_tensor(vis.pixels), shaded)
    else:
        samples = np.array(bg)
        samples[vis.pixels] = shaded
    image = vis.downsample(samples.reshape(tuple(vis.shape) + (3,)))
    return image.clamp(0, 1) if torch_in else np.clip(image, 0.0, 1.0)
