"""``morphable convert``: any readable model -> the native npz (fast to load)."""
from ..io.native import save_model_npz
from .common import add_model_argument, model_from


def add_parser(sub):
    p = sub.add_parser("convert", help="convert a model (eos .bin, ICT, BFM .h5, FLAME .pkl) to .npz")
    add_model_argument(p)
    p.add_argument("--out", required=True, help="output .npz")
    return p


def run(args):
    save_model_npz(model_from(args), args.out)
    print(args.out)
    return 0
