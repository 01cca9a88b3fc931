"""Build the API reference: ``python docs/api/build.py OUT`` (``make docs``: OUT = build/docs).

Writes index.rst and one page per module of morphable, neural and evaluation (found from the
packages' files) into ``OUT/src``, then runs Sphinx (conf.py here) nitpicky with warnings as
errors into ``OUT/html``, from scratch every time: a rebuild that reused its saved state would
not repeat an unchanged page's warnings. Exits with Sphinx's status: 0 when nothing warned.
``--modules NAME ...`` builds the pages of those modules only.
"""
import argparse
import shutil
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
PACKAGES = ("morphable", "neural", "evaluation")


def modules(package: str) -> list:
    """The dotted names of ``package`` and of every module and subpackage under it, sorted;
    ``__main__`` and private (``_x``) modules left out."""
    names = []
    for path in sorted((ROOT / package).rglob("*.py")):
        parts = path.relative_to(ROOT).with_suffix("").parts
        if not all((ROOT.joinpath(*parts[:i]) / "__init__.py").is_file()
                   for i in range(1, len(parts))):
            continue                                   # a folder that is not a package
        if parts[-1] == "__init__":
            parts = parts[:-1]
        elif parts[-1].startswith("_"):
            continue
        names.append(".".join(parts))
    return sorted(names)


def _toctree(names: list) -> list:
    return [".. toctree::", "   :maxdepth: 1", "", *[f"   {name}" for name in names], ""]


def write_pages(src: Path, names: list) -> None:
    """index.rst, with the top modules of ``names`` in its table of contents, and a page per
    module (its docstring and members, then its submodules' pages) into ``src``."""
    src.mkdir(parents=True)
    top = [name for name in names if name.rpartition(".")[0] not in names]
    (src / "index.rst").write_text((HERE / "index.rst").read_text() + "\n" + "\n".join(_toctree(top)))
    for name in names:
        children = [n for n in names if n.rpartition(".")[0] == name]
        lines = [name, "=" * len(name), "", f".. automodule:: {name}", ""]
        if children:
            lines += [".. rubric:: Modules", "", *_toctree(children)]
        (src / f"{name}.rst").write_text("\n".join(lines))


def main(argv=None) -> int:
    from sphinx.cmd.build import build_main

    parser = argparse.ArgumentParser(prog="python docs/api/build.py", description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="folder of the pages (src), the HTML (html) and doctrees")
    parser.add_argument("--modules", nargs="+", metavar="NAME",
                        help=f"the modules to document (default: all of {', '.join(PACKAGES)})")
    args = parser.parse_args(argv)
    for folder in ("src", "html", "doctrees"):
        shutil.rmtree(args.out / folder, ignore_errors=True)
    write_pages(args.out / "src", args.modules or [n for p in PACKAGES for n in modules(p)])
    return build_main(["-W", "--keep-going", "-n", "-q", "-c", str(HERE), "-d", str(args.out / "doctrees"),
                       str(args.out / "src"), str(args.out / "html")])


if __name__ == "__main__":
    sys.exit(main())
