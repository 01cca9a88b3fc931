"""Real photos of a scanned person: ``morphable fit`` with and without refinement, against the scan.

james' scan (``../shared/data/scans/james``, menpo3d test assets, BSD-3) comes with the
scanner's two raw camera photos of the same instant, side by side in ``james.jpg`` (two
three-quarter views, 1200 x 1600 px each). This bench splits them, runs ``morphable fit``
(the command a user runs: detection with the default detector, then the fit, then
``--refine`` when it is not ``none``) on each photo alone and on both together, reads the
written mesh and compares it with the scan the way the Florence protocol does
(:func:`evaluation.florence.protocol.evaluate`: landmark similarity, crop of 95 mm around the
nose tip, point-to-plane ICP, mean point-to-plane error in mm). The model's mean face and the
model fitted to the scan's surface (the floor no fit of this model can go below) are the
reference rows. Each row has its error and its run time (the fit's own ``runtime_ms`` from the
report, and the wall time of the whole command).

Command (one row set per refinement)::

    python -m evaluation.bench_scan_photos --refine none --report reports/james_photos_none.json
    python -m evaluation.bench_scan_photos --refine photometric --report reports/james_photos_photometric.json

``--fit-args`` passes further options to ``morphable fit`` (e.g. a refinement's settings).
james is held out: settings are not to be chosen on this bench.
"""
from __future__ import annotations

import argparse
import json
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from morphable.errors import FitError, InputError, one_line_errors

__all__ = ["split_photos", "fit_mesh", "scan_rows", "format_rows", "main"]

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
JAMES = DATA / "scans" / "james"


