"""``morphable sample``: a random face (or the mean) with chosen expression weights."""
from ..io.mesh import write_mesh
from .common import add_model_argument, model_from, parse_weights


def add_parser(sub):
    p = sub.add_parser("sample", help="write a random identity with chosen expressions as a mesh")
    add_model_argument(p)
    p.add_argument("--identity-std", type=float, default=1.0,
                   help="std of the random identity coefficients (0 = mean face; default 1)")
    p.add_argument("--expression", action="append", metavar="NAME=W", help="expression weight (repeatable; default: neutral)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--out", required=True, help="output mesh (.obj with UVs, .ply, .stl)")
    return p


def run(args):
    model = model_from(args)
    vertices, _ = model.sample(args.seed, identity_std=args.identity_std,
                               expression=parse_weights(model, args.expression))
    write_mesh(args.out, vertices, model.triangles, model.uv, model.triangle_uv)
    print(args.out)
    return 0
