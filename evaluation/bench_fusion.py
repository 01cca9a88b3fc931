"""How to weigh the face mesh against the landmark network when fusing them
(:mod:`morphable.detection.fusion`): rules for the face mesh's σ compared on validation sets,
never on a test set.

A rule gives the face mesh's σ on a face from the mean squared distance between the two
readings' 478 points, ``mean |d|²`` px², and the network's mean σ², ``mean σ²``:
``σ_o² = a mean|d|² - b mean σ²`` (at least ``FLOOR² mean σ²``), :data:`RULES`:

- ``independent`` (a, b) = (1/2, 1), the library's (:func:`~morphable.detection.fusion.other_std_px`):
  the estimate for two independent errors;
- ``double`` (1, 1): the face mesh's σ² counted about twice that;
- ``half`` (1/4, 1/2): half of it.

``packs``: the trainer's held-out faces (:func:`evaluation.bench_network.held_out`: the last 256
faces of the synthetic SFM pack, the annotated pack's validation split, the profiled pack's), each
read by the network and by the face mesh in the pack's face box; NME (mean distance of the
labelled 68 points / the 68 points' extent, %) per ``|yaw|`` bin and over all faces, of the 68 rows
(the network's own, the face mesh's mapped, fused) and of the SFM fit to the 478 rows as
``morphable fit`` makes it (scored by its projected 68 points, 3D convention). A face the face
mesh does not find is the network's alone in the fused rows, and a failure in the face mesh's.

``florence RULE -- ARGS``: ``python -m evaluation.florence ARGS`` with that rule in the fused
detector (the Florence protocol's ICT and SFM subjects are the fitter's validation sets; james
is held out)::

    python -m evaluation.bench_fusion packs --report reports/bench_fusion_packs.json
    python -m evaluation.bench_fusion florence double -- --synthetic-scan ict --n-scans 6 \\
        --n-videos 5 --detect --landmark-detector fused --appearance ... --report r.json
"""
from __future__ import annotations

import argparse
import functools
import sys
from pathlib import Path
from unittest import mock

import numpy as np

from morphable.errors import FitError, one_line_errors
from morphable.io.atomic import write_json

__all__ = ["RULES", "rule", "main"]

RULES = {"independent": (0.5, 1.0), "double": (1.0, 1.0), "half": (0.25, 0.5)}
"""name -> (a, b) of ``σ_o² = a mean|d|² - b mean σ²``."""


def rule(name: str):
    """The ``other_std_px(measured, other) -> px`` of rule ``name`` (:data:`RULES`): the
    library's :func:`~morphable.detection.fusion.other_std_px` with that rule's coefficients."""
    from morphable.detection.fusion import other_std_px

    a, b = RULES[name]
    return functools.partial(other_std_px, a=a, b=b)


def _readings(d: dict) -> list:
    """(network, face mesh or None) Detections of each held-out face, in its pack's box."""
    from morphable.detection import detect
    from neural.landmarks.detector import extent_box

    out = []
    for img, box in zip(d["images"], extent_box(d["boxes"])):
        net = detect(img, landmark_detector="network", box=box)
        try:
            mesh = detect(img, landmark_detector="facemesh", box=box)
        except FitError:
            mesh = None
        out.append((net, mesh))
    return out


def _fitted68(model, found, size) -> np.ndarray:
    from morphable.fitting import fit_landmarks
    from morphable.fitting.options import detection_settings

    res = fit_landmarks(model, found.points, size, **detection_settings([found], len(found.points)))
    return res.landmarks_68_px("3d")[0]


def _packs(args) -> dict:
    from morphable import load_model
    from morphable.detection import fusion
    from neural.faces.points import BOX_SCALE, box_side

    from .bench_alignment import yaw_table
    from .bench_network import PACKS, held_out

    model = load_model("sfm")
    report = {}
    for name, d in held_out(Path(args.packs or PACKS)).items():
        n = len(d["images"]) if args.n is None else min(args.n, len(d["images"]))
        d = {k: v[:n] for k, v in d.items()}
        size = box_side(d["boxes"]) / BOX_SCALE
        image_size = (d["images"].shape[2], d["images"].shape[1])
        readings = _readings(d)
        rows = {"network": [net for net, _ in readings], "face mesh": [m for _, m in readings]}
        for r in RULES:
            with mock.patch.object(fusion, "other_std_px", rule(r)):
                rows[f"fused, {r}"] = [net if m is None else fusion.fuse(net, m) for net, m in readings]
        table = {}
        for row, found in rows.items():
            for what in ("68 rows", "fit"):
                err = np.full(n, np.nan)
                for i, f in enumerate(found):
                    if f is not None:
                        pred = f.ibug68 if what == "68 rows" else _fitted68(model, f, image_size)
                        dist = np.linalg.norm(pred - d["points"][i], axis=-1)
                        err[i] = 100 * np.nanmean(dist) / size[i]
                tab = yaw_table(err, d["yaw_deg"])
                table[f"{row}: {what}"] = {"bins": [b["nme_percent"] for b in tab["bins"]],
                                           "all": float(np.nanmean(err)),
                                           "failures": int(np.isnan(err).sum())}
        report[name] = {"faces": n, "rows": table}
        print(f"\n{name}, {n} faces (NME %, face mesh failures in brackets)\n\n"
              "| reading | 0-30° | 30-60° | 60-90° | all |\n|---|---|---|---|---|")
        for row, v in table.items():
            cells = " | ".join("—" if b is None else f"{b:.2f}" for b in v["bins"])
            fail = f" ({v['failures']})" if v["failures"] else ""
            print(f"| {row} | {cells} | {v['all']:.3f}{fail} |", flush=True)
    return report


@one_line_errors("python -m evaluation.bench_fusion")
def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    rest = []
    if "--" in argv:
        i = argv.index("--")
        argv, rest = argv[:i], argv[i + 1:]
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    q = sub.add_parser("packs", help="the rules on the held-out faces of the training packs")
    q.add_argument("--n", type=int, help="the first N faces of each pack (default all)")
    q.add_argument("--packs", help="the folder of the landmark packs (default landmark_data/)")
    q.add_argument("--report", help="JSON of the tables")
    f = sub.add_parser("florence", help="evaluation.florence with a rule (its arguments after --)")
    f.add_argument("rule", choices=tuple(RULES))
    args = p.parse_args(argv)
    if args.command == "florence":
        from morphable.detection import fusion

        from .florence.cli import main as florence

        with mock.patch.object(fusion, "other_std_px", rule(args.rule)):
            return florence(rest)
    import torch

    torch.set_num_threads(1)
    report = _packs(args)
    if args.report:
        write_json(args.report, report)
        print(f"\nwrote {args.report}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
