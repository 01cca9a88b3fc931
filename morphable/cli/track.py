"""``morphable track``: every face of a video, shot by shot, joined into people; one identity
per person, and a pose and expression for every frame they are in.

Writes ``DIR/track.npz`` (per-frame arrays per person and per track) and ``DIR/track.json``
(shots, people, tracks, per-frame status, settings), and on request ``DIR/overlay.mp4`` (every
person's fitted mesh over every frame, with their number) and an animated mesh per person
(``track.glb`` for one, ``person_K.glb`` for several). ``--person K`` / ``--largest`` keep one
person. Nothing is written unless the whole video was tracked and some face fitted.

The command line of :func:`morphable.tracking.track_footage` and
:func:`morphable.pipeline.write_footage`.
"""
from __future__ import annotations

import time

import numpy as np

from ..errors import InputError
from .common import add_detector_arguments, add_model_argument, model_from


def add_parser(sub):
    from ..tracking import DEFAULT_SMOOTHING_HZ

    p = sub.add_parser("track", help="track every face of a video through its shots: one identity "
                                     "per person, pose and expression per frame")
    p.add_argument("video", metavar="VIDEO", help="a video file (.mp4, .mov, .mkv, ...)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder for track.npz and track.json (made if missing; its parent must exist)")
    add_model_argument(p)
    add_detector_arguments(p)
    p.add_argument("--identity-frames", type=int, default=9, metavar="N",
                   help="frames per person, spread over their tracked frames, each fitted alone "
                        "and their identities averaged (default 9)")
    p.add_argument("--smoothing-hz", type=float, default=DEFAULT_SMOOTHING_HZ, metavar="HZ",
                   help=f"cut-off of the temporal prior, Hz; 0: none (default {DEFAULT_SMOOTHING_HZ:g})")
    p.add_argument("--overlay-video", action="store_true",
                   help="also write DIR/overlay.mp4: every person's fitted mesh over every frame, "
                        "with their number")
    p.add_argument("--animated-mesh", action="store_true",
                   help="also write an animated mesh per person, DIR/person_K.glb (DIR/track.glb "
                        "when one person is written; glTF 2.0 binary: identity in the base mesh, "
                        "expressions as morph targets, the head pose per frame, timed at the "
                        "video's frame rate)")
    keep = p.add_mutually_exclusive_group()
    keep.add_argument("--person", type=int, metavar="K",
                      help="write person K only (people are numbered by first appearance from 0)")
    keep.add_argument("--largest", action="store_true",
                      help="write only the person whose face covers the most pixels over the video")
    return p


def run(args):
    from ..pipeline import check_track_folder, keep_person, write_footage
    from ..tracking import track_footage

    check_track_folder(args.out)
    if args.identity_frames < 1:
        raise InputError(f"--identity-frames must be >= 1, got {args.identity_frames}")
    if not args.smoothing_hz >= 0:
        raise InputError(f"--smoothing-hz must be >= 0, got {args.smoothing_hz}")
    if args.person is not None and args.person < 0:
        raise InputError(f"--person must be >= 0, got {args.person}")
    start = time.perf_counter()
    footage = track_footage(args.video, model=model_from(args), identity_frames=args.identity_frames,
                            landmark_detector=args.landmark_detector, face_detector=args.face_detector,
                            smoothing_hz=args.smoothing_hz, progress=not args.quiet)
    seconds = time.perf_counter() - start
    n_people = len(footage.people)
    ids = list(range(n_people))
    if args.person is not None or args.largest:
        k = footage.largest_person() if args.largest else args.person
        if args.person is not None and args.person >= n_people:
            raise InputError(f"{args.video}: --person {args.person}, but {n_people} "
                             f"{'person was' if n_people == 1 else 'people were'} found (0 to {n_people - 1})")
        footage, ids = keep_person(footage, k), [k]
    written = write_footage(footage, args.out, video=args.video,
                            settings={"smoothing_hz": args.smoothing_hz, "identity_frames": args.identity_frames},
                            seconds=seconds, overlay_video=args.overlay_video, animated_mesh=args.animated_mesh,
                            person_ids=ids)
    F = footage.n_frames
    if len(footage.people) == 1:
        lost = [int(i) for i in np.flatnonzero(~footage.people[0].tracked)]
        faces = f"person {ids[0]} of {n_people}: {len(lost)} lost{_ranges(lost)}"
    else:
        faces = f"{n_people} people in {len(footage.tracks)} tracks"
    print(f"{args.video}: {F} frames, {len(footage.shots)} shot{'s' * (len(footage.shots) > 1)}, {faces}, "
          f"face detector run on {int(footage.detected.sum())}; {F / seconds:.1f} frames/s; wrote "
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
