"""How each face detector's box sits on the landmark network's framing: the numbers of
:data:`neural.landmarks.detector.BOX_FRAMING`.

For AFLW2000-3D photos (research use only), each face detector's largest box
``(cx, cy, side)`` (side: the mean of width and height) against the framing the network was
trained on, :func:`neural.faces.points.face_box` of the photo's 68 points (3D convention):
the medians of ``framing side / side`` and of the centre offset ``/ side``, and how many faces
the detector found. Photos ``--start`` to ``--start + --n`` (the default leaves out the first
100, on which the detector is measured).

    python -m evaluation.detector_boxes --start 100 --n 200
"""
from __future__ import annotations

import argparse

import numpy as np

__all__ = ["framing_of", "main"]


def framing_of(boxes, framing) -> np.ndarray:
    """Detector boxes (N, 4) px and the faces' framing boxes (N, 4) px -> (N, 3): framing side
    over box side, centre offsets x and y over box side."""
    b, f = np.asarray(boxes, np.float64), np.asarray(framing, np.float64)
    side = ((b[:, 2] - b[:, 0]) + (b[:, 3] - b[:, 1])) / 2
    fside = ((f[:, 2] - f[:, 0]) + (f[:, 3] - f[:, 1])) / 2
    dc = ((f[:, :2] + f[:, 2:]) - (b[:, :2] + b[:, 2:])) / 2
    return np.column_stack([fside / side, dc / side[:, None]])


def main(argv=None) -> int:
    from morphable.detection import detect_faces
    from morphable.detection.images import read_image
    from neural.faces.points import face_box

    from .bench_alignment import data_root, load_aflw2000

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--start", type=int, default=100)
    p.add_argument("--n", type=int, default=200)
    p.add_argument("--detectors", nargs="+", default=["full-range", "hog"])
    args = p.parse_args(argv)
    d = load_aflw2000(data_root(), args.start + args.n)
    paths, gt = d["paths"][args.start:], d["gt"][args.start:]
    framing = face_box(gt)
    for kind in args.detectors:
        lm = "dlib" if kind in ("hog", "cnn") else "facemesh"
        rows = []
        for path, f in zip(paths, framing):
            boxes = detect_faces(read_image(path), landmark_detector=lm, face_detector=kind)
            if len(boxes):
                rows.append(framing_of(boxes[:1], f[None])[0])
        r = np.array(rows).reshape(-1, 3)
        med = np.median(r, axis=0)
        print(f"{kind}: found {len(r)}/{len(paths)}; framing side / box side {med[0]:.3f}, "
              f"centre offset / box side ({med[1]:+.3f}, {med[2]:+.3f}); "
              f"scale IQR {np.percentile(r[:, 0], 25):.3f}-{np.percentile(r[:, 0], 75):.3f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
