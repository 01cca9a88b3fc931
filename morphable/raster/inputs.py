"""What the bake and render commands draw: a mesh file, a model's mean, or a fitted frame."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError

__all__ = ["Mesh", "load_mesh", "load_fit_frame", "read_fit_report"]

_MESH_SUFFIXES = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf")


@dataclass
class Mesh:
    """vertices (V, 3) mm; triangles (F, 3); uv (T, 2) or None; triangle_uv (F, 3) or None
    (None with uv = per-vertex uv); texture: path of the texture image named by the file's
    material, or None; model: the MorphableModel it came from, or None."""

    vertices: np.ndarray
    triangles: np.ndarray
    uv: np.ndarray | None = None
    triangle_uv: np.ndarray | None = None
    texture: Path | None = None
    model: object = None

    @property
    def layout(self):
        """(triangles, uv, triangle_uv, vertices) for :func:`morphable.raster.uv_normal_map`."""
        if self.model is not None:
            return self.model
        if self.uv is None:
            raise InputError("the mesh has no UV coordinates")
        return self.triangles, self.uv, self.triangle_uv, self.vertices


def _obj_texture(path: Path) -> Path | None:
    """The diffuse map (map_Kd) of the first material library an OBJ names, if it exists."""
    try:
        libs = [ln.split(None, 1)[1].strip() for ln in path.read_text(errors="replace").splitlines()
                if ln.startswith("mtllib ")]
    except (OSError, IndexError):
        return None
    for lib in libs:
        mtl = path.parent / lib
        if not mtl.is_file():
            continue
        for ln in mtl.read_text(errors="replace").splitlines():
            if ln.strip().startswith("map_Kd"):
                tex = path.parent / ln.strip().split()[-1]
                if tex.is_file():
                    return tex
    return None


def load_mesh(spec) -> Mesh:
    """A mesh file (.obj keeps its UV indices exactly; other formats through trimesh) or a
    model name/path (its mean shape with its UV layout)."""
    from ..io.registry import load_model

    p = Path(str(spec))
    if p.suffix.lower() in _MESH_SUFFIXES:
        if not p.is_file():
            raise InputError(f"{p}: no such file")
        if p.suffix.lower() == ".obj":
            from ..io.obj import read_obj

            o = read_obj(p)
            uv, tuv = o.uv, o.triangle_uv
            if uv is not None and (tuv is None or (tuv < 0).any()):
                uv, tuv = None, None  # some faces lack texture coordinates
            return Mesh(o.vertices, o.triangles, uv, tuv, _obj_texture(p))
        from ..io.mesh import read_mesh

        m = read_mesh(p)
        uv = getattr(m.visual, "uv", None)
        return Mesh(np.asarray(m.vertices), np.asarray(m.faces, dtype=np.int64),
                    None if uv is None else np.asarray(uv, dtype=np.float64))
    model = load_model(spec)
    return Mesh(model.mean, model.triangles, model.uv, model.triangle_uv, model=model)


def _frame_camera(frame: dict, where: str):
    from ..camera import Camera, euler_to_matrix

    if isinstance(frame.get("camera"), dict):
        return Camera.from_dict(frame["camera"])
    try:
        kind = frame.get("camera", frame.get("kind", "affine"))
        R = (np.asarray(frame["rotation"]) if "rotation" in frame else
             euler_to_matrix(frame["yaw_deg"], frame["pitch_deg"], frame["roll_deg"]))
        t = frame.get("translation_mm", frame.get("translation"))
        return Camera(kind=kind, rotation=R, translation=np.asarray(t, dtype=np.float64),
                      scale=float(frame.get("scale_px_per_mm", frame.get("scale", 1.0))),
                      focal=float(frame.get("focal_px", 1.0)),
                      image_size=tuple(frame["image_size"]),
                      principal=frame.get("principal_px"))
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{where}: frame has no usable camera ({type(e).__name__}: {e})") from None


def read_fit_report(path) -> dict:
    """The JSON object of a fit report; InputError naming the file when it is not one."""
    path = Path(path)
    try:
        report = json.loads(path.read_text())
    except OSError as e:
        raise InputError(f"{path}: cannot read ({e.strerror or e})") from None
    except ValueError as e:
        raise InputError(f"{path}: not a JSON fit report ({e})") from None
    if not isinstance(report, dict):
        raise InputError(f"{path}: not a JSON fit report")
    return report


def load_fit_frame(path, frame: int = 0, model=None):
    """Mesh and camera of one frame of a fit report (``morphable fit`` JSON).

    Reads ``model``, ``identity``, ``frames[i]`` (pose, translation, camera kind, scale or
    focal, image size, expression weights by name) and, when present, ``cameras[i]`` in
    :meth:`~morphable.camera.Camera.to_dict` form.

    Returns
    -------
    mesh : Mesh (the fitted vertices, mm, with the model's UV layout)
    camera : morphable.camera.Camera
    """
    from ..camera import Camera
    from ..io.registry import load_model

    path = Path(path)
    report = read_fit_report(path)
    model = model or load_model(report.get("model", "sfm"))
    frames = report.get("frames") or []
    cameras = report.get("cameras") or []
    n = max(len(frames), len(cameras))
    if not 0 <= frame < n:
        raise InputError(f"{path}: frame {frame} requested, the report has {n} frames")
    f = frames[frame] if frame < len(frames) else {}
    camera = (Camera.from_dict(cameras[frame]) if frame < len(cameras)
              else _frame_camera(f, f"{path} frame {frame}"))
    identity = f.get("identity", report.get("identity"))
    expression = f.get("expression")
    if isinstance(expression, dict):
        weights = np.zeros(model.n_expression)
        for name, w in expression.items():
            weights[model.expression_index(name)] = float(w)
        expression = weights
    vertices = model.vertices(identity, expression)
    return Mesh(vertices, model.triangles, model.uv, model.triangle_uv, model=model), camera
