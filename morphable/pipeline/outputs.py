"""What a fit writes: the mesh, the JSON report, the UV texture, the overlays and a
refinement's render, all or nothing.

:func:`check_output_paths` fails before any work when an output cannot be written;
:func:`write_outputs` checks again, then writes each file atomically and, should one fail (or
the texture or an overlay fail to be made), removes those it wrote.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["check_output_paths", "write_outputs", "MESH_KINDS", "check_mesh_kind", "albedo_texture", "resize_texture",
           "paint_mask", "mask_in_photo"]


MESH_KINDS = ("neutral", "expressive")
"""What a fit's mesh file holds: the person's identity without expression, or each frame's
face with its expression."""


def check_mesh_kind(kind: str) -> None:
    """InputError unless ``kind`` is one of :data:`MESH_KINDS`."""
    if kind not in MESH_KINDS:
        raise InputError(f"mesh kind must be one of {', '.join(MESH_KINDS)}, got {kind!r}")


def check_output_paths(mesh=None, report=None, texture=None, overlay=None,
                       refine_render=None) -> None:
    """InputError naming the output that cannot be written: its folder missing, a mesh suffix
    :func:`morphable.io.mesh.write_mesh` does not write, a texture or refinement render that is
    not a .png, an overlay that is not a .png/.jpg, or an .obj mesh whose material library
    cannot name the texture (a path with spaces). None: not written."""
    from ..io.mesh import mesh_format, mtl_texture_reference
    from ..overlay import check_overlay_path
    from ..raster.png import check_png_path

    if overlay:
        check_overlay_path(overlay)
    for path in (texture, refine_render):
        if path:
            check_png_path(path)
    if mesh and texture and mesh_format(mesh) == "obj":
        mtl_texture_reference(mesh, texture)
    for path in (mesh, report):
        if path and not Path(path).resolve().parent.is_dir():
            raise InputError(f"{path}: folder {Path(path).resolve().parent} does not exist")
    if mesh:
        mesh_format(mesh)


def write_outputs(result, mesh=None, report=None, texture=None, overlay=None, *,
                  texture_size: int = 512, overlay_style: str | None = "shaded",
                  overlay_crop: float | None = None, refine_render=None,
                  mesh_kind: str = "neutral", overlay_mask: bool = False,
                  albedo: bool = True) -> list:
    """Write what :meth:`morphable.pipeline.ImageFit.write` writes (see there); returns the
    paths written."""
    from ..io.atomic import all_or_nothing, atomic_path

    check_output_paths(mesh, report, texture, overlay, refine_render)
    check_mesh_kind(mesh_kind)
    fit = result.fit
    if refine_render and not result.refinements:
        raise InputError(f"{refine_render}: the fit was not refined, so there is no render of it")
    if overlay_mask and not result.refinements:
        raise InputError(f"{overlay}: the fit was not refined, so there is no photometric mask "
                         "to draw")
    recovered = albedo_texture(result) if albedo else None
    if texture and fit.model.uv is None:
        raise InputError(f"{fit.model.name}: the model has no UV coordinates, so a texture "
                         "cannot be written")
    content = dict(result.report)
    written = []
    with all_or_nothing(written):
        if refine_render:
            from ..raster import save_image_png

            state = result.refinements[0]
            written.append(Path(save_image_png(refine_render, np.concatenate([state.target, state.rendered], 1))))
        if overlay:  # first: drawing is the likeliest step to fail
            from ..overlay import overlay_paths, save_overlay

            paths = overlay_paths(overlay, fit.n_frames)
            for i, (path, image) in enumerate(zip(paths, result.images())):
                if overlay_mask:
                    image = paint_mask(image, result.refinements[i])
                written.append(save_overlay(path, image, fit, i, mesh=overlay_style, crop=overlay_crop))
            content["overlays"] = [str(p) for p in paths]
        uv, tuv = fit.model.uv, fit.model.triangle_uv
        tex = None
        if texture and recovered is not None:
            from ..raster import save_image_png

            written.append(Path(save_image_png(texture, resize_texture(recovered, texture_size))))
            tex = recovered                 # the model's own UVs go with it
            content["texture"] = {"path": str(texture), "size": texture_size,
                                  "kind": "albedo (photometric refinement)"}
        elif texture:
            from ..texture import extract_texture, save_texture

            tex = extract_texture(fit, result.images(), size=texture_size)
            written.append(save_texture(tex, texture))
            uv, tuv = tex.uv, tex.triangle_uv
            content["texture"] = {"path": str(texture), "size": texture_size, "kind": "photo",
                                  "observed": float(tex.observed[tex.layout].mean()),
                                  "mirrored": float(tex.mirrored[tex.layout].mean()),
                                  "runtime_ms": tex.runtime_ms}
        if mesh:
            from ..io.mesh import write_mesh

            from ..overlay import overlay_paths

            material = texture if tex is not None and Path(mesh).suffix.lower() == ".obj" else None
            if mesh_kind == "neutral":
                meshes = [(mesh, write_mesh(mesh, result.mesh_vertices(), fit.model.triangles, uv, tuv,
                                            texture=material))]
            else:
                meshes = [(path, write_mesh(path, v, fit.model.triangles, uv, tuv, texture=material))
                          for path, v in zip(overlay_paths(mesh, fit.n_frames),
                                             result.mesh_vertices(mesh_kind))]
            for path, done in meshes:
                written.append(done)
                if material:
                    written.append(Path(path).with_suffix(".mtl"))
            content["mesh"] = {"kind": mesh_kind, "paths": [str(p) for p, _ in meshes]}
        if report:
            with atomic_path(report) as tmp:
                Path(tmp).write_text(json.dumps(content, indent=2))
            written.append(Path(report))
    return [Path(p) for p in written]


def albedo_texture(result):
    """(S, S, 3) float in [0, 1]: the albedo texture a photometric refinement recovered (in
    the model's own UV layout), or None when the fit was not refined so."""
    states = getattr(result, "refinements", None) or []
    tex = states[0].appearance.get("texture") if states else None
    return None if tex is None else np.clip(tex[0].double().numpy(), 0.0, 1.0)


def resize_texture(image, size: int) -> np.ndarray:
    """(S, S, 3) float [0, 1] -> (size, size, 3), bilinear."""
    from PIL import Image

    planes = [np.asarray(Image.fromarray(np.ascontiguousarray(image[..., c], dtype=np.float32))
                         .resize((size, size), Image.BILINEAR)) for c in range(3)]
    return np.clip(np.stack(planes, -1), 0.0, 1.0)


def paint_mask(image, state) -> np.ndarray:
    """A photo (path or array) with the face pixels its refinement's photometric mask
    (:func:`mask_in_photo`) weighs under 0.5 tinted red -> (H, W, 3) uint8."""
    from ..detection.images import as_image

    photo = as_image(image)[0].astype(np.float64)
    face, kept = mask_in_photo(state, photo.shape[:2])
    out = (face * (kept < 0.5))[..., None]
    photo = photo * (1 - 0.6 * out) + out * 0.6 * np.array([255.0, 0, 0])
    return np.clip(np.round(photo), 0, 255).astype(np.uint8)


def mask_in_photo(state, shape) -> tuple[np.ndarray, np.ndarray]:
    """A refinement's crop-sized mask carried to its photo's pixels (nearest crop pixel).

    Parameters
    ----------
    state : :class:`~morphable.refinement.Refinement` (``mask``, ``coverage`` (R, R) over the
        crop ``crop`` = (left, top, side) px)
    shape : (H, W) of the photo

    Returns
    -------
    face : (H, W) float, 1 where the fitted face covers over half the crop pixel, else 0
    kept : (H, W) float in [0, 1], the mask's weight (0 outside the crop)
    """
    H, W = shape
    left, top, side = state.crop
    R = state.mask.shape[0]
    ys, xs = np.mgrid[0:H, 0:W]
    i = np.floor((ys + 0.5 - top) * R / side).astype(int)
    j = np.floor((xs + 0.5 - left) * R / side).astype(int)
    inside = (i >= 0) & (i < R) & (j >= 0) & (j < R)
    face = np.zeros((H, W))
    kept = np.zeros((H, W))
    face[inside] = state.coverage[i[inside], j[inside]] > 0.5
    kept[inside] = state.mask[i[inside], j[inside]]
    return face, kept
