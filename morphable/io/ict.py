"""Readers for the ICT FaceKit model (USC ICT, MIT licence): the packed ``ict_face_model.npz``
and the original folder of OBJ files (``generic_neutral_mesh.obj``, ``identityNNN.obj``,
one OBJ per expression). ICT stores centimetres; models come out in millimetres.
"""
from __future__ import annotations

import re
import zipfile
from pathlib import Path

import numpy as np

from ..errors import InputError
from .obj import read_obj, read_obj_vertices

__all__ = ["load_ict_npz", "load_ict_folder", "ICT_LANDMARKS_IBUG68", "ICT_SEGMENTS"]

CM_TO_MM = 10.0

# Multi-PIE / iBUG 68 landmark vertices, from the ICT-FaceKit README (0-based).
ICT_LANDMARKS_IBUG68 = np.array([
    1225, 1888, 1052, 367, 1719, 1722, 2199, 1447, 966, 3661, 4390, 3927, 3924, 2608, 3272, 4088,
    3443, 268, 493, 1914, 2044, 1401, 3615, 4240, 4114, 2734, 2509, 978, 4527, 4942, 4857, 1140,
    2075, 1147, 4269, 3360, 1507, 1542, 1537, 1528, 1518, 1511, 3742, 3751, 3756, 3721, 3725, 3732,
    5708, 5695, 2081, 0, 4275, 6200, 6213, 6346, 6461, 5518, 5957, 5841, 5702, 5711, 5533, 6216,
    6207, 6470, 5517, 5966], dtype=np.int64)

# Vertex ranges [start, stop) of the geometries, from the ICT-FaceKit README.
ICT_SEGMENTS = {
    "face": (0, 9409), "narrow_face": (0, 6706), "head_neck": (9409, 11248),
    "mouth_socket": (11248, 13294), "eye_socket_left": (13294, 13678),
    "eye_socket_right": (13678, 14062), "gums_tongue": (14062, 17039), "teeth": (17039, 21451),
    "eyeball_left": (21451, 23021), "eyeball_right": (23021, 24591), "eyelashes": (25351, 26719),
}


def _segments(n_vertices: int) -> dict:
    return {k: np.arange(a, b) for k, (a, b) in ICT_SEGMENTS.items() if b <= n_vertices}


def load_ict_npz(path, name: str = "ict"):
    """Load the packed ICT FaceKit npz (keys ``mean``, ``identity_basis``, ``expression_basis``,
    ``expression_names``, ``triangles``, ``uv``, ``triangle_uv_index``, ``landmarks_ibug68``).

    Returns
    -------
    MorphableModel in millimetres (identity coefficients ~ N(0, 1), expression weights in [0, 1]).
    """
    from ..model import MorphableModel

    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as d:
            data = {k: d[k] for k in ("mean", "identity_basis", "expression_basis",
                                      "expression_names", "triangles", "uv", "triangle_uv_index",
                                      "landmarks_ibug68")}
    except KeyError as e:
        raise InputError(f"{path}: not an ICT FaceKit npz (missing {e})") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as e:
        raise InputError(f"{path}: cannot read npz ({e})") from None
    mean = data["mean"]
    return MorphableModel.from_arrays(
        mean=mean * np.float32(CM_TO_MM), triangles=data["triangles"],
        identity_basis=data["identity_basis"] * np.float32(CM_TO_MM),
        expression_basis=data["expression_basis"] * np.float32(CM_TO_MM),
        expression_names=[str(s) for s in data["expression_names"]],
        expression_kind="blendshapes", landmark_ids=data["landmarks_ibug68"],
        uv=data["uv"], triangle_uv=data["triangle_uv_index"],
        segments=_segments(len(mean)), name=name, source=str(path))


def load_ict_folder(folder, name: str = "ict"):
    """Load the original ICT FaceKit folder of OBJ files.

    ``generic_neutral_mesh.obj`` is the mean; ``identityNNN.obj`` are the mean plus one
    identity mode (coefficient 1 = one std); every other OBJ is the mean plus one expression
    blendshape at weight 1. Quads are fan-triangulated.
    """
    from ..model import MorphableModel

    folder = Path(folder)
    neutral_path = folder / "generic_neutral_mesh.obj"
    if not neutral_path.is_file():
        raise InputError(f"{folder}: not an ICT FaceKit folder (no generic_neutral_mesh.obj)")
    neutral = read_obj(neutral_path)
    V = len(neutral.vertices)
    identity, expression, names = [], [], []
    for p in sorted(folder.glob("*.obj")):
        if p == neutral_path:
            continue
        v = read_obj_vertices(p)
        if v.shape != (V, 3):
            raise InputError(f"{p}: {len(v)} vertices, generic_neutral_mesh.obj has {V}")
        if re.fullmatch(r"identity\d+", p.stem):
            identity.append(v - neutral.vertices)
        else:
            expression.append(v - neutral.vertices)
            names.append(p.stem)
    scale = CM_TO_MM
    empty = np.zeros((0, V, 3))
    return MorphableModel.from_arrays(
        mean=neutral.vertices * scale, triangles=neutral.triangles,
        identity_basis=np.stack(identity) * scale if identity else empty,
        expression_basis=np.stack(expression) * scale if expression else empty,
        expression_names=names, expression_kind="blendshapes" if names else "none",
        landmark_ids=ICT_LANDMARKS_IBUG68 if V > ICT_LANDMARKS_IBUG68.max() else np.full(68, -1),
        uv=neutral.uv, triangle_uv=neutral.triangle_uv, segments=_segments(V),
        name=name, source=str(folder))
