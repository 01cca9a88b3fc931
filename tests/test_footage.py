"""Footage: shot cuts, every face of a photo, several people through a video's shots.

The clips are small and built here: pattern clips for the shot detector, and for the tracker
London-set photos (CC BY 4.0, ../shared/data) pasted into frames, moved and cut between, so
that where each face is, and who it is, is known."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

av = pytest.importorskip("av")
pytest.importorskip("scenedetect")

from morphable.errors import InputError  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
W, H = 320, 240
SIDE = 110           # px, the pasted photos' side (the face about half of it)


def _cli(args, cwd):
    return subprocess.run([sys.executable, "-m", "morphable.cli", *args], cwd=cwd, capture_output=True,
                          text=True, env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=600)


def _pattern(seed: int, shift: int = 0) -> np.ndarray:
    """A textured frame (blocks of random colour), moved ``shift`` px right."""
    rng = np.random.default_rng(seed)
    blocks = rng.integers(0, 256, (H // 16, W // 16 + 4, 3), dtype=np.uint8)
    big = np.repeat(np.repeat(blocks, 16, 0), 16, 1)
    return np.ascontiguousarray(big[:, 32 - shift:32 - shift + W])


def test_cuts_and_fades_are_found_and_a_pan_is_not_a_cut(tmp_path):
    from morphable.shots import find_shots
    from morphable.video import write_video

    frames = [_pattern(1, i) for i in range(12)]                       # a slow pan: no cut
    frames += [_pattern(2, i) for i in range(10)]                      # a hard cut at 12
    frames += [(_pattern(2, 10) * (1 - k / 4)).astype(np.uint8) for k in range(1, 5)]   # fade out 22-25
    frames += [np.zeros((H, W, 3), np.uint8)] * 3                      # black 26-28
    frames += [(_pattern(3) * (k / 4)).astype(np.uint8) for k in range(1, 5)]       # fade in 29-32
    frames += [_pattern(3, i) for i in range(8)]                       # 33-40
    clip = write_video(tmp_path / "cuts.mp4", frames, fps=25)
    shots = find_shots(clip)
    cuts = [a for a, _ in shots[1:]]
    assert shots[0][0] == 0 and shots[-1][1] == len(frames)
    assert len(cuts) == 2, shots
    assert cuts[0] == 12
    assert 24 <= cuts[1] <= 31, cuts            # within the fade's dark stretch (within 2 frames)


def test_associate_takes_the_best_overlap():
    from morphable.tracking import associate

    tracks = [[0, 0, 100, 100], [90, 0, 190, 100]]
    found = [[95, 5, 195, 105], [5, 0, 105, 100], [400, 0, 500, 100]]
    assert sorted(associate(tracks, found)) == [(0, 1), (1, 0)]
    assert associate(tracks, [[300, 300, 310, 310]]) == []
    assert associate([], found) == []


def test_join_tracks_by_descriptor_never_two_at_once():
    from morphable.tracking import join_tracks

    rng = np.random.default_rng(0)
    a, b = rng.normal(size=128), rng.normal(size=128)
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)       # 1.4 apart
    near = lambda x: (x + rng.normal(0, 0.02, (3, 128))).astype(np.float32)   # noqa: E731
    descriptors = [near(a), near(b), near(a), near(b), near(a)]
    frames = [np.arange(0, 10), np.arange(0, 10), np.arange(10, 20), np.arange(20, 30), np.arange(25, 30)]
    person = join_tracks(descriptors, frames)
    # tracks 0, 2 are A, 1 and 3 B; track 4 is A's descriptor but shares frames with track 3 (B)
    # and with nothing of A's: it may join A
    assert person[0] == person[2] == person[4] != person[1] == person[3]
    # the same face twice at once (track 0 and a copy in the same frames) stays two people
    person = join_tracks([near(a), near(a)], [np.arange(5), np.arange(3, 8)])
    assert person.tolist() == [0, 1]
    # a threshold below the distance joins nothing
    assert len(set(join_tracks(descriptors, frames, threshold=0.01).tolist())) == 5


# --- with real faces ---------------------------------------------------------------------------
def _face(data_dir, n: int, side: int = SIDE) -> np.ndarray:
    from PIL import Image

    with Image.open(data_dir / "faces" / "frl_london" / "neutral_front" / f"{n:03d}_03.jpg") as im:
        return np.asarray(im.convert("RGB").resize((side, side)))


def _paste(frame, face, x, y):
    frame[y:y + face.shape[0], x:x + face.shape[1]] = face
    return frame


@pytest.fixture(scope="module")
def people_clip(tmp_path_factory, data_dir):
    """Three shots at 25 frames/s: 0-9 persons A (left, moving right) and B (right); 10-17 C
    alone; 18-25 A alone, larger. ``centres``: per frame, the pasted faces' centres by person."""
    from morphable.video import write_video

    A, B, C = _face(data_dir, 1), _face(data_dir, 2), _face(data_dir, 3)
    A2 = _face(data_dir, 1, 150)
    frames, centres = [], []
    for i in range(10):
        f = np.full((H, W, 3), 90, np.uint8)
        _paste(f, A, 10 + 2 * i, 60)
        _paste(f, B, 190, 70)
        frames.append(f)
        centres.append({"A": (10 + 2 * i + SIDE / 2, 60 + SIDE / 2), "B": (190 + SIDE / 2, 70 + SIDE / 2)})
    for i in range(8):
        frames.append(_paste(np.full((H, W, 3), 30, np.uint8), C, 100 + i, 50))
        centres.append({"C": (100 + i + SIDE / 2, 50 + SIDE / 2)})
    for i in range(8):
        frames.append(_paste(np.full((H, W, 3), 170, np.uint8), A2, 90, 40 + i))
        centres.append({"A": (90 + 75, 40 + i + 75)})
    d = tmp_path_factory.mktemp("people")
    write_video(d / "people.mp4", frames, fps=25)
    return {"dir": d, "path": d / "people.mp4", "centres": centres}


