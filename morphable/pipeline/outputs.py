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

__all__ = ["check_output_paths", "write_outputs"]


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
                  overlay_crop: float | None = None, refine_render=None) -> list:
    """Write what :meth:`morphable.pipeline.ImageFit.write` writes (see there); returns the
    paths written."""
    from ..io.atomic import atomic_path

    check_output_paths(mesh, report, texture, overlay, refine_render)
    fit = result.fit
    if refine_render and not result.refinements:
        raise InputError(f"{refine_render}: the fit was not refined, so there is no render of it")
    if texture and fit.model.uv is None:
        raise InputError(f"{fit.model.name}: the model has no UV coordinates, so a texture "
                         "cannot be written")
    content = dict(result.report)
    written = []
    try:
        if refine_render:
            from ..raster import save_image_png

            state = result.refinements[0]
            written.append(Path(save_image_png(refine_render, np.concatenate([state.target, state.rendered], 1))))
        if overlay:  # first: drawing is the likeliest step to fail
            from ..overlay import overlay_paths, save_overlay

            paths = overlay_paths(overlay, fit.n_frames)
            for i, (path, image) in enumerate(zip(paths, result.images())):
                written.append(save_overlay(path, image, fit, i, mesh=overlay_style, crop=overlay_crop))
            content["overlays"] = [str(p) for p in paths]
        uv, tuv = fit.model.uv, fit.model.triangle_uv
        tex = None
        if texture:
            from ..texture import extract_texture, save_texture

            tex = extract_texture(fit, result.images(), size=texture_size)
            written.append(save_texture(tex, texture))
            uv, tuv = tex.uv, tex.triangle_uv
            content["texture"] = {"path": str(texture), "size": texture_size,
                                  "observed": float(tex.observed[tex.layout].mean()),
                                  "mirrored": float(tex.mirrored[tex.layout].mean()),
                                  "runtime_ms": tex.runtime_ms}
        if mesh:
            from ..io.mesh import write_mesh

            material = texture if tex is not None and Path(mesh).suffix.lower() == ".obj" else None
            written.append(write_mesh(mesh, result.mesh_vertices(), fit.model.triangles, uv, tuv,
                                      texture=material))
            if material:
                written.append(Path(mesh).with_suffix(".mtl"))
        if report:
            with atomic_path(report) as tmp:
                Path(tmp).write_text(json.dumps(content, indent=2))
            written.append(Path(report))
    except BaseException:
        # all or nothing: a mesh without its report (or a report naming overlays that are not
        # there) would pass for a finished fit
        for path in written:
            Path(path).unlink(missing_ok=True)
        raise
    return [Path(p) for p in written]
