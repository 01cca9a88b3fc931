"""The real-photo GAR pack (neural.gar.build_real): a small build from ../shared, the alignment's
camera, the held-out rule."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from neural.gar.build_real import SOURCES, build, held_out, list_photos  # noqa: E402
from neural.gar.real_faces import REQUIRED_KEYS, load_pack  # noqa: E402


@pytest.fixture(scope="module")
def built(data_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("real") / "real64.npz"
    report = build(data_dir, out, resolution=64, limit=3)
    return out, report, load_pack(out)


def test_pack_keys_shapes_and_report(built):
    out, report, a = built
    N = len(a["image"])
    assert set(REQUIRED_KEYS) <= set(a) and {"fit_pose", "fit_identity", "fit_expression"} <= set(a)
    assert a["image"].shape == (N, 64, 64, 3) and a["image"].dtype == np.uint8
    assert a["normals"].shape == (N, 64, 64, 3) and a["mask"].shape == (N, 64, 64)
    assert a["landmarks"].shape == (N, 68, 2) and a["fit_pose"].shape == (N, 3)
    assert set(a["source"]) <= set(SOURCES) and 6 <= N <= 9
    assert report["total"]["passed"] == N and report["pack_bytes"] == out.stat().st_size
    assert (out.parent / "fits_aflw.npz").is_file() and out.with_suffix(".json").is_file()
    for s in SOURCES:
        c = report["sources"][s]
        assert c["photos"] == 3 and c["passed"] <= c["face_found"] <= 3
        assert 0 <= c["dark_share"] <= 1
    assert report["normal_error_deg_p99"] < 3          # normal_scale 64


def test_normals_sit_on_the_photos_face(built):
    _, _, a = built
    for i in range(len(a["image"])):
        m, lm = a["mask"][i], a["landmarks"][i]
        on = np.abs(a["normals"][i]).sum(-1) > 0
        # normals where the fit covers the pixel (edge pixels of a quarter coverage have none)
        assert not (on & (m == 0)).any() and on[m >= 0.5].all()
        x, y = np.round(lm[30]).astype(int)             # the nose tip
        assert m[y, x] > 0.5, a["name"][i]
        # brows, nose, eyes, outer lips (the inner lips may lie in the open mouth, no mesh)
        inner = lm[17:60][np.isfinite(lm[17:60]).all(1)]
        ix, iy = np.clip(np.round(inner).astype(int), 0, 63).T
        assert (m[iy, ix] > 0.5).mean() >= 0.95, a["name"][i]
        # the mask reaches up to the forehead: its centroid sits above the features' one
        ys, xs = np.nonzero(m > 0.5)
        assert np.linalg.norm([xs.mean(), ys.mean()] - inner.mean(0)) < 10, a["name"][i]
        assert a["normals"][i][y, x, 2] > 0.5           # the nose tip faces the camera


def test_held_out_is_fixed_and_by_person(built, data_dir):
    _, _, a = built
    keys = {it["name"]: it["person_key"] for s in SOURCES for it in list_photos(data_dir, s, 3)}
    assert [held_out(keys[n]) for n in a["name"]] == a["held_out"].tolist()
    london = list_photos(data_dir, "london")
    by_person = {}
    for it in london:
        by_person.setdefault(it["person"], set()).add(held_out(it["person_key"]))
    assert len(by_person) == 102 and all(len(v) == 1 for v in by_person.values())
    frac = np.mean([held_out(it["person_key"]) for it in list_photos(data_dir, "aflw")])
    assert 0.035 < frac < 0.065, frac


def test_rebuild_at_another_resolution_reuses_the_fits(built, data_dir):
    out, _, a64 = built
    report = build(data_dir, out.with_name("real32.npz"), resolution=32, limit=3)
    assert all(t["fitted_now"] == 0 for s, t in report["timings_s"].items() if s in SOURCES)
    a32 = load_pack(out.with_name("real32.npz"))
    assert a32["name"].tolist() == a64["name"].tolist()
    # the same framing at half the size: pixel centres x32 = (x64 + 0.5) / 2 - 0.5
    assert np.nanmax(np.abs(a32["landmarks"] - ((a64["landmarks"] + 0.5) / 2 - 0.5))) < 0.05


@pytest.mark.parametrize("kind", ["affine", "perspective"])
def test_aligned_camera_projects_as_the_warp_maps(kind):
    from morphable.camera import Camera
    from neural.gar.data import aligned_camera

    cam = Camera.looking_at_face((400, 300), yaw=20, pitch=-10, roll=5, kind=kind)
    pts = np.random.default_rng(0).uniform(-60, 60, (20, 3))
    a = np.radians(25)
    A = np.array([[np.cos(a), -np.sin(a), 7.0], [np.sin(a), np.cos(a), -3.0]]) * [[0.3], [0.3]]
    crop = aligned_camera(cam, A, 64)
    expected = cam.project(pts) @ A[:, :2].T + A[:, 2]
    assert np.allclose(crop.project(pts), expected, atol=1e-9)
    assert crop.image_size == (64, 64)


@pytest.mark.parametrize("scale", [0.6, 0.2])
def test_warp_image_puts_a_photo_point_where_the_similarity_says(scale):
    from neural.gar.data import warp_image

    photo = np.zeros((300, 400, 3), np.uint8)
    photo[148:153, 198:203] = 255                        # a bright 5 px square at (200, 150)
    a = np.radians(-15)
    A = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0]]) * scale
    A[:, 2] = [32, 32] - A[:, :2] @ [200, 150]           # the square to the crop's centre
    crop = warp_image(photo, A, 64).astype(float).sum(-1)
    ys, xs = np.mgrid[:64, :64]
    w = np.clip(crop, 0, None)
    assert np.allclose([(xs * w).sum() / w.sum(), (ys * w).sum() / w.sum()], [32, 32], atol=0.25)


def test_a_crop_past_the_photo_shows_faded_mirrored_background_not_black():
    from morphable.refinement import pad_like_ffhq
    from neural.gar.data import warp_image

    rng = np.random.default_rng(0)
    photo = rng.integers(60, 200, size=(120, 120, 3), dtype=np.uint8)
    photo[:, :60] = (200, 40, 40)                          # left half red, right half noise
    A = np.array([[0.25, 0.0, 0.0], [0.0, 0.25, 0.0]])
    A[:, 2] = [32, 32] - A[:, :2] @ [60, 60]               # 256 px of photo into 64: past its edges
    crop = warp_image(photo, A, 64).astype(float)
    # the photo spans crop pixels 17-47; the blur reaches a few pixels into it, as in FFHQ
    expected = warp_image(np.pad(photo, ((68, 68), (68, 68), (0, 0)), mode="reflect"),
                          A + [[0, 0, -17], [0, 0, -17]], 64).astype(float)
    assert np.abs(crop[25:39, 25:39] - expected[25:39, 25:39]).max() <= 2.0     # rounding
    assert crop.sum(-1).min() > 100                        # no black anywhere
    # the mirror fades into the photo's median colour towards the padding's outer edge
    padded, (dx, dy) = pad_like_ffhq(photo, (-68, -68, 188, 188))
    median = np.median(padded.reshape(-1, 3).astype(float), axis=0)
    assert (dx, dy) == (94, 94) and padded.shape == (120 + 2 * 94, 120 + 2 * 94, 3)  # 68 + 0.1 of 256
    assert np.abs(padded[0, 0] - median).max() <= 1.0
    assert np.abs(padded[dy + 10, 2] - median).max() < np.abs(padded[dy + 10, dx - 2] - median).max()
