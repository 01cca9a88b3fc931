"""The photometric fit (docs/photometric.md): closed forms, mask, visibility re-casting,
gradients, recovery of a known face, several frames with one identity, bad inputs."""
import dataclasses
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from morphable.camera import Camera  # noqa: E402
from morphable.cli import main  # noqa: E402
from morphable.errors import InputError  # noqa: E402
from morphable.fitting import fit_landmarks  # noqa: E402
from morphable.raster import render, sh_basis  # noqa: E402
from morphable.raster.lambertian_fit import solve_albedo, solve_light, texel_index  # noqa: E402
from morphable.refinement import refine, refine_shared  # noqa: E402


@pytest.fixture(scope="module")
def face(sfm):
    """A known SFM face rendered at 192 px by our Lambertian renderer (a side light), its
    vertices and its landmark fit from landmarks with 1 px noise."""
    rng = np.random.default_rng(5)
    alpha = rng.normal(0, 1.0, sfm.n_identity)
    cam = Camera.looking_at_face((192, 192), yaw=20, pitch=-5, face_width_px=110)
    verts = sfm.vertices(alpha)
    from morphable.raster import DirectionalLight, sh_from_lights

    light = sh_from_lights([DirectionalLight((0.7, 0.3, 1.0), 0.7)], ambient=0.35)
    image = render(verts, sfm.triangles, cam, colors=np.array([0.75, 0.55, 0.45]), light=light,
                   background=(0.2, 0.3, 0.4), supersample=2)
    lm = cam.project(sfm.landmark_positions(alpha)) + rng.normal(0, 1.0, (68, 2))
    fit = fit_landmarks(sfm, lm[None], np.array([[192.0, 192.0]]), n_iterations=3)
    return image, fit, alpha, cam


def test_light_closed_form_recovers_a_known_light():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(400, 3))
    n[:, 2] = np.abs(n[:, 2])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    light = rng.normal(0, 0.3, (9, 3))
    light[0] += 1.0
    albedo = rng.uniform(0.2, 0.9, (400, 3))
    target = albedo * (sh_basis(n) @ light)
    got = solve_light(albedo, sh_basis(n), target, np.ones(400), strength=0.0)
    np.testing.assert_allclose(got, light, atol=1e-8)
    # pixels of weight 0 (masked out) do not count, however wrong they are
    w = np.ones(400)
    w[:50] = 0
    target[:50] = 0.0
    np.testing.assert_allclose(solve_light(albedo, sh_basis(n), target, w, strength=0.0), light, atol=1e-8)


def test_albedo_closed_form_recovers_a_known_texture():
    rng = np.random.default_rng(1)
    S = 8
    truth = rng.uniform(0.1, 0.9, (S * S, 3))
    uv = rng.uniform(0, 1, (3000, 2))
    texels = texel_index(uv, S)
    shading = rng.uniform(0.3, 1.5, (3000, 3))
    target = truth[texels] * shading
    prior = np.full((S * S, 3), 0.5)
    got = solve_albedo(texels, shading, target, np.ones(3000), prior, strength=1e-9)
    np.testing.assert_allclose(got, truth, atol=1e-6)
    # a texel no pixel sees is its prior; a strong prior pulls the others towards it
    seen = np.isin(np.arange(S * S), texels[100:])
    far = solve_albedo(texels[100:], shading[100:], target[100:], np.ones(2900), prior, 1e-9)
    np.testing.assert_allclose(far[~seen], 0.5)
    strong = solve_albedo(texels, shading, target, np.ones(3000), prior, strength=1e6)
    assert np.abs(strong - 0.5).max() < 1e-3


def test_texel_index_convention():
    # texel (row, col) of an S x S map has its centre at u = (col + 0.5) / S, v = 1 - (row + 0.5) / S
    S = 4
    uv = np.array([[(1 + 0.5) / S, 1 - (2 + 0.5) / S], [0.0, 1.0], [1.0, 0.0]])
    assert texel_index(uv, S).tolist() == [2 * S + 1, 0, S * S - 1]