@pytest.fixture(scope="module")
def footage(people_clip):
    from morphable.tracking import track_footage

    return track_footage(people_clip["path"])


def test_shots_tracks_and_people(footage, people_clip):
    assert footage.shots == [(0, 10), (10, 18), (18, 26)]
    # every face tracked through its shot, one track per face and shot
    spans = sorted((t.shot, t.first_frame, t.last_frame) for t in footage.tracks)
    assert spans == [(0, 0, 9), (0, 0, 9), (1, 10, 17), (2, 18, 25)], spans
    # who is who: each track's faces where its person's face was pasted, no switch inside a shot
    names = {}
    for t in footage.tracks:
        p = footage.people[t.person]
        for f in t.frames:
            centre = np.nanmean(p.landmarks_68_px[f], 0)
            name = min(people_clip["centres"][f],
                       key=lambda n: np.hypot(*(centre - people_clip["centres"][f][n])))
            assert np.hypot(*(centre - people_clip["centres"][f][name])) < 0.15 * SIDE, (t.id, f, centre)
            names.setdefault(t.id, set()).add(name)
    assert all(len(v) == 1 for v in names.values()), names
    person = {next(iter(names[t.id])): set() for t in footage.tracks}
    for t in footage.tracks:
        person[next(iter(names[t.id]))].add(t.person)
    # A's two tracks (shots 0 and 2) joined across the cut; three people in all
    assert len(footage.people) == 3 and all(len(v) == 1 for v in person.values()), person
    assert len({next(iter(v)) for v in person.values()}) == 3
    # the face detector ran at the shots' starts, not on every frame
    assert footage.detected[[0, 10, 18]].all() and footage.detected.sum() <= 6
    # every face was fitted, with a mesh
    assert all(set(t.status) == {"fitted"} for t in footage.tracks)
    a = footage.people[next(iter(person["A"]))]
    assert a.tracked.sum() == 18 and np.isfinite(a.euler_deg[a.tracked]).all()


