"""The landmark network's detector options side by side: one or two passes, with and without
the mirrored crop (``mirror``), on the held-out packs or on AFLW2000-3D.

``--set validation`` (the default; choose options here, never on a test set): the faces the
trainer holds out, each framed by its pack's face box: the last 256 faces of the synthetic
SFM pack (exact labels), the annotated pack's validation split (AFLW's own sparse 2D
annotations of visible points, 4-16 of the 68) and the profiled pack's (its 3D-convention
fit, 66 points). Error: mean distance of the labelled 68 points / the 68 points' extent (the
face box side / :data:`neural.faces.points.BOX_SCALE`), %, per ``|yaw|`` bin, their mean and the
mean over all faces; calibration: the mean of d² / (2σ²) over the labelled points (1 when the
network's σ is right).

``--set aflw2000`` (research use only; a test set): given the 68 ground-truth points' extent
as the box (the dataset's box) and with its own face detection (``face_detector="auto"``),
NME as :mod:`evaluation.bench_alignment` (mean point distance / sqrt(w h) of the ground
truth's box, per ``|yaw|`` bin and their mean); faces missed; and for the default options how
much of the error is a bias all faces share (:func:`bias_table`). With the dataset's box, a
row of the peer 3DDFA-V2 (its released MobileNet-0.5, :mod:`evaluation.peers_3ddfa`, files from
``--3ddfa-dir`` or ``$MORPHABLE_3DDFA_DIR``; one printed line says when it is skipped).

Median wall ms per face on one thread (torch's or onnxruntime's: ``--backend``, default the
detector's, :mod:`neural.landmarks.runtime`; the photo decoded first, not timed; with the
dataset's box each photo read by every option in turn).

    python -m evaluation.bench_network --set validation --weights runs/ldmk_cpu_c/landmarks.pt
    python -m evaluation.bench_network --set aflw2000 --n 100
    python -m evaluation.bench_network --set aflw2000 --n 200 --backend torch
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from morphable.errors import FitError, InputError, one_line_errors

from .peers_3ddfa import add_dir_argument

__all__ = ["main", "OPTIONS", "bias_table", "held_out"]

OPTIONS = ((1, False), (1, True), (2, False), (2, True))
"""(passes, mirror) compared."""
PACKS = Path(__file__).resolve().parents[1] / "landmark_data"


def _row(name, errors, yaw, ms, missed=0, calibration=None) -> str:
    from .bench_alignment import yaw_table

    tab = yaw_table(errors, yaw)
    cells = [f"{b['nme_percent']:.2f}" if b["nme_percent"] is not None else "—" for b in tab["bins"]]
    mean = f"{tab['mean_percent']:.2f}" if tab["mean_percent"] is not None else "—"
    every = f"{np.nanmean(errors):.2f}" if np.isfinite(errors).any() else "—"
    cal = "" if calibration is None else f" {np.nanmean(calibration):.2f} |"
    return f"| {name} | {' | '.join(cells)} | {mean} | {every} | {missed} |{cal} {np.median(ms):.1f} |"


def _option(passes, mirror) -> str:
    return f"{passes} pass{'es' * (passes > 1)}{', mirror' if mirror else ''}"


def held_out(packs: Path, hold_out: int = 256) -> dict:
    """The trainer's held-out faces (:func:`neural.landmarks.train.load_sources`) of the packs
    under ``packs`` that exist (InputError when none does): name ->
    dict of ``images`` (N, H, W, 3) uint8, ``points`` (N, 68, 2) px (NaN unlabelled),
    ``boxes`` (N, 4) framing px, ``yaw_deg`` (N,)."""
    from neural.landmarks.data import load_source
    from neural.faces.points import IBUG_ROWS

    out = {}
    for name, kind, sub in (("synthetic SFM", "synthetic", "synthetic_sfm160"),
                            ("annotated (AFLW)", "annotated", "annotated"),
                            ("profiled", "profiled", "profiled")):
        if not (packs / sub).is_dir():
            continue
        s = load_source(packs / sub, kind, "validation")
        if kind == "synthetic":
            s = s.subset(np.arange(max(0, len(s) - hold_out), len(s)))
        out[name] = {"images": s.images.numpy(), "points": s.points.numpy()[:, IBUG_ROWS],
                     "boxes": s.boxes.numpy().astype(np.float64), "yaw_deg": s.yaw}
    if not out:
        raise InputError(f"{packs}: none of the packs synthetic_sfm160, annotated, profiled "
                         "(make landmark-data builds them)")
    return out


def _validation(args) -> None:
    from neural.landmarks.detector import NetworkDetector, extent_box
    from neural.faces.points import BOX_SCALE, box_side

    detectors = {opt: NetworkDetector(args.weights, passes=opt[0], mirror=opt[1], backend=args.backend)
                 for opt in OPTIONS}
    for name, d in held_out(Path(args.packs)).items():
        n = len(d["images"]) if args.n is None else min(args.n, len(d["images"]))
        extent = extent_box(d["boxes"][:n])
        size = box_side(d["boxes"][:n]) / BOX_SCALE
        print(f"\n{name}, {n} faces\n\n| options | 0-30° | 30-60° | 60-90° | mean | all | missed | "
              "d²/2σ² | median ms |\n|---|---|---|---|---|---|---|---|---|")
        for (passes, mirror), det in detectors.items():
            err, cal, ms = np.full(n, np.nan), np.full(n, np.nan), []
            for i in range(n):
                t = time.perf_counter()
                found = det.detect(d["images"][i], box=extent[i])
                ms.append((time.perf_counter() - t) * 1e3)
                dist = np.linalg.norm(found.ibug68 - d["points"][i], axis=-1)
                err[i] = 100 * np.nanmean(dist) / size[i]
                cal[i] = np.nanmean(dist ** 2 / (2 * found.ibug68_sigma_px ** 2))
            print(_row(_option(passes, mirror), err, d["yaw_deg"][:n], ms, calibration=cal), flush=True)


def bias_table(pred, gt, norm, yaw_deg) -> str:
    """How much of an error is a bias every face of a ``|yaw|`` bin shares (a difference of
    landmark definition, say) -> a markdown table: per bin, the NME (% of ``norm``) and the
    NME after subtracting each point's mean normalised offset, the mean estimated on the
    other half of the bin's faces (even and odd rows, cross-fitted: no face scores its own
    bias away), and the points with the largest bias (1-based iBUG numbers, % of ``norm``).
    A diagnosis, not a correction: nothing uses the bias.

    pred, gt : (N, 68, 2) px; norm (N,) px; yaw_deg (N,)"""
    from .bench_alignment import yaw_bins

    lines = ["| \\|yaw\\| | faces | NME % | without the shared bias % | largest bias (iBUG point: %) |",
             "|---|---|---|---|---|"]
    for lo, hi, mask in yaw_bins(yaw_deg):
        sel = np.flatnonzero(mask)
        r = (pred[sel] - gt[sel]) / norm[sel, None, None]
        if len(sel) < 2:
            continue
        halves = (np.arange(len(sel)) % 2 == 0, np.arange(len(sel)) % 2 == 1)
        left = np.concatenate([np.linalg.norm(r[ev] - np.nanmean(r[fit], 0), axis=-1).ravel()
                               for fit, ev in (halves, halves[::-1])])
        mu = np.linalg.norm(np.nanmean(r, 0), axis=-1)
        top = np.argsort(-np.nan_to_num(mu))[:5]
        name = f"{lo:.0f}-{hi:.0f}°" if np.isfinite(hi) else f"> {lo:.0f}°"
        lines.append(f"| {name} | {len(sel)} | {100 * np.nanmean(np.linalg.norm(r, axis=-1)):.2f} | "
                     f"{100 * np.nanmean(left):.2f} | "
                     f"{', '.join(f'{k + 1}: {100 * mu[k]:.1f}' for k in top)} |")
    return "\n".join(lines)


def _aflw2000(args) -> None:
    from morphable.detection.images import read_image
    from neural.landmarks.detector import MIRROR, PASSES, NetworkDetector

    from .bench_alignment import box_size, data_root, dataset_boxes, load_aflw2000, nme
    from .peers_3ddfa import ThreeDDFA, unavailable

    d = load_aflw2000(data_root(), args.n)
    gt, yaw = d["gt"], d["yaw_deg"]
    norm = box_size(gt)
    boxes = dataset_boxes(gt)
    images = [read_image(path) for path in d["paths"]]
    why = unavailable(args.ddfa_dir)
    if why:
        print(f"3ddfa-v2: skipped, {why}")
    print("| box, options | 0-30° | 30-60° | 60-90° | mean | all | missed | median ms |\n"
          "|---|---|---|---|---|---|---|---|")
    detectors = {opt: NetworkDetector(args.weights, passes=opt[0], mirror=opt[1],
                                      backend=args.backend) for opt in OPTIONS}
    readers = {f"68 points' extent, {_option(*opt)}": (lambda img, box, det=det: det.detect(img, box=box).ibug68)
               for opt, det in detectors.items()}
    if not why:
        readers["68 points' extent, 3DDFA-V2 MobileNet-0.5 (released)"] = ThreeDDFA(args.ddfa_dir).ibug68
    for read in readers.values():
        read(images[0], boxes[0])                            # warm-up
    pred = {k: np.full(gt.shape, np.nan) for k in readers}
    ms = {k: [] for k in readers}
    # each photo read by every option in turn, so that a change of the machine's load falls on all
    for i, img in enumerate(images):
        for k, read in readers.items():
            t = time.perf_counter()
            pred[k][i] = read(img, boxes[i])
            ms[k].append((time.perf_counter() - t) * 1e3)
    for k in readers:
        print(_row(k, nme(pred[k], gt, norm), yaw, ms[k]), flush=True)
    default = pred[f"68 points' extent, {_option(PASSES, MIRROR)}"]
    for (passes, mirror), det in detectors.items():
        pred, ms, found = np.full(gt.shape, np.nan), [], {}
        for i, img in enumerate(images):
            t = time.perf_counter()
            try:
                r = det.detect(img)
            except FitError:
                continue
            ms.append((time.perf_counter() - t) * 1e3)
            pred[i] = r.ibug68
            found[r.detector] = found.get(r.detector, 0) + 1
        missed = len(images) - sum(found.values())
        how = ", ".join(f"{v} by {k.split()[1]}" for k, v in sorted(found.items()))
        print(_row(f"own detection ({how}), {_option(passes, mirror)}", nme(pred, gt, norm), yaw,
                   ms, missed), flush=True)
    print("\nThe default options' error (68 points' extent) and what is left of it without a bias "
          "that every face of a bin shares:\n")
    print(bias_table(default, gt, norm, yaw))


@one_line_errors("python -m evaluation.bench_network")
def main(argv=None) -> int:
    import importlib.util

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--set", choices=("validation", "aflw2000"), default="validation")
    p.add_argument("--n", type=int, help="the first N faces of each set (default: validation all, "
                   "aflw2000 100)")
    p.add_argument("--packs", default=str(PACKS), help="the folder of the landmark packs "
                   "(validation; default landmark_data/)")
    p.add_argument("--weights", help="landmarks.pt (default: $MORPHABLE_LANDMARK_WEIGHTS or the committed)")
    add_dir_argument(p)
    p.add_argument("--backend", choices=("auto", "onnxruntime", "torch"), default="auto",
                   help="what runs the network (auto: onnxruntime where its graph is beside the weights)")
    args = p.parse_args(argv)
    if importlib.util.find_spec("torch") is not None:
        import torch

        torch.set_num_threads(1)
    if args.set == "validation":
        _validation(args)
    else:
        args.n = 100 if args.n is None else args.n
        _aflw2000(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
