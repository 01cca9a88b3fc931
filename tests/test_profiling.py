"""Face profiling (morphable.profiling): geometry of the turn, labels and visibility, the CLI."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from morphable.errors import InputError

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def small_photo(data_dir, tmp_path_factory):
    """image_0010 and its 68 points at a quarter of the size (320 x 256), with its fit."""
    from PIL import Image

    from morphable.io.landmark_files import read_pts, write_pts
    from morphable.pipeline import fit_images

    d = tmp_path_factory.mktemp("profile")
    with Image.open(data_dir / "images" / "image_0010.png") as im:
        im.convert("RGB").resize((320, 256), Image.Resampling.BOX).save(d / "face.png")
    pts = read_pts(data_dir / "images" / "image_0010.pts")
    write_pts(d / "face.pts", (pts + 0.5) / 4 - 0.5)
    fit = fit_images([d / "face.png"], [d / "face.pts"]).fit
    return d, fit


def test_zero_turn_gives_the_photos_own_labels_and_picture(small_photo):
    from morphable.detection import read_image
    from morphable.labels import label_schemes, project_labels
    from morphable.profiling import profile_photo

    d, fit = small_photo
    photo = read_image(d / "face.png")
    out = profile_photo(photo, fit, 0.0, texture_size=128)
    own = project_labels(fit.vertices(0, dtype=np.float64), fit.model.triangles, fit.cameras[0],
                         label_schemes(fit.model))
    for k in ("68", "478"):
        np.testing.assert_allclose(out["landmarks_px"][k], own[f"points{k}"], atol=1e-4)
        assert (out["visible"][k] == own[f"visible{k}"]).all()
    # the fit's fixed 68 points are where the fit put them
    fixed = np.isfinite(fit.fitted_landmarks[0]).all(1) & np.isfinite(out["landmarks_px"]["68"]).all(1)
    fixed[:17] = False                                    # the outline points slide
    assert fixed.sum() > 40
    np.testing.assert_allclose(out["landmarks_px"]["68"][fixed], fit.fitted_landmarks[0][fixed], atol=0.5)
    diff = np.abs(out["image"].astype(float) - photo)
    assert diff.mean() < 2.0, diff.mean()                 # grey levels
    assert out["image"].shape == photo.shape and out["image"].dtype == np.uint8
    np.testing.assert_allclose(out["camera"].rotation, fit.cameras[0].rotation, atol=1e-12)


def test_turn_moves_labels_the_cameras_way_and_hides_the_far_side(small_photo):
    from morphable.camera import Camera
    from morphable.profiling import profile_photo, turned_camera

    d, fit = small_photo
    v = fit.vertices(0, dtype=np.float64)
    yaw0 = fit.cameras[0].euler_deg[0]
    texture = None
    outs = {}
    for dy in (-90.0, 20.0, 90.0):
        outs[dy] = profile_photo(d / "face.png", fit, dy, texture=texture, texture_size=64)
    # the turned camera's yaw is the fit's plus the turn (the fit's roll is small)
    assert abs(outs[20.0]["camera"].euler_deg[0] - (yaw0 + 20)) < 2.0
    # labels move as a camera of larger yaw moves them: nose tip (30) against the eyes' middle
    mean = fit.model.mean
    ids = fit.model.landmark_ids
    a, b = (Camera.looking_at_face((256, 256), yaw=y).project(mean[[ids[30], ids[39], ids[42]]])
            for y in (0.0, 20.0))
    expected = np.sign((b[0] - (b[1] + b[2]) / 2)[0] - (a[0] - (a[1] + a[2]) / 2)[0])
    p0, p1 = fit.fitted_landmarks[0], outs[20.0]["landmarks_px"]["68"]
    moved = (p1[30] - (p1[39] + p1[42]) / 2)[0] - (p0[30] - (p0[39] + p0[42]) / 2)[0]
    assert np.sign(moved) == expected and abs(moved) > 1.0, moved
    # at +-90 the outer eye corner that turns away is hidden, the other one seen
    for dy in (-90.0, 90.0):
        out = outs[dy]
        P = v[[ids[36], ids[45]]]
        far = int(np.argmax(out["camera"].depth(P)))
        corner = (36, 45)
        assert not out["visible"]["68"][corner[far]]
        assert out["visible"]["68"][corner[1 - far]]
    # the two turns hide opposite sides
    assert (outs[90.0]["visible"]["478"] & outs[-90.0]["visible"]["478"]).mean() < 0.3
    # the turned camera keeps the pivot where it was
    cam = fit.cameras[0]
    c = np.array([1.0, 2.0, -50.0])
    np.testing.assert_allclose(turned_camera(cam, c, 35.0, 10.0).project(c[None]), cam.project(c[None]),
                               atol=1e-9)
    assert np.abs(outs[90.0]["image"].astype(float) - outs[-90.0]["image"]).mean() > 3


def test_bad_turns_and_sizes(small_photo):
    from morphable.profiling import profile_photo

    d, fit = small_photo
    with pytest.raises(InputError, match="yaw turn"):
        profile_photo(d / "face.png", fit, 120.0)
    with pytest.raises(InputError, match="pitch turn"):
        profile_photo(d / "face.png", fit, 0.0, float("nan"))
    with pytest.raises(InputError, match="frame 1"):
        profile_photo(d / "face.png", fit, 10.0, frame=1)
    with pytest.raises(InputError, match="320x256"):
        profile_photo(np.zeros((100, 100, 3), np.uint8), fit, 10.0)


def test_cli_writes_picture_and_labels(small_photo, tmp_path):
    d, _ = small_photo
    r = subprocess.run([sys.executable, "-m", "morphable.cli", "-q", "profile", str(d / "face.png"),
                        "--landmarks", str(d / "face.pts"), "--yaw", "-40", "--pitch", "10",
                        "--texture-size", "64", "--out", str(tmp_path / "p.png"),
                        "--labels", str(tmp_path / "p.json")],
                       cwd=REPO, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    lab = json.loads((tmp_path / "p.json").read_text())
    assert len(lab["points68"]) == 68 and len(lab["visible478"]) == 478
    assert sum(p is None for p in lab["points68"]) == 2      # SFM's inner mouth corners
    assert abs(lab["camera"]["pitch_deg"]) > 3 and 10 < sum(lab["visible68"]) < 68
    # read back: the picture and the labels of the same turn of the same fit, made here
    from PIL import Image

    from morphable.profiling import profile_photo

    _, fit = small_photo
    here = profile_photo(d / "face.png", fit, -40.0, 10.0, texture_size=64)
    written = np.asarray(Image.open(tmp_path / "p.png").convert("RGB"), dtype=float)
    assert written.shape == here["image"].shape == (256, 320, 3)
    assert np.abs(written - here["image"]).mean() < 0.5
    got = np.array([p if p is not None else [np.nan, np.nan] for p in lab["points68"]])
    np.testing.assert_allclose(got, here["landmarks_px"]["68"], atol=1e-6)
    assert lab["visible478"] == here["visible"]["478"].tolist()
