"""Footage benchmark: shot cuts, several people, identities joined across shots, group photos.

Three measurements (docs/video.md, "Footage: several people and shot cuts"):

- ``--clips N``: multi-shot clips built from real photos with known truth: London-set people
  (CC BY 4.0; a neutral photo in one shot and the same person smiling in another) and AFLW
  crops (**research use only**), pasted into 640 x 480 frames, moved, zoomed and cut between
  (hard cuts and a fade through black), two or three faces at once, a person leaving the
  picture and coming back. The tracker (:func:`morphable.tracking.track_footage`) is scored
  on: cut precision and recall (a cut found within 2 frames; a fade's anywhere in its dark
  stretch), identity switches inside a shot and across shots (CLEAR-MOT style: the tracker's
  person matched to a true face changes), fragmentation (a true person's matched run
  interrupted while present and resumed in the same shot), missed and false faces, MOTA (1 - (misses + false + switches) /
  faces present), the eye-centre NME of the London faces (their templates' pupils against the
  mean of the fitted iBUG eye points, over the interocular distance), and frames/s;
- ``--speed``: the tracking loop's frames/s for one face and for three faces, 640 x 480
  (``--speed-detectors network fused --rounds 3``: the landmark detectors interleaved);
- ``--group N``: the first N 300-W AFW photos (**research use only**) with two faces or more
  annotated: faces found by :func:`morphable.detection.detect_all` (its tiles too) and fitted
  (``morphable.fit_images(..., all_faces=True)``) against the faces annotated;
- ``--moving-head N``: ``bench_video``'s moving-head clip (N frames) through the one-face
  tracker and this one, error and jitter against its truth;
- ``--calibrate``: the descriptor distance of :data:`morphable.descriptors.SAME_PERSON_DISTANCE`
  from London pairs (each person's neutral against their smiling photo; other people's) and
  pairs of AFLW crops (distinct photos, taken for distinct people): the middle between the
  same-person distances' 95th percentile and the different-person distances' 5th.

Run with ``python -m evaluation.bench_footage --clips 3 --speed --group 20 --calibrate``.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from morphable.errors import InputError, one_line_errors

__all__ = ["make_clip", "score_clip", "calibrate", "group_photos", "speed", "main"]

W, H, FPS = 640, 480, 25.0
TOLERANCE = 2
"""A cut found within this many frames of the true one counts as found."""


def _london(data: Path, n: int, view: str = "neutral"):
    """A London photo (512, 512, 3) uint8 and its pupils (2, 2) px (from the neutral photo's
    template: the same person's smiling photo is taken at the same framing)."""
    from PIL import Image

    folder, suffix = ("neutral_front", "03") if view == "neutral" else ("smiling_front", "08")
    with Image.open(data / "faces" / "frl_london" / folder / f"{n:03d}_{suffix}.jpg") as im:
        photo = np.asarray(im.convert("RGB"))
    tem = (data / "faces" / "frl_london" / "neutral_front" / f"{n:03d}_03.tem").read_text().split("\n")
    pupils = np.array([[float(v) for v in line.split()] for line in tem[1:3]])
    return photo, pupils if view == "neutral" else None


def _aflw(data: Path, k: int):
    from PIL import Image

    index = np.load(data / "faces" / "aflw_crops" / "index.npz")
    name = str(index["names"][k])
    with Image.open(data / "faces" / "aflw_crops" / "crops" / name) as im:
        return np.asarray(im.convert("RGB")), None


def _background(rng, shade: int) -> np.ndarray:
    """A textured background (smooth blocks), a different one per shot."""
    from PIL import Image

    small = rng.integers(max(0, shade - 60), min(255, shade + 60), (6, 8, 3)).astype(np.uint8)
    return np.asarray(Image.fromarray(small).resize((W, H), Image.BILINEAR))


def _paste(frame, photo, side: float, cx: float, cy: float):
    """``photo`` resized to ``side`` px, centred at (cx, cy), clipped by the frame -> the
    transform (scale, x0, y0) from photo px to frame px and the visible fraction."""
    from PIL import Image

    s = int(round(side))
    img = np.asarray(Image.fromarray(photo).resize((s, s), Image.BILINEAR))
    x0, y0 = int(round(cx - s / 2)), int(round(cy - s / 2))
    fx0, fy0, fx1, fy1 = max(0, x0), max(0, y0), min(W, x0 + s), min(H, y0 + s)
    if fx1 > fx0 and fy1 > fy0:
        frame[fy0:fy1, fx0:fx1] = img[fy0 - y0:fy1 - y0, fx0 - x0:fx1 - x0]
    visible = max(0, fx1 - fx0) * max(0, fy1 - fy0) / (s * s)
    return (s / photo.shape[0], x0, y0), visible


def make_clip(path, data, seed: int = 0) -> dict:
    """Write a multi-shot clip to ``path`` (640 x 480, 25 frames/s, 5 shots, 195 frames) and
    return its truth: ``cuts`` (frame, kind, (first, last) of a fade's dark stretch), per frame
    the faces ``[{"person", "box", "pupils" or None}]`` (box px; pupils (2, 2) px for London
    neutral photos) of faces at least half visible."""
    from morphable.video import write_video

    data = Path(data)
    rng = np.random.default_rng(seed)
    london = sorted((data / "faces" / "frl_london" / "neutral_front").glob("*.jpg"))
    people = [int(london[i].stem[:3]) for i in rng.choice(len(london), 4, replace=False)]
    crops = rng.choice(11000, 2, replace=False)
    neutral = {p: _london(data, n) for p, n in enumerate(people)}
    smiling = {p: _london(data, n, "smiling") for p, n in enumerate(people)}
    aflw = {4 + k: _aflw(data, int(c)) for k, c in enumerate(crops)}
    # shots: (frames, shade, [(person, photos, side(t), cx(t), cy(t))]) with t in [0, 1]
    shots = [
        (40, 90, [(0, neutral, lambda t: 170, lambda t: 170 + 60 * t, lambda t: 220),
                  (1, neutral, lambda t: 150, lambda t: 470, lambda t: 230 - 20 * t)]),
        (30, 150, [(2, neutral, lambda t: 180 + 100 * t, lambda t: 320, lambda t: 240)]),
        (45, 60, [(0, smiling, lambda t: 150, lambda t: 130, lambda t: 230),
                  (4, aflw, lambda t: 130, lambda t: 320, lambda t: 200 + 30 * t),
                  # leaves the picture to the right and comes back
                  (1, smiling, lambda t: 150, lambda t: 520 + 300 * np.sin(np.pi * t) ** 2, lambda t: 250)]),
        (40, 120, [(3, neutral, lambda t: 200, lambda t: 200 + 40 * t, lambda t: 240),
                   (2, smiling, lambda t: 160, lambda t: 470, lambda t: 240)]),
        (30, 180, [(4, aflw, lambda t: 260 - 60 * t, lambda t: 300, lambda t: 240),
                   (5, aflw, lambda t: 120, lambda t: 560, lambda t: 120)]),
    ]
    frames, truth, cuts = [], [], []
    fade = 4, 3                                  # frames to black and of black, before shot 3
    for k, (n, shade, cast) in enumerate(shots):
        if k == 3:
            first = len(frames) + fade[0]
            cuts.append({"frame": first + fade[1] // 2, "kind": "fade",
                         "span": [first - 1, first + fade[1] + fade[0]]})
        elif k:
            cuts.append({"frame": len(frames), "kind": "cut", "span": [len(frames), len(frames)]})
        background = _background(rng, shade)
        shot_frames = []
        for i in range(n):
            t = i / max(1, n - 1)
            frame = background.copy()
            faces = []
            for person, photos, side, cx, cy in cast:
                photo, pupils = photos[person]
                (s, x0, y0), visible = _paste(frame, photo, side(t), cx(t), cy(t))
                if visible >= 0.5:
                    faces.append({"person": person, "box": [x0, y0, x0 + s * photo.shape[1], y0 + s * photo.shape[0]],
                                  "pupils": None if pupils is None else (pupils * s + [x0, y0]).tolist()})
            shot_frames.append((frame, faces))
        if k == 3:   # the previous shot fades out, black, this one fades in
            last = frames[-1]
            fades = [((last * (1 - (j + 1) / (fade[0] + 1))).astype(np.uint8), []) for j in range(fade[0])]
            fades += [(np.zeros_like(last), [])] * fade[1]
            fades += [((shot_frames[0][0] * ((j + 1) / (fade[0] + 1))).astype(np.uint8), []) for j in range(fade[0])]
            frames += [f for f, _ in fades]
            truth += [t for _, t in fades]
        frames += [f for f, _ in shot_frames]
        truth += [t for _, t in shot_frames]
    write_video(path, frames, fps=FPS)
    return {"cuts": cuts, "faces": truth, "n_frames": len(frames), "london": people,
            "aflw": [int(c) for c in crops]}


def _eye_centres(lm68) -> np.ndarray:
    """(68, 2) px -> (2, 2): the mean of each eye's six iBUG points (the subject's right eye,
    on the image's left, first)."""
    return np.stack([np.nanmean(lm68[36:42], 0), np.nanmean(lm68[42:48], 0)])


def score_clip(footage, truth) -> dict:
    """The tracker's result against a clip's truth (see the module)."""
    found = [a for a, _ in footage.shots[1:]]
    hit = set()
    for c in truth["cuts"]:
        lo, hi = c["span"][0] - TOLERANCE, c["span"][1] + TOLERANCE
        match = [f for f in found if lo <= f <= hi]
        if match:
            hit.add(c["frame"])
    used = {f for f in found for c in truth["cuts"] if c["span"][0] - TOLERANCE <= f <= c["span"][1] + TOLERANCE}
    precision = len(used) / len(found) if found else 1.0
    recall = len(hit) / len(truth["cuts"])
    # per frame: the tracker's faces (person, box of its fitted points) matched to the true ones
    shot_of = np.zeros(truth["n_frames"], int)
    for k, (a, b) in enumerate(footage.shots):
        shot_of[a:b] = k
    last = {}                 # true person -> (predicted person, frame, shot) of their last match
    switches_in, switches_across, fragments, misses, false, present, nme = 0, 0, 0, 0, 0, 0, []
    predicted_ids, gap = {}, set()
    for f, faces in enumerate(truth["faces"]):
        if f and shot_of[f] != shot_of[f - 1]:
            gap.clear()
        pred = []
        for k, p in enumerate(footage.people):
            if p.tracked[f]:
                lm = p.landmarks_68_px[f]
                pred.append((k, np.nanmean(lm, 0), lm))
        present += len(faces)
        taken = set()
        for face in faces:
            b = np.array(face["box"], float)
            centre, side = (b[:2] + b[2:]) / 2, b[2] - b[0]
            best = min(((np.hypot(*(c - centre)), k, lm) for k, c, lm in pred if k not in taken),
                       default=None, key=lambda x: x[0])
            if best is None or best[0] > 0.35 * side:
                misses += 1
                if face["person"] in last:
                    gap.add(face["person"])
                continue
            _, k, lm = best
            taken.add(k)
            who = face["person"]
            predicted_ids.setdefault(who, set()).add(k)
            if who in last:
                pk, pf, ps = last[who]
                if pk != k:
                    if ps == shot_of[f]:
                        switches_in += 1
                    else:
                        switches_across += 1
                if ps == shot_of[f] and who in gap:      # present, missed, and found again
                    fragments += 1
            gap.discard(who)
            last[who] = (k, f, shot_of[f])
            if face["pupils"] is not None:
                pupils = np.array(face["pupils"])
                eyes = _eye_centres(lm)
                nme.append(float(np.linalg.norm(eyes - pupils, axis=1).mean() / np.linalg.norm(pupils[1] - pupils[0])))
        false += len(pred) - len(taken)
    return {"frames": truth["n_frames"], "cuts": len(truth["cuts"]), "cuts_found": len(found),
            "cut_precision": precision, "cut_recall": recall, "switches_in_shot": switches_in,
            "switches_across_shots": switches_across, "fragmentation": fragments,
            "people_true": len(predicted_ids), "people_found": len(footage.people),
            "ids_per_person": float(np.mean([len(v) for v in predicted_ids.values()])),
            "faces_present": present, "misses": misses, "false": false,
            "mota": 1 - (misses + false + switches_in + switches_across) / max(1, present),
            "eye_nme": float(np.mean(nme)) if nme else None, "nme_frames": len(nme)}


def calibrate(data, n_aflw: int = 200, seed: int = 0) -> dict:
    """Descriptor distances of same-person and different-person pairs -> the threshold of the
    fewest errors (each kind weighted equally) and its error rates."""
    from morphable.descriptors import descriptor_distance, face_descriptors
    from morphable.detection import detect_all

    data = Path(data)

    def describe(photo):
        faces = detect_all(photo)
        if not faces:
            return None
        big = max(faces, key=lambda d: np.ptp(d.ibug68[:, 0]))
        return face_descriptors(photo, [big.ibug68])[0]

    neutral, smiling = {}, {}
    for path in sorted((data / "faces" / "frl_london" / "neutral_front").glob("*.jpg")):
        n = int(path.stem[:3])
        a, b = describe(_london(data, n)[0]), describe(_london(data, n, "smiling")[0])
        if a is not None and b is not None:
            neutral[n], smiling[n] = a, b
    ids = sorted(neutral)
    d = descriptor_distance(np.array([neutral[i] for i in ids]), np.array([smiling[i] for i in ids]))
    same = np.diag(d)
    other = [d[~np.eye(len(ids), dtype=bool)]]
    rng = np.random.default_rng(seed)
    crops = []
    for k in rng.choice(11000, n_aflw, replace=False):
        from PIL import Image

        photo = _aflw(data, int(k))[0]
        big = np.asarray(Image.fromarray(photo).resize((240, 240), Image.BILINEAR))
        v = describe(big)
        if v is not None:
            crops.append(v)
    crops = np.array(crops)
    dc = descriptor_distance(crops, crops)
    other.append(dc[np.triu_indices(len(crops), 1)])
    other = np.concatenate(other)
    at = lambda t: {"threshold": round(float(t), 2), "same_person_split": float(np.mean(same >= t)),   # noqa: E731
                    "different_joined": float(np.mean(other < t))}
    # the middle of the gap between the two kinds' tails: a video's frames of one person lie
    # further apart than two studio photos (pose, blur, light), so the margin is kept both ways
    middle = (np.percentile(same, 95) + np.percentile(other, 5)) / 2
    return {"london_people": len(ids), "aflw_crops": len(crops), "same_pairs": len(same),
            "different_pairs": len(other), "same_distance_median": float(np.median(same)),
            "same_distance_p95": float(np.percentile(same, 95)), "same_distance_max": float(same.max()),
            "different_distance_p5": float(np.percentile(other, 5)),
            "different_distance_min": float(other.min()), "chosen": at(middle),
            "table": [at(t) for t in (0.4, 0.45, 0.5, 0.55, 0.6, 0.65)]}


def group_photos(data, n: int = 20) -> dict:
    """The first ``n`` AFW photos with two faces or more annotated: faces found and fitted
    against those annotated (a found face is an annotated one when its 68 points' centre lies
    within a third of the annotated face's size of the annotation's)."""
    import morphable
    from morphable.detection import detect_all
    from morphable.errors import FitError
    from morphable.io.landmark_files import read_pts

    folder = Path(data) / "images" / "300w" / "afw"
    groups = {}
    for pts in sorted(folder.glob("*.pts")):
        groups.setdefault(pts.stem.rsplit("_", 1)[0], []).append(pts)
    photos = [(k, v) for k, v in groups.items() if len(v) >= 2][:n]
    present = found = fitted = extra = 0
    for stem, files in photos:
        image = folder / f"{files[0].stem}.jpg"
        truth = [read_pts(p) for p in files]
        faces = detect_all(image, tiles=True)
        try:
            fits = morphable.fit_images(image, all_faces=True)
        except FitError:
            fits = []
        present += len(truth)
        matched = set()
        for d in faces:
            c = d.ibug68.mean(0)
            for j, t in enumerate(truth):
                if j not in matched and np.hypot(*(c - t.mean(0))) < np.ptp(t[:, 0]) / 3:
                    matched.add(j)
                    break
            else:
                extra += 1
        found += len(matched)
        fitted_ok = set()
        for r in fits:
            c = np.nanmean(r.fit.landmarks_68_px()[0], 0)
            for j, t in enumerate(truth):
                if np.hypot(*(c - t.mean(0))) < np.ptp(t[:, 0]) / 3:
                    fitted_ok.add(j)
        fitted += len(fitted_ok)
    return {"photos": len(photos), "faces_annotated": present, "found": found, "fitted": fitted,
            "found_not_annotated": extra}


def _moving_clip(path, data, n_faces: int, n_frames: int = 150) -> None:
    """``n_faces`` London faces (about 160 px) drifting over a 640 x 480 clip, one shot."""
    from morphable.video import write_video

    photos = [_london(Path(data), n)[0] for n in (1, 2, 3)[:n_faces]]
    rng = np.random.default_rng(0)
    background = _background(rng, 100)

    def frames():
        for i in range(n_frames):
            t = i / n_frames
            frame = background.copy()
            for k, photo in enumerate(photos):
                cx = (k + 0.5) * W / n_faces + 20 * np.sin(2 * np.pi * t + k)
                _paste(frame, photo, 160 + 20 * np.sin(2 * np.pi * t), cx, 240 + 15 * np.cos(2 * np.pi * t))
            yield frame

    write_video(path, frames(), fps=FPS)


def speed(data, folder, n_frames: int = 150, detectors=("auto",), rounds: int = 1) -> dict:
    """Frames/s of :func:`~morphable.tracking.track_footage` on 640 x 480 clips of one and of
    three faces, for each landmark detector of ``detectors`` in turn, ``rounds`` times (the
    model loaded and the detectors warmed up first; interleaved, so that a change of the
    machine's load falls on all): the median of the tracking loop alone (the shots given) and
    of the whole call."""
    import os

    from morphable.io.registry import load_model
    from morphable.shots import find_shots
    from morphable.tracking import track_footage

    model = load_model("sfm")
    warm = Path(folder) / "warm_up.mp4"
    _moving_clip(warm, data, 1, 5)
    for d in detectors:
        track_footage(warm, model=model, landmark_detector=d)     # networks loaded, untimed
    clips = {}
    for n in (1, 3):
        clips[n] = Path(folder) / f"speed_{n}.mp4"
        _moving_clip(clips[n], data, n, n_frames)
    times = {}
    for _ in range(int(rounds)):
        for n in (1, 3):
            for d in detectors:
                t0 = time.perf_counter()
                shots = find_shots(clips[n])
                t1 = time.perf_counter()
                track_footage(clips[n], model=model, shots=shots, landmark_detector=d)
                t2 = time.perf_counter()
                times.setdefault((n, d), []).append((n_frames / (t2 - t1), n_frames / (t2 - t0)))
    out = {f"{n} face{'s' * (n > 1)}, {d}": {"loop_fps": float(np.median([a for a, _ in v])),
                                              "end_to_end_fps": float(np.median([b for _, b in v])),
                                              "runs": len(v)} for (n, d), v in times.items()}
    out["load_average"] = list(os.getloadavg())
    return out


def moving_head(folder, n_frames: int = 300, rounds: int = 2) -> dict:
    """``bench_video``'s moving-head video (:func:`evaluation.bench_video.make_video`: a real
    photo seen through a window moving along a known path, 640 x 480, its 68 annotated points
    as truth) through the one-face tracker (:func:`~morphable.tracking.track_video`) and the
    footage tracker (:func:`~morphable.tracking.track_footage`), interleaved ``rounds`` times:
    error (px) and jitter (px/frame²) of the fitted iBUG-68 points as ``bench_video`` reports
    them, frames lost, median frames/s."""
    import os

    from evaluation.bench_video import error, jitter, load_detector, make_video
    from morphable.io.registry import load_model
    from morphable.tracking import track_footage, track_video

    clip = Path(folder) / "moving_head.mp4"
    truth = make_video(clip, n_frames)
    model = load_model("sfm")
    load_detector(clip)
    track_footage(clip, model=model)                       # networks loaded once, untimed
    runs = {}
    for _ in range(int(rounds)):
        for name, run in (("track_video", track_video), ("track_footage", track_footage)):
            t = time.perf_counter()
            out = run(clip, model=model)
            seconds = time.perf_counter() - t
            tr = out if name == "track_video" else out.people[int(np.argmax([p.tracked.sum() for p in out.people]))]
            runs.setdefault(name, []).append({
                "error_px": error(tr.landmarks_68_px, truth), "jitter_px": jitter(tr.landmarks_68_px),
                "frames_lost": int((~tr.tracked).sum()), "fps": n_frames / seconds,
                "people": 1 if name == "track_video" else len(out.people)})
    out = {name: {**v[-1], "fps": float(np.median([r["fps"] for r in v]))} for name, v in runs.items()}
    out["truth_jitter_px"] = jitter(truth)
    out["load_average"] = list(os.getloadavg())
    return out


@one_line_errors("python -m evaluation.bench_footage")
def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.bench_footage", description=__doc__.split("\n\n")[0])
    p.add_argument("--data", default="../shared/data")
    p.add_argument("--clips", type=int, default=0, metavar="N", help="multi-shot clips (seeds 0..N-1)")
    p.add_argument("--speed", action="store_true", help="frames/s for one and three faces")
    p.add_argument("--speed-detectors", nargs="+", metavar="NAME",
                   help="--speed: these landmark detectors in turn (default --landmark-detector)")
    p.add_argument("--rounds", type=int, default=1, help="--speed: rounds, medians reported")
    p.add_argument("--group", type=int, default=0, metavar="N", help="AFW group photos")
    p.add_argument("--calibrate", action="store_true", help="the descriptor threshold")
    p.add_argument("--moving-head", type=int, default=0, metavar="FRAMES",
                   help="bench_video's moving-head video through both trackers")
    p.add_argument("--landmark-detector", default="auto",
                   help="the tracker's landmark detector (morphable.detection; default auto)")
    p.add_argument("--work", default="runs/bench_footage", help="folder for the clips")
    p.add_argument("--out", help="JSON results")
    args = p.parse_args(argv)
    if not Path(args.data).is_dir():
        raise InputError(f"{args.data}: no such folder")
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    results = {}
    if args.calibrate:
        results["calibration"] = calibrate(args.data)
        print(json.dumps(results["calibration"], indent=1))
    if args.clips:
        from morphable.io.registry import load_model
        from morphable.tracking import track_footage

        model = load_model("sfm")
        rows = []
        for seed in range(args.clips):
            path = work / f"clip_{seed}.mp4"
            truth = make_clip(path, args.data, seed)
            t = time.perf_counter()
            footage = track_footage(path, model=model, landmark_detector=args.landmark_detector)
            row = {"seed": seed, "landmark_detector": args.landmark_detector, **score_clip(footage, truth), "fps": truth["n_frames"] / (time.perf_counter() - t)}
            rows.append(row)
            print(json.dumps(row))
        results["clips"] = rows
    if args.speed:
        results["speed"] = speed(args.data, work, detectors=args.speed_detectors or [args.landmark_detector],
                                 rounds=args.rounds)
        print(json.dumps(results["speed"], indent=1))
    if args.moving_head:
        results["moving_head"] = moving_head(work, args.moving_head, args.rounds)
        print(json.dumps(results["moving_head"], indent=1))
    if args.group:
        results["group"] = group_photos(args.data, args.group)
        print(json.dumps(results["group"]))
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
