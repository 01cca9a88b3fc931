"""A Wavefront OBJ reader that keeps vertex order and polygon/UV indexing exactly as written.

Model files need their vertex ids preserved (landmark ids, bases and blendshapes index
them), which general mesh loaders do not promise once UV seams split vertices. Scans and
other meshes go through trimesh (:mod:`morphable.io.mesh`).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["ObjMesh", "read_obj", "read_obj_vertices"]


@dataclass
class ObjMesh:
    """vertices (V, 3); triangles (F, 3) fan-triangulated; uv (T, 2) or None;
    triangle_uv (F, 3) or None; polygons (P, n) -1 padded, as in the file."""

    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray | None
    triangle_uv: np.ndarray | None
    polygons: np.ndarray


def _lines(path: Path) -> list[str]:
    try:
        return path.read_text(errors="replace").splitlines()
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None


def _floats(path: Path, rows: list[str], width: int, what: str) -> np.ndarray:
    try:
        a = np.array([r.split()[1:width + 1] for r in rows], dtype=np.float64)
    except ValueError:
        raise InputError(f"{path}: malformed {what} line") from None
    if a.ndim != 2 or a.shape[1] != width:
        raise InputError(f"{path}: {what} lines need {width} numbers")
    if not np.isfinite(a).all():
        raise InputError(f"{path}: {what} coordinates contain NaN or inf")
    return a


def read_obj_vertices(path) -> np.ndarray:
    """Only the ``v`` lines of an OBJ -> (V, 3) float64 (fast path for blendshape folders)."""
    path = Path(path)
    rows = [ln for ln in _lines(path) if ln.startswith("v ")]
    if not rows:
        raise InputError(f"{path}: no vertices")
    return _floats(path, rows, 3, "vertex")


def read_obj(path) -> ObjMesh:
    """Read vertices, UVs and polygons of an OBJ; polygons are fan-triangulated."""
    path = Path(path)
    lines = _lines(path)
    v_rows = [ln for ln in lines if ln.startswith("v ")]
    vt_rows = [ln for ln in lines if ln.startswith("vt ")]
    f_rows = [ln.split()[1:] for ln in lines if ln.startswith("f ")]
    if not v_rows or not f_rows:
        raise InputError(f"{path}: an OBJ mesh needs vertices and faces")
    vertices = _floats(path, v_rows, 3, "vertex")
    uv = _floats(path, vt_rows, 2, "texture coordinate") if vt_rows else None
    width = max(len(f) for f in f_rows)
    poly = np.full((len(f_rows), width), -1, dtype=np.int64)
    poly_uv = np.full_like(poly, -1)
    try:
        for i, f in enumerate(f_rows):
            for j, corner in enumerate(f):
                parts = corner.split("/")
                poly[i, j] = int(parts[0])
                if len(parts) > 1 and parts[1]:
                    poly_uv[i, j] = int(parts[1])
    except ValueError:
        raise InputError(f"{path}: malformed face line {i + 1}") from None
    counts = (poly != -1).sum(1)
    if counts.min() < 3:
        raise InputError(f"{path}: a face has fewer than 3 corners")
    # OBJ is 1-based; negative ids count back from the end
    for a, n in ((poly, len(vertices)), (poly_uv, 0 if uv is None else len(uv))):
        neg = a < -1
        a[a > 0] -= 1
        a[neg] += n + 1
        if (a >= n).any():
            raise InputError(f"{path}: face refers to a missing vertex or texture coordinate")
    tris, tri_uv = [], []
    for k in range(1, width - 1):
        use = counts > k + 1
        tris.append(np.stack([poly[use, 0], poly[use, k], poly[use, k + 1]], 1))
        tri_uv.append(np.stack([poly_uv[use, 0], poly_uv[use, k], poly_uv[use, k + 1]], 1))
    # keep each polygon's fan triangles together, in file order
    order = np.argsort(np.concatenate([np.flatnonzero(counts > k + 1) for k in range(1, width - 1)]),
                       kind="stable")
    triangles = np.concatenate(tris)[order]
    triangle_uv = np.concatenate(tri_uv)[order]
    has_uv = uv is not None and (triangle_uv >= 0).all()
    return ObjMesh(vertices, triangles, uv if has_uv else None, triangle_uv if has_uv else None, poly)
