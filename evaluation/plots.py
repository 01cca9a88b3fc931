"""Plots of evaluation reports (matplotlib, extra ``viz``/``eval``): the one plotting module.

- :func:`error_vs_runtime` — error against run time per method, from the JSON of
  ``python -m evaluation.report`` (``{"points": [...], "methods", "conditions", ...}``);
- :func:`condition_bars` — mean ± std error per method and condition, from a Florence report
  (``python -m evaluation.florence``: ``{"methods": {m: {condition: cell}}, ...}``) or from an
  error-vs-runtime result (the best effort level of each method);
- :func:`fitting_sweep` — ``evaluation.bench_fitting``'s synthetic sweep (``{"curves", ...}``);
- :func:`plot_report` — any of these from a JSON file, chosen by its keys
  (``python -m evaluation.plots REPORT.json --out plot.png``).

Figures are drawn on a :class:`matplotlib.figure.Figure` with the Agg canvas (no pyplot
state, no display needed) and written atomically; every function returns the path.

Examples
--------
>>> import tempfile
>>> report = {"methods": {"ours": {"indoor": {"mean_mm": 1.2, "std_mm": 0.8}},
...                       "eos": {"indoor": {"mean_mm": 0.9, "std_mm": 0.6}}}}
>>> condition_bars(report, Path(tempfile.mkdtemp()) / "bars.png").name
'bars.png'
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity

__all__ = ["error_vs_runtime", "condition_bars", "fitting_sweep", "plot_report", "report_kind",
           "check_plot_path"]


def _figure(size):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=size)
    FigureCanvasAgg(fig)
    return fig


_FORMATS = ("png", "pdf", "svg", "jpg", "jpeg")


def check_plot_path(path) -> Path:
    """Raise InputError unless ``path`` is a .png/.pdf/.svg/.jpg in an existing folder
    (check before a long run, not after)."""
    path = Path(path)
    if path.suffix.lstrip(".").lower() not in _FORMATS:
        raise InputError(f"{path}: plots are written as .png, .pdf, .svg or .jpg")
    if not path.resolve().parent.is_dir():
        raise InputError(f"{path}: output folder {path.resolve().parent} does not exist")
    return path


def _save(fig, path, dpi=120) -> Path:
    from morphable.io.atomic import atomic_path

    path = check_plot_path(path)
    fmt = path.suffix.lstrip(".").lower()
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=dpi, format=fmt)
    return path


def _key_error(path, e) -> InputError:
    return InputError(f"{path}: not a report of this kind (missing {e})")


def error_vs_runtime(result: dict, path) -> Path:
    """Error (mm) against seconds per video (log scale), one curve per method.

    Parameters
    ----------
    result : dict from :func:`evaluation.report.run`: ``points`` (each with ``method``,
        ``frames``, ``s_per_video`` s, ``mean_mm`` mm or None when failed), ``methods``,
        ``conditions``, ``scan``.
    path : output image (.png, .pdf, .svg)

    Dots are the effort levels (labelled with frames per video); the line of a method is the
    best error it reaches within each time budget; a method that takes no time (the mean
    face) is a dashed floor.
    """
    try:
        points, methods = result["points"], result["methods"]
        title = (f"Error vs run time, {Path(result['scan']).name}, mean of "
                 f"{'/'.join(result['conditions'])}")
    except (KeyError, TypeError) as e:
        raise _key_error("result", e) from None
    fig = _figure((7, 4.5))
    ax = fig.add_subplot()
    for m in methods:
        pts = [p for p in points if p["method"] == m and p.get("mean_mm") is not None]
        if not pts:
            continue
        if all(p["s_per_video"] == 0 for p in pts):  # no fitting: a floor, not a curve
            ax.axhline(pts[0]["mean_mm"], ls="--", color="gray", label=f"{m} (no fitting)")
            continue
        pts.sort(key=lambda p: p["s_per_video"])
        x = np.array([max(p["s_per_video"], 1e-4) for p in pts])
        y = np.array([p["mean_mm"] for p in pts])
        front = y <= np.minimum.accumulate(y)
        line, = ax.plot(x[front], y[front], "-", label=m)
        ax.plot(x, y, "o", color=line.get_color(), alpha=0.8, ms=4)
        for p, xi in zip(pts, x):
            ax.annotate(str(p["frames"]), (xi, p["mean_mm"]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
    ax.set_xscale("log")
    ax.set_xlabel("seconds per video (fitting only)")
    ax.set_ylabel("point-to-plane error (mm)")
    ax.set_title(title + "\n(dots: effort levels labelled with frames per video; lines: best "
                 "error within a time budget)", fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(fontsize=8)
    return _save(fig, path)


def _cells(report: dict) -> dict:
    """{method: {condition: (mean_mm, std_mm) or None}} from either report shape."""
    if "points" in report:  # error vs run time: the best effort level of each method
        out = {}
        for m in report["methods"]:
            pts = [p for p in report["points"] if p["method"] == m and p.get("mean_mm") is not None]
            if pts:
                best = min(pts, key=lambda p: p["mean_mm"])
                out[f"{m} ({best['label']})"] = {
                    c: (cell["mean_mm"], cell.get("std_mm", 0.0)) if "mean_mm" in cell else None
                    for c, cell in best["per_condition"].items()}
        return out
    return {m: {c: (cell["mean_mm"], cell.get("std_mm", 0.0)) if "mean_mm" in cell else None
                for c, cell in per.items()}
            for m, per in report["methods"].items()}


def condition_bars(report: dict, path, metric: str = "point-to-plane error (mm)") -> Path:
    """Grouped bars: one group per condition, one bar per method, mean ± std (mm).

    Parameters
    ----------
    report : a Florence report (``{"methods": {m: {condition: {"mean_mm", "std_mm"}}}}``;
        failed cells hold ``"error"`` and are marked "failed") or an error-vs-runtime result.
    path : output image (.png, .pdf, .svg)
    """
    try:
        cells = _cells(report)
    except (KeyError, TypeError, AttributeError) as e:
        raise _key_error("report", e) from None
    methods = list(cells)
    conds = list(dict.fromkeys(c for per in cells.values() for c in per))
    if not methods or not conds:
        raise InputError("report: no methods or conditions to plot")
    wide = max(len(m) for m in methods) > 18
    fig = _figure((max(5.0, 1.2 + 0.45 * len(methods) * len(conds)) + 3.0 * wide, 4))
    ax = fig.add_subplot()
    width = 0.8 / len(methods)
    x = np.arange(len(conds))
    for i, m in enumerate(methods):
        vals = [cells[m].get(c) for c in conds]
        mean = np.array([v[0] if v else np.nan for v in vals])
        std = np.array([v[1] if v else 0.0 for v in vals])
        xi = x - 0.4 + width * (i + 0.5)
        ax.bar(xi, np.nan_to_num(mean), width, yerr=std, capsize=3, label=m)
        for xj, v in zip(xi, mean):
            ax.annotate("failed" if np.isnan(v) else f"{v:.2f}", (xj, 0 if np.isnan(v) else v),
                        ha="center", va="bottom", fontsize=7, xytext=(0, 2),
                        textcoords="offset points")
    ax.set_xticks(x, conds)
    ax.set_ylabel(metric)
    ax.set_ylim(bottom=0)
    ax.grid(True, axis="y", alpha=0.3)
    ax.set_axisbelow(True)
    # outside the axes, where it cannot hide a bar or its error bar
    if wide:  # long labels (effort levels): beside the axes
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    else:
        ax.legend(fontsize=8, ncol=min(len(methods), 4), loc="upper center",
                  bbox_to_anchor=(0.5, -0.1))
    return _save(fig, path)


def fitting_sweep(result: dict, path) -> Path:
    """Mean 3D vertex error (mm) against time per fit (ms) of ``evaluation.bench_fitting``.

    ``result``: ``{"curves": {name: [{"ms", "mean_mm"}, ...]}, "sigma_px", "n", "eos":
    {"ms", "mean_mm"} (optional)}``.
    """
    try:
        curves = result["curves"]
        title = (f"SFM landmark fitting, noise {result['sigma_px']:g} px, n={result['n']}"
                 "\n(points: 0, 1, 2, 4, 8 LM iterations)")
    except (KeyError, TypeError) as e:
        raise _key_error("result", e) from None
    fig = _figure((6, 4))
    ax = fig.add_subplot()
    for name, pts in curves.items():
        ax.plot([p["ms"] for p in pts], [p["mean_mm"] for p in pts], "o-", label=f"ours, {name}")
    if "eos" in result:
        ax.plot([result["eos"]["ms"]], [result["eos"]["mean_mm"]], "k*", ms=12,
                label="eos fit_shape_and_pose")
    ax.set_xscale("log")
    ax.set_xlabel("time per fit (ms, median)")
    ax.set_ylabel("mean 3D vertex error (mm)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    return _save(fig, path, dpi=90)


def report_kind(report: dict) -> str:
    """"runtime" (evaluation.report), "florence" (evaluation.florence) or "sweep"
    (evaluation.bench_fitting); InputError otherwise."""
    if isinstance(report, dict):
        if "points" in report:
            return "runtime"
        if isinstance(report.get("methods"), dict):
            return "florence"
        if "curves" in report:
            return "sweep"
    raise InputError("report: not an evaluation report (expected 'points', 'methods' or 'curves')")


def plot_report(report_path, out, kind: str | None = None) -> Path:
    """Plot a report JSON file -> ``out``.

    ``kind``: "runtime" (error vs run time), "bars" (per-condition bars), "sweep"; default
    by the report: error vs run time for ``evaluation.report``, bars for Florence reports,
    the sweep for ``bench_fitting``.
    """
    p = Path(report_path)
    try:
        report = json.loads(p.read_text())
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"{p}: cannot read ({getattr(e, 'strerror', None) or e})") from None
    except json.JSONDecodeError as e:
        raise InputError(f"{p}: not JSON ({e.msg} at line {e.lineno})") from None
    try:
        found = report_kind(report)
    except InputError as e:
        raise InputError(f"{p}: {str(e).removeprefix('report: ')}") from None
    kind = kind or {"runtime": "runtime", "florence": "bars", "sweep": "sweep"}[found]
    allowed = {"runtime": ("runtime", "bars"), "florence": ("bars",), "sweep": ("sweep",)}[found]
    if kind not in allowed:
        raise InputError(f"{p}: a {found} report cannot be drawn as {kind!r} "
                         f"(choose {', '.join(allowed)})")
    draw = {"runtime": error_vs_runtime, "bars": condition_bars, "sweep": fitting_sweep}[kind]
    try:
        return draw(report, out)
    except InputError as e:
        raise InputError(f"{p}: {e}") from None
    except (KeyError, TypeError, AttributeError) as e:
        raise _key_error(p, e) from None


@one_line_errors("python -m evaluation.plots")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.plots",
                                description="plot an evaluation report JSON (matplotlib)")
    p.add_argument("report", metavar="REPORT", help="JSON of evaluation.report, evaluation.florence "
                                                    "or evaluation.bench_fitting")
    p.add_argument("--out", required=True, help="output image (.png, .pdf, .svg)")
    p.add_argument("--kind", choices=("runtime", "bars", "sweep"),
                   help="plot (default: error vs run time for evaluation.report, per-condition "
                        "bars for Florence reports, the sweep for bench_fitting)")
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    check_plot_path(args.out)
    if not Path(args.report).is_file():
        raise InputError(f"{args.report}: no such report")
    print(plot_report(args.report, args.out, kind=args.kind))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
