"""Error against run time: the Florence protocol at several effort levels per method.

Each method runs at a few effort levels (frames per video 1/3/5/10, iterations, identity
modes, gar's refinement steps) on every condition; each level gives one point (seconds per
video, mean point-to-plane error over the conditions). Writes ``reports/error_vs_runtime.png``
(one curve per method), ``.json`` and ``.md``::

    python -m evaluation.report            # the james scan from ../shared/data
    python -m evaluation.report --scan S --scan-landmarks L --out reports
"""
from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

import numpy as np
from tqdm import tqdm

from morphable.errors import FitError, InputError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity

from .florence.methods import prepare_methods, reconstruct_video
from .florence.protocol import evaluate, video_landmarks
from .scans import UNITS, load_scan
from .videos import CONDITIONS

__all__ = ["EFFORTS", "run", "write_outputs", "main"]

_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "scans" / "james"

FRAMES = (1, 3, 5, 10)
EFFORTS = {
    "ours": [{"label": f"{k} frames, {it} iterations", "frames": k, "settings": {"n_iterations": it}}
             for it in (0, 8) for k in FRAMES]
    + [{"label": "5 frames, 20 identity modes", "frames": 5, "settings": {"n_identity": 20}}],
    "ours-independent": [{"label": f"{k} frames", "frames": k, "settings": {}} for k in FRAMES],
    "eos": [{"label": f"{k} frames, {it} iterations", "frames": k, "settings": {"num_iterations": it}}
            for it in (1, 5) for k in FRAMES],
    "mean-face": [{"label": "no fitting", "frames": 1, "settings": {}}],
    "gar": [{"label": f"{k} frames, {s} steps", "frames": k, "settings": {"steps": s}}
            for k, s in ((5, 25), (5, 50), *((k, 100) for k in FRAMES))],
}
"""Effort levels per method: frames per video and the method's own settings."""


def run(scan, model, methods, conditions, seed: int = 0, video_frames: int = 30, log=None,
        progress: bool = False) -> dict:
    """Evaluate every effort level -> ``{"points": [...], "methods", "conditions", ...}``.

    ``log``: callable taking one line per effort level; ``progress``: a tqdm bar (stderr).

    Each point: method, label, frames, settings, ``s_per_video`` (mean over conditions),
    ``mean_mm`` (mean over conditions of the per-video mean error), ``per_condition``.
    """
    for m in methods:
        if m not in EFFORTS:
            raise InputError(f"no effort levels for method {m!r}; choose from {', '.join(EFFORTS)}")
    frames = sorted({e["frames"] for m in methods for e in EFFORTS[m]})
    if max(frames) > video_frames:
        raise InputError(f"--video-frames {video_frames}: effort levels need {max(frames)} frames")
    # made and prepared before minutes of videos and fits (gar: fails here without the plugin)
    made = prepare_methods(methods, model, scan)
    # gar refines the rendered frames themselves
    videos = {(c, k): video_landmarks(scan, model, c, k, video_frames, seed,
                                      with_frames=any(m.needs_images for m in made.values()))
              for c in conditions for k in frames}
    points = []
    bar = tqdm(total=sum(len(EFFORTS[m]) for m in methods) * len(conditions), disable=not progress,
               desc="error vs run time", unit="fit")
    for m in methods:
        for effort in EFFORTS[m]:
            per, secs = {}, []
            for c in conditions:
                bar.set_postfix_str(f"{m}, {effort['label']}, {c}", refresh=False)
                try:
                    rec = reconstruct_video(made[m], videos[(c, effort["frames"])][0],
                                            effort["settings"])
                    cell, _ = evaluate(rec, scan)
                except FitError as e:
                    per[c] = {"error": str(e)}
                    bar.update()
                    continue
                per[c] = {"mean_mm": cell["mean_mm"], "std_mm": cell["std_mm"],
                          "s_per_video": rec.seconds}
                secs.append(rec.seconds)
                bar.update()
            ok = [p["mean_mm"] for p in per.values() if "mean_mm" in p]
            point = {"method": m, "label": effort["label"], "frames": effort["frames"],
                     "settings": effort["settings"], "per_condition": per,
                     "s_per_video": float(np.mean(secs)) if secs else None,
                     "mean_mm": float(np.mean(ok)) if len(ok) == len(conditions) else None}
            points.append(point)
            if log:
                log(f"{m:>17s} {effort['label']:<28s} "
                    + (f"{point['mean_mm']:.3f} mm  {point['s_per_video']:.3f} s/video"
                       if point["mean_mm"] is not None else "failed"))
    bar.close()
    return {"points": points, "methods": list(methods), "conditions": list(conditions),
            "scan": scan.source, "model": model.name, "seed": seed, "video_frames": video_frames,
            "metric": "point-to-plane mm, mean over vertices, then over conditions"}


