"""A contact sheet of one scan's frames on both renderings: ``python -m evaluation.pbr``.

Per condition, one sampled frame of the Florence protocol's synthetic video (seed
``--seed``), rendered by ``morphable.raster`` (top row) and by :mod:`evaluation.pbr` (bottom
row), each shown at 256 px::

    python -m evaluation.pbr --scan ../shared/data/scans/james/james.obj \\
        --scan-landmarks ../shared/data/scans/james/james.ljson --out docs/img/pbr_frames.jpg
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors


@one_line_errors("evaluation.pbr")
def main(argv=None) -> int:
    from PIL import Image

    from morphable import load_model
    from morphable.io.atomic import atomic_path

    from ..scans import load_scan
    from ..videos import CONDITIONS, render_frames, synthetic_video
    from . import render_frames as render_pbr

    p = argparse.ArgumentParser(prog="python -m evaluation.pbr", description=__doc__.split("\n")[0])
    p.add_argument("--scan", required=True)
    p.add_argument("--scan-landmarks", required=True)
    p.add_argument("--out", required=True, help="output .jpg or .png")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--frame", type=int, default=2, help="which sampled frame (0-4)")
    args = p.parse_args(argv)
    out = Path(args.out)
    if out.suffix.lower() not in (".jpg", ".jpeg", ".png") or not out.resolve().parent.is_dir():
        raise InputError(f"{out}: need a .jpg or .png in an existing folder")
    if not 0 <= args.frame < 5:
        raise InputError(f"--frame {args.frame}: must be 0-4")
    scan = load_scan(args.scan, args.scan_landmarks)
    reference = load_model("sfm").landmark_positions()
    columns = []
    for c in CONDITIONS:
        video = synthetic_video(scan, c, reference, seed=args.seed)
        frame = [video.sampled[args.frame]]
        pair = [render_frames(scan, video, frames=frame, seed=args.seed)[0],
                render_pbr(scan, video, frames=frame, seed=args.seed)[0]]
        columns.append(np.concatenate([np.asarray(Image.fromarray(np.round(f * 255).astype(np.uint8))
                                                  .resize((256, 256), Image.LANCZOS)) for f in pair], 0))
    with atomic_path(out) as tmp:
        Image.fromarray(np.concatenate(columns, 1)).save(tmp, format="PNG" if out.suffix.lower() == ".png"
                                                         else "JPEG", quality=88)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
