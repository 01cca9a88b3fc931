"""What travels to a lent GPU machine for a recipe of :mod:`neural.gpu_recipe`, and the
tracked files parked out of the tree while it does.

The device tool copies the working tree (tracked files, untracked files git does not
ignore) and the ignored paths named in its ``carry``: 64 MiB in all (:data:`BUDGET_MIB`).
The tracked tree alone is larger (mostly committed weights), so for a run the tracked files
of :data:`PARK_MIN_BYTES` or more that the recipe does not read are moved out of the tree
and the index (``park``), and put back afterwards (``restore``); what the GPU machine's 16
cores can make (the synthetic landmark faces) is generated there from a small kit
(``kit``: the SFM model), not carried.

``python -m neural.gpu_travel plan RECIPE [--carry PATH ...]``: the plan as JSON (what
travels, what is parked, the MiB of each and the total against the budget); exit 2 when it
does not fit. ``python -m neural.gpu_travel park RECIPE [--carry PATH ...] [--to DIR]``:
park (refused when the plan does not fit, or when files are parked already);
``python -m neural.gpu_travel restore [--to DIR]``: put them back (``DIR/parked.json`` lists
them). ``python -m neural.gpu_travel kit --data ../shared/data``: copy the synthetic
faces' kit into ``gpu_kit/`` (ignored; carried). Run from the repository root.

Recipes (:data:`NEEDS`): ``landmarks`` reads the committed landmark network (``--init``);
``gar`` the fine-tuned aux networks of ``neural/gar/weights/real`` and the committed GARs it
continues (``--init``).
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path

from morphable.errors import InputError, one_line_errors

__all__ = ["BUDGET_MIB", "PARK_MIN_BYTES", "NEEDS", "CARRY", "KIT", "tracked_files",
           "travel_plan", "park", "restore", "copy_kit", "main"]

BUDGET_MIB = 64.0
"""What the device tool carries in all: working tree and carried paths (MiB)."""
PARK_MIN_BYTES = 256 * 1024
"""Tracked files of this size or more travel only when the recipe reads them."""
NEEDS = {
    "landmarks": ("neural/landmarks/weights/landmarks.pt",),
    "gar": ("neural/gar/weights/real/aux_N.pt", "neural/gar/weights/real/aux_P.pt",
            "neural/gar/weights/real/aux_L.pt", "neural/gar/weights/real/aux_R.pt",
            "neural/gar/weights/aux_R.pt", "neural/gar/weights/real/gar_tiny.pt",
            "neural/gar/weights/gpu/gar_128.pt"),
}
"""The tracked files of :data:`PARK_MIN_BYTES` or more that each recipe reads."""
CARRY = {
    "landmarks": ("landmark_data/annotated_trainval_128.npz", "landmark_data/profiled_128.npz",
                  "gpu_kit"),
    "gar": ("gar_data/real128.npz",),
}
"""The ignored paths each recipe's run carries by default (``make landmark-gpu`` /
``make gar-gpu`` read them): the compact real packs (docs/landmark_packs.md), the GAR's
128-px pack, and the synthetic faces' kit."""
KIT = ("models/sfm",)
"""What ``kit`` copies from the shared data folder into ``gpu_kit/data`` (4.7 MB): enough
for :mod:`neural.faces.build_synthetic` ``--textures 0 --backgrounds none`` there."""


def _size(path: Path) -> int:
    if path.is_symlink() or path.is_file():
        return path.lstat().st_size if path.is_symlink() else path.stat().st_size
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())


def tracked_files(root=".") -> dict:
    """Tracked path (str, relative to ``root``) -> bytes in the working tree (absent files
    left out)."""
    try:
        out = subprocess.run(["git", "ls-files", "-z"], cwd=root, capture_output=True,
                             check=True).stdout
    except (OSError, subprocess.CalledProcessError) as e:
        raise InputError(f"{root}: not a git working tree ({e})") from None
    root = Path(root)
    files = {}
    for name in out.decode().split("\0"):
        if name and ((root / name).exists() or (root / name).is_symlink()):
            files[name] = _size(root / name)
    return files


