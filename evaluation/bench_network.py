"""The landmark network's own 68 points on AFLW2000-3D (research use only), the detector's
choices side by side: given the 68 ground-truth points' extent as the box (the dataset's box)
and with its own face detection (``face_detector="auto"``: mediapipe's full-range detector,
the network's window search when it finds none), each with one and with two passes.

NME as :mod:`evaluation.bench_alignment` (mean point distance / sqrt(w h) of the ground
truth's box, per |yaw| bin and their mean); faces missed; median wall ms per photo on one
torch thread (the photo decoded first, not timed).

    python -m evaluation.bench_network --n 100 --weights runs/ldmk_cpu/landmarks.pt
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from morphable.errors import FitError, one_line_errors

__all__ = ["main"]


def _row(name, pred, gt, yaw, ms, missed=0) -> str:
    from .bench_alignment import box_size, nme, yaw_table

    tab = yaw_table(nme(pred, gt, box_size(gt)), yaw)
    cells = [f"{b['nme_percent']:.2f}" if b["nme_percent"] is not None else "—" for b in tab["bins"]]
    mean = f"{tab['mean_percent']:.2f}" if tab["mean_percent"] is not None else "—"
    return f"| {name} | {' | '.join(cells)} | {mean} | {missed} | {np.median(ms):.0f} |"


@one_line_errors("python -m evaluation.bench_network")
def main(argv=None) -> int:
    import torch

    from morphable.detection.images import read_image
    from neural.landmark_detector import NetworkDetector

    from .bench_alignment import data_root, dataset_boxes, load_aflw2000

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n", type=int, default=100, help="the first N photos")
    p.add_argument("--weights", help="landmarks.pt (default: $MORPHABLE_LANDMARK_WEIGHTS or the committed)")
    args = p.parse_args(argv)
    torch.set_num_threads(1)
    d = load_aflw2000(data_root(), args.n)
    gt, yaw = d["gt"], d["yaw_deg"]
    boxes = dataset_boxes(gt)
    images = [read_image(path) for path in d["paths"]]
    print("| box | 0-30° | 30-60° | 60-90° | mean | missed | median ms |\n|---|---|---|---|---|---|---|")
    for passes in (1, 2):
        det = NetworkDetector(args.weights, passes=passes)
        pred, ms = np.full(gt.shape, np.nan), []
        for i, img in enumerate(images):
            t = time.perf_counter()
            pred[i] = det.detect(img, box=boxes[i]).ibug68
            ms.append((time.perf_counter() - t) * 1e3)
        print(_row(f"68 points' extent, {passes} pass{'es' * (passes > 1)}", pred, gt, yaw, ms), flush=True)
    for passes in (1, 2):
        det = NetworkDetector(args.weights, passes=passes)
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
        print(_row(f"own detection ({how}), {passes} pass{'es' * (passes > 1)}", pred, gt, yaw, ms,
                   missed), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