def test_track_command_writes_every_person_and_keeps_one(people_clip, footage):
    d = people_clip["dir"]
    r = _cli(["track", "people.mp4", "--out", "all", "--overlay-video", "--animated-mesh", "-q"], d)
    assert r.returncode == 0, r.stderr
    assert "3 shots, 3 people in 4 tracks" in r.stdout
    summary = json.loads((d / "all" / "track.json").read_text())
    assert summary["cuts"] == [10, 18] and len(summary["people"]) == 3 and len(summary["tracks"]) == 4
    assert len(summary["frame_status"]) == 26
    assert [len(f["faces"]) for f in summary["frame_status"]] == [2] * 10 + [1] * 16
    assert all(face["status"] == "fitted" for f in summary["frame_status"] for face in f["faces"])
    assert sorted(p.name for p in (d / "all").glob("person_*.glb")) == ["person_0.glb", "person_1.glb", "person_2.glb"]
    t = np.load(d / "all" / "track.npz")
    assert t["person0_euler_deg"].shape == (26, 3) and t["shots"].tolist() == [[0, 10], [10, 18], [18, 26]]
    assert sorted(t["track_person"].tolist()) == sorted(tr["person"] for tr in summary["tracks"])
    from morphable.video import probe

    assert probe(d / "all" / "overlay.mp4").n_frames == 26
    # --largest: A (the largest face, in two shots), written as one person
    r = _cli(["track", "people.mp4", "--out", "one", "--largest", "--animated-mesh", "-q"], d)
    assert r.returncode == 0, r.stderr
    one = json.loads((d / "one" / "track.json").read_text())
    assert len(one["people"]) == 1 and one["frames_tracked"] == 18
    assert one["frames_lost"] == list(range(10, 18))
    assert (d / "one" / "track.glb").is_file()
    # --person beyond the people found: one line, nothing written
    r = _cli(["track", "people.mp4", "--out", "none", "--person", "5", "-q"], d)
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "--person 5, but 3 people were found" in r.stderr and not (d / "none").exists()


@pytest.fixture(scope="module")
def two_faces(tmp_path_factory, data_dir):
    from PIL import Image

    d = tmp_path_factory.mktemp("photo")
    photo = np.full((260, 480, 3), 120, np.uint8)
    _paste(photo, _face(data_dir, 2, 200), 260, 40)        # the right one larger
    _paste(photo, _face(data_dir, 1, 160), 20, 60)
    Image.fromarray(photo).save(d / "two.png")
    return d


def test_fit_all_faces_and_one_face(two_faces):
    import morphable

    d = two_faces
    results = morphable.fit_images(d / "two.png", all_faces=True)
    assert [r.report["face"]["index"] for r in results] == [0, 1]
    boxes = [r.report["face"]["box_px"] for r in results]
    assert boxes[0][0] < 180 < 260 < boxes[1][0]                     # left to right
    # each fit on its own face: the fitted points within the face's pasted square
    for r, (x0, x1) in zip(results, [(20, 180), (260, 460)]):
        x = np.nanmean(r.fit.landmarks_68_px()[0][:, 0])
        assert x0 < x < x1
    r = _cli(["fit", "two.png", "--all-faces", "--out-mesh", "m.obj", "--report", "r.json",
              "--overlay", "o.png", "-q"], d)
    assert r.returncode == 0, r.stderr
    assert all((d / n).is_file() for n in ("m_0.obj", "m_1.obj", "r_0.json", "r_1.json", "o.png"))
    assert json.loads((d / "r_1.json").read_text())["face"]["faces_found"] == 2
    # default: the largest (the right one) and a line saying the other was seen
    r = _cli(["fit", "two.png", "--report", "largest.json"], d)
    assert r.returncode == 0 and "1 other face seen" in r.stdout, r.stdout + r.stderr
    largest = json.loads((d / "largest.json").read_text())
    assert largest["faces_seen"] == 2
    assert np.nanmean([p[0] for p in largest["frames"][0]["landmarks_68_px"] if p]) > 260
    r = _cli(["fit", "two.png", "--face", "0", "--report", "f0.json", "-q"], d)
    assert r.returncode == 0, r.stderr
    f0 = json.loads((d / "f0.json").read_text())
    assert np.nanmean([p[0] for p in f0["frames"][0]["landmarks_68_px"] if p]) < 180


