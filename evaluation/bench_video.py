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

Rows are timed in frames per second and in CPU milliseconds per frame (the process's CPU time,
all threads), after the detector's one-off load (paid once per process, printed apart).

``--florence``: rendered Florence videos (:mod:`evaluation.videos`, 30 frames/s, H.264) of
james's scan and/or of the photo-dressed validation subjects (``--subjects james ict sfm``,
``--n-scans`` of each model, :func:`validation_subjects`), tracked and compared with the
truth: shape per frame (the Florence metric), head rotation, jitter against the truth's own,
for the track (averaged identity, prior at 4 Hz), without the prior, with the shared identity,
and per-frame fits; the validation figures are means over the subjects.

Run::

    python -m evaluation.bench_video --frames 300 --rss-frames 30 --report reports/bench_video.json
    python -m evaluation.bench_video --florence --subjects james ict sfm --n-scans 4 --frames 30 \
        --report reports/bench_video_florence_validation.json
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

from morphable.errors import InputError, one_line_errors
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


def timed(fn, *args, **kwargs):
    """``fn(*args, **kwargs)`` -> (its result, wall-clock s, CPU s of this process, all its
    threads): the CPU time tells a change apart on cores that other jobs share."""
    t, c = time.perf_counter(), time.process_time()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t, time.process_time() - c


def load_detector(clip) -> float:
    """Run the default detector once on the first frame of ``clip`` -> seconds: its one-off
    load (mediapipe's import and graph), paid once per process, so that no timed row pays it."""
    from morphable.detection import detect_landmarks
    from morphable.video import iter_frames

    return timed(detect_landmarks, next(iter(iter_frames(clip))).image)[1]


def jitter(points) -> float:
    """Mean frame-to-frame acceleration of (F, 68, 2) points over consecutive finite frames,
    px per frame²."""
    acc = np.linalg.norm(np.diff(points, 2, axis=0), axis=-1)
    return float(np.nanmean(acc))


def error(points, truth) -> float:
    """Mean point-to-point distance, px, over the frames where ``points`` are finite."""
    return float(np.nanmean(np.linalg.norm(points - truth, axis=-1)))


def per_frame_fits(path, model) -> np.ndarray:
    """Independent fits (:func:`per_frame_results`) -> (F, 68, 2) px, NaN where no face."""
    return np.array([np.full((68, 2), np.nan) if r is None else r.landmarks_68_px()[0]
                     for r in per_frame_results(path, model)])


def peak_rss_mb(path) -> float:
    """Peak resident memory (MB) of a fresh process that streams every frame of ``path``: its
    ``VmHWM`` (``ru_maxrss`` would carry the parent's peak over the fork)."""
    code = ("import sys; from morphable.video import iter_frames; "
            "n = sum(1 for _ in iter_frames(sys.argv[1])); "
            "hwm = next(l for l in open('/proc/self/status') if l.startswith('VmHWM')); "
            "print(n, int(hwm.split()[1]) / 1024)")
    out = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, check=True)
    return float(out.stdout.split()[1])


def camera_vertices(rotations, vertices, shifts=None) -> np.ndarray:
    """(F, V, 3) mm: meshes (F, V, 3) or one (V, 3) turned by (F, 3, 3) rotations and moved by
    (F, 2) image-plane shifts, mm (the camera frame without depth, which an affine camera
    does not see)."""
    out = np.einsum("fij,fvj->fvi", rotations, np.broadcast_to(vertices, (len(rotations), *np.shape(vertices)[-2:])))
    if shifts is not None:
        out[..., :2] += np.asarray(shifts)[:, None, :]
    return out


def shape_errors(model, meshes, scan) -> np.ndarray:
    """(F,) mm: each model-frame mesh (F, V, 3) against the scan by the Florence metric
    (landmark similarity, ICP, mean point-to-plane error within 95 mm of the nose tip)."""
    from evaluation.florence.methods import Reconstruction
    from evaluation.florence.protocol import evaluate

    return np.array([evaluate(Reconstruction.from_vertices(model, v, 0.0, 1), scan)[0]["mean_mm"]
                     for v in meshes])


def rotation_error_deg(rotations, truth) -> np.ndarray:
    """(F,) degrees: the angle of R_i truth_i^T."""
    cos = (np.einsum("fij,fij->f", rotations, truth) - 1.0) / 2.0
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def per_frame_results(path, model) -> list:
    """Independent fits: each frame detected and fitted alone, as ``morphable fit`` fits a
    detection (:func:`morphable.fitting.options.detection_settings`) -> FitResult or None per
    frame."""
    from morphable.detection import detect
    from morphable.errors import FitError
    from morphable.fitting import fit_landmarks
    from morphable.fitting.options import detection_settings
    from morphable.video import iter_frames

    out = []
    for frame in iter_frames(path):
        try:
            found = detect(frame.image)
        except FitError:
            out.append(None)
            continue
        out.append(fit_landmarks(model, found.points, frame.size,
                                 **detection_settings([found], len(found.points))))
    return out


