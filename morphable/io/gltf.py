"""glTF 2.0 binary (.glb) of an animated mesh: a base mesh, morph targets and per-keyframe
morph weights and node pose, written with numpy, ``struct`` and ``json`` only.

The file holds one mesh (positions, vertex normals of the base, triangles), its morph targets
(position offsets, named in ``mesh.extras.targetNames`` as Blender and three.js read them),
one node carrying the mesh, one animation (rotation, translation, uniform scale and morph
weights of that node at the keyframe times, linear interpolation) and, on request, an
orthographic camera. glTF's unit is the metre: millimetres are divided by 1000 on the way
out. The model's axes are glTF's (x to the subject's left, y up, z out of the face: the
asset's front faces +z), so a pose in the OpenGL camera frame of :mod:`morphable.camera` is
the node's pose in a scene whose camera sits on +z looking along -z.
"""
from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

from ..errors import InputError
from .atomic import atomic_path

__all__ = ["write_animated_glb", "matrix_to_quaternion", "GLB_MAGIC", "CHUNK_JSON", "CHUNK_BIN"]

GLB_MAGIC = 0x46546C67      # b"glTF" little-endian
CHUNK_JSON = 0x4E4F534A     # b"JSON"
CHUNK_BIN = 0x004E4942      # b"BIN\0"
_FLOAT, _UINT = 5126, 5125
_ARRAY_BUFFER, _ELEMENT_ARRAY_BUFFER = 34962, 34963
MM = 1e-3                   # metres per millimetre


def matrix_to_quaternion(rotations) -> np.ndarray:
    """(..., 3, 3) rotation matrices -> (..., 4) unit quaternions (x, y, z, w), glTF's order,
    w >= 0 (Shepperd's method: the largest of the four diagonal combinations is divided by,
    so that no branch loses precision).

    >>> matrix_to_quaternion(np.eye(3))
    array([0., 0., 0., 1.])
    """
    R = np.asarray(rotations, dtype=np.float64)
    m00, m11, m22 = R[..., 0, 0], R[..., 1, 1], R[..., 2, 2]
    # 4 q_k^2 for k = w, x, y, z
    sq = np.stack([1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1)
    k = np.argmax(sq, -1)
    d = 2.0 * np.sqrt(np.maximum(np.take_along_axis(sq, k[..., None], -1)[..., 0], 1e-300))
    a, b, c = R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]
    e, f, g = R[..., 0, 1] + R[..., 1, 0], R[..., 0, 2] + R[..., 2, 0], R[..., 1, 2] + R[..., 2, 1]
    # (x, y, z, w) * d for each choice of the largest component
    cand = np.stack([np.stack([a, b, c, d * d / 4], -1), np.stack([d * d / 4, e, f, a], -1),
                     np.stack([e, d * d / 4, g, b], -1), np.stack([f, g, d * d / 4, c], -1)], -2)
    q = np.take_along_axis(cand, k[..., None, None], -2)[..., 0, :] / d[..., None]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., 3:] < 0, -q, q)


