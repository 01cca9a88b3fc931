"""What the commands share: argument helpers, output checks, the mesh or fit a command draws."""
from __future__ import annotations

from ..errors import InputError
from ..io.registry import DEFAULT_MODEL, load_model


def add_model_argument(parser, text: str | None = None) -> None:
    """``--model`` (default :data:`~morphable.io.registry.DEFAULT_MODEL`); ``text`` replaces
    its help where a command uses the model otherwise."""
    parser.add_argument("--model", default=DEFAULT_MODEL,
                        help=text or f"model name (sfm, ict) or path to a model file/folder (default {DEFAULT_MODEL})")


def add_fitting_arguments(parser) -> None:
    """The landmark-fitting options shared by ``fit`` and ``fit-batch``."""
    parser.add_argument("--camera", choices=("affine", "perspective"), default="affine",
                        help="affine (scaled orthographic) or perspective (pinhole) (default affine)")
    parser.add_argument("--focal-px", type=float, default=None,
                        help="focal length in px (perspective; default max(W, H))")
    parser.add_argument("--n-iterations", type=int, default=4,
                        help="nonlinear iterations (default 4)")
    parser.add_argument("--robust", choices=("huber",), default=None,
                        help="huber: Huber loss against outlying landmarks (default: least squares)")
    parser.add_argument("--landmark-std", type=landmark_std_arg, default=1.0, metavar="PX|auto",
                        help="landmark noise in px, or auto: estimated from the fit (default 1 px)")
    add_detector_arguments(parser)


def add_detector_arguments(parser) -> None:
    """The detector choice of every command that detects landmarks (images without files)."""
    from ..detection import FACE_DETECTORS, LANDMARK_DETECTORS

    parser.add_argument("--landmark-detector", choices=LANDMARK_DETECTORS, default="auto",
                        help="landmarks for images without landmark files: network (the neural "
                             "plugin's landmark network, 478 + 68 points with a sigma each), "
                             "facemesh (mediapipe, 478 points), dlib (68), fused (the network, then "
                             "the face mesh in the network's box, the two fused by their "
                             "uncertainty; either alone where the other finds no face); auto "
                             "(default): fused where mediapipe is installed and the network can run "
                             "(its weights, with onnxruntime or torch), else facemesh, else "
                             "network, else dlib")
    faces = dict.fromkeys(f for v in FACE_DETECTORS.values() for f in v)
    parser.add_argument("--face-detector", choices=tuple(faces), default="auto",
                        help="the landmark detector's face detector: short-range or full-range "
                             "(facemesh), hog or cnn (dlib), any of these or windows (network and "
                             "fused: the network's own face score over a window grid); auto "
                             "(default): the landmark detector's own (facemesh: its short-range "
                             "search of the whole photo, then full-range where that finds no "
                             "face; dlib: hog; network and fused: mediapipe's short-range then "
                             "full-range, else dlib's hog, then the windows where they find no "
                             "face)")


def add_loss_weight_argument(parser, flag: str = "--loss-weight", what: str = "refinement") -> None:
    """``KEY=VALUE`` overrides of the refinement's loss weights
    (:data:`morphable.refinement.DEFAULT_WEIGHTS`); read them with
    :func:`morphable.refinement.parse_loss_weights`."""
    parser.add_argument(flag, nargs="+", metavar="KEY=VALUE",
                        help=f"{what} loss weights instead of the defaults "
                             "(morphable.refinement.DEFAULT_WEIGHTS), e.g. lmk=10 photo=0; what "
                             "they do: docs/neural.md")


def landmark_std_arg(text: str):
    """argparse type of ``--landmark-std``: a noise > 0 in px, or "auto"."""
    import argparse

    if text == "auto":
        return text
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a number nor 'auto'") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"{text!r}: must be > 0")
    return value


def renderer_options(inverter=None, what: str = "--refine") -> dict:
    """``get_renderer``'s options for a refinement: ``--inverter`` (the gar renderer's V) only
    when given. A one-line error first when torch (the neural extra) is missing."""
    try:
        import torch  # noqa: F401
    except ImportError as e:
        raise InputError(f"{what} needs the neural extra: pip install -e '.[neural]' ({e})") from None
    return {"inverter": inverter} if inverter else {}