def florence_tracking(scan, model, conditions, n_frames: int, work: Path, seed: int = 0) -> dict:
    """Track rendered Florence videos of ``scan`` (:func:`evaluation.videos.write_rendered_video`,
    ``n_frames`` per condition) -> {condition: {row: figures}}; the mp4 files stay in ``work``.

    Rows: ``truth`` (its rigid motion), ``track`` (prior at 4 Hz), ``track, no prior``,
    ``track, identity shared`` (prior at 4 Hz, ``identity="shared"``), ``per-frame fits``. Figures: ``shape_mm`` (mean over frames of :func:`shape_errors`),
    ``rotation_deg`` (mean angle from the true head rotation), ``jitter_mm`` (vertex
    acceleration, :func:`jitter`, of the face turned and moved in the image plane),
    ``frames_per_s``, ``frames_lost``."""
    from evaluation.videos import synthetic_video, write_rendered_video
    from morphable.camera import euler_to_matrix
    from morphable.tracking import DEFAULT_IDENTITY, track_video

    out = {}
    for c in conditions:
        video = synthetic_video(scan, c, model.landmark_positions(), n_frames=n_frames, seed=seed)
        clip = write_rendered_video(scan, video, work / f"{c}.mp4", seed=seed)
        true_rot = np.stack([euler_to_matrix(*p) for p in video.poses_deg])
        load_detector(clip)     # once per process: no timed row pays the detector's load
        rows, neutral = {}, None
        for name, hz, how in (("track", 4.0, DEFAULT_IDENTITY), ("track, no prior", 0.0, DEFAULT_IDENTITY),
                              ("track, identity shared", 4.0, "shared")):
            tr, seconds, cpu = timed(track_video, clip, model=model, smoothing_hz=hz, identity=how)
            ok = tr.tracked
            meshes = np.full((n_frames, model.n_vertices, 3), np.nan)
            meshes[ok] = tr.fit.vertices()
            rot = np.stack([euler_to_matrix(*e) if np.isfinite(e).all() else np.full((3, 3), np.nan)
                            for e in tr.euler_deg])
            neutral = model.vertices(tr.identity) if neutral is None else neutral
            rows[name] = {"shape_mm": float(shape_errors(model, meshes[ok], scan).mean()),
                          "rotation_deg": float(np.nanmean(rotation_error_deg(rot, true_rot))),
                          "jitter_mm": jitter(camera_vertices(rot, meshes, tr.translation[:, :2])),
                          "frames_per_s": n_frames / seconds, "cpu_ms_per_frame": 1e3 * cpu / n_frames,
                          "frames_lost": int((~ok).sum())}
        single, seconds, cpu = timed(per_frame_results, clip, model)
        ok = np.array([r is not None for r in single])
        meshes = np.full((n_frames, model.n_vertices, 3), np.nan)
        rot = np.full((n_frames, 3, 3), np.nan)
        shift = np.full((n_frames, 2), np.nan)
        for i, r in enumerate(single):
            if r is not None:
                meshes[i], rot[i], shift[i] = r.vertices(0), r.cameras[0].rotation, r.cameras[0].translation[:2]
        rows["per-frame fits"] = {"shape_mm": float(shape_errors(model, meshes[ok], scan).mean()),
                                  "rotation_deg": float(np.nanmean(rotation_error_deg(rot, true_rot))),
                                  "jitter_mm": jitter(camera_vertices(rot, meshes, shift)),
                                  "frames_per_s": n_frames / seconds,
                                  "cpu_ms_per_frame": 1e3 * cpu / n_frames, "frames_lost": int((~ok).sum())}
        # the truth: the scan is rigid, the face turns with the head (the tracked identity's
        # vertices, so that the vertex set is the same); the head's centre does not move
        rows = {"truth": {"jitter_mm": jitter(camera_vertices(true_rot, neutral))}, **rows}
        out[c] = {"image_size": list(video.image_size), "rows": rows}
    return out


