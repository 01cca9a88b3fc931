"""``morphable track``: one identity, and a pose and expression for every frame of a video.

Writes ``DIR/track.npz`` (per-frame arrays, :class:`morphable.tracking.TrackResult`) and
``DIR/track.json`` (frames, lost frames, frame rate, identity, settings), and on request
``DIR/overlay.mp4`` (the fitted mesh over every frame) and ``DIR/track.glb`` (the animated
mesh for viewers, :func:`morphable.tracking.write_track_glb`). Nothing is written unless the whole
video was tracked.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from ..errors import InputError
from .common import add_detector_arguments, add_model_argument, model_from

NPZ_KEYS = ("time_s", "tracked", "detected", "euler_deg", "translation", "scale", "expression",
            "landmarks_68_px", "detector_px", "detector_std_px", "raw_euler_deg", "raw_expression",
            "landmark_rmse_px", "identity")
"""The arrays of ``track.npz`` (units: :class:`morphable.tracking.TrackResult`)."""


def add_parser(sub):
    from ..tracking import DEFAULT_IDENTITY, DEFAULT_SMOOTHING_HZ, IDENTITY_MODES

    p = sub.add_parser("track", help="track a face through a video: one identity, pose and "
                                     "expression per frame")
    p.add_argument("video", metavar="VIDEO", help="a video file (.mp4, .mov, .mkv, ...)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder for track.npz and track.json (made if missing; its parent must exist)")
    add_model_argument(p)
    add_detector_arguments(p)
    p.add_argument("--identity-frames", type=int, default=9, metavar="N",
                   help="frames spread uniformly for the identity fit (default 9)")
    p.add_argument("--identity", choices=IDENTITY_MODES, default=DEFAULT_IDENTITY,
                   help="the identity from the identity frames: one fit of them all (shared) or "
                        f"each fitted alone and averaged (average); default {DEFAULT_IDENTITY}")
    p.add_argument("--smoothing-hz", type=float, default=DEFAULT_SMOOTHING_HZ, metavar="HZ",
                   help=f"cut-off of the temporal prior, Hz; 0: none (default {DEFAULT_SMOOTHING_HZ:g})")
    p.add_argument("--overlay-video", action="store_true",
                   help="also write DIR/overlay.mp4: the fitted mesh over every frame")
    p.add_argument("--animated-mesh", action="store_true",
                   help="also write DIR/track.glb: the mesh animated through the video (glTF 2.0 "
                        "binary: identity in the base mesh, expressions as morph targets, the "
                        "head pose per frame, timed at the video's frame rate)")
    return p


def run(args):
    from ..io.atomic import atomic_path
    from ..tracking import track_video, write_track_glb

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder")
    if not out.exists() and not out.resolve().parent.is_dir():
        raise InputError(f"{out}: folder {out.resolve().parent} does not exist")
    if args.identity_frames < 1:
        raise InputError(f"--identity-frames must be >= 1, got {args.identity_frames}")
    if not args.smoothing_hz >= 0:
        raise InputError(f"--smoothing-hz must be >= 0, got {args.smoothing_hz}")
    start = time.perf_counter()
    tr = track_video(args.video, model=model_from(args), identity_frames=args.identity_frames,
                     identity=args.identity,
                     landmark_detector=args.landmark_detector, face_detector=args.face_detector,
                     smoothing_hz=args.smoothing_hz, progress=not args.quiet)
    seconds = time.perf_counter() - start
    lost = [int(i) for i in np.flatnonzero(~tr.tracked)]
    summary = {"video": str(args.video), "model": tr.fit.model.name if tr.fit else args.model,
               "frames": tr.n_frames, "frames_tracked": int(tr.tracked.sum()), "frames_lost": lost,
               "frames_detected": int(tr.detected.sum()), "fps": tr.fps,
               "image_size": list(tr.image_size), "identity": [float(x) for x in tr.identity],
               "smoothing_hz": args.smoothing_hz, "identity_frames": args.identity_frames,
               "identity_mode": args.identity,
               "landmark_rmse_px": _mean(tr.landmark_rmse_px), "tracking_fps": tr.n_frames / seconds}
    if not tr.tracked.any():
        raise InputError(f"{args.video}: the face was lost in every frame")
    out.mkdir(exist_ok=True)
    written = []
    try:
        # the glTF first: cheap, so that its problems come before the overlay's long write
        if args.animated_mesh:
            written.append(write_track_glb(tr, out / "track.glb"))
        if args.overlay_video:
            written.append(_overlay_video(args.video, tr, out / "overlay.mp4"))
        with atomic_path(out / "track.npz") as tmp:
            np.savez_compressed(tmp, **{k: np.asarray(getattr(tr, k)) for k in NPZ_KEYS},
                                fps=tr.fps, image_size=np.array(tr.image_size))
        written.append(out / "track.npz")
        with atomic_path(out / "track.json") as tmp:
            Path(tmp).write_text(json.dumps(summary, indent=2))
        written.append(out / "track.json")
    except BaseException:
        # all or nothing: a track without its arrays (or arrays without the asked-for files)
        # would pass for a finished one
        for p in written:
            p.unlink(missing_ok=True)
        raise
    print(f"{args.video}: {tr.n_frames} frames, {len(lost)} lost{_ranges(lost)}, face detector run on "
          f"{int(tr.detected.sum())}; {summary['tracking_fps']:.1f} frames/s; wrote "
          + " ".join(str(p) for p in written))
    return 0


def _mean(values) -> float | None:
    v = np.asarray(values, dtype=np.float64)
    return float(np.nanmean(v)) if np.isfinite(v).any() else None


def _ranges(frames) -> str:
    """[3, 4, 5, 9] -> " (frames 3-5, 9)"."""
    if not frames:
        return ""
    parts, a = [], frames[0]
    for prev, cur in zip(frames, frames[1:] + [None]):
        if cur != prev + 1 if cur is not None else True:
            parts.append(f"{a}" if a == prev else f"{a}-{prev}")
            a = cur
    return f" (frames {', '.join(parts)})"


def _overlay_video(video, tr, path) -> Path:
    """The fitted mesh (wireframe) over every frame, lost frames as they are, streamed."""
    from ..overlay import draw_overlay
    from ..video import iter_frames, write_video

    index = {int(f): i for i, f in enumerate(np.flatnonzero(tr.tracked))}

    def frames():
        for frame in iter_frames(video):
            i = index.get(frame.index)
            if i is None:
                yield frame.image
            else:
                yield draw_overlay(frame.image, tr.fit, i, mesh="wireframe", landmarks=False)

    return write_video(path, frames(), fps=tr.fps or 30.0)