def test_mask_leaves_out_a_synthetic_occluder(face, sfm):
    from morphable.refinement.crop import crop_image

    image, fit, _, cam = face
    occluded = image.copy()
    box = (slice(85, 120), slice(60, 95))          # a green patch over a cheek and the nose
    occluded[box] = (0.1, 0.8, 0.2)
    _, report, state = refine(occluded, fit, "classical", steps=0, resolution=128,
                              return_state=True)
    clean = crop_image(image, state.crop, 128)
    patch = np.abs(state.target - clean).max(-1) > 0.1
    face_px = state.coverage > 0.5
    assert patch.sum() > 100
    assert state.mask[patch & face_px].mean() < 0.05
    assert state.mask[~patch & face_px].mean() > 0.6
    assert 0.3 < report["mask_coverage"] < 0.95


def test_visibility_is_recast_as_the_pose_moves(face):
    from morphable.refinement.geometry import rodrigues
    from morphable.refinement.problem import recast, set_up

    image, fit, _, _ = face
    p = set_up(image, fit, 0, 128)
    verts = fit.model.vertices(fit.frame_identity[0], fit.expression[0])
    same = recast(p, verts, p.camera.rotation, p.camera.translation)
    np.testing.assert_array_equal(same.vis.triangle_id, p.vis.triangle_id)
    turn = rodrigues(torch.tensor([0.0, np.radians(15.0), 0.0], dtype=torch.float64)).numpy()
    moved = recast(p, verts, turn @ p.camera.rotation, p.camera.translation)
    changed = (moved.vis.triangle_id != p.vis.triangle_id).mean()
    assert changed > 0.05
    assert not np.allclose(moved.uv, p.uv)
    # the loop re-casts: with re-casting the crop's face pixels follow the refined pose
    _, rep = refine(image, fit, "classical", steps=4, resolution=128, recast_every=2)
    assert rep["recast_every"] == 2 and rep["stage_s"]["visibility"] > 0


@pytest.mark.parametrize("resolution", [32, 128])
def test_gradients_match_finite_differences(face, resolution):
    # the photometric and landmark terms in float64 against finite differences, on the
    # full-image path (32 px, 2 x 2 samples) and the surface-point path (128 px)
    from morphable.raster.classical_renderer import ClassicalRenderer
    from morphable.refinement.geometry import pixel_view
    from morphable.refinement.loss import loss_function
    from morphable.refinement.problem import set_up, start
    from morphable.raster import normal_map

    image, fit, _, _ = face
    renderer = ClassicalRenderer(texture_size=32)
    p = set_up(image, fit, 0, resolution)
    p = dataclasses.replace(p, image=p.image.double(), landmarks=p.landmarks.double())
    u = start([p], renderer)
    verts = fit.model.vertices(fit.frame_identity[0], fit.expression[0])
    n = normal_map(verts, fit.model.triangles, vis=p.vis)
    cover = p.coverage[0, 0].numpy()
    renderer.solve_appearance(u.appearances, [pixel_view(fit.model, p.vis, n, p.uv, p.target, cover)])
    u.appearances[0] = {k: v.double() for k, v in u.appearances[0].items()}
    u.rotation0s = [r.double() for r in u.rotation0s]
    u.translation0s = [t.double() for t in u.translation0s]
    rest_a, rest_b = u.alpha.detach().double(), u.betas[0].detach().double()
    weights = {"photo": 1000.0, "feat": 0.0, "lmk": 1.0, "beta": 1e-4}
    losses = loss_function(lambda: p, u, 0, renderer, weights)
    mask = p.coverage.double()

    def f(a, b, rot, trans):
        u.alpha = torch.cat([a, rest_a[3:]])
        u.betas = [torch.cat([b, rest_b[2:]])]
        u.rots, u.transes = [rot], [trans]
        return losses(mask)[0]

    args = (rest_a[:3].clone().requires_grad_(True), rest_b[:2].clone().requires_grad_(True),
            torch.full((3,), 1e-3, dtype=torch.float64, requires_grad=True),
            torch.zeros(3, dtype=torch.float64, requires_grad=True))
    # the crop is sampled bilinearly at the projected points: piecewise linear, so a finite
    # difference that crosses a pixel centre differs from the derivative by a little
    assert torch.autograd.gradcheck(f, args, eps=1e-6, atol=2e-3, rtol=1e-2)


