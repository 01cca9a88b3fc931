"""The ``morphable`` command line: thin wrappers that parse arguments, call the API and write
files atomically. Bad input ends with one line on stderr and exit status 2, never a traceback.

Each command lives in its own module here with ``add_parser(subparsers)`` and ``run(args)``.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from ..errors import MorphableError
from ..logs import add_verbosity_arguments, configure, verbosity

COMMANDS = ["info", "sample", "convert", "download", "bake", "render", "show", "fit", "fit-batch", "texture", "profile",
            "track", "edit"]
"""Module names under ``morphable.cli``; the order is the order of ``morphable --help``."""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="morphable", description="3D morphable face model toolkit")
    add_verbosity_arguments(parser)
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name in COMMANDS:
        module = importlib.import_module(f"{__name__}.{name.replace('-', '_')}")
        p = module.add_parser(sub)
        add_verbosity_arguments(p, defaults=False)   # `morphable fit ... -q` as well as `morphable -q fit`
        p.set_defaults(_run=module.run)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    configure(verbosity(args))
    try:
        return args._run(args) or 0
    except MorphableError as e:
        print(f"morphable {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"morphable {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