class _Buffer:
    """The binary chunk and the accessors into it, each in its own 4-byte aligned view."""

    def __init__(self):
        self.parts, self.size, self.views, self.accessors = [], 0, [], []

    def add(self, array, kind: str, target=None, bounds: bool = False) -> int:
        """Append ``array`` (float32 or uint32) -> accessor index; ``kind``: SCALAR, VEC3, VEC4."""
        data = np.ascontiguousarray(array)
        blob = data.tobytes()
        view = {"buffer": 0, "byteOffset": self.size, "byteLength": len(blob)}
        if target is not None:
            view["target"] = target
        self.views.append(view)
        self.parts.append(blob + b"\0" * (-len(blob) % 4))
        self.size += len(blob) + (-len(blob) % 4)
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}[kind]
        acc = {"bufferView": len(self.views) - 1, "componentType": _UINT if data.dtype == np.uint32 else _FLOAT,
               "count": int(data.size // width), "type": kind}
        if bounds:
            flat = data.reshape(-1, width)
            acc["min"] = [v.item() for v in flat.min(0)]
            acc["max"] = [v.item() for v in flat.max(0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def write_animated_glb(path, vertices, triangles, times_s, rotations, translations_mm, scales=None,
                       targets=None, weights=None, target_names=(), orthographic_mm=None,
                       camera_distance_mm: float = 1000.0, name: str = "face", extras=None) -> Path:
    """Write an animated mesh as a glTF 2.0 binary, atomically (no file on error).

    Parameters
    ----------
    path : output ``.glb``
    vertices : (V, 3) base mesh, mm
    triangles : (T, 3) int, counter-clockwise seen from outside
    times_s : (F,) strictly increasing keyframe times, s, the first >= 0 (glTF's rule)
    rotations : (F, 3, 3) the node's rotation at each keyframe (mesh -> scene)
    translations_mm : (F, 3) the node's translation, mm
    scales : (F,) the node's uniform scale (dimensionless), default 1
    targets : (E, V, 3) morph target offsets, mm per unit weight, or None
    weights : (F, E) morph weights at each keyframe (any real values)
    target_names : E names (``mesh.extras.targetNames``)
    orthographic_mm : (xmag, ymag) half-width and half-height of an orthographic camera's view,
        mm, or None for no camera; the camera sits at (0, 0, ``camera_distance_mm``) looking
        along -z and sees depths up to twice that distance
    name : the mesh's and node's name
    extras : JSON-able dict stored as the animation's ``extras``

    Returns ``path``. The scene's coordinates are ``t + R (s X)`` in metres (mm / 1000).
    InputError names the file and the problem (shapes, non-finite values, times not increasing,
    an unwritable folder).
    """
    path = Path(path)
    V = np.asarray(vertices, dtype=np.float64)
    tri = np.asarray(triangles)
    t = np.asarray(times_s, dtype=np.float64).reshape(-1)
    F = len(t)
    R = np.asarray(rotations, dtype=np.float64)
    T = np.asarray(translations_mm, dtype=np.float64)
    S = np.ones(F) if scales is None else np.asarray(scales, dtype=np.float64).reshape(-1)
    D = np.zeros((0, *V.shape)) if targets is None else np.asarray(targets, dtype=np.float64)
    E = len(D)
    W = np.zeros((F, 0)) if weights is None else np.asarray(weights, dtype=np.float64)
    problem = None
    if V.ndim != 2 or V.shape[1] != 3 or len(V) < 3:
        problem = f"vertices must be (V >= 3, 3), got {V.shape}"
    elif tri.ndim != 2 or tri.shape[1] != 3 or len(tri) == 0 or tri.dtype.kind not in "iu" \
            or tri.min() < 0 or tri.max() >= len(V):
        problem = f"triangles must be (T, 3) indices below {len(V)}"
    elif F == 0 or R.shape != (F, 3, 3) or T.shape != (F, 3) or S.shape != (F,):
        problem = (f"need F >= 1 keyframes: times (F,), rotations (F, 3, 3), translations (F, 3), "
                   f"scales (F,); got {t.shape}, {R.shape}, {T.shape}, {S.shape}")
    elif D.shape != (E, *V.shape) or W.shape != (F, E) or len(target_names) not in (0, E):
        problem = f"targets must be (E, {len(V)}, 3) with weights (F, E) and E names, got {D.shape}, {W.shape}"
    elif not all(np.isfinite(a).all() for a in (V, t, R, T, S, D, W)):
        problem = "non-finite values (NaN or inf)"
    elif np.any(np.diff(t) <= 0) or t[0] < 0:
        problem = "keyframe times must increase strictly from 0 s or later"
    elif orthographic_mm is not None and not (np.all(np.asarray(orthographic_mm) > 0) and camera_distance_mm > 0):
        problem = "the orthographic camera needs positive magnifications and distance"
    if problem:
        raise InputError(f"{path}: {problem}")

    from ..normals import vertex_normals

    buf = _Buffer()
    f32 = np.float32
    pos = buf.add((V * MM).astype(f32), "VEC3", _ARRAY_BUFFER, bounds=True)
    nor = buf.add(vertex_normals(V, tri).astype(f32), "VEC3", _ARRAY_BUFFER)
    idx = buf.add(tri.astype(np.uint32).reshape(-1), "SCALAR", _ELEMENT_ARRAY_BUFFER, bounds=True)
    # min/max are required for morph target positions (the viewer's bounding box)
    morphs = [{"POSITION": buf.add((d * MM).astype(f32), "VEC3", _ARRAY_BUFFER, bounds=True)} for d in D]
    quats = matrix_to_quaternion(R)
    # q and -q are one rotation, but interpolating between them is not: keep neighbours close
    flip = np.cumprod(np.r_[1.0, np.sign(np.einsum("fi,fi->f", quats[1:], quats[:-1]) + 1e-300)])
    quats = quats * flip[:, None]
    time_acc = buf.add(t.astype(f32), "SCALAR", bounds=True)
    outputs = {"rotation": buf.add(quats.astype(f32), "VEC4"),
               "translation": buf.add((T * MM).astype(f32), "VEC3"),
               "scale": buf.add(np.repeat(S, 3).astype(f32), "VEC3")}
    if E:
        outputs["weights"] = buf.add(W.astype(f32).reshape(-1), "SCALAR")
    primitive = {"attributes": {"POSITION": pos, "NORMAL": nor}, "indices": idx, "mode": 4}
    mesh = {"name": name, "primitives": [primitive]}
    node = {"name": name, "mesh": 0, "rotation": [float(x) for x in quats[0]],
            "translation": [float(x) for x in T[0] * MM], "scale": [float(S[0])] * 3}
    if E:
        primitive["targets"] = morphs
        mesh["weights"] = [float(x) for x in W[0]]
        if len(target_names):
            mesh["extras"] = {"targetNames": [str(n) for n in target_names]}
    nodes = [node]
    doc = {"asset": {"version": "2.0", "generator": "morphable"}, "scene": 0}
    if orthographic_mm is not None:
        xmag, ymag = (float(m) * MM for m in orthographic_mm)
        dist = float(camera_distance_mm) * MM
        doc["cameras"] = [{"type": "orthographic", "orthographic": {
            "xmag": xmag, "ymag": ymag, "znear": dist / 1000.0, "zfar": 2.0 * dist}}]
        nodes.append({"name": "camera", "camera": 0, "translation": [0.0, 0.0, dist]})
    channels = [{"sampler": i, "target": {"node": 0, "path": p}} for i, p in enumerate(outputs)]
    samplers = [{"input": time_acc, "output": a, "interpolation": "LINEAR"} for a in outputs.values()]
    animation = {"name": name, "channels": channels, "samplers": samplers}
    if extras:
        animation["extras"] = extras
    doc.update({"scenes": [{"nodes": list(range(len(nodes)))}], "nodes": nodes, "meshes": [mesh],
                "animations": [animation], "accessors": buf.accessors, "bufferViews": buf.views,
                "buffers": [{"byteLength": buf.size}]})
    js = json.dumps(doc, separators=(",", ":")).encode()
    js += b" " * (-len(js) % 4)
    binary = b"".join(buf.parts)
    total = 12 + 8 + len(js) + 8 + len(binary)
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(struct.pack("<III", GLB_MAGIC, 2, total))
            fh.write(struct.pack("<II", len(js), CHUNK_JSON) + js)
            fh.write(struct.pack("<II", len(binary), CHUNK_BIN) + binary)
    return path
