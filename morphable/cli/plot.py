"""``morphable plot``: draw an evaluation report (error vs run time, per-condition bars)."""
from pathlib import Path


def add_parser(sub):
    p = sub.add_parser("plot", help="plot an evaluation report JSON (matplotlib)")
    p.add_argument("report", metavar="REPORT", help="JSON of evaluation.report, evaluation.florence "
                                                    "or evaluation.bench_fitting")
    p.add_argument("--out", required=True, help="output image (.png, .pdf, .svg)")
    p.add_argument("--kind", choices=("runtime", "bars", "sweep"),
                   help="plot (default: error vs run time for evaluation.report, per-condition "
                        "bars for Florence reports, the sweep for bench_fitting)")
    return p


def run(args):
    from ..errors import InputError
    from ..plots import check_plot_path, plot_report

    check_plot_path(args.out)
    if not Path(args.report).is_file():
        raise InputError(f"{args.report}: no such report")
    print(plot_report(args.report, args.out, kind=args.kind))
    return 0
