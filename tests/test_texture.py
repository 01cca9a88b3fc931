"""Texture extraction from photos (morphable.texture) and its command-line round trip."""
import json
import subprocess
import sys

import numpy as np
import pytest

from morphable.errors import InputError


def known_texture(size=64):
    """A smooth RGB texture (low frequencies only, so that two resamplings keep it)."""
    c = (np.arange(size) + 0.5) / size
    u, v = np.meshgrid(c, 1 - c)
    return np.stack([0.2 + 0.6 * u, 0.2 + 0.6 * v, 0.5 + 0.3 * np.sin(2 * np.pi * (u + v))], -1)


def rendered(model, tex, yaw=0.0, size=256):
    from morphable.raster import frame_mesh, render

    cam = frame_mesh(model.mean, (size, size), yaw=yaw, kind="perspective")
    image = render(model.mean, model.triangles, cam, texture=(model.uv, model.triangle_uv, tex),
                   light=np.eye(9)[0], background=(0.0, 1.0, 0.0))
    return cam, image


def test_recovers_a_known_texture_where_visible(sfm):
    from morphable.raster import sample_texture
    from morphable.texture import texture_from_views

    truth = known_texture(64)
    cam, image = rendered(sfm, truth)
    tex = texture_from_views(sfm, sfm.mean, [cam], [image], size=64, mirror=False)
    sure = tex.confidence > 0.5
    assert sure.sum() > 0.3 * tex.layout.sum()
    err = np.abs(tex.image - truth)[sure].mean()
    assert err < 0.02, err
    # the green background never leaks into observed texels
    assert (tex.image[tex.observed, 1] - truth[tex.observed, 1] < 0.25).all()
    assert sample_texture(tex.image, np.array([[0.5, 0.5]])).shape == (1, 3)


def test_confidence_zero_where_unseen_and_fill_without_nan(sfm):
    from morphable.normals import vertex_normals
    from morphable.raster import interpolate, uv_visibility
    from morphable.texture import texture_from_views

    cam, image = rendered(sfm, known_texture(64), yaw=70)
    tex = texture_from_views(sfm, sfm.mean, [cam], [image], size=64)
    table = uv_visibility(sfm.triangles, sfm.uv, sfm.triangle_uv, 64)
    n = interpolate(table, vertex_normals(sfm.mean, sfm.triangles))
    p = interpolate(table, sfm.mean)
    facing = np.einsum("ijc,ijc->ij", n, cam.view_directions(p))
    away = table.mask & (facing < 0)
    assert away.sum() > 100
    assert (tex.confidence[away] == 0).all()
    assert tex.observed.any() and tex.mirrored.any()
    assert not (tex.mirrored & tex.observed).any()
    assert np.isfinite(tex.image).all() and tex.image.min() >= 0 and tex.image.max() <= 1
    assert 0 <= tex.confidence.min() and tex.confidence.max() <= 1


def test_multi_frame_blend_sees_more_than_either_frame(sfm):
    from morphable.texture import texture_from_views

    truth = known_texture(64)
    views = [rendered(sfm, truth, yaw=y) for y in (-50, 50)]
    one = [texture_from_views(sfm, sfm.mean, [c], [im], size=64, mirror=False) for c, im in views]
    both = texture_from_views(sfm, sfm.mean[None].repeat(2, 0), [c for c, _ in views],
                              [im for _, im in views], size=64, mirror=False)
    assert both.observed.sum() > max(t.observed.sum() for t in one)
    assert (both.observed == (one[0].observed | one[1].observed)).all()
    assert np.abs(both.image - truth)[both.confidence > 0.5].mean() < 0.02


def test_push_pull_fills_holes_with_neighbours():
    from morphable.texture import push_pull_fill

    img = np.full((16, 16, 3), np.nan)
    w = np.zeros((16, 16))
    img[:, :8], w[:, :8] = 0.2, 1.0
    img[:, 8:12], w[:, 8:12] = 0.8, 1.0
    out = push_pull_fill(img, w)
    assert np.isfinite(out).all()
    assert np.allclose(out[:, :8], 0.2) and np.allclose(out[:, 8:12], 0.8)
    assert (np.abs(out[:, 12:] - 0.8) < 0.3).all()       # the hole takes its neighbours' colour
    with pytest.raises(InputError, match="every weight is 0"):
        push_pull_fill(img, np.zeros((16, 16)))


