"""Videos: decoding and tracking speed, tracking error and jitter against a known motion, and
the memory of streaming a long 4K video.

The test video is a real photo moving along a known path: ``shared/data/images/image_0010.png``
scaled by 0.625 (its face about 230 px wide) and seen through a 640 x 480 window that moves by
a sum of sines (60 px at 0.5 Hz and 8 px at 2 Hz horizontally, 30 px at 0.7 Hz vertically,
whole pixels), written as H.264 (crf 18) at 30 frames/s. The truth of every frame is the
photo's 68 annotated points moved with the window, so that

- *error* is the mean distance (px) between the fitted face's projected iBUG-68 points
  (``landmarks_68_px``) and the truth, per frame, averaged over frames;
- *jitter* is the mean frame-to-frame acceleration of those points, px per frame², against
  the truth's own (its whole-pixel path has some);

for ``morphable track`` with its temporal prior, without it (``smoothing_hz=0``), and for
independent per-frame fits (each frame detected and fitted alone, its own identity).
Speeds are frames per second on this machine's cores, the tracking's including its identity
fit and the model load, as the command runs. Peak memory (``--rss-frames``): the resident set
(``VmHWM``) of a process that streams a 3840 x 2160 video (the test video's frames tiled) through
:func:`morphable.video.iter_frames`, for a video and one four times as long.

Run::

    python -m evaluation.bench_video --frames 300 --rss-frames 30 --report reports/bench_video.json
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from morphable.errors import one_line_errors
from morphable.logs import add_verbosity_arguments, configure, verbosity

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SCALE = 0.625
FPS = 30.0


def window_path(n: int) -> np.ndarray:
    """(n, 2) whole-pixel (x, y) offsets of the 640 x 480 window in the scaled photo."""
    t = np.arange(n) / FPS
    x = 80 + 60 * np.sin(2 * np.pi * 0.5 * t) + 8 * np.sin(2 * np.pi * 2.0 * t)
    y = 80 + 30 * np.sin(2 * np.pi * 0.7 * t)
    return np.round(np.c_[x, y]).astype(int)


def make_video(path, n: int):
    """Write the test video -> (n, 68, 2) true landmarks, px."""
    from PIL import Image

    from morphable.io.landmark_files import read_pts
    from morphable.video import write_video

    with Image.open(DATA / "images" / "image_0010.png") as im:
        photo = np.asarray(im.convert("RGB").resize((round(im.width * SCALE), round(im.height * SCALE)),
                                                    Image.LANCZOS))
    pts = read_pts(DATA / "images" / "image_0010.pts") * SCALE
    offsets = window_path(n)
    write_video(path, (photo[y:y + 480, x:x + 640] for x, y in offsets), fps=FPS)
    return pts[None] - offsets[:, None, :]


def jitter(points) -> float:
    """Mean frame-to-frame acceleration of (F, 68, 2) points over consecutive finite frames,
    px per frame²."""
    acc = np.linalg.norm(np.diff(points, 2, axis=0), axis=-1)
    return float(np.nanmean(acc))


def error(points, truth) -> float:
    """Mean point-to-point distance, px, over the frames where ``points`` are finite."""
    return float(np.nanmean(np.linalg.norm(points - truth, axis=-1)))


def per_frame_fits(path, model) -> np.ndarray:
    """Independent fits: each frame detected and fitted alone -> (F, 68, 2) px."""
    from morphable.detection import detect_landmarks
    from morphable.errors import FitError
    from morphable.fitting import fit_landmarks
    from morphable.fitting.noise import DETECTED_MODEL_STD_MM
    from morphable.video import iter_frames

    out = []
    for frame in iter_frames(path):
        try:
            pts = detect_landmarks(frame.image)
        except FitError:
            out.append(np.full((68, 2), np.nan))
            continue
        res = fit_landmarks(model, pts, frame.size, model_std_mm=DETECTED_MODEL_STD_MM)
        out.append(res.landmarks_68_px()[0])
    return np.array(out)


def peak_rss_mb(path) -> float:
    """Peak resident memory (MB) of a fresh process that streams every frame of ``path``: its
    ``VmHWM`` (``ru_maxrss`` would carry the parent's peak over the fork)."""
    code = ("import sys; from morphable.video import iter_frames; "
            "n = sum(1 for _ in iter_frames(sys.argv[1])); "
            "hwm = next(l for l in open('/proc/self/status') if l.startswith('VmHWM')); "
            "print(n, int(hwm.split()[1]) / 1024)")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True)
    return float(out.stdout.split()[1])


@one_line_errors("python -m evaluation.bench_video")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=300, help="length of the test video (default 300)")
    p.add_argument("--rss-frames", type=int, default=0,
                   help="4K memory test: a video of this many frames and one 4 times as long (0: skip)")
    p.add_argument("--report", help="JSON report")
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))

    from morphable import load_model
    from morphable.tracking import track_video
    from morphable.video import iter_frames, write_video

    work = Path(tempfile.mkdtemp(prefix="bench_video."))
    clip = work / "clip.mp4"
    truth = make_video(clip, args.frames)
    model = load_model("sfm")
    t = time.perf_counter()
    n = sum(1 for _ in iter_frames(clip))
    decode_fps = n / (time.perf_counter() - t)
    rows = {"truth": {"jitter_px": jitter(truth)}}
    for name, hz in (("track", 4.0), ("track, no prior", 0.0)):
        t = time.perf_counter()
        tr = track_video(clip, model=model, smoothing_hz=hz)
        seconds = time.perf_counter() - t
        rows[name] = {"error_px": error(tr.landmarks_68_px, truth), "jitter_px": jitter(tr.landmarks_68_px),
                      "frames_per_s": n / seconds, "frames_lost": int((~tr.tracked).sum()),
                      "face_detector_runs": int(tr.detected.sum())}
    t = time.perf_counter()
    single = per_frame_fits(clip, model)
    rows["per-frame fits"] = {"error_px": error(single, truth), "jitter_px": jitter(single),
                              "frames_per_s": n / (time.perf_counter() - t)}
    report = {"frames": n, "size": [640, 480], "decode_fps": decode_fps, "rows": rows}
    if args.rss_frames:
        first = next(iter_frames(clip)).image
        big = np.tile(first, (5, 6, 1))[:2160, :3840]
        rss = {}
        for k in (args.rss_frames, 4 * args.rss_frames):
            path = work / f"4k_{k}.mp4"
            write_video(path, (np.roll(big, 4 * i, axis=1) for i in range(k)), fps=FPS, crf=28)
            rss[k] = peak_rss_mb(path)
            path.unlink()
        report["peak_rss_mb_4k"] = rss
    print(f"{n} frames 640x480: decoding {decode_fps:.0f} frames/s")
    print(f"{'':18s} {'error px':>9s} {'jitter px/frame²':>17s} {'frames/s':>9s}")
    for name, r in rows.items():
        print(f"{name:18s} {r.get('error_px', float('nan')):9.2f} {r['jitter_px']:17.3f} "
              f"{r.get('frames_per_s', float('nan')):9.1f}")
    if args.rss_frames:
        print("peak RSS streaming 3840x2160: " + ", ".join(f"{k} frames {v:.0f} MB"
                                                          for k, v in report["peak_rss_mb_4k"].items()))
    if args.report:
        from morphable.io.atomic import atomic_path

        with atomic_path(args.report) as tmp:
            Path(tmp).write_text(json.dumps(report, indent=2))
    for f in work.iterdir():
        f.unlink()
    work.rmdir()
    return 0


if __name__ == "__main__":
    sys.exit(main())
