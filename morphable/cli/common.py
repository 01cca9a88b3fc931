"""Argument helpers shared by the commands."""
from __future__ import annotations

from ..errors import InputError
from ..io.registry import DEFAULT_MODEL, load_model


def add_model_argument(parser) -> None:
    parser.add_argument("--model", default=DEFAULT_MODEL,
                        help=f"model name (sfm, ict) or path to a model file/folder (default {DEFAULT_MODEL})")


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