def travel_plan(recipe: str, root=".", carry=None, budget_mib: float = BUDGET_MIB) -> dict:
    """The plan of ``recipe`` (a key of :data:`NEEDS`) in the tree at ``root``.

    carry : ignored paths that travel (default :data:`CARRY`'s; absent ones are listed in
        ``missing``)

    Returns dict: ``travel_mib`` (tracked files that stay), ``carry`` (path -> MiB),
    ``missing`` (carried paths not there), ``park`` (the tracked paths to move out, largest
    first) and ``park_mib``, ``total_mib`` and ``budget_mib``, ``fits`` (bool)."""
    if recipe not in NEEDS:
        raise InputError(f"recipe must be one of {', '.join(NEEDS)}, got {recipe!r}")
    root = Path(root)
    files = tracked_files(root)
    parked = sorted((p for p, n in files.items()
                     if n >= PARK_MIN_BYTES and p not in NEEDS[recipe]), key=lambda p: -files[p])
    carry = CARRY[recipe] if carry is None else tuple(carry)
    carried = {c: round(_size(root / c) / 2 ** 20, 2) for c in carry if (root / c).exists()}
    mib = 2 ** 20
    travel = sum(n for p, n in files.items() if p not in parked) / mib
    total = travel + sum(carried.values())
    return {"recipe": recipe, "travel_mib": round(travel, 2), "carry": carried,
            "missing": [c for c in carry if c not in carried], "park": parked,
            "park_mib": round(sum(files[p] for p in parked) / mib, 2),
            "total_mib": round(total, 2), "budget_mib": budget_mib, "fits": total <= budget_mib}


def _manifest(to: Path) -> Path:
    return to / "parked.json"


def park(recipe: str, root=".", to=None, carry=None, budget_mib: float = BUDGET_MIB) -> dict:
    """Move the plan's ``park`` files into ``to`` (default ``../gpu-park-<tree name>``) and
    out of the index; ``to/parked.json`` lists them. -> the plan. InputError when the plan
    does not fit or ``to`` holds parked files already."""
    root = Path(root).resolve()
    to = Path(to) if to else root.parent / f"gpu-park-{root.name}"
    if _manifest(to).exists():
        raise InputError(f"{_manifest(to)}: files are parked already (restore them first)")
    plan = travel_plan(recipe, root, carry, budget_mib)
    if not plan["fits"]:
        raise InputError(f"{recipe}: {plan['total_mib']} MiB would travel, over "
                         f"{plan['budget_mib']} MiB even with {plan['park_mib']} MiB parked")
    to.mkdir(parents=True, exist_ok=True)
    _manifest(to).write_text(json.dumps({"root": str(root), "files": plan["park"]}, indent=1))
    for p in plan["park"]:
        (to / p).parent.mkdir(parents=True, exist_ok=True)
        shutil.move(str(root / p), str(to / p))
    if plan["park"]:
        subprocess.run(["git", "rm", "-q", "--cached", "--", *plan["park"]], cwd=root, check=True)
    return plan


def restore(root=".", to=None) -> list:
    """Put the files :func:`park` moved back into the tree and the index -> their paths."""
    root = Path(root).resolve()
    to = Path(to) if to else root.parent / f"gpu-park-{root.name}"
    if not _manifest(to).exists():
        raise InputError(f"{_manifest(to)}: nothing parked")
    files = json.loads(_manifest(to).read_text())["files"]
    for p in files:
        if (to / p).exists() or (to / p).is_symlink():
            (root / p).parent.mkdir(parents=True, exist_ok=True)
            shutil.move(str(to / p), str(root / p))
    if files:
        subprocess.run(["git", "reset", "-q", "--", *files], cwd=root, check=True)
    _manifest(to).unlink()
    return files


def copy_kit(data, out="gpu_kit") -> Path:
    """Copy :data:`KIT` from the shared data folder ``data`` into ``out/data`` -> that
    folder (``--data`` of :mod:`neural.faces.build_synthetic` on the GPU machine)."""
    data, dest = Path(data), Path(out) / "data"
    for part in KIT:
        if not (data / part).exists():
            raise InputError(f"{data / part}: not found (the shared data folder, --data)")
        shutil.copytree(data / part, dest / part, dirs_exist_ok=True)
    return dest


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m neural.gpu_travel",
                                description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)
    for name in ("plan", "park"):
        c = sub.add_parser(name)
        c.add_argument("recipe", choices=sorted(NEEDS))
        c.add_argument("--carry", nargs="*", help="ignored paths that travel (default: the "
                       "recipe's, neural.gpu_travel.CARRY)")
        if name == "park":
            c.add_argument("--to", help="where the parked files go")
    r = sub.add_parser("restore")
    r.add_argument("--to", help="where the parked files are")
    k = sub.add_parser("kit")
    k.add_argument("--data", default="../shared/data")
    k.add_argument("--out", default="gpu_kit")
    return p


@one_line_errors("neural.gpu_travel")
def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "plan":
        plan = travel_plan(args.recipe, ".", args.carry)
        print(json.dumps(plan, indent=1))
        return 0 if plan["fits"] else 2
    if args.command == "park":
        plan = park(args.recipe, ".", args.to, args.carry)
        print(f"parked {len(plan['park'])} files ({plan['park_mib']} MiB); "
              f"{plan['total_mib']} MiB travel; missing: {', '.join(plan['missing']) or 'none'}")
    elif args.command == "restore":
        print(f"restored {len(restore('.', args.to))} files")
    else:
        print(copy_kit(args.data, args.out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