def test_bad_inputs_one_line_nothing_written(two_faces, tmp_path):
    from morphable.video import write_video

    d = two_faces
    rng = np.random.default_rng(1)
    write_video(d / "noface.mp4", [rng.integers(0, 60, (H, W, 3), dtype=np.uint8) for _ in range(8)])
    # an audio-only file: an AAC stream, no video
    out = av.open(str(d / "audio.m4a"), "w")
    s = out.add_stream("aac", rate=16000)
    for k in range(4):
        frame = av.AudioFrame.from_ndarray(np.zeros((1, 1024), np.float32), format="fltp", layout="mono")
        frame.sample_rate, frame.pts = 16000, 1024 * k
        for p in s.encode(frame):
            out.mux(p)
    for p in s.encode():
        out.mux(p)
    out.close()
    before = sorted(p.name for p in d.iterdir())
    for args, message in [
        (["fit", "two.png", "--face", "5", "--report", "x.json"],
         "two.png: face 5 asked for, 2 faces were found (0 to 1)"),
        (["fit", "two.png", "--face", "-1", "--report", "x.json"], "--face must be >= 0"),
        (["fit", "two.png", "two.png", "--all-faces", "--report", "x.json"], "--all-faces: for one photo"),
        (["track", "noface.mp4", "--out", "t"], "noface.mp4: no face found in any of its 8 frames"),
        (["track", "audio.m4a", "--out", "t"], "audio.m4a: no video stream"),
    ]:
        r = _cli(args, d)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and message in r.stderr, (args, r.stderr)
    assert sorted(p.name for p in d.iterdir()) == before
    with pytest.raises(InputError, match="face 5 asked for"):
        import morphable

        morphable.fit_images(d / "two.png", face=5)


def test_one_frame_video(two_faces):
    from PIL import Image

    from morphable.video import write_video

    d = two_faces
    write_video(d / "one.mp4", [np.asarray(Image.open(d / "two.png"))[:256, :480]])
    r = _cli(["track", "one.mp4", "--out", "one", "-q"], d)
    assert r.returncode == 0, r.stderr
    summary = json.loads((d / "one" / "track.json").read_text())
    assert summary["frames"] == 1 and summary["shots"] == [[0, 1]] and len(summary["people"]) == 2
    assert [f["person"] for f in summary["frame_status"][0]["faces"]] == [0, 1]


def test_phone_rotation_and_variable_frame_rate(two_faces):
    """A phone clip stored on its side with rotation metadata is tracked upright; a
    variable-frame-rate file keeps each frame's time."""
    from PIL import Image

    from morphable.tracking import track_footage
    from morphable.video import write_video

    d = two_faces
    photo = np.asarray(Image.open(d / "two.png"))[:256, :480]
    # stored turned 90 degrees clockwise, with a display rotation of 90 (counter-clockwise) to undo it
    write_video(d / "phone.mp4", [np.ascontiguousarray(np.rot90(photo, -1))] * 4, rotation_deg=90)
    times = [0.0, 1 / 30, 1 / 30 + 0.1, 1 / 30 + 0.2]       # as tests/test_video.py writes one
    write_video(d / "vfr.mkv", [photo] * 4, times_s=times)
    for name in ("phone.mp4", "vfr.mkv"):
        result = track_footage(d / name)
        assert result.image_size == (480, 256), name
        assert len(result.people) == 2 and all(p.tracked.all() for p in result.people), name
        # the faces upright where the photo has them: the left one left of 180 px, eyes above mouth
        lm = result.people[0].landmarks_68_px[0]
        assert np.nanmean(lm[:, 0]) < 180 and np.nanmean(lm[36:48, 1]) < np.nanmean(lm[48:68, 1]), name
    np.testing.assert_allclose(result.people[0].time_s, times, atol=2e-3)


