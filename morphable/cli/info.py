"""``morphable info``: what a model holds."""
import json

from .common import add_model_argument, model_from


def add_parser(sub):
    p = sub.add_parser("info", help="print a model's sizes, units and landmarks")
    add_model_argument(p)
    p.add_argument("--json", action="store_true", help="print JSON")
    return p


def run(args):
    info = model_from(args).info()
    if args.json:
        print(json.dumps(info, indent=2))
        return 0
    for key in ("name", "source", "n_vertices", "n_triangles", "n_identity", "n_expression",
                "expression_kind", "units", "n_landmarks"):
        print(f"{key:16s} {info[key]}")
    return 0