def florence_protocol_on_videos(scan, model, clips: dict, methods, n_frames: int = 30) -> dict:
    """``florence --videos`` on the mp4 files against ``florence --detect`` on the same frames
    rendered (with its pinhole camera of known focal, and with ``--camera affine`` as the
    videos' unknown focal forces) -> {"detect": report, "detect, affine": report, "videos":
    report, "landmark_shift_px": {condition: median distance between the detections}}."""
    from evaluation.florence.protocol import run_protocol, video_landmarks

    conditions = list(clips)
    detect = ("auto", "auto")
    out = {"detect": run_protocol(scan, model, methods, conditions, n_frames=n_frames,
                                  detect=detect)[0],
           "detect, affine": run_protocol(scan, model, methods, conditions, n_frames=n_frames,
                                          detect=detect, efforts={"ours": {"camera": "affine"}})[0],
           "videos": run_protocol(scan, model, methods, conditions, videos=clips, detect=detect)[0]}
    shift = {}
    for c, clip in clips.items():
        a = video_landmarks(scan, model, c, 5, n_frames, 0, detect=detect)[0].landmarks
        b = video_landmarks(scan, model, c, 5, n_frames, 0, detect=detect, video=clip)[0].landmarks
        shift[c] = float(np.nanmedian(np.linalg.norm(a - b, axis=-1)))
    out["landmark_shift_px"] = shift
    return out


APPEARANCES = ("image_0010.png", "takeo.ppm", "breakingbad.jpg", "einstein.jpg")
"""The photos whose colours the validation subjects wear in turn (``shared/data/images``), as
``evaluation.florence --synthetic-scan ... --appearance`` dresses them in docs/evaluation.md."""


def validation_subjects(scan_model, n_scans: int, photos, scan_seed: int = 100):
    """The photo-dressed validation subjects of ``evaluation.florence --synthetic-scan NAME
    --n-scans N --appearance PHOTOS``: subjects sampled from ``scan_model``
    (:func:`evaluation.scans.model_scan`, seeds ``scan_seed``...) wearing the colours of
    ``photos`` in turn (:func:`evaluation.scans.photo_colors`) -> generator of Scans, mm."""
    from evaluation.scans import model_scan, photo_colors

    looks = [photo_colors(scan_model, p) for p in photos]
    for i in range(n_scans):
        yield model_scan(scan_model, scan_seed + i, colors=looks[i % len(looks)])


def mean_tracking(runs) -> dict:
    """{condition: {row: figures}} of several subjects -> the same, each figure the mean over
    the subjects (``frames_lost``: the sum), with ``n`` the subjects averaged."""
    runs = list(runs)
    out = {}
    for c in runs[0]:
        rows = {}
        for name in runs[0][c]["rows"]:
            cells = [r[c]["rows"][name] for r in runs]
            rows[name] = {k: (int(sum(x[k] for x in cells)) if k == "frames_lost"
                              else float(np.mean([x[k] for x in cells]))) for k in cells[0]}
        out[c] = {"image_size": runs[0][c]["image_size"], "rows": rows, "n": len(runs)}
    return out


def print_tracking(title: str, tracking: dict) -> None:
    print(title)
    print(f"{'':26s} {'shape mm':>9s} {'rotation °':>10s} {'jitter mm/frame²':>17s} {'frames/s':>9s} "
          f"{'CPU ms/frame':>13s} {'lost':>5s}")
    for c, r in tracking.items():
        for name, x in r["rows"].items():
            print(f"{c + ' ' + name:26s} {x.get('shape_mm', float('nan')):9.3f} "
                  f"{x.get('rotation_deg', float('nan')):10.2f} {x['jitter_mm']:17.4f} "
                  f"{x.get('frames_per_s', float('nan')):9.1f} {x.get('cpu_ms_per_frame', float('nan')):13.1f} "
                  f"{x.get('frames_lost', 0):5d}")


def florence_main(args) -> int:
    """``--florence``: the benchmark on rendered Florence videos of james and/or of the
    photo-dressed validation subjects (``--subjects``)."""
    from evaluation.florence.protocol import format_table
    from evaluation.scans import load_scan
    from morphable import load_model

    model = load_model("sfm")
    work = Path(tempfile.mkdtemp(prefix="bench_video."))
    report = {}
    try:
        for subject in args.subjects:
            if subject != "james":
                scan_model = load_model(subject)
                photos = [Path(p) for p in args.appearance] if args.appearance else [
                    DATA / "images" / p for p in APPEARANCES]
                runs = []
                for k, scan in enumerate(validation_subjects(scan_model, args.n_scans, photos)):
                    runs.append(florence_tracking(scan, model, args.conditions, args.frames, work))
                    print_tracking(f"{subject} subject {k} ({scan.source}), {args.frames} frames each",
                                   runs[-1])
                report[subject] = {"subjects": runs, "mean": mean_tracking(runs),
                                   "appearance": [p.name for p in photos]}
                print_tracking(f"\n{subject}: mean over {args.n_scans} photo-dressed subjects "
                               f"({', '.join(p.name for p in photos)} in turn), {args.frames} frames "
                               "each, 30 frames/s", report[subject]["mean"])
                continue
            scan = load_scan(DATA / "scans" / "james" / "james.obj", DATA / "scans" / "james" / "james.ljson")
            report["tracking"] = florence_tracking(scan, model, args.conditions, args.frames, work)
            print_tracking(f"rendered Florence videos of james, {args.frames} frames each, 30 frames/s",
                           report["tracking"])
            if args.florence_methods:
                clips = {c: work / f"{c}.mp4" for c in args.conditions}
                runs = florence_protocol_on_videos(scan, model, clips, args.florence_methods, args.frames)
                report["florence"] = runs
                for name in ("detect", "detect, affine", "videos"):
                    print(f"\n{name}:\n" + format_table(runs[name]))
                print("\nmedian distance between the detections on the rendered frames and on the mp4 "
                      "frames, px: " + ", ".join(f"{c} {v:.2f}" for c, v in runs["landmark_shift_px"].items()))
        _write_report(args.report, report)
    finally:
        for f in work.iterdir():
            f.unlink()
        work.rmdir()
    return 0


