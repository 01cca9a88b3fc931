"""morphable.video: videos read frame by frame, upright, with their timestamps; bad files
answered with one line naming them. Every video here is written by the test itself."""
import tracemalloc

import numpy as np
import pytest

av = pytest.importorskip("av")

from morphable.errors import InputError  # noqa: E402
from morphable.video import (VideoFrame, is_video, iter_frames, probe, sample_frames,  # noqa: E402
                             sample_indices, write_video)


def frames(n, h=48, w=64):
    """n frames: a white block in the top-left corner, frame i's number as the grey level
    8 i of the bottom rows, so that a decoded frame tells which it is and which way up it is."""
    for i in range(n):
        a = np.zeros((h, w, 3), np.uint8)
        a[:8, :16] = 255
        a[-8:, 20:] = 8 * i % 256
        yield a


def number(frame: VideoFrame) -> int:
    return int(round(frame.image[-6:-2, 24:-4].mean() / 8))


@pytest.fixture(scope="module")
def clip(tmp_path_factory):
    return write_video(tmp_path_factory.mktemp("v") / "clip.mp4", frames(30), fps=25)


def test_probe_and_every_frame_in_order(clip):
    info = probe(clip)
    assert (info.width, info.height, info.n_frames, info.rotation_deg) == (64, 48, 30, 0)
    assert info.fps == pytest.approx(25) and info.duration_s == pytest.approx(30 / 25, abs=0.05)
    got = list(iter_frames(clip))
    assert [f.index for f in got] == list(range(30))
    assert [number(f) for f in got] == list(range(30))
    np.testing.assert_allclose([f.time_s for f in got], np.arange(30) / 25, atol=1e-3)
    assert got[3].image.shape == (48, 64, 3) and got[3].image.dtype == np.uint8
    assert got[3].label == f"{clip}#3" and got[3].size == (64, 48)


def test_uniform_sampling(clip):
    np.testing.assert_array_equal(sample_indices(30, 5), [0, 7, 14, 22, 29])
    got = sample_frames(clip, 5)
    assert [f.index for f in got] == [0, 7, 14, 22, 29] == [number(f) for f in got]
    assert len(sample_frames(clip, 100)) == 30          # a short video: all its frames
    with pytest.raises(InputError, match="cannot sample 0 frames"):
        sample_frames(clip, 0)
    with pytest.raises(InputError, match=r"frame 40 asked for, the video has 30"):
        list(iter_frames(clip, [3, 40]))


def test_variable_frame_rate_keeps_each_frames_time(tmp_path):
    times = np.r_[0, np.cumsum([1 / 30] * 4 + [0.1] * 5)]
    path = write_video(tmp_path / "vfr.mkv", frames(10), times_s=times)
    got = list(iter_frames(path))
    np.testing.assert_allclose([f.time_s for f in got], times, atol=2e-3)
    assert [number(f) for f in got] == list(range(10))


@pytest.mark.parametrize("rotation, corner", [(90, "bottom-left"), (270, "top-right"), (180, "bottom-right")])
def test_rotation_metadata_is_applied(tmp_path, rotation, corner):
    path = write_video(tmp_path / "phone.mp4", frames(3), rotation_deg=rotation)
    info = probe(path)
    assert info.rotation_deg == rotation
    assert (info.width, info.height) == ((48, 64) if rotation % 180 else (64, 48))
    image = next(iter_frames(path)).image
    assert image.shape == (info.height, info.width, 3)
    y, x = np.argwhere(image[..., 0] > 128).mean(0)
    h, w = image.shape[:2]
    assert corner == f"{'top' if y < h / 2 else 'bottom'}-{'left' if x < w / 2 else 'right'}"


def test_streaming_keeps_memory_flat(tmp_path):
    path = write_video(tmp_path / "long.mp4", frames(150, 240, 320))
    one = 240 * 320 * 3
    tracemalloc.start()
    n = sum(1 for _ in iter_frames(path))
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert n == 150
    assert peak < 10 * one, peak          # 150 frames would be 35 MB


