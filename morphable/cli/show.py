"""``morphable show``: a mesh or a fit in 3D (pyvista), with landmarks, a scan, errors."""
import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..io.mesh import read_mesh
from ..io.registry import DEFAULT_MODEL, load_model
from .common import add_model_argument


def add_parser(sub):
    p = sub.add_parser("show", help="view a mesh or fit.json (pyvista; --screenshot works headless)")
    p.add_argument("mesh", metavar="MESH_OR_FIT", help="mesh file (.obj .ply .stl) or a fit report .json")
    add_model_argument(p, text="the model whose landmark vertices --landmarks draws on a mesh (a fit "
                               f"report brings its own) (default {DEFAULT_MODEL})")
    p.add_argument("--frame", type=int, default=0, help="frame of a multi-frame fit (default 0)")
    p.add_argument("--image", help="photo drawn as the background")
    p.add_argument("--scan", help="scan mesh overlaid semi-transparent (same units and frame)")
    p.add_argument("--landmarks", action="store_true", help="draw the model's landmark vertices")
    p.add_argument("--errors", help="per-vertex errors: .npy (V,) in mm, or an evaluation report .json "
                                    "with 'per_vertex_errors' naming such a file")
    p.add_argument("--texture", help="texture image for the mesh's UVs (default: the OBJ's "
                                     "material map; a fit report: e.g. fit --out-texture's)")
    p.add_argument("--no-texture", action="store_true", help="ignore the OBJ's material map")
    p.add_argument("--view", default="front", choices=["front", "left", "right", "top"],
                   help="camera direction (default front)")
    p.add_argument("--screenshot", help="write a PNG instead of opening a window")
    p.add_argument("--size", default="1024x768", help="window or screenshot size WIDTHxHEIGHT (default 1024x768)")
    return p


def _read_json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{path}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{path}: not JSON ({e.msg} at line {e.lineno})") from None


def _from_fit(path: Path, frame: int):
    rep = _read_json(path)
    try:
        model = load_model(rep["model"])
        frames = rep["frames"]
        if not -len(frames) <= frame < len(frames):
            raise InputError(f"{path}: --frame {frame} but the fit has {len(frames)} frames")
        f = frames[frame]
        identity = f.get("identity", rep["identity"])
        expression = [f["expression"].get(n, 0.0) for n in model.expression_names]
    except (KeyError, TypeError, AttributeError) as e:
        raise InputError(f"{path}: not a fit report (missing {e})") from None
    return model, model.vertices(identity, expression)


def _errors(spec: str, n: int) -> np.ndarray:
    path = Path(spec)
    if path.suffix == ".json":
        rep = _read_json(path)
        if "per_vertex_errors" not in rep:
            raise InputError(f"{path}: no 'per_vertex_errors' entry")
        path = path.parent / rep["per_vertex_errors"]
    try:
        e = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as err:
        raise InputError(f"{path}: cannot read errors ({err})") from None
    if e.shape != (n,):
        raise InputError(f"{path}: {e.shape} errors for a mesh of {n} vertices")
    return e


def run(args):
    from ..viewer import parse_size, show_mesh

    size = parse_size(args.size)
    path = Path(args.mesh)
    texture = None
    if args.texture and not Path(args.texture).is_file():
        raise InputError(f"{args.texture}: no such texture file")
    if path.suffix == ".json":
        model, vertices = _from_fit(path, args.frame)
        triangles = model.triangles
        if args.texture and not args.no_texture:
            from ..raster import as_texture
            from ..texture import texture_layout

            image = as_texture(args.texture)
            texture = (*texture_layout(model, image.shape[0])[:2], image)
    else:
        mesh = read_mesh(path)
        vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.faces)
        model = load_model(args.model) if args.landmarks else None
        if model is not None and model.n_vertices != len(vertices):
            raise InputError(f"{path}: {len(vertices)} vertices, model {model.name} has "
                             f"{model.n_vertices}: landmarks need a mesh of the model")
        if path.suffix.lower() == ".obj" and not args.no_texture:
            from ..raster.inputs import load_mesh

            obj = load_mesh(path)
            image = args.texture or obj.texture
            if image is not None and obj.uv is None:
                raise InputError(f"{path}: the mesh has no UV coordinates for --texture")
            if image is not None:
                # the UV indices are read_obj's: draw its vertices and triangles with them
                vertices, triangles = obj.vertices, obj.triangles
                texture = (obj.uv, obj.triangle_uv, image)
    landmarks = None
    if args.landmarks:
        ids = model.landmark_ids[model.landmark_ids >= 0]
        landmarks = vertices[ids]
    scan = None
    if args.scan:
        s = read_mesh(args.scan)
        scan = (np.asarray(s.vertices), np.asarray(s.faces))
    errors = _errors(args.errors, len(vertices)) if args.errors else None
    image = None
    if args.image:
        from ..detection import read_image

        # decoded here: VTK's reader crashes the process on a truncated or corrupt file
        image = read_image(args.image)
    out = show_mesh(vertices, triangles, landmarks=landmarks, scan=scan, errors=errors,
                    image=image, view=args.view, size=size, screenshot=args.screenshot,
                    title=path.name, texture=texture)
    if out:
        print(out)
    return 0
