"""Face and landmark detection (morphable.detection): dlib (the 'detect' extra) and the face
mesh (mediapipe), the photo reader, the detector choice. Timing is the benchmark's
(evaluation.bench_detection), not asserted here."""
import json

import numpy as np
import pytest

from morphable import FitError, InputError


@pytest.fixture(scope="module")
def takeo(data_dir):
    return data_dir / "images" / "takeo.ppm"


@pytest.fixture(scope="module")
def photo(data_dir):
    return data_dir / "images" / "image_0010.png"


def _face_size(pts):
    return float(np.sqrt(np.prod(pts.max(0) - pts.min(0))))


# --- the photo reader (no detector needed) ---------------------------------------------------

def test_unreadable_image(tmp_path):
    from morphable.detection import read_image

    bad = tmp_path / "x.png"
    bad.write_bytes(b"not a png")
    with pytest.raises(InputError, match="x.png"):
        read_image(bad)
    with pytest.raises(InputError, match="missing.png: cannot read image"):
        read_image(tmp_path / "missing.png")


def _variants(photo, d):
    """image_0010 as grayscale, RGBA, 16-bit grey and EXIF-rotated (stored turned by 90
    degrees, orientation 6 saying so) -> {name: path}."""
    from PIL import Image

    im = Image.open(photo).convert("RGB")
    out = {}
    out["grey"] = d / "grey.png"
    im.convert("L").save(out["grey"])
    out["rgba"] = d / "rgba.png"
    rgba = im.convert("RGBA")
    rgba.putalpha(255)
    rgba.save(out["rgba"])
    out["grey16"] = d / "grey16.png"
    grey16 = (np.asarray(im.convert("L"), dtype=np.uint16) * 257)
    Image.fromarray(grey16).save(out["grey16"])
    out["exif"] = d / "exif.jpg"
    exif = Image.Exif()
    exif[0x0112] = 6  # "rotate 90 clockwise to view": stored turned counter-clockwise
    im.transpose(Image.Transpose.ROTATE_90).save(out["exif"], exif=exif, quality=95)
    return out


def test_read_image_makes_every_encoding_upright_rgb(photo, tmp_path):
    from morphable.detection import image_size, read_image

    ref = read_image(photo).astype(np.float64)
    for name, path in _variants(photo, tmp_path).items():
        img = read_image(path)
        assert img.dtype == np.uint8 and img.shape == ref.shape, name
        assert image_size(path) == (ref.shape[1], ref.shape[0]), name
        # same picture, same way up (grey: ITU-R 601 luma, as PIL makes it; JPEG: its loss)
        expect = ref if name in ("rgba", "exif") else np.repeat((ref @ [0.299, 0.587, 0.114])[..., None], 3, -1)
        assert np.abs(img - expect).mean() < 3, name


# --- the detector choice ----------------------------------------------------------------------

def test_detector_choice_is_checked():
    from morphable.detection import resolve_detectors

    assert resolve_detectors("dlib", "auto") == ("dlib", "hog")
    assert resolve_detectors("facemesh", "full-range") == ("facemesh", "full-range")
    with pytest.raises(InputError, match="'hog' does not go with the facemesh"):
        resolve_detectors("facemesh", "hog")
    with pytest.raises(InputError, match="'full-range' does not go with the dlib"):
        resolve_detectors("dlib", "full-range")
    with pytest.raises(InputError, match="landmark detector"):
        resolve_detectors("nosuch")


