"""Overlays of a fit on its photo: landmark pixels at the fitted positions, the mesh over the face."""
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from morphable import InputError
from morphable.overlay import FITTED_COLOR, GIVEN_COLOR, draw_overlay, write_overlays

pytest.importorskip("open3d")

SCALE = 4  # image_0010 (1280x1024) shrunk to 320x256 keeps the tests fast


@pytest.fixture(scope="module")
def photo_fit(data_dir, tmp_path_factory):
    from morphable import load_model
    from morphable.fitting import fit_landmarks
    from morphable.io.landmark_files import read_pts, write_pts

    d = data_dir / "images"
    with Image.open(d / "image_0010.png") as im:
        small = im.convert("RGB").resize((1280 // SCALE, 1024 // SCALE), Image.BILINEAR)
    # pixel centres at integers: x' = (x + 0.5) / s - 0.5
    lm = (read_pts(d / "image_0010.pts") + 0.5) / SCALE - 0.5
    folder = tmp_path_factory.mktemp("overlay")
    small.save(folder / "face.png")
    write_pts(folder / "face.pts", lm)
    res = fit_landmarks(load_model("sfm"), lm[None], np.array([small.size], dtype=np.float64))
    return np.asarray(small), res, folder


def _changed(a, b):
    return np.abs(a.astype(int) - b.astype(int)).sum(-1) > 6


def test_fitted_landmarks_are_red_at_their_positions(photo_fit):
    img, res, _ = photo_fit
    out = draw_overlay(img, res, mesh=None, radius=2)
    assert out.shape == img.shape and out.dtype == np.uint8
    fitted = res.fitted_landmarks[0]
    ok = np.isfinite(fitted).all(1)
    assert ok.sum() >= 40
    for x, y in fitted[ok]:
        assert tuple(out[int(round(y)), int(round(x))]) == FITTED_COLOR
    # given landmarks far from every fitted one show as green crosses
    given = res.landmarks[0]
    far = [p for p in given[np.isfinite(given).all(1)]
           if np.min(np.linalg.norm(fitted[ok] - p, axis=1)) > 3.5]
    assert far, "every given landmark lies under a fitted one: the test would check nothing"
    for x, y in far:
        assert tuple(out[int(round(y)), int(round(x))]) == GIVEN_COLOR
    # nothing else changed: far from all landmarks the photo is untouched
    pts = np.concatenate([fitted[ok], given[np.isfinite(given).all(1)]])
    yy, xx = np.mgrid[:img.shape[0], :img.shape[1]]
    d = np.min(np.hypot(xx[..., None] - pts[:, 0], yy[..., None] - pts[:, 1]), -1)
    assert not _changed(out, img)[d > 5].any()


def _inner_face(res, shape):
    """(H, W) bool: inside the convex hull of the given nose and eye landmarks (27-47; the SFM mouth is open)."""
    from scipy.spatial import Delaunay

    p = res.landmarks[0][27:48]
    hull = Delaunay(p[np.isfinite(p).all(1)])
    yy, xx = np.mgrid[:shape[0], :shape[1]]
    return (hull.find_simplex(np.stack([xx, yy], -1).reshape(-1, 2)) >= 0).reshape(shape[:2])


def test_shaded_mesh_covers_the_face(photo_fit):
    img, res, _ = photo_fit
    inner = _inner_face(res, img.shape)
    assert inner.sum() > 500
    # opaque: the grey mesh (r = g = b) hides the skin-coloured photo over the inner face
    opaque = draw_overlay(img, res, alpha=1.0, landmarks=False).astype(int)
    grey = np.abs(opaque - opaque.mean(-1, keepdims=True)).max(-1) <= 2
    assert grey[inner].mean() > 0.98 and grey.mean() < 0.5
    # blended: every inner-face pixel moves, nothing far from the face does
    out = draw_overlay(img, res, mesh="shaded", landmarks=False)
    changed = _changed(out, img)
    assert changed[inner].mean() > 0.9
    lm = res.landmarks[0][np.isfinite(res.landmarks[0]).all(1)]
    (X0, Y0), (X1, Y1) = lm.min(0) - 40, lm.max(0) + 40
    far = np.ones_like(changed)
    far[max(0, int(Y0)):int(Y1), max(0, int(X0)):int(X1)] = False
    assert not changed[far].any()
    # alpha 0 leaves the photo as it was
    assert np.array_equal(draw_overlay(img, res, alpha=0.0, landmarks=False), img)


def test_wireframe_draws_lines_inside_the_face(photo_fit):
    img, res, _ = photo_fit
    out = draw_overlay(img, res, mesh="wireframe", alpha=1.0, landmarks=False)
    changed = _changed(out, img)
    frac = changed[_inner_face(res, img.shape)].mean()
    assert 0.2 < frac < 1.0  # lines with photo between them (320 px: dense, not solid)
    from scipy.ndimage import binary_dilation

    # the lines stay on the mesh's silhouette (give or take the line width)
    shaded = _changed(draw_overlay(img, res, alpha=1.0, landmarks=False), img)
    assert not (changed & ~binary_dilation(shaded, iterations=2)).any()


def test_bad_inputs(photo_fit, tmp_path):
    img, res, _ = photo_fit
    with pytest.raises(InputError, match="image is 100x80"):
        draw_overlay(np.zeros((80, 100, 3), np.uint8), res)
    with pytest.raises(InputError, match="got shape"):
        draw_overlay(np.zeros((256, 320, 2)), res)
    nan = img / 255.0
    nan[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="finite"):
        draw_overlay(nan, res)
    grey = draw_overlay(img.mean(-1).astype(np.uint8), res, mesh=None)  # (H, W) photos work
    assert grey.shape == img.shape
    with pytest.raises(InputError, match="nothing.png: cannot read image"):
        draw_overlay(tmp_path / "nothing.png", res)
    with pytest.raises(InputError, match="frame 3"):
        draw_overlay(img, res, frame=3)
    with pytest.raises(InputError, match="mesh="):
        draw_overlay(img, res, mesh="solid")
    with pytest.raises(InputError, match="alpha"):
        draw_overlay(img, res, alpha=2)
    with pytest.raises(InputError, match="overlay must be a .png or .jpg"):
        write_overlays(tmp_path / "o.gif", res, [img])
    with pytest.raises(InputError, match="2 images for a fit of 1"):
        write_overlays(tmp_path / "o.png", res, [img, img])
    assert list(tmp_path.iterdir()) == []


def test_fit_cli_writes_the_overlay(photo_fit):
    img, res, folder = photo_fit
    run = lambda *a: subprocess.run([sys.executable, "-m", "morphable.cli", *map(str, a)],  # noqa: E731
                                    capture_output=True, text=True, cwd=folder)
    out = run("fit", "face.png", "--landmarks", "face.pts", "--overlay", "o.png", "--report", "r.json")
    cut = run("fit", "face.png", "--landmarks", "face.pts", "--overlay", "c.jpg", "--overlay-crop", "0.1",
              "--overlay-style", "wireframe")
    assert cut.returncode == 0, cut.stderr
    w, h = Image.open(folder / "c.jpg").size
    assert w < img.shape[1] and h < img.shape[0]
    assert out.returncode == 0, out.stderr
    o = np.asarray(Image.open(folder / "o.png"))
    assert o.shape == img.shape
    assert _changed(o, img).mean() > 0.02
    red = np.all(o == FITTED_COLOR, -1)
    fitted = res.fitted_landmarks[0][np.isfinite(res.fitted_landmarks[0]).all(1)]
    ys, xs = np.round(fitted[:, 1]).astype(int), np.round(fitted[:, 0]).astype(int)
    assert red[ys, xs].mean() > 0.95  # same fit, same pixels
    two = run("fit", "face.png", "face.png", "--landmarks", "face.pts", "face.pts", "--overlay", "t.png",
              "--overlay-style", "none")
    assert two.returncode == 0, two.stderr
    for name in ("t_0.png", "t_1.png"):  # one overlay per image
        t = np.asarray(Image.open(folder / name))
        assert t.shape == img.shape and np.all(t == FITTED_COLOR, -1).sum() > 40
    assert not (folder / "t.png").exists()
    bad = run("fit", "face.png", "--landmarks", "face.pts", "--overlay", "x.bmp", "--report", "x.json")
    assert bad.returncode == 2 and "x.bmp: overlay must be a .png or .jpg" in bad.stderr
    assert not (folder / "x.json").exists() and "Traceback" not in bad.stderr


def test_crop_is_the_face_box_of_the_full_overlay(photo_fit):
    from morphable.overlay import face_box

    img, res, _ = photo_fit
    full = draw_overlay(img, res)
    x0, y0, x1, y1 = face_box(res, margin=0.1)
    cut = draw_overlay(img, res, crop=0.1)
    assert np.array_equal(cut, full[y0:y1, x0:x1])
    assert cut.shape[0] < img.shape[0] and cut.shape[1] < img.shape[1]
    # every fitted landmark and the whole mesh lie inside the box
    fitted = res.fitted_landmarks[0][np.isfinite(res.fitted_landmarks[0]).all(1)]
    assert (fitted >= [x0, y0]).all() and (fitted < [x1, y1]).all()
    changed = _changed(full, img)
    assert changed[y0:y1, x0:x1].sum() == changed.sum()
    assert face_box(res, margin=100.0) == (0, 0, img.shape[1], img.shape[0])  # clipped
    with pytest.raises(InputError, match="crop=-1"):
        draw_overlay(img, res, crop=-1)


def test_dense_landmarks_are_drawn_as_small_marks(photo_fit):
    # a fit to 478 face-mesh points: every given and fitted point drawn, smaller than the 68's
    from dataclasses import replace

    img, res, _ = photo_fit
    rng = np.random.default_rng(0)
    lo, hi = np.nanmin(res.landmarks[0], 0), np.nanmax(res.landmarks[0], 0)
    fitted = rng.uniform(lo, hi, (1, 478, 2))
    dense = replace(res, landmarks=fitted + rng.normal(0, 2, fitted.shape), fitted_landmarks=fitted)
    out = draw_overlay(img, dense, mesh=None)
    for x, y in np.round(fitted[0]).astype(int):
        assert tuple(out[y, x]) == FITTED_COLOR
    r68 = max(2, min(img.shape[:2]) // 250)
    changed68 = _changed(draw_overlay(img, res, mesh=None), img).sum() / 68
    changed478 = _changed(out, img).sum() / 478
    assert r68 >= 2 and changed478 < changed68     # smaller marks per point