def test_detections_waiting_on_disk_give_the_same_track(people_clip, footage, monkeypatch):
    """A track's older detections go to disk in chunks (memory bounded for long videos): with
    chunks of 3 rows the result is the one held in memory."""
    from morphable.tracking import footage as module
    from morphable.tracking import track_footage

    monkeypatch.setattr(module, "CHUNK_ROWS", 3)
    again = track_footage(people_clip["path"])
    assert [(t.person, t.first_frame, t.last_frame) for t in again.tracks] == \
        [(t.person, t.first_frame, t.last_frame) for t in footage.tracks]
    for a, b in zip(again.people, footage.people):
        np.testing.assert_array_equal(a.tracked, b.tracked)
        np.testing.assert_allclose(a.euler_deg[a.tracked], b.euler_deg[b.tracked])
        np.testing.assert_allclose(a.identity, b.identity)


def test_no_mesh_where_the_box_holds_no_face(data_dir, tmp_path):
    """A face replaced mid-shot by a featureless head-coloured blob (as a back of a head is):
    the track ends there, reported with its face score, and no mesh is fitted on the blob."""
    from morphable.tracking import track_footage
    from morphable.video import write_video

    face = _face(data_dir, 4, 150)
    blob = np.full_like(face, 120)
    yy, xx = np.mgrid[:150, :150]
    blob[((yy - 70) / 60) ** 2 + ((xx - 75) / 45) ** 2 < 1] = (150, 110, 90)
    frames = []
    for i in range(10):
        f = np.full((H, W, 3), 70, np.uint8)
        _paste(f, face if i < 6 else blob, 80 + i, 45)
        frames.append(f)
    write_video(tmp_path / "turn.mp4", frames, fps=25)
    result = track_footage(tmp_path / "turn.mp4")
    assert len(result.shots) == 1 and len(result.people) == 1, result.shots
    (track,) = result.tracks
    assert (track.first_frame, track.last_frame) == (0, 5) and track.lost[0] == 6
    assert track.lost[1] is None or track.lost[1] < 0.5
    np.testing.assert_array_equal(result.people[0].tracked, np.arange(10) < 6)
    status = result.frame_status()
    assert [f["status"] for f in status[6]["faces"]] == ["lost"] and status[7]["faces"] == []


def test_fit_on_a_video_keeps_one_person(data_dir, tmp_path):
    """``morphable fit CLIP``: the person of the first frame (the larger face there) is fitted
    in every sampled frame, also where another person's face is the larger; a frame showing
    only the other person is skipped."""
    import morphable
    from morphable.video import write_video

    A_big, A_small = _face(data_dir, 5, 150), _face(data_dir, 5, 90)
    B_big, B_small = _face(data_dir, 6, 150), _face(data_dir, 6, 90)
    frames = []
    for i in range(9):
        f = np.full((H, W, 3), 80, np.uint8)
        if i < 3:
            _paste(_paste(f, A_big, 20, 45), B_small, 215, 75)                # A the larger
        elif i < 6:
            _paste(_paste(f, A_small, 20, 75), B_big, 150, 45)                # B the larger
        else:
            _paste(f, B_big, 150, 45)                                         # B alone
        frames.append(f)
    write_video(tmp_path / "two.mp4", frames, fps=25)
    result = morphable.fit_images(tmp_path / "two.mp4", video_frames=9)
    report = result.report
    assert [f["frame"] for f in report["video_frames"]] == list(range(6))
    assert [s["reason"] for s in report["frames_skipped"]] == ["only other people's faces"] * 3
    x = [np.nanmean(result.fit.landmarks_68_px()[k][:, 0]) for k in range(6)]
    assert all(v < 140 for v in x), x           # A, on the left, in every fitted frame
    # the largest face of each frame alone would have been B's in frames 3-5
    from morphable.detection import detect

    assert np.nanmean(detect(result.pictures[3].pixels()).points[:, 0]) > 150