def test_a_known_face_is_fit_closer_than_the_landmark_start(sfm):
    # an inverse crime by design: frames rendered by the Lambertian SH image model the fit
    # assumes (procedural albedo, a light per frame), the solver must find the truth there
    from neural.faces.renders import SyntheticFaces

    from evaluation.bench_photometric import synthetic_person

    faces = SyntheticFaces(model=sfm, resolution=192)
    rng = np.random.default_rng(11)
    person = synthetic_person(faces, rng, 3)
    lm = person["landmarks"] + rng.normal(0, 1.0, person["landmarks"].shape)
    fit = fit_landmarks(sfm, lm, np.tile([192.0, 192.0], (3, 1)), n_iterations=4)
    new, reports, _ = refine_shared(list(person["images"]), fit, "classical", steps=60,
                                    resolution=128)
    truth = sfm.vertices(person["identity"])

    def err(f):
        return np.linalg.norm(f.neutral_vertices(np.float64) - truth, axis=1).mean()
    # 3.93 -> 3.77 mm at the defaults (photometric weight 300, albedo prior 0.5; 3.56 with the
    # stronger albedo prior 4 of before, which this Lambertian image model rewards and the
    # physically based validation frames did not); a wrong sign or a pixel term that drifts
    # the shape lands above the start
    assert err(new) < 0.97 * err(fit), (err(fit), err(new))
    # one identity for the three frames, as the fit's identity
    np.testing.assert_array_equal(new.frame_identity, np.tile(new.identity, (3, 1)))
    assert all(not r["fallback"] and r["mask_coverage"] > 0.5 for r in reports)


def test_several_photos_write_the_refined_identity(data_dir, tmp_path, sfm):
    # the bug of issue 54: several frames refined, the mesh written was the unrefined identity
    from mesh_check import assert_mesh_holds, report_expressive_vertices, report_vertices

    img, pts = data_dir / "images" / "image_0010.png", data_dir / "images" / "image_0010.pts"
    report = tmp_path / "fit.json"
    assert main(["fit", str(img), str(img), "--landmarks", str(pts), str(pts), "--refine",
                 "photometric", "--steps", "8", "--report", str(report),
                 "--out-mesh", str(tmp_path / "fit.obj")]) == 0
    rep = json.loads(report.read_text())
    assert_mesh_holds(tmp_path / "fit.obj", report_vertices(rep, sfm), sfm.triangles)
    assert main(["fit", str(img), str(img), "--landmarks", str(pts), str(pts),
                 "--report", str(tmp_path / "plain.json")]) == 0
    plain = json.loads((tmp_path / "plain.json").read_text())
    assert np.abs(np.subtract(rep["identity"], plain["identity"])).max() > 1e-3
    assert [r["frames_together"] for r in rep["refine"]] == [2, 2]
    assert rep["mesh"]["kind"] == "neutral"
    # --mesh expressive: each frame's face, the same rule as for one photo
    assert main(["fit", str(img), str(img), "--landmarks", str(pts), str(pts), "--refine",
                 "photometric", "--steps", "2", "--report", str(report), "--mesh", "expressive",
                 "--out-mesh", str(tmp_path / "x.ply")]) == 0
    rep = json.loads(report.read_text())
    for i in range(2):
        assert_mesh_holds(tmp_path / f"x_{i}.ply", report_expressive_vertices(rep, sfm, i), sfm.triangles)


def test_cli_writes_the_albedo_and_the_mask(data_dir, tmp_path):
    from PIL import Image

    img, pts = data_dir / "images" / "image_0010.png", data_dir / "images" / "image_0010.pts"
    tex, overlay, report = tmp_path / "albedo.png", tmp_path / "over.png", tmp_path / "fit.json"
    assert main(["fit", str(img), "--landmarks", str(pts), "--refine", "photometric", "--steps", "4",
                 "--out-texture", str(tex), "--texture-size", "64", "--overlay", str(overlay),
                 "--overlay-mask", "--report", str(report)]) == 0
    rep = json.loads(report.read_text())
    assert rep["texture"]["kind"].startswith("albedo") and Image.open(tex).size == (64, 64)
    run = rep["refine"][0]
    assert 0.05 < run["mask_coverage"] <= 1 and run["photometric_residual"] < 0.2
    assert set(run["stage_s"]) == {"set_up", "appearance", "mask", "visibility", "geometry"}
    assert Image.open(overlay).size == Image.open(img).size
    # on request the photos' colours instead (shading included)
    assert main(["fit", str(img), "--landmarks", str(pts), "--refine", "photometric", "--steps", "1",
                 "--out-texture", str(tex), "--texture-size", "64", "--texture-source", "photo",
                 "--report", str(report)]) == 0
    assert json.loads(report.read_text())["texture"]["kind"] == "photo"


