"""Detection time per photo: dlib (HOG face detector + 68-point predictor) against the face
mesh (mediapipe, 478 points), on the 4 classic photos of ``../shared/data/images`` and the
first photos of 300-W (afw) and AFLW2000-3D.

Each photo is decoded first (not timed), detected once as a warm-up (the first call loads the
models), then ``--repeats`` more times; a photo's time is the median of those. The table
gives, per set and detector, the median and the maximum over the photos, the photos' size in
megapixels and how many faces were found. Command::

    python -m evaluation.bench_detection --n-300w 15 --n-aflw 15 --report reports/bench_detection.json

The issue's target: detection <= 30 ms per photo of <= 1.5 MP.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from morphable.errors import one_line_errors

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
CLASSIC = ("image_0010.png", "takeo.ppm", "einstein.jpg", "breakingbad.jpg")
DETECTORS = (("dlib", "hog"), ("facemesh", "auto"))


def photo_sets(n_300w: int, n_aflw: int) -> dict:
    """{set name: [paths]}."""
    return {"classic": [DATA / "images" / c for c in CLASSIC],
            "300-W afw": sorted((DATA / "images" / "300w" / "afw").glob("*.jpg"))[:n_300w],
            "AFLW2000-3D": sorted((DATA / "aflw2000").glob("image*.jpg"))[:n_aflw]}


def time_photo(img: np.ndarray, landmark_detector: str, face_detector: str, repeats: int):
    """-> (median ms of ``repeats`` calls after a warm-up, whether a face was found)."""
    from morphable.detection import detect_landmarks
    from morphable.errors import FitError

    def once():
        t = time.perf_counter()
        try:
            detect_landmarks(img, landmark_detector=landmark_detector, face_detector=face_detector)
            found = True
        except FitError:
            found = False
        return 1000 * (time.perf_counter() - t), found

    _, found = once()
    return float(np.median([once()[0] for _ in range(max(1, repeats))])), found


def run(sets: dict, repeats: int = 3) -> dict:
    from morphable.detection import read_image

    out = {}
    for name, paths in sets.items():
        images = [read_image(p) for p in paths]
        mp = [im.shape[0] * im.shape[1] / 1e6 for im in images]
        row = {"n": len(images), "megapixels": [round(min(mp), 3), round(max(mp), 3)]}
        for ld, fd in DETECTORS:
            timed = [time_photo(im, ld, fd, repeats) for im in images]
            ms = [t for t, _ in timed]
            row[ld] = {"median_ms": round(float(np.median(ms)), 1), "max_ms": round(float(np.max(ms)), 1),
                       "found": int(sum(f for _, f in timed)),
                       "per_photo_ms": {p.name: round(t, 1) for p, t in zip(paths, ms)}}
        out[name] = row
    return out


def format_table(result: dict) -> str:
    lines = ["| photos | n | MP | dlib hog: median / max ms, found | face mesh: median / max ms, found |",
             "|---|---|---|---|---|"]
    for name, r in result.items():
        cells = [f"{r[d]['median_ms']:.0f} / {r[d]['max_ms']:.0f}, {r[d]['found']}/{r['n']}"
                 for d, _ in DETECTORS]
        lines.append(f"| {name} | {r['n']} | {r['megapixels'][0]:.2f}-{r['megapixels'][1]:.2f} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines)


@one_line_errors("python -m evaluation.bench_detection")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.bench_detection",
                                description=__doc__.split("\n\n")[0])
    p.add_argument("--n-300w", type=int, default=15, help="300-W afw photos (default 15)")
    p.add_argument("--n-aflw", type=int, default=15, help="AFLW2000-3D photos (default 15)")
    p.add_argument("--repeats", type=int, default=3, help="timed calls per photo after the warm-up")
    p.add_argument("--report", help="output JSON")
    args = p.parse_args(argv)
    result = run(photo_sets(args.n_300w, args.n_aflw), args.repeats)
    print(format_table(result))
    if args.report:
        from morphable.io.atomic import atomic_path

        with atomic_path(args.report) as tmp:
            Path(tmp).write_text(json.dumps({"command": "python -m evaluation.bench_detection "
                                             + " ".join(sys.argv[1:] if argv is None else argv),
                                             "sets": result}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