def _markdown(result: dict) -> str:
    conds = result["conditions"]
    lines = [f"Error against run time on `{Path(result['scan']).name}` (model {result['model']}, "
             f"seed {result['seed']}); error = point-to-plane mm, mean over vertices.", "",
             "| method | effort | s / video | " + " | ".join(conds) + " | mean |",
             "| --- | --- | ---: | " + " | ".join("---:" for _ in conds) + " | ---: |"]
    for p in result["points"]:
        cells = [f"{p['per_condition'][c]['mean_mm']:.3f}" if "mean_mm" in p["per_condition"][c]
                 else "failed" for c in conds]
        secs = "-" if p["s_per_video"] is None else f"{p['s_per_video']:.3f}"
        mean = "-" if p["mean_mm"] is None else f"**{p['mean_mm']:.3f}**"
        lines.append(f"| {p['method']} | {p['label']} | {secs} | " + " | ".join(cells) + f" | {mean} |")
    return "\n".join(lines) + "\n"


def write_outputs(result: dict, out: Path, stem: str = "error_vs_runtime") -> list:
    """Write ``stem``.png/.json/.md into ``out`` (atomically) -> the paths."""
    from morphable.io.atomic import atomic_path
    from evaluation.plots import error_vs_runtime

    paths = [out / f"{stem}.{ext}" for ext in ("png", "json", "md")]
    error_vs_runtime(result, paths[0])
    with atomic_path(paths[1]) as tmp:
        tmp.write_text(json.dumps(result, indent=1))
    with atomic_path(paths[2]) as tmp:
        tmp.write_text(_markdown(result))
    return paths


@one_line_errors("evaluation.report")
def main(argv=None) -> int:
    from tqdm.contrib.logging import logging_redirect_tqdm

    p = argparse.ArgumentParser(prog="python -m evaluation.report", description=__doc__.split("\n")[0])
    p.add_argument("--scan", default=str(_DATA / "james.obj"))
    p.add_argument("--scan-landmarks", default=str(_DATA / "james.ljson"))
    p.add_argument("--scan-units", default="auto", choices=[*UNITS, "auto"])
    p.add_argument("--methods", nargs="+", default=list(EFFORTS))
    p.add_argument("--conditions", nargs="+", default=list(CONDITIONS))
    p.add_argument("--model", default="sfm")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--video-frames", type=int, default=30)
    p.add_argument("--out", default="reports", help="output folder (created if missing)")
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    for c in args.conditions:
        if c not in CONDITIONS:
            raise InputError(f"unknown condition {c!r}; choose from {', '.join(CONDITIONS)}")
    out = Path(args.out)
    existing = next(p for p in (out, *out.absolute().parents) if p.exists())
    if not existing.is_dir():  # fail now, not after minutes of fitting
        raise InputError(f"{out}: cannot create the output folder ({existing} is a file)")
    from morphable import load_model

    model = load_model(args.model)
    scan = load_scan(args.scan, args.scan_landmarks, args.scan_units)
    with logging_redirect_tqdm():
        result = run(scan, model, args.methods, args.conditions, args.seed, args.video_frames,
                     log=logging.getLogger("evaluation.report").info, progress=not args.quiet)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise InputError(f"{out}: cannot create the output folder ({e.strerror or e})") from None
    result["command"] = "python -m evaluation.report " + " ".join(
        sys.argv[1:] if argv is None else argv)
    paths = write_outputs(result, out)
    print(_markdown(result))
    print("wrote " + ", ".join(map(str, paths)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