@pytest.mark.parametrize("kind", ["black", "saturated"])
def test_a_photo_the_mask_leaves_empty_is_a_one_line_error(data_dir, tmp_path, capsys, kind):
    from PIL import Image

    src, pts = data_dir / "images" / "image_0010.png", data_dir / "images" / "image_0010.pts"
    size = Image.open(src).size
    photo = tmp_path / f"{kind}.png"
    Image.new("RGB", size, (0, 0, 0) if kind == "black" else (255, 255, 255)).save(photo)
    mesh = tmp_path / "fit.obj"
    capsys.readouterr()
    assert main(["fit", str(photo), "--landmarks", str(pts), "--refine", "photometric",
                 "--steps", "2", "--out-mesh", str(mesh), "--report", str(tmp_path / "r.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "under 5 %" in err and str(photo) in err
    assert sorted(p.name for p in tmp_path.iterdir()) == [photo.name]


def test_a_model_without_uvs_is_a_one_line_error(data_dir, tmp_path, capsys, sfm):
    from morphable.io import save_model_npz

    bare = save_model_npz(dataclasses.replace(sfm, uv=None, triangle_uv=None), tmp_path / "bare.npz")
    img, pts = data_dir / "images" / "image_0010.png", data_dir / "images" / "image_0010.pts"
    capsys.readouterr()
    assert main(["fit", str(img), "--landmarks", str(pts), "--model", str(bare), "--refine",
                 "photometric", "--out-mesh", str(tmp_path / "fit.obj")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no UV coordinates" in err and "bare.npz" in err
    assert not (tmp_path / "fit.obj").exists()


def test_a_gar_without_weights_is_a_one_line_error(data_dir, tmp_path, capsys, monkeypatch):
    pytest.importorskip("neural.gar.renderer")
    monkeypatch.setenv("MORPHABLE_GAR_WEIGHTS", str(tmp_path / "missing.pt"))
    img, pts = data_dir / "images" / "image_0010.png", data_dir / "images" / "image_0010.pts"
    capsys.readouterr()
    assert main(["fit", str(img), "--landmarks", str(pts), "--refine", "gar",
                 "--out-mesh", str(tmp_path / "fit.obj")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "missing.pt" in err
    assert not (tmp_path / "fit.obj").exists()


def test_images_of_another_size_than_the_fit_are_refused(face):
    image, fit, _, _ = face
    with pytest.raises(InputError, match="image is 96x192, frame 0 of the fit is 192x192"):
        refine(image[:, :96], fit, "classical", steps=1)
    with pytest.raises(InputError, match="2 images for 1 frames"):
        refine_shared([image, image], fit, "classical", frames=[0])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_grey_and_tiny_faces_stay_finite(face, dtype):
    image, fit, _, _ = face
    grey = np.full(image.shape, 0.5, dtype=dtype)
    new, rep = refine(grey, fit, "classical", steps=3, resolution=128)
    assert np.isfinite(new.identity).all() and np.isfinite(rep["loss"]).all()
    # a face one pixel wide: a one-line error, never NaN
    tiny = dataclasses.replace(fit, landmarks=fit.landmarks * 0 + 96.0,
                               fitted_landmarks=fit.fitted_landmarks * 0 + 96.0)
    with pytest.raises(InputError, match="px wide|landmarks are missing"):
        refine(image.astype(dtype), tiny, "classical", steps=1)


def test_a_frame_the_mask_leaves_empty_keeps_its_landmark_fit(face, sfm, caplog):
    image, fit, alpha, cam = face
    lm = np.asarray(fit.landmarks[0])
    two = fit_landmarks(sfm, np.stack([lm, lm]), np.array([[192.0, 192.0]] * 2), n_iterations=3)
    black = np.zeros_like(image)
    with caplog.at_level("WARNING", logger="morphable.refinement"):
        new, reports, _ = refine_shared([image, black], two, "classical", steps=6, resolution=128)
    assert [r["fallback"] for r in reports] == [False, True]
    assert reports[1]["mask_coverage"] < 0.05 and "keeps its landmark fit" in caplog.text
    # its expression and pose stay the landmark fit's; the shared identity is the refined one
    np.testing.assert_array_equal(new.expression[1], two.expression[1])
    np.testing.assert_array_equal(new.cameras[1].rotation, two.cameras[1].rotation)
    np.testing.assert_array_equal(new.frame_identity[1], new.identity)
    assert np.abs(new.identity - two.identity).max() > 1e-4
