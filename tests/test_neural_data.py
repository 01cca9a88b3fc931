"""Synthetic GAR training data and the aligned image folder."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("open3d")

from morphable.errors import FitError, InputError  # noqa: E402
from morphable.metrics import umeyama  # noqa: E402
from neural.gar.data import AlignedImageFolder, align_image
from neural.faces.renders import SyntheticFaces, template


@pytest.fixture(scope="module")
def batch(data_dir):
    data = SyntheticFaces(resolution=32, n_identities=3, seed=1)
    return data.sample(4, rng=0, pair=True)


def test_synthetic_batch_labels(batch):
    assert batch["image"].shape == (4, 3, 32, 32) and batch["normals_b"].shape == (4, 3, 32, 32)
    assert batch["mask"].shape == (4, 1, 32, 32) and batch["landmarks"].shape == (4, 68, 2)
    assert batch["image"].min() >= -1 and batch["image"].max() <= 1
    n, m = batch["normals"], batch["mask"][:, 0]
    norm = n.norm(dim=1)
    # unit normals on the face, exactly zero on the background
    assert torch.allclose(norm[m > 0.99], torch.ones(()), atol=1e-4)
    assert torch.all(norm[m == 0] == 0)
    # visible surfaces face the camera (+z towards the viewer)
    assert (n[:, 2][m > 0.99] > 0).float().mean() > 0.97
    assert 0.15 < float(m.mean()) < 0.8
    # defined landmarks (SFM: 50 fixed vertices) fall inside the image
    lm = batch["landmarks"]
    ok = ~torch.isnan(lm[..., 0])
    assert int(ok[0].sum()) == 50
    assert (lm[ok] > 0).all() and (lm[ok] < 31).all()
    # pairs: same identity in another pose
    assert (batch["identity_id"] >= 0).all() and (batch["identity_id"] < 3).all()
    data = SyntheticFaces(resolution=32, n_identities=3, seed=1)      # the fixture's pool
    assert batch["identity"].shape == (4, data.model.n_identity) and batch["skin_tone"].shape == (4,)
    assert (batch["skin_tone"].abs() <= 3 ** 0.5).all()          # uniform, unit variance
    for i, iid in enumerate(batch["identity_id"].tolist()):
        torch.testing.assert_close(batch["identity"][i],
                                   torch.as_tensor(data._pool[iid]["identity"], dtype=torch.float32))
    assert not torch.allclose(batch["pose"], batch["pose_b"])
    assert not torch.allclose(batch["normals"], batch["normals_b"])


def test_synthetic_deterministic_and_posed(data_dir):
    data = SyntheticFaces(resolution=32)
    a, b = data.sample(2, rng=[5, 7]), data.sample(2, rng=[5, 7])
    assert torch.equal(a["image"], b["image"]) and torch.equal(a["normals"], b["normals"])
    # the face turns with the yaw: the nose tip (landmark 30) moves right for positive yaw
    rng = np.random.default_rng(0)
    ident = data.draw_identity(rng)
    e = np.zeros(data.model.n_expression)
    sh = np.zeros((9, 3))
    sh[0] = 1
    bg = np.zeros((32, 32, 3))
    left = data.render(ident["identity"], ident["albedo"], e, (-30, 0, 0), sh, bg)
    right = data.render(ident["identity"], ident["albedo"], e, (30, 0, 0), sh, bg)
    assert right["landmarks"][30, 0] > left["landmarks"][30, 0] + 3
    # under a uniform white environment the image is the albedo times coverage
    assert left["image"][left["mask"] == 0].max() == 0


def test_template_and_similarity(data_dir):
    t = template(64)
    eye_r, eye_l = np.nanmean(t[36:42], 0), np.nanmean(t[42:48], 0)
    # FFHQ framing: inter-ocular distance a quarter of the crop, eyes level
    assert abs(np.linalg.norm(eye_l - eye_r) - 16) < 1.5 and abs(eye_l[1] - eye_r[1]) < 0.5
    np.testing.assert_allclose(template(128), (t + 0.5) * 2 - 0.5, atol=1e-6, equal_nan=True)
    ang = np.radians(20)
    R = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
    src = np.random.default_rng(0).random((10, 2)) * 50
    scale, rotation, t = umeyama(src, 1.7 * src @ R.T + [3, -4])
    np.testing.assert_allclose(scale * rotation, 1.7 * R, atol=1e-9)
    np.testing.assert_allclose(t, [3, -4], atol=1e-9)
    with pytest.raises(FitError, match="2 corresponding"):
        umeyama(np.full((3, 2), np.nan), src[:3])
    with pytest.raises(FitError, match="coincident"):
        umeyama(np.ones((3, 2)), src[:3])


def test_align_real_photo(data_dir, tmp_path):
    from PIL import Image

    from morphable.io.landmark_files import read_pts

    img = Image.open(data_dir / "images" / "image_0010.png").convert("RGB")
    pts = read_pts(data_dir / "images" / "image_0010.pts")
    out = align_image(img, pts, 64)
    assert out.shape == (64, 64, 3) and out.dtype == np.uint8
    # the warp sends the photo's landmarks next to the template: mean residual < 2 px
    scale, R, t = umeyama(pts, template(64))
    moved = scale * pts @ R.T + t
    ok = ~np.isnan(template(64)[:, 0])
    assert np.mean(np.linalg.norm(moved[ok] - template(64)[ok], axis=1)) < 2.0
    # and the warped image holds the photo's pixel there: sample the nose tip
    x, y = moved[30]
    src = np.asarray(img, dtype=float)[int(round(pts[30, 1])), int(round(pts[30, 0]))]
    assert np.abs(out[int(round(y)), int(round(x))].astype(float) - src).mean() < 40
    # a folder with the image and its .pts beside it (links, nothing copied into the repo)
    (tmp_path / "a.png").symlink_to(data_dir / "images" / "image_0010.png")
    (tmp_path / "a.pts").symlink_to(data_dir / "images" / "image_0010.pts")
    folder = AlignedImageFolder(tmp_path, 64)
    x = folder[0]
    assert len(folder) == 1 and x.shape == (3, 64, 64) and -1 <= float(x.min()) < float(x.max()) <= 1
    with pytest.raises(InputError, match="no images"):
        AlignedImageFolder(tmp_path / "empty" if (tmp_path / "empty").mkdir() is None else None)


def test_folder_without_faces(tmp_path):
    pytest.importorskip("dlib")
    from PIL import Image

    Image.new("RGB", (80, 80), (128, 128, 128)).save(tmp_path / "grey.png")
    folder = AlignedImageFolder(tmp_path, 32)
    assert folder.load(0) is None
    with pytest.raises(InputError, match="no face found"):
        folder[0]


def test_folder_detects_landmarks(tmp_path, data_dir):
    pytest.importorskip("dlib")
    (tmp_path / "a.png").symlink_to(data_dir / "images" / "image_0010.png")   # no .pts
    detected = AlignedImageFolder(tmp_path, 64)[0]
    (tmp_path / "a.pts").symlink_to(data_dir / "images" / "image_0010.pts")
    annotated = AlignedImageFolder(tmp_path, 64)[0]
    # dlib's landmarks and the ground truth give nearly the same crop
    assert float((detected - annotated).abs().mean()) < 0.15