def split_photos(path, out_dir) -> list:
    """The scanner's side-by-side photos -> [left, right] PNG paths written in ``out_dir``.

    ``path``: an image of two photos of the same size side by side (width = 2 x height x
    aspect); InputError when its width is odd.
    """
    from PIL import Image

    path = Path(path)
    try:
        im = Image.open(path).convert("RGB")
    except (OSError, ValueError) as e:
        raise InputError(f"{path}: cannot read image ({e})") from None
    W, H = im.size
    if W % 2:
        raise InputError(f"{path}: width {W} is odd: not two photos side by side")
    out = []
    for name, box in (("left", (0, 0, W // 2, H)), ("right", (W // 2, 0, W, H))):
        p = Path(out_dir) / f"{path.stem}_{name}.png"
        im.crop(box).save(p)
        out.append(p)
    return out


def fit_mesh(photos, out_dir, refine: str = "none", model: str = "sfm", fit_args=()) -> dict:
    """Run ``morphable fit PHOTOS --out-mesh --report [--refine REFINE] FIT_ARGS`` ->
    {"vertices": (V, 3) mm of the written mesh, "wall_s": the command's wall time,
    "fit_s": the landmark fit's own time and "refine_s" the refinement's (all photos), from
    the report, "report": the report}.

    FitError with the command's last line when it fails.
    """
    from morphable.io.mesh import read_mesh

    stem = Path(out_dir) / "_".join(Path(p).stem for p in photos)
    cmd = [sys.executable, "-m", "morphable.cli", "fit", *map(str, photos), "--model", model,
           "--out-mesh", f"{stem}.obj", "--report", f"{stem}.json", *fit_args]
    if refine != "none":
        cmd += ["--refine", refine]
    t = time.perf_counter()
    run = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if run.returncode != 0:
        last = (run.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise FitError(f"{shlex.join(cmd)}: {last}")
    report = json.loads(Path(f"{stem}.json").read_text())
    runs = report.get("refine") or []
    return {"vertices": np.asarray(read_mesh(f"{stem}.obj").vertices, dtype=np.float64),
            "wall_s": wall, "fit_s": report["runtime_ms"] / 1000.0,
            "refine_s": max((r["runtime_s"] for r in runs), default=0.0), "report": report}


def scan_rows(refine: str = "none", model_name: str = "sfm", fit_args=(), work=None,
              scan_dir=JAMES) -> list:
    """The bench's rows -> list of dicts (``row``, ``mean_mm``, ``ratio_to_mean_face``,
    ``runtime_s``: landmark fit plus refinement, ``refine_s``, ``wall_s``, ``mask_coverage``
    per photo): mean face, fit to the scan's surface, then the fits of the left photo, the
    right photo and both."""
    from morphable import load_model

    from .florence.methods import Reconstruction, SurfaceFit
    from .florence.protocol import evaluate
    from .scans import load_scan

    scan_dir = Path(scan_dir)
    scan = load_scan(scan_dir / "james.obj", scan_dir / "james.ljson")
    model = load_model(model_name)
    rows = []

    def add(name, vertices, runtime_s, wall_s=None, **more):
        cell, _ = evaluate(Reconstruction.from_vertices(model, vertices, runtime_s, 1), scan)
        rows.append({"row": name, "mean_mm": round(cell["mean_mm"], 4),
                     "runtime_s": round(runtime_s, 3),
                     "wall_s": None if wall_s is None else round(wall_s, 2), **more})

    add("mean face", model.mean.astype(np.float64), 0.0)
    floor = SurfaceFit()
    floor.prepare(model, scan)
    add("model fitted to the scan (floor)", floor.vertices, floor.seconds)
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(work) if work else Path(tmp)
        left, right = split_photos(scan_dir / "james.jpg", work)
        for name, photos in (("left photo", [left]), ("right photo", [right]),
                             ("both photos", [left, right])):
            out = fit_mesh(photos, work, refine, model_name, fit_args)
            add(f"{name}, refine {refine}", out["vertices"], out["fit_s"] + out["refine_s"],
                out["wall_s"], refine_s=round(out["refine_s"], 2),
                mask_coverage=[r.get("mask_coverage") for r in out["report"].get("refine") or []])
    reference = rows[0]["mean_mm"]
    for r in rows:
        r["ratio_to_mean_face"] = round(r["mean_mm"] / reference, 3)
    return rows


def format_rows(rows) -> str:
    """A markdown table of :func:`scan_rows`."""
    lines = ["| row | point-to-plane mm | × mean face | fit + refine s | wall s (command) |",
             "| --- | --- | --- | --- | --- |"]
    for r in rows:
        wall = "-" if r["wall_s"] is None else f"{r['wall_s']:.1f}"
        lines.append(f"| {r['row']} | {r['mean_mm']:.3f} | {r['ratio_to_mean_face']:.2f} | "
                     f"{r['runtime_s']:.2f} | {wall} |")
    return "\n".join(lines)


@one_line_errors("evaluation.bench_scan_photos")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.bench_scan_photos",
                                description=__doc__.split("\n")[0])
    p.add_argument("--refine", default="none",
                   help="none, or a --refine choice of morphable fit (classical, gar, photometric...)")
    p.add_argument("--model", default="sfm")
    p.add_argument("--fit-args", default="", help="further options for morphable fit (one string)")
    p.add_argument("--scan-dir", default=str(JAMES), help="folder with james.obj, .ljson, .jpg")
    p.add_argument("--work", help="keep the split photos, meshes and reports in this folder")
    p.add_argument("--report", help="JSON with the rows")
    args = p.parse_args(argv)
    if args.work and not Path(args.work).is_dir():
        raise InputError(f"{args.work}: --work folder does not exist")
    if args.report and not Path(args.report).resolve().parent.is_dir():
        raise InputError(f"{args.report}: output folder does not exist")
    rows = scan_rows(args.refine, args.model, shlex.split(args.fit_args), args.work, args.scan_dir)
    print(format_rows(rows))
    if args.report:
        from morphable.io.atomic import atomic_path

        command = "python -m evaluation.bench_scan_photos " + shlex.join(
            sys.argv[1:] if argv is None else argv)
        with atomic_path(args.report) as tmp:
            Path(tmp).write_text(json.dumps({"command": command, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