def test_bad_inputs(sfm):
    from morphable.model import MorphableModel
    from morphable.texture import texture_from_views

    cam, image = rendered(sfm, known_texture(16), size=64)
    with pytest.raises(InputError, match="2 images for a fit of 1 frames"):
        texture_from_views(sfm, sfm.mean, [cam], [image, image], size=16)
    with pytest.raises(InputError, match="image is 32x32, frame 0 of the fit is 64x64"):
        texture_from_views(sfm, sfm.mean, [cam], [image[:32, :32]], size=16)
    bare = MorphableModel.from_arrays(mean=sfm.mean, triangles=sfm.triangles, name="bare")
    with pytest.raises(InputError, match="no UV coordinates"):
        texture_from_views(bare, sfm.mean, [cam], [image], size=16)


def test_ict_layout_keeps_other_tiles_off_the_face(ict):
    from morphable.raster.visibility import uv_visibility
    from morphable.texture import texture_layout

    uv, tuv, textured = texture_layout(ict, 64)
    assert 0 < textured.sum() < len(textured)
    assert (uv[tuv[textured]] <= 1).all()
    spare = uv[tuv[~textured]]
    assert np.allclose(spare, spare[0])                   # one texel for all the rest
    table = uv_visibility(ict.triangles, uv, tuv, 64)
    assert textured[table.triangle_id[table.mask]].all()


def cli(*args, cwd):
    return subprocess.run([sys.executable, "-m", "morphable.cli", *map(str, args)], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def test_fit_out_texture_round_trip(tmp_path, data_dir):
    from PIL import Image

    from morphable.raster.inputs import load_mesh

    img, pts = data_dir / "images/image_0010.png", data_dir / "images/image_0010.pts"
    r = cli("fit", img, "--landmarks", pts, "--out-mesh", "fit.obj", "--out-texture", "face.png",
            "--texture-size", 128, "--report", "fit.json", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "fit.mtl").read_text().splitlines()[-1] == "map_Kd face.png"
    assert (tmp_path / "fit.obj").read_text().startswith("mtllib fit.mtl\n")
    with Image.open(tmp_path / "face.png") as im:
        assert im.size == (128, 128)
    mesh = load_mesh(tmp_path / "fit.obj")
    assert mesh.texture == tmp_path / "face.png" and mesh.uv is not None
    r = cli("render", "fit.obj", "--light", "none", "--size", 128, "--out", "flat.png", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    flat = np.asarray(Image.open(tmp_path / "flat.png").convert("RGB"), dtype=float)
    face = flat[(flat < 250).any(-1)]
    assert len(face) > 2000 and face[:, 0].mean() > face[:, 2].mean() + 20   # skin, not grey
    # `morphable texture` rebuilds the fit from the report alone: the same texture as the fit's
    r = cli("texture", "fit.json", "--size", 128, "--out", "t128.png", "--confidence", "c128.png",
            cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    again = np.asarray(Image.open(tmp_path / "t128.png").convert("RGB"), dtype=float)
    assert np.abs(again - np.asarray(Image.open(tmp_path / "face.png").convert("RGB"), dtype=float)).max() <= 1
    seen = json.loads((tmp_path / "fit.json").read_text())["texture"]["observed"]
    assert f"{100 * seen:.1f} % of the face seen" in r.stdout
    # the confidence: a cosine per texel, zero where no view sees it (the far cheek, the texels
    # off the face's layout)
    conf = np.asarray(Image.open(tmp_path / "c128.png").convert("L"), dtype=float) / 255
    assert 0.3 < (conf > 0).mean() < seen and conf.max() > 0.9
    r = cli("show", "fit.obj", "--screenshot", "shot.png", "--size", "128x128", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    shot = np.asarray(Image.open(tmp_path / "shot.png").convert("RGB"), dtype=float)
    face = shot[(shot < 250).any(-1)]
    assert face[:, 0].mean() > face[:, 2].mean() + 20                          # textured


def test_texture_path_with_spaces_is_refused_before_anything_is_written(tmp_path, data_dir):
    (tmp_path / "a b").mkdir()
    img = data_dir / "images" / "image_0010.png"
    r = subprocess.run([sys.executable, "-m", "morphable.cli", "fit", str(img), "--landmarks",
                        str(img.with_suffix(".pts")), "--out-mesh", "m.obj", "--out-texture",
                        "a b/t.png"], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and "a b/t.png: a texture path with spaces" in r.stderr
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["a b"]