def _write_report(path, report) -> None:
    if path:
        from morphable.io.atomic import atomic_path

        with atomic_path(path) as tmp:
            Path(tmp).write_text(json.dumps(report, indent=2))


@one_line_errors("python -m evaluation.bench_video")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=300, help="length of the test video (default 300)")
    p.add_argument("--rss-frames", type=int, default=0,
                   help="4K memory test: a video of this many frames and one 4 times as long (0: skip)")
    p.add_argument("--report", help="JSON report")
    p.add_argument("--florence", action="store_true",
                   help="instead: track rendered Florence videos (--frames per condition) of --subjects")
    p.add_argument("--subjects", nargs="+", default=["james"], choices=["james", "ict", "sfm"],
                   help="--florence: james's scan, and/or the photo-dressed validation subjects "
                        "sampled from ict or sfm (default james)")
    p.add_argument("--n-scans", type=int, default=8,
                   help="--florence: validation subjects per model (seeds 100...; default 8)")
    p.add_argument("--appearance", nargs="+", metavar="PHOTO",
                   help="--florence: photos the validation subjects wear in turn (default "
                        + ", ".join(APPEARANCES) + " in shared/data/images)")
    p.add_argument("--conditions", nargs="+", default=["cooperative", "indoor", "outdoor"],
                   help="--florence: conditions")
    p.add_argument("--florence-methods", nargs="*", default=[],
                   help="--florence: also florence --videos on the mp4 files against --detect "
                        "on the same frames, with these methods")
    add_verbosity_arguments(p)
    args = p.parse_args(argv)
    configure(verbosity(args))
    if args.n_scans < 1:
        raise InputError(f"--n-scans must be >= 1, got {args.n_scans}")
    if args.florence:
        return florence_main(args)

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
    detector_s = load_detector(clip)
    for name, hz in (("track", 4.0), ("track, no prior", 0.0)):
        tr, seconds, cpu = timed(track_video, clip, model=model, smoothing_hz=hz)
        rows[name] = {"error_px": error(tr.landmarks_68_px, truth), "jitter_px": jitter(tr.landmarks_68_px),
                      "frames_per_s": n / seconds, "cpu_ms_per_frame": 1e3 * cpu / n,
                      "frames_lost": int((~tr.tracked).sum()), "face_detector_runs": int(tr.detected.sum())}
    single, seconds, cpu = timed(per_frame_fits, clip, model)
    rows["per-frame fits"] = {"error_px": error(single, truth), "jitter_px": jitter(single),
                              "frames_per_s": n / seconds, "cpu_ms_per_frame": 1e3 * cpu / n}
    report = {"frames": n, "size": [640, 480], "decode_fps": decode_fps, "detector_load_s": detector_s,
              "rows": rows}
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
    print(f"{n} frames 640x480: decoding {decode_fps:.0f} frames/s; the detector's one-off load "
          f"{detector_s:.2f} s (before the timed rows)")
    print(f"{'':18s} {'error px':>9s} {'jitter px/frame²':>17s} {'frames/s':>9s} {'CPU ms/frame':>13s}")
    for name, r in rows.items():
        print(f"{name:18s} {r.get('error_px', float('nan')):9.2f} {r['jitter_px']:17.3f} "
              f"{r.get('frames_per_s', float('nan')):9.1f} {r.get('cpu_ms_per_frame', float('nan')):13.1f}")
    if args.rss_frames:
        print("peak RSS streaming 3840x2160: " + ", ".join(f"{k} frames {v:.0f} MB"
                                                          for k, v in report["peak_rss_mb_4k"].items()))
    _write_report(args.report, report)
    for f in work.iterdir():
        f.unlink()
    work.rmdir()
    return 0


if __name__ == "__main__":
    sys.exit(main())
