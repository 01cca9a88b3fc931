"""Landmark files: iBUG ``.pts`` (2D, 1-based pixels) and menpo ``.ljson`` (2D or 3D).

Image coordinates in the toolkit: x right, y down, 0-based, the centre of the top-left pixel
at (0, 0). ``.pts`` files are 1-based, so reading subtracts 1 and writing adds 1.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_path

__all__ = ["read_pts", "write_pts", "read_ljson", "write_ljson"]


def read_pts(path) -> np.ndarray:
    """Read an iBUG ``.pts`` file -> (N, 2) float64 pixel coordinates, 0-based.

    Examples
    --------
    >>> points = read_pts("../shared/data/images/image_0010.pts")   # its first row: 611.284152 272.773913
    >>> points.shape, points[0].round(6).tolist()
    ((68, 2), [610.284152, 271.773913])
    """
    path = Path(path)
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    head, _, rest = text.partition("{")
    body, close, _ = rest.partition("}")
    if not close:
        raise InputError(f"{path}: not a .pts file (no {{ ... }} block)")
    n = None
    for line in head.splitlines():
        key, _, value = line.partition(":")
        if key.strip() == "n_points":
            try:
                n = int(value)
            except ValueError:
                raise InputError(f"{path}: bad n_points line") from None
    try:
        pts = np.array([[float(x) for x in ln.split()] for ln in body.splitlines() if ln.strip()])
    except ValueError:
        raise InputError(f"{path}: non-numeric coordinates") from None
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"{path}: expected 'x y' per line")
    if n is not None and n != len(pts):
        raise InputError(f"{path}: header says {n} points, file has {len(pts)}")
    if not np.isfinite(pts).all():
        raise InputError(f"{path}: coordinates contain NaN or inf")
    return pts - 1.0


def write_pts(path, points) -> None:
    """Write (N, 2) 0-based pixel coordinates as a 1-based iBUG ``.pts`` file (atomically)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or not np.isfinite(pts).all():
        raise InputError(f"{path}: need finite (N, 2) points, got shape {pts.shape}")
    lines = ["version: 1", f"n_points: {len(pts)}", "{"]
    lines += [f"{x + 1:.6f} {y + 1:.6f}" for x, y in pts] + ["}"]
    with atomic_path(path) as tmp:
        tmp.write_text("\n".join(lines) + "\n")


def read_ljson(path) -> tuple[np.ndarray, dict]:
    """Read a menpo ``.ljson`` (versions 1-3; the first group of v3 files).

    Returns
    -------
    points : (N, D) float64, D = 2 or 3; NaN rows where a point is null.
        2D menpo points are (y, x); they are returned as (x, y) pixels.
    labels : dict of str to (n,) int array
        Label name -> point indices (e.g. ``chin``, ``leye``, ``mouth``).
    """
    path = Path(path)
    try:
        d = json.loads(path.read_text())
        if d.get("version") == 3 or "groups" in d:
            d = next(iter(d["groups"].values()))
        pts = d["landmarks"]["points"]
        labels = {lab["label"]: np.asarray(lab["mask"], dtype=np.int64) for lab in d.get("labels", [])}
        arr = np.array([[math.nan if c is None else float(c) for c in p] for p in pts], dtype=np.float64)
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    except (ValueError, KeyError, TypeError, StopIteration, AttributeError) as e:
        raise InputError(f"{path}: not a menpo landmark file ({type(e).__name__}: {e})") from None
    if arr.ndim != 2 or arr.shape[1] not in (2, 3) or len(arr) == 0:
        raise InputError(f"{path}: points must be a non-empty list of 2D or 3D points")
    if np.isinf(arr).any():
        raise InputError(f"{path}: coordinates contain inf")
    for name, mask in labels.items():
        if mask.size and (mask.min() < 0 or mask.max() >= len(arr)):
            raise InputError(f"{path}: label {name!r} refers to a missing point")
    if arr.shape[1] == 2:
        arr = arr[:, ::-1].copy()
    return arr, labels


def write_ljson(path, points, labels: dict | None = None) -> None:
    """Write (N, 2) pixel (x, y) or (N, 3) points as a menpo v2 ``.ljson`` (atomically)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3):
        raise InputError(f"{path}: need (N, 2) or (N, 3) points, got shape {pts.shape}")
    if pts.shape[1] == 2:
        pts = pts[:, ::-1]
    doc = {
        "version": 2,
        "landmarks": {"points": [[None if not np.isfinite(c) else float(c) for c in p] for p in pts],
                      "connectivity": []},
        "labels": [{"label": k, "mask": [int(i) for i in v]} for k, v in (labels or {}).items()],
    }
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(doc))
