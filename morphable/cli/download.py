"""``morphable download``: fetch a model's public files into the cache, checksums verified."""
from ..io.registry import MODELS, download


def add_parser(sub):
    p = sub.add_parser("download", help="download a model's original public files (sha256-checked)")
    p.add_argument("name", choices=sorted(MODELS))
    p.add_argument("--dest", help="folder (default: the user cache, ~/.cache/morphable)")
    p.add_argument("--url", help="alternative source (a mirror, or a file:// folder or zip) "
                                 "(default: the model's public original)")
    return p


def run(args):
    spec = MODELS[args.name]
    print(f"{args.name}: {spec['description']}; licence: {spec['license']}")
    print(download(args.name, args.dest, args.url))
    return 0