def model_from(args):
    return load_model(args.model)


def parse_weights(model, items) -> "list[float]":
    """``["happiness=0.8", ...]`` -> an expression coefficient vector of the model."""
    weights = [0.0] * model.n_expression
    for item in items or []:
        name, sep, value = item.partition("=")
        if not sep:
            raise InputError(f"--expression {item!r}: expected NAME=WEIGHT")
        try:
            w = float(value)
        except ValueError:
            raise InputError(f"--expression {item!r}: weight is not a number") from None
        weights[model.expression_index(name)] = w
    return weights


def check_outputs(*paths):
    """Fail before any work when a .png output cannot be written (no partial outputs); None
    entries are skipped (:func:`morphable.raster.png.check_png_path`)."""
    from ..raster.png import check_png_path

    for path in paths:
        if path is not None:
            check_png_path(path)


def add_camera_arguments(p, size_default):
    """Camera options shared by bake and render."""
    p.add_argument("--size", type=int, default=None,
                   help=f"image size in pixels: square for MESH (default {size_default}); with "
                        "--fit the fit's image scaled to this width (default its own size)")
    p.add_argument("--camera", choices=("affine", "perspective"), default="affine",
                   help="projection for MESH (default affine); a fit brings its own camera")
    p.add_argument("--yaw", type=float, default=0.0,
                   help="degrees, positive turns the nose to the image right (default 0)")
    p.add_argument("--pitch", type=float, default=0.0,
                   help="degrees, positive turns the nose down (default 0)")
    p.add_argument("--roll", type=float, default=0.0,
                   help="degrees, counter-clockwise in the image (default 0)")
    p.add_argument("--supersample", type=int, default=1,
                   help="antialiasing samples per pixel and axis (default 1)")


def add_source_arguments(p):
    """What bake and render draw: MESH, a fit (``--fit``, ``--frame``) or a model's mean."""
    p.add_argument("mesh", nargs="?", metavar="MESH",
                   help="mesh file (.obj .ply .stl .off .glb) or model name; default the --model mean")
    p.add_argument("--fit", metavar="FIT.json", help="draw a fitted face with its camera instead of MESH")
    p.add_argument("--frame", type=int, default=0, help="frame of the fit report (default 0)")
    add_model_argument(p, text="model name (sfm, ict) or path to a model file/folder: its mean is "
                               "drawn when neither MESH nor --fit is given (then default "
                               f"{DEFAULT_MODEL}); with --fit, drawn instead of the fit's own model")
    p.set_defaults(model=None)  # None: MESH, or the fit's own model


def source_and_camera(args, size_default):
    """(Mesh, Camera or None) from MESH / --fit / --model and the camera options."""
    from ..io.registry import DEFAULT_MODEL, load_model
    from ..raster import frame_mesh
    from ..raster.inputs import load_fit_frame, load_mesh

    if args.size is not None and args.size <= 0:
        raise InputError(f"--size must be a positive number of pixels, got {args.size}")
    if args.fit and args.mesh:
        raise InputError("give either MESH or --fit, not both")
    if args.fit:
        mesh, cam = load_fit_frame(args.fit, args.frame,
                                   model=None if args.model is None else load_model(args.model))
        if args.size is not None:
            cam = resized(cam, args.size / cam.image_size[0])
        return mesh, cam
    mesh = load_mesh(args.mesh or args.model or DEFAULT_MODEL)
    size = args.size or size_default
    cam = frame_mesh(mesh.vertices, (size, size), yaw=args.yaw, pitch=args.pitch, roll=args.roll,
                     kind=args.camera)
    return mesh, cam


def resized(camera, factor):
    """The camera for the same view in an image scaled by ``factor``."""
    from dataclasses import replace

    W, H = camera.image_size
    size = (max(1, round(W * factor)), max(1, round(H * factor)))
    principal = (camera.principal + 0.5) * factor - 0.5
    return replace(camera, scale=camera.scale * factor, focal=camera.focal * factor,
                   image_size=size, principal=principal)
