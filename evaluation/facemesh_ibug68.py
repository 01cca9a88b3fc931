"""Derive ``morphable.detection.facemesh.FACEMESH_TO_IBUG68``: per iBUG-68 point, the face-mesh
point that lies nearest to it on annotated photos.

On each photo the face mesh runs in the annotation's box (so that it describes the annotated
face); each of the 68 annotated points is compared with every mesh point, the distance
normalised by sqrt(w * h) of the annotation's box and averaged over the photos; per iBUG
point the mesh point with the smallest mean wins. The jaw (iBUG 1-17) chooses among the
face-oval points only (they are the mesh's outline, as the jaw is the annotation's); the
others among the 468 mesh points (not the iris points). Command::

    python -m evaluation.facemesh_ibug68 --n-300w 30

prints the table and, per point, its mean normalised distance. A stopgap: the 478-point
fit (the surface correspondence of issue 24) supersedes it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
CLASSIC = ("image_0010.png", "takeo.ppm", "einstein.jpg", "breakingbad.jpg")


def photos(n_300w: int) -> list:
    """(image, .pts) pairs: the 4 classic photos, then the first ``n_300w`` 300-W afw ones."""
    classic = [DATA / "images" / c for c in CLASSIC]
    afw = sorted((DATA / "images" / "300w" / "afw").glob("*.jpg"))[:n_300w]
    return [(p, p.with_suffix(".pts")) for p in classic + afw]


def face_oval() -> np.ndarray:
    """Indices of mediapipe's face-oval points (its FACEMESH_FACE_OVAL edges)."""
    from mediapipe.python.solutions.face_mesh_connections import FACEMESH_FACE_OVAL

    return np.array(sorted({i for e in FACEMESH_FACE_OVAL for i in e}), dtype=np.int64)


def mean_distances(pairs) -> tuple[np.ndarray, int]:
    """(68, 478) mean normalised distance between the annotated and the mesh points, and the
    number of photos where the mesh found the face."""
    from morphable.detection.facemesh import detect_landmarks
    from morphable.errors import FitError
    from morphable.io.landmark_files import read_pts

    total, n = np.zeros((68, 478)), 0
    for image, pts in pairs:
        truth = read_pts(pts)
        lo, hi = truth.min(0), truth.max(0)
        try:
            mesh = detect_landmarks(image, box=np.concatenate([lo, hi]))
        except FitError:
            print(f"{image.name}: no face found, skipped", file=sys.stderr)
            continue
        size = np.sqrt(np.prod(hi - lo))
        total += np.linalg.norm(truth[:, None] - mesh[None], axis=-1) / size
        n += 1
    return total / max(n, 1), n


def derive(distances: np.ndarray) -> np.ndarray:
    """(68, 478) distances -> (68,) mesh index per iBUG point (jaw: face-oval points)."""
    oval = face_oval()
    inner = np.arange(468)
    table = np.empty(68, dtype=np.int64)
    for i in range(68):
        cand = oval if i < 17 else inner
        table[i] = cand[np.argmin(distances[i, cand])]
    return table


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--n-300w", type=int, default=30, help="300-W afw photos after the 4 classic ones")
    args = p.parse_args(argv)
    d, n = mean_distances(photos(args.n_300w))
    table = derive(d)
    print(f"# {n} photos")
    print("FACEMESH_TO_IBUG68 = np.array([")
    for row in range(0, 68, 12):
        print("    " + ", ".join(str(int(v)) for v in table[row:row + 12]) + ",")
    print("], dtype=np.int64)")
    err = d[np.arange(68), table]
    print(f"# mean normalised distance per point: median {np.median(err):.4f}, max {err.max():.4f} "
          f"(iBUG {int(err.argmax()) + 1})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
