"""``morphable track``: one identity, and a pose and expression for every frame of a video.

Writes ``DIR/track.npz`` (per-frame arrays, :class:`morphable.tracking.TrackResult`) and
``DIR/track.json`` (frames, lost frames, frame rate, identity, settings), and on request
``DIR/overlay.mp4`` (the fitted mesh over every frame) and ``DIR/track.glb`` (the animated
mesh for viewers, :func:`morphable.tracking.write_track_glb`). Nothing is written unless the whole
video was tracked.

The command line of :func:`morphable.tracking.track_video` and
:func:`morphable.pipeline.write_track`.
"""
from __future__ import annotations

import time

import numpy as np

from ..errors import InputError
from .common import add_detector_arguments, add_model_argument, model_from


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
    from ..pipeline import check_track_folder, write_track
    from ..tracking import track_video

    check_track_folder(args.out)
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
    written = write_track(tr, args.out, video=args.video,
                          settings={"smoothing_hz": args.smoothing_hz, "identity_frames": args.identity_frames,
                                    "identity_mode": args.identity},
                          seconds=seconds, overlay_video=args.overlay_video, animated_mesh=args.animated_mesh)
    lost = [int(i) for i in np.flatnonzero(~tr.tracked)]
    print(f"{args.video}: {tr.n_frames} frames, {len(lost)} lost{_ranges(lost)}, face detector run on "
          f"{int(tr.detected.sum())}; {tr.n_frames / seconds:.1f} frames/s; wrote "
          + " ".join(str(p) for p in written))
    return 0


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