def _faststart(path, n=60):
    """An mp4 with its index first, as cameras and streaming sites write them: cut, it still
    opens and its header still counts n frames."""
    out = av.open(str(path), "w", options={"movflags": "faststart"})
    s = out.add_stream("libx264", rate=30)
    s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
    for a in frames(n):
        for p in s.encode(av.VideoFrame.from_ndarray(a, format="rgb24")):
            out.mux(p)
    for p in s.encode():
        out.mux(p)
    out.close()
    return path


def _no_stream(path):
    """An mp4 whose writer got no frame: FFmpeg drops the empty video stream."""
    out = av.open(str(path), "w")
    s = out.add_stream("libx264", rate=30)
    s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
    out.start_encoding()
    out.close()
    return path


def test_bad_files_one_line_naming_the_file(tmp_path, clip):
    (tmp_path / "text.mp4").write_text("not a video\n")
    data = clip.read_bytes()
    (tmp_path / "noindex.mp4").write_bytes(data[:len(data) // 2])   # cut before its index (at the end)
    fast = _faststart(tmp_path / "fast.mp4").read_bytes()
    (tmp_path / "cut.mp4").write_bytes(fast[:int(len(fast) * 0.8)])
    _no_stream(tmp_path / "empty.mp4")
    cases = {"text.mp4": "cannot read video (not a video, or cut off)",
             "noindex.mp4": "cannot read video (not a video, or cut off)",
             "cut.mp4": "cut off",
             "empty.mp4": "no video stream (no frames)",
             "missing.mp4": "no such video"}
    for name, message in cases.items():
        path = tmp_path / name
        for read in (lambda p: list(iter_frames(p)), lambda p: sample_frames(p, 5)):
            with pytest.raises(InputError) as e:
                read(path)
            text = str(e.value)
            assert text.startswith(str(path)) and message in text and "\n" not in text, text
    with pytest.raises(InputError, match="no frames to write"):
        write_video(tmp_path / "none.mp4", [])
    assert not (tmp_path / "none.mp4").exists()


def test_is_video():
    assert is_video("a/clip.MOV") and is_video("x.mkv") and not is_video("face.png")


def test_missing_library_says_how_to_install(monkeypatch, clip):
    import sys

    monkeypatch.setitem(sys.modules, "av", None)
    with pytest.raises(InputError, match=r"video extra: pip install"):
        probe(clip)


# --- morphable fit on videos -------------------------------------------------------------------
@pytest.fixture(scope="module")
def face_clip(tmp_path_factory, data_dir):
    """A 12-frame 320 x 256 clip of image_0010 panning right 2 px a frame, frames 3 and 4 grey
    (no face), and a clip with no face at all."""
    from PIL import Image

    d = tmp_path_factory.mktemp("faces")
    with Image.open(data_dir / "images" / "image_0010.png") as im:
        photo = np.asarray(im.convert("RGB").resize((320, 256)))
    clip = [np.roll(photo, 2 * i, axis=1) for i in range(12)]
    for i in (3, 4):
        clip[i] = np.full_like(photo, 128)
    write_video(d / "face.mp4", clip)
    write_video(d / "grey.mp4", [np.full_like(photo, 128)] * 6)
    Image.fromarray(photo).save(d / "face.png")
    return d


def _cli(args, cwd):
    import os
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    return subprocess.run([sys.executable, "-m", "morphable.cli", *args], cwd=cwd, capture_output=True,
                          text=True, env={**os.environ, "PYTHONPATH": str(repo)}, timeout=300)


def test_fit_samples_a_video_skips_faceless_frames_and_mixes_with_photos(face_clip):
    import json

    r = _cli(["fit", "face.mp4", "face.png", "--frames", "6", "--report", "fit.json",
              "--overlay", "o.png", "-q"], face_clip)
    assert r.returncode == 0, r.stderr
    report = json.loads((face_clip / "fit.json").read_text())
    # sample_indices(12, 6) = 0 2 4 7 9 11: frame 4 is grey
    assert [f["image"] for f in report["frames"]] == [f"face.mp4#{i}" for i in (0, 2, 7, 9, 11)] + ["face.png"]
    assert report["frames_skipped"] == [{"image": "face.mp4#4", "time_s": pytest.approx(4 / 30, abs=1e-3),
                                         "reason": "no face found"}]
    assert [f["frame"] for f in report["video_frames"]] == [0, 2, 7, 9, 11]
    assert report["shared_identity"] and report["n_frames"] == 6
    assert "face.mp4#4" in r.stdout and "skipped" in r.stdout
    # the frames pan right by 2 px each: the fitted landmarks follow them
    x = np.array([np.nanmean([p[0] for p in f["landmarks_68_px"] if p]) for f in report["frames"][:5]])
    np.testing.assert_allclose(np.diff(x) / np.diff([0, 2, 7, 9, 11]), 2.0, atol=0.5)
    assert sorted(p.name for p in face_clip.glob("o_*.png")) == [f"o_{i}.png" for i in range(6)]


def test_fit_video_errors(face_clip):
    before = sorted(p.name for p in face_clip.iterdir())
    for args, message in [
        (["fit", "grey.mp4", "--report", "x.json"], "grey.mp4: no face found in any of the 5 sampled frames"),
        (["fit", "face.mp4", "--frames", "0", "--report", "x.json"], "--frames must be >= 1, got 0"),
        (["fit", "face.mp4", "--landmarks", "face.pts"], "face.mp4: landmark files are for photos"),
    ]:
        r = _cli(args, face_clip)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and message in r.stderr, r.stderr
    assert sorted(p.name for p in face_clip.iterdir()) == before


# --- morphable track ---------------------------------------------------------------------------
def test_track_writes_every_frame_reports_lost_ones_and_detects_only_when_lost(face_clip):
    import json

    r = _cli(["track", "face.mp4", "--out", "trk", "--overlay-video", "--animated-mesh", "-q"], face_clip)
    assert r.returncode == 0, r.stderr
    summary = json.loads((face_clip / "trk" / "track.json").read_text())
    assert summary["frames"] == 12 and summary["frames_lost"] == [3, 4] and summary["fps"] == pytest.approx(30)
    assert len(summary["identity"]) == 63
    assert "2 lost (frames 3-4)" in r.stdout
    t = np.load(face_clip / "trk" / "track.npz")
    assert t["landmarks_68_px"].shape == (12, 68, 2) and t["euler_deg"].shape == (12, 3)
    assert t["detector_px"].shape[:2] == (12, 478) and t["expression"].shape == (12, 6)
    np.testing.assert_array_equal(t["tracked"], ~np.isin(np.arange(12), [3, 4]))
    assert np.isnan(t["landmarks_68_px"][[3, 4]]).all() and np.isfinite(t["euler_deg"][t["tracked"]]).all()
    # the face detector: the first frame, the two lost ones, the first after them, and the
    # search for faces entering the picture, every QUICK_S (0.25 s: 8 frames) after the one at 3
    from morphable.tracking import QUICK_S

    assert round(QUICK_S * 30) == 8
    np.testing.assert_array_equal(np.flatnonzero(t["detected"]), [0, 3, 4, 5, 11])
    # the face pans right 2 px a frame: so do the fitted points
    ok = t["tracked"]
    x = np.nanmean(t["landmarks_68_px"][ok, :, 0], 1)
    slope = np.polyfit(np.flatnonzero(ok), x, 1)[0]
    assert slope == pytest.approx(2.0, abs=0.4)
    assert probe(face_clip / "trk" / "overlay.mp4").n_frames == 12
    _check_track_glb(face_clip / "trk" / "track.glb", t)
    # the detector's σ per frame where it gives one (the network, alone or fused), NaN if lost
    from morphable.detection import resolve_detectors

    assert np.isnan(t["detector_std_px"][[3, 4]]).all()
    if resolve_detectors()[0] in ("fused", "network"):
        assert (t["detector_std_px"][ok] > 0).all()


def _check_track_glb(path, t):
    """The animated mesh: one keyframe per tracked frame at its time, and each keyframe's scene
    seen through the file's orthographic camera lands where the track's camera puts the
    tracked mesh in the video frame (px)."""
    from glb_reader import animated_vertices, read_glb

    from morphable import load_model
    from morphable.camera import Camera, euler_to_matrix

    doc, acc = read_glb(path)
    model = load_model("sfm")
    ok = np.flatnonzero(t["tracked"])
    anim = doc["animations"][0]
    np.testing.assert_allclose(acc(anim["samplers"][0]["input"])[:, 0], t["time_s"][ok], rtol=1e-6)
    assert anim["extras"]["frames_lost"] == [3, 4] and anim["extras"]["frames"] == ok.tolist()
    prim = doc["meshes"][0]["primitives"][0]
    assert acc(prim["attributes"]["POSITION"]).shape == (model.n_vertices, 3)
    assert len(prim["targets"]) == model.n_expression
    assert doc["meshes"][0]["extras"]["targetNames"] == list(model.expression_names)
    cam = doc["cameras"][0]["orthographic"]
    W, H = (int(x) for x in t["image_size"])
    for k, f in enumerate(ok):
        truth = Camera(kind="affine", rotation=euler_to_matrix(*t["euler_deg"][f]),
                       translation=t["translation"][f], scale=t["scale"][f], image_size=(W, H)).project(
            model.vertices(t["identity"], t["expression"][f]))
        v = animated_vertices(doc, acc, k)
        px = np.c_[(W - 1) / 2 + v[:, 0] / cam["xmag"] * W / 2, (H - 1) / 2 - v[:, 1] / cam["ymag"] * H / 2]
        np.testing.assert_allclose(px, truth, atol=0.02)


def test_track_bad_inputs_write_nothing(face_clip):
    (face_clip / "file.txt").write_text("x")
    before = sorted(p.name for p in face_clip.iterdir())
    for args, message in [
        (["track", "grey.mp4", "--out", "t"], "grey.mp4: no face found in any of its 6 frames"),
        (["track", "face.mp4", "--out", "file.txt"], "file.txt: exists and is not a folder"),
        (["track", "face.mp4", "--out", "nosuch/t"], "nosuch does not exist"),
        (["track", "face.mp4", "--out", "t", "--smoothing-hz", "-1"], "--smoothing-hz must be >= 0"),
    ]:
        r = _cli(args, face_clip)
        assert r.returncode == 2 and r.stderr.count("\n") == 1 and message in r.stderr, r.stderr
    assert sorted(p.name for p in face_clip.iterdir()) == before


def test_temporal_prior_removes_jitter_and_keeps_the_motion():
    from morphable.tracking import smooth_trajectories

    fps, rng = 30.0, np.random.default_rng(0)
    t = np.arange(300) / fps
    truth = np.c_[20 * np.sin(2 * np.pi * 0.5 * t), 5 * np.sin(2 * np.pi * 1.5 * t)]   # head motion, deg
    measured = truth + rng.normal(0, 1.0, truth.shape)                                  # detector jitter
    tracked = np.ones(300, bool)
    tracked[100:103] = False                                                              # a lost stretch
    smooth = smooth_trajectories(measured, tracked, fps, cutoff_hz=4.0)
    np.testing.assert_array_equal(smooth[100:103], measured[100:103])

    def jitter(x):   # mean frame-to-frame acceleration
        return np.abs(np.diff(x[tracked][:95], 2, axis=0)).mean()

    assert jitter(smooth) < 0.25 * jitter(measured)
    assert jitter(smooth) < 1.5 * jitter(truth) + 0.2
    err = lambda x: np.sqrt(((x - truth)[tracked] ** 2).mean())   # noqa: E731
    assert err(smooth) < 0.6 * err(measured)
    np.testing.assert_array_equal(smooth_trajectories(measured, tracked, fps, cutoff_hz=0), measured)


@pytest.mark.parametrize("n", [3, 4, 7, 200])
def test_prior_solve_matches_the_dense_system(n):
    from morphable.tracking import solve_prior

    D2 = np.diff(np.eye(n), 2, axis=0)
    y = np.random.default_rng(n).normal(size=(n, 5))
    for lam in (0.3, 40.0, 2e4):
        np.testing.assert_allclose(solve_prior(y, lam), np.linalg.solve(np.eye(n) + lam * D2.T @ D2, y),
                                   rtol=1e-9, atol=1e-9 * lam)


def test_batched_fits_equal_one_fit_per_frame_and_refuse_points_without_a_face(sfm):
    from morphable.camera import Camera
    from morphable.fitting import fit_landmarks
    from morphable.fitting.noise import DETECTED_MODEL_STD_MM
    from morphable.tracking import fit_frames, fixed_identity_model

    rng = np.random.default_rng(3)
    fixed = fixed_identity_model(sfm, rng.normal(0, 1, sfm.n_identity))
    points = [Camera.looking_at_face(image_size=(640, 480), yaw=y, pitch=p).project(fixed.landmark_positions())
              + rng.normal(0, 1.5, (68, 2)) for y, p in ((0, 0), (25, -5), (-30, 10), (10, 20))]
    points[2] = rng.uniform(100, 400, (68, 2))      # points scattered in a box without a face
    points.insert(1, None)
    fits = fit_frames(fixed, points, (640, 480))
    assert fits[1] is None and fits[3] is None
    for i in (0, 2, 4):
        one = fit_landmarks(fixed, points[i], (640, 480), n_identity=0, model_std_mm=DETECTED_MODEL_STD_MM)
        cam, expression, rmse = fits[i]
        np.testing.assert_allclose(cam.rotation, one.cameras[0].rotation, atol=1e-9)
        np.testing.assert_allclose(cam.translation, one.cameras[0].translation, atol=1e-7)
        np.testing.assert_allclose(expression, one.expression[0], atol=1e-9)
        assert rmse == pytest.approx(float(one.landmark_rmse_px[0]), rel=1e-9) and rmse < 4


def test_detections_are_fitted_as_morphable_fit_fits_them(sfm):
    # a Detection brings its σ and its convention (478 points: fixed surface points); bare
    # points are a detector without σ whose outline slides
    from morphable.camera import Camera
    from morphable.detection import Detection
    from morphable.fitting import fit_landmarks
    from morphable.fitting.options import detection_settings
    from morphable.fitting.schemes import fit_scheme
    from morphable.tracking import fit_frames, fixed_identity_model

    rng = np.random.default_rng(4)
    fixed = fixed_identity_model(sfm, rng.normal(0, 1, sfm.n_identity))
    scheme = fit_scheme(fixed, 478)
    found = []
    for yaw in (-40.0, 0.0, 35.0):
        cam = Camera.looking_at_face(image_size=(640, 480), yaw=yaw)
        pts = cam.project(scheme.points(fixed.mean.reshape(-1, 3))) + rng.normal(0, 1.0, (478, 2))
        sigma = rng.uniform(0.5, 4.0, 478)
        found.append(Detection(pts, sigma, pts[:68], sigma[:68], "facemesh478", "3d", "network box"))
    fits = fit_frames(fixed, found, (640, 480))
    bare = fit_frames(fixed, [d.points for d in found], (640, 480))
    for d, (cam, expression, rmse), other in zip(found, fits, bare):
        one = fit_landmarks(fixed, d.points, (640, 480), n_identity=0, shared_identity=False,
                            **detection_settings([d], 478))
        np.testing.assert_allclose(cam.rotation, one.cameras[0].rotation, atol=1e-8)
        np.testing.assert_allclose(expression, one.expression[0], atol=1e-8)
        assert rmse == pytest.approx(float(one.landmark_rmse_px[0]), rel=1e-8)
        assert not np.allclose(other[0].rotation, cam.rotation, atol=1e-8)


def test_bench_video_averages_subjects_and_refuses_no_subjects(capsys):
    from evaluation.bench_video import main, mean_tracking

    def run(shape, lost):
        return {"indoor": {"image_size": [512, 512], "rows": {
            "track": {"shape_mm": shape, "jitter_mm": 2 * shape, "frames_lost": lost}}}}

    mean = mean_tracking([run(1.0, 1), run(2.0, 0), run(4.5, 2)])
    assert mean["indoor"]["n"] == 3
    assert mean["indoor"]["rows"]["track"] == {"shape_mm": 2.5, "jitter_mm": 5.0, "frames_lost": 3}
    assert main(["--florence", "--subjects", "ict", "--n-scans", "0"]) == 2
    assert capsys.readouterr().err.strip().endswith("--n-scans must be >= 1, got 0")
