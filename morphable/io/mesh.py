"""Mesh files: export (OBJ with UVs written here; PLY, STL... through trimesh) and reading of
scans (trimesh)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_path

__all__ = ["write_mesh", "obj_text", "read_mesh", "uv_unwelded", "mtl_texture_reference", "mesh_format",
           "MESH_FORMATS"]

MESH_FORMATS = ("obj", "ply", "stl", "off", "glb", "gltf")
"""The formats :func:`write_mesh` writes, by file suffix."""


def uv_unwelded(vertices, triangles, uv, triangle_uv):
    """Split vertices along UV seams so that each output vertex has one UV (OBJ/PLY need it).

    ``vertices`` (V, 3), ``triangles`` (F, 3), ``uv`` (T, 2), ``triangle_uv`` (F, 3) ->
    (vertices (V', 3), triangles (F, 3), uv (V', 2)) with one UV per vertex."""
    pairs = np.stack([triangles.ravel(), triangle_uv.ravel()], 1)
    unique, inverse = np.unique(pairs, axis=0, return_inverse=True)
    return vertices[unique[:, 0]], inverse.reshape(-1, 3), uv[unique[:, 1]]


def write_mesh(path, vertices, triangles, uv=None, triangle_uv=None, vertex_colors=None,
               texture=None) -> Path:
    """Write a triangle mesh; the format follows the suffix (.obj, .ply, .stl, .off, .glb).

    Parameters
    ----------
    vertices : (V, 3) float, mm
    triangles : (F, 3) int
    uv : (V, 2) or (T, 2) float in [0, 1], optional
    triangle_uv : (F, 3) int ids into ``uv`` when UVs are not per vertex
    vertex_colors : (V, 3) or (V, 4) uint8 or float in [0, 1], optional
    texture : path of a texture image, optional (OBJ with ``uv`` only): the OBJ names a
        material library ``NAME.mtl``, written beside it, whose material maps this image
        (``map_Kd``, a path relative to the OBJ's folder), so that viewers and
        ``morphable render`` draw it

    The file is written atomically; with per-triangle UVs, vertices on UV seams are
    duplicated (vertex order then differs from the model's). An OBJ without vertex colours is
    written here (:func:`obj_text`, the lines trimesh writes), the rest through trimesh,
    whose import (scipy's with it, about a second) a fit's OBJ does without.
    """
    path = Path(path)
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(triangles, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) == 0:
        raise InputError(f"{path}: vertices must be a non-empty (V, 3) array")
    if not np.isfinite(v).all():
        raise InputError(f"{path}: vertices contain NaN or inf; nothing written")
    if uv is not None:
        uv = np.asarray(uv, dtype=np.float64)
        if triangle_uv is not None:
            v, f, uv = uv_unwelded(v, f, uv, np.asarray(triangle_uv))
    suffix = mesh_format(path)
    if texture is not None and (suffix != "obj" or uv is None):
        raise InputError(f"{path}: a texture needs an .obj mesh with UV coordinates")
    with atomic_path(path) as tmp:
        if suffix == "obj" and vertex_colors is None:
            text = obj_text(v, f, uv)
            if texture is not None:
                mtl = path.with_suffix(".mtl")
                _write_mtl(mtl, texture)
                first_face = text.index("\nf ") + 1
                text = f"mtllib {mtl.name}\n" + text[:first_face] + "usemtl face\n" + text[first_face:]
            tmp.write_text(text)
        else:
            import trimesh

            visual = None if uv is None else trimesh.visual.TextureVisuals(uv=uv)
            mesh = trimesh.Trimesh(v, f, visual=visual, process=False)
            if vertex_colors is not None and visual is None:
                mesh.visual.vertex_colors = vertex_colors
            if suffix == "obj":
                tmp.write_text(trimesh.exchange.obj.export_obj(mesh, include_texture=True,
                                                               include_normals=False))
            else:
                mesh.export(tmp, file_type=suffix)
    return path


def mesh_format(path) -> str:
    """The format :func:`write_mesh` writes to ``path`` (its suffix, lower case, without the
    dot), or an InputError naming the file when it writes none by that suffix."""
    path = Path(path)
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in MESH_FORMATS:
        raise InputError(f"{path}: unknown mesh format {path.suffix!r} (.obj .ply .stl .off .glb)")
    return suffix


def obj_text(vertices, triangles, uv=None) -> str:
    """Wavefront OBJ text of a mesh: ``v`` lines (8 decimals), ``vt`` lines where ``uv`` (V, 2)
    gives one per vertex, ``f`` lines (1-based, ``i/i`` with UVs) -- the lines of trimesh's
    ``export_obj``, without its header and material lines.

    >>> print(obj_text(np.eye(3), [[0, 1, 2]]), end="")
    v 1.00000000 0.00000000 0.00000000
    v 0.00000000 1.00000000 0.00000000
    v 0.00000000 0.00000000 1.00000000
    f 1 2 3
    """
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(triangles, dtype=np.int64) + 1
    parts = [("v %.8f %.8f %.8f\n" * len(v)) % tuple(v.ravel())]
    if uv is not None:
        uv = np.asarray(uv, dtype=np.float64)
        parts.append(("vt %.8f %.8f\n" * len(uv)) % tuple(uv.ravel()))
        parts.append(("f %d/%d %d/%d %d/%d\n" * len(f)) % tuple(np.repeat(f.ravel(), 2)))
    else:
        parts.append(("f %d %d %d\n" * len(f)) % tuple(f.ravel()))
    return "".join(parts)


def mtl_texture_reference(mesh_path, texture) -> str:
    """The name by which the ``.mtl`` beside ``mesh_path`` refers to ``texture``: its path
    relative to the mesh's folder, POSIX style. InputError naming the texture when that path
    holds white space, which .mtl files cannot name (call it before writing anything)."""
    import os

    rel = Path(os.path.relpath(Path(texture).resolve(), Path(mesh_path).resolve().parent)).as_posix()
    if any(c.isspace() for c in rel):
        raise InputError(f"{texture}: a texture path with spaces cannot be named in an .mtl file")
    return rel


def _write_mtl(path: Path, texture) -> None:
    """A material library with one material ``face`` whose diffuse map is ``texture``
    (relative to the library's folder, where the OBJ is)."""
    rel = mtl_texture_reference(path, texture)
    with atomic_path(path) as tmp:
        tmp.write_text(f"newmtl face\nKa 1 1 1\nKd 1 1 1\nKs 0 0 0\nd 1\nillum 1\n"
                       f"map_Kd {rel}\n")


def read_mesh(path):
    """Read a mesh file -> trimesh.Trimesh (vertex order kept, no merging).

    Raises InputError naming the file for unreadable files and empty meshes.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such file")
    try:
        mesh = trimesh.load(path, force="mesh", process=False, maintain_order=True)
    except Exception as e:  # trimesh raises many types for bad files
        raise InputError(f"{path}: cannot read mesh ({type(e).__name__}: {e})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.vertices) == 0 or len(mesh.faces) == 0:
        raise InputError(f"{path}: empty mesh (no triangles)")
    if not np.isfinite(mesh.vertices).all():
        raise InputError(f"{path}: vertices contain NaN or inf")
    return mesh
