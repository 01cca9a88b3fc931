"""Argument helpers shared by the commands."""
from __future__ import annotations

from ..errors import InputError
from ..io.registry import DEFAULT_MODEL, load_model


def add_model_argument(parser) -> None:
    parser.add_argument("--model", default=DEFAULT_MODEL,
                        help=f"model name (sfm, ict) or path to a model file/folder (default {DEFAULT_MODEL})")


def add_fitting_arguments(parser) -> None:
    """The landmark-fitting options shared by ``fit`` and ``fit-batch``."""
    parser.add_argument("--camera", choices=("affine", "perspective"), default="affine")
    parser.add_argument("--focal-px", type=float, default=None,
                        help="focal length in px (perspective; default max(W, H))")
    parser.add_argument("--n-iterations", type=int, default=4,
                        help="nonlinear iterations (default 4)")
    parser.add_argument("--robust", choices=("huber",), default=None,
                        help="huber: Huber loss against outlying landmarks (default: least squares)")
    parser.add_argument("--landmark-std", type=landmark_std_arg, default=1.0, metavar="PX|auto",
                        help="landmark noise in px, or auto: estimated from the fit (default 1)")
    add_detector_arguments(parser)


def add_detector_arguments(parser) -> None:
    """The detector choice of every command that detects landmarks (images without files)."""
    from ..detection import FACE_DETECTORS, LANDMARK_DETECTORS

    parser.add_argument("--landmark-detector", choices=LANDMARK_DETECTORS, default="auto",
                        help="landmarks for images without landmark files: network (the neural "
                             "plugin's landmark network, 478 + 68 points with a sigma each), "
                             "facemesh (mediapipe, 478 points), dlib (68); auto: facemesh when "
                             "installed, and the network for a face it does not find when the "
                             "network's weights are present; else the network; else dlib "
                             "(default)")
    faces = dict.fromkeys(f for v in FACE_DETECTORS.values() for f in v)
    parser.add_argument("--face-detector", choices=tuple(faces), default="auto",
                        help="the landmark detector's face detector: short-range or full-range "
                             "(facemesh), hog or cnn (dlib), any of these or windows (network: "
                             "its own face score over a window grid); default auto: its own default")


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