def test_cli_refuses_a_face_detector_of_the_other_landmark_detector(photo, capsys):
    from morphable.cli import main

    assert main(["fit", str(photo), "--landmark-detector", "dlib", "--face-detector", "full-range"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "does not go with the dlib landmark detector" in err[0]


# --- fusing two readings (morphable.detection.fusion) -----------------------------------------

def _reading(points, sigma=None, name="network box"):
    from morphable.detection import Detection

    pts = np.asarray(points, dtype=float)
    sig = None if sigma is None else np.broadcast_to(np.asarray(sigma, dtype=float), (478,)).copy()
    return Detection(pts, sig, pts[:68], None if sig is None else sig[:68], "facemesh478", "3d", name,
                     score=None if sig is None else 0.9, box=np.array([0.0, 0, 100, 100]))


def test_fuse_weighs_each_reading_by_its_sigma():
    from morphable.detection.fusion import FLOOR, fuse, other_std_px

    rng = np.random.default_rng(0)
    truth = rng.uniform(0, 100, (478, 2))
    sigma = np.where(np.arange(478) < 239, 1.0, 6.0)       # half the points sure, half not
    net = _reading(truth + sigma[:, None] * rng.standard_normal((478, 2)), sigma)
    mesh = _reading(truth + 2.0 * rng.standard_normal((478, 2)), name="facemesh auto")
    f = fuse(net, mesh)
    assert f.detector == "network box + facemesh" and f.score == 0.9
    np.testing.assert_array_equal(f.box, net.box)
    s = other_std_px(net, mesh)
    w = (1 / sigma ** 2) / (1 / sigma ** 2 + 1 / s ** 2)
    np.testing.assert_allclose(f.points, w[:, None] * net.points + (1 - w[:, None]) * mesh.points)
    np.testing.assert_allclose(f.sigma_px, 1 / np.sqrt(1 / sigma ** 2 + 1 / s ** 2))
    np.testing.assert_allclose(f.ibug68, f.points[:68])
    # the sure points follow the network, the unsure ones the face mesh; the fused reading is
    # nearer the truth than either
    assert (w[:239] > 0.5).all() and (w[239:] < 0.5).all()
    err = {k: np.linalg.norm(d.points - truth, axis=1).mean() for k, d in
           (("net", net), ("mesh", mesh), ("fused", f))}
    assert err["fused"] < min(err["net"], err["mesh"]), err
    # readings that agree exactly: the other detector's σ is the floor, not 0
    assert other_std_px(net, _reading(net.points)) == pytest.approx(FLOOR * np.sqrt(np.mean(sigma ** 2)))
    # a face mesh that misread the face (40 px off): its weight nearly vanishes
    far = fuse(net, _reading(truth + 40.0))
    assert np.abs(far.points - net.points)[:239].max() < 0.05


def test_fuse_refuses_readings_it_cannot_weigh():
    from morphable.detection.fusion import fuse

    net, mesh = _reading(np.zeros((478, 2)), 2.0), _reading(np.ones((478, 2)))
    for a, b in ((mesh, net), (net, net), (mesh, mesh)):
        with pytest.raises(InputError, match="must give σ"):
            fuse(a, b)
    from morphable.detection import Detection

    dlib = Detection(np.ones((68, 2)), None, np.ones((68, 2)), None, "ibug68", "2d", "dlib hog")
    with pytest.raises(InputError, match=r"facemesh478 points \(3d convention\), dlib hog gives ibug68 points \(2d\)"):
        fuse(net, dlib)


# --- dlib -------------------------------------------------------------------------------------

def test_dlib_landmarks_match_the_annotation(takeo):
    pytest.importorskip("dlib")
    from morphable.detection import detect_faces, detect_landmarks
    from morphable.io.landmark_files import read_pts

    boxes = detect_faces(takeo, landmark_detector="dlib")
    assert boxes.shape[1] == 4 and len(boxes) >= 1
    pts = detect_landmarks(takeo, landmark_detector="dlib")
    truth = read_pts(takeo.with_suffix(".pts"))
    assert pts.shape == (68, 2)
    assert np.sqrt(((pts - truth) ** 2).sum(1).mean()) < 10
    # a given box skips detection and gives the same points
    np.testing.assert_allclose(detect_landmarks(takeo, landmark_detector="dlib", box=boxes[0]), pts)


@pytest.mark.parametrize("detector, package", [("dlib", "dlib"), ("facemesh", "mediapipe")])
def test_no_face_is_reported(detector, package):
    pytest.importorskip(package)
    from morphable.detection import detect_landmarks

    with pytest.raises(FitError, match="no face"):
        detect_landmarks(np.full((120, 160, 3), 128, np.uint8), landmark_detector=detector)


@pytest.mark.parametrize("box", [(10, 10, 5, 50), (0, 0, 1)])
def test_bad_box_and_image(box):
    from morphable.detection import detect_landmarks

    for detector in ("dlib", "facemesh"):
        with pytest.raises(InputError):
            detect_landmarks(np.zeros((50, 50, 3), np.uint8), landmark_detector=detector, box=box)
        with pytest.raises(InputError):
            detect_landmarks(np.zeros((50,)), landmark_detector=detector, box=(0, 0, 10, 10))


def test_cli_fit_detects_when_no_landmarks_given(takeo, tmp_path):
    pytest.importorskip("dlib")
    from morphable.cli import main

    report = tmp_path / "fit.json"
    assert main(["fit", str(takeo), "--landmark-detector", "dlib", "--report", str(report)]) == 0
    rep = json.loads(report.read_text())
    assert rep["landmarks"] == ["dlib hog"] and rep["frames"][0]["landmark_rmse_px"] < 10
    # detected landmarks are fitted with the detector's error, annotated ones with the default
    from morphable.fitting.noise import DETECTED_MODEL_STD_MM, MODEL_STD_MM

    assert rep["frames"][0]["model_std_mm"] == DETECTED_MODEL_STD_MM
    assert main(["fit", str(takeo), "--landmarks", str(takeo.with_suffix(".pts")),
                 "--report", str(report)]) == 0
    assert json.loads(report.read_text())["frames"][0]["model_std_mm"] == MODEL_STD_MM


# --- the face mesh ----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def mesh_points(photo):
    pytest.importorskip("mediapipe")
    from morphable.detection import detect_landmarks

    return detect_landmarks(photo, landmark_detector="facemesh")


def test_facemesh_finds_478_points_and_its_68_match_the_annotation(photo, mesh_points, monkeypatch):
    from morphable.detection import detect_ibug68
    from morphable.io.landmark_files import read_pts

    assert mesh_points.shape == (478, 2) and np.isfinite(mesh_points).all()
    truth = read_pts(photo.with_suffix(".pts"))
    lm = detect_ibug68(photo, landmark_detector="facemesh")
    err = np.linalg.norm(lm - truth, axis=1) / _face_size(truth)
    assert lm.shape == (68, 2) and err.mean() < 0.04 and np.median(err[17:]) < 0.03
    # auto is the face mesh where mediapipe is installed and the landmark network cannot run
    import morphable.detection as det

    monkeypatch.setattr(det, "_network_ready", lambda: False)
    np.testing.assert_allclose(detect_ibug68(photo), lm)


def test_facemesh_table_names_68_distinct_mesh_points():
    from morphable.detection.facemesh import FACEMESH_TO_IBUG68

    assert FACEMESH_TO_IBUG68.shape == (68,) and FACEMESH_TO_IBUG68.dtype == np.int64
    assert FACEMESH_TO_IBUG68.min() >= 0 and FACEMESH_TO_IBUG68.max() < 468
    assert len(set(FACEMESH_TO_IBUG68.tolist())) == 68


def test_facemesh_box_and_largest_face(photo, mesh_points):
    from PIL import Image

    from morphable.detection import detect_faces, detect_landmarks

    size = _face_size(mesh_points)
    box = detect_faces(photo, landmark_detector="facemesh")[0]
    assert box[0] < mesh_points[:, 0].mean() < box[2] and box[1] < mesh_points[:, 1].mean() < box[3]
    in_box = detect_landmarks(photo, landmark_detector="facemesh", box=box)
    assert np.linalg.norm(in_box - mesh_points, axis=1).mean() < 0.03 * size
    # two faces side by side, the second at half the size: the larger one is found, and a
    # box around the smaller one gives that one
    im = Image.open(photo).convert("RGB")
    W, H = im.size
    canvas = Image.new("RGB", (W + W // 2, H), (90, 90, 90))
    canvas.paste(im, (0, 0))
    canvas.paste(im.resize((W // 2, H // 2)), (W, H // 4))
    big = detect_landmarks(np.asarray(canvas), landmark_detector="facemesh")
    assert np.linalg.norm(big - mesh_points, axis=1).mean() < 0.03 * size
    small_box = (W, H // 4, W + W // 2, H // 4 + H // 2)
    small = detect_landmarks(np.asarray(canvas), landmark_detector="facemesh", box=small_box)
    expect = (mesh_points + 0.5) / 2 - 0.5 + [W, H // 4]
    assert np.linalg.norm(small - expect, axis=1).mean() < 0.03 * size / 2


def test_facemesh_finds_a_small_face_in_a_large_photo(photo, mesh_points):
    from PIL import Image

    from morphable.detection import detect_landmarks

    im = Image.open(photo).convert("RGB")
    W, H = im.size
    s = 60 / (mesh_points[:, 0].max() - mesh_points[:, 0].min())   # a face 60 px wide
    small = im.resize((round(W * s), round(H * s)), Image.Resampling.BILINEAR)
    canvas = Image.new("RGB", (1500, 1000), (200, 200, 200))        # 1.5 MP
    canvas.paste(small, (900, 500))
    pts = detect_landmarks(np.asarray(canvas), landmark_detector="facemesh")
    expect = (mesh_points + 0.5) * [small.size[0] / W, small.size[1] / H] - 0.5 + [900, 500]
    assert np.linalg.norm(pts - expect, axis=1).mean() < 0.06 * _face_size(expect)
    # far below the detector's minimum size (6 px): reported, not guessed
    tiny = im.resize((round(W * s / 10), round(H * s / 10)))
    canvas.paste((200, 200, 200), (0, 0, 1500, 1000))
    canvas.paste(tiny, (900, 500))
    with pytest.raises(FitError, match="no face found"):
        detect_landmarks(np.asarray(canvas), landmark_detector="facemesh")


def test_facemesh_on_grey_rgba_16bit_and_exif_rotated_photos(photo, mesh_points, tmp_path):
    from morphable.detection import detect_landmarks

    size = _face_size(mesh_points)
    for name, path in _variants(photo, tmp_path).items():
        pts = detect_landmarks(path, landmark_detector="facemesh")
        d = np.linalg.norm(pts - mesh_points, axis=1).mean()
        assert d < 0.03 * size, (name, d)


def test_478_point_files_are_read_and_fitted(photo, mesh_points, tmp_path):
    from morphable.detection.facemesh import to_ibug68
    from morphable.pipeline import fit_images, read_landmark_file

    np.save(tmp_path / "a.npy", mesh_points)
    (tmp_path / "b.json").write_text(json.dumps(mesh_points.tolist()))
    (tmp_path / "c.json").write_text(json.dumps({"landmarks": mesh_points.tolist()}))
    for name in ("a.npy", "b.json", "c.json"):
        np.testing.assert_allclose(read_landmark_file(tmp_path / name, (1280, 1024)), mesh_points)
    result = fit_images([photo], [tmp_path / "a.npy"])
    res, report = result.fit, result.report
    # the fit takes the 478 points themselves (the facemesh478 scheme)
    np.testing.assert_allclose(res.landmarks[0], mesh_points)
    assert report["frames"][0]["landmark_rmse_px"] < 10
    lm68 = report["frames"][0]["landmarks_68_px"]       # null where SFM has no such point
    assert len(lm68) == 68 and sum(p is not None and len(p) == 2 for p in lm68) == 66
    # with a 68-point file beside it, one landmark set for both: the face mesh's mapped to 68
    pts = photo.with_suffix(".pts")
    res = fit_images([photo, photo], [pts, tmp_path / "a.npy"]).fit
    assert res.landmarks.shape == (2, 68, 2)
    np.testing.assert_allclose(res.landmarks[1], to_ibug68(mesh_points))


def test_import_loads_no_detector():
    import subprocess
    import sys

    code = ("import sys, morphable, morphable.detection, morphable.pipeline, morphable.cli, morphable.video; "
            "print([m for m in ('mediapipe', 'cv2', 'dlib', 'matplotlib', 'av') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
