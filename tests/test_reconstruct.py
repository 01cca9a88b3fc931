"""Reconstruction by renderer inversion, the inverter V, face editing and their CLI."""
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from morphable.camera import Camera  # noqa: E402
from morphable.cli import main  # noqa: E402
from morphable.errors import InputError  # noqa: E402
from morphable.fitting import fit_landmarks  # noqa: E402
from morphable.raster import DirectionalLight, render, sh_from_lights  # noqa: E402
from morphable.refinement import crop_camera, crop_image, edit, face_crop, refine  # noqa: E402
from neural.gar.config import get_config  # noqa: E402
from neural.gar.networks import Generator  # noqa: E402
from neural.gar.networks import pixel_norm  # noqa: E402
from neural.gar.inverter import Inverter, inverter_loss, load_inverter, save_inverter  # noqa: E402
from neural.gar.renderer import GARRenderer  # noqa: E402


@pytest.fixture(scope="module")
def synthetic(sfm):
    """A known SFM face rendered at 200 x 200 under a coloured side light, and its
    landmark fit from the exact projected landmarks."""
    rng = np.random.default_rng(3)
    alpha = rng.normal(0, 0.8, 20)
    beta = np.zeros(sfm.n_expression)
    beta[sfm.expression_index("happiness")] = 0.5
    cam = Camera.looking_at_face((200, 200), yaw=15, pitch=-5, face_width_px=120)
    verts = sfm.vertices(alpha, beta)
    light = sh_from_lights([DirectionalLight((0.6, 0.3, 1.0), (0.8, 0.7, 0.6))], ambient=0.3)
    image = render(verts, sfm.triangles, cam, colors=np.array([0.8, 0.6, 0.5]), light=light,
                   background=(0.2, 0.3, 0.4), supersample=2)
    lm = cam.project(sfm.landmark_positions(alpha, beta))
    fit = fit_landmarks(sfm, lm[None], np.array([[200.0, 200.0]]), n_iterations=3)
    return image, fit, verts


def test_face_crop_is_the_training_framing():
    from neural.faces.renders import template

    left, top, side = face_crop(template(64))
    assert round(side, 1) == 64.0 and round(left + side / 2, 1) == 32.0  # the template fills its crop


def test_face_frame_is_one_rule_in_2d_and_3d(sfm):
    from morphable.refinement import face_frame

    lm = sfm.landmark_positions()
    centre, width = face_frame(lm)                   # the training framing, mm
    assert 240 < width < 270 and centre.shape == (3,)
    # moved and scaled, the frame follows; the x, y of the points alone frame the same x, y
    c2, w2 = face_frame(2.0 * lm + 10.0)
    np.testing.assert_allclose(c2, 2.0 * centre + 10.0)
    assert w2 == pytest.approx(2.0 * width)
    frontal = lm.copy()
    frontal[:, 2] = 0.0
    c_xy, w_xy = face_frame(frontal[:, :2])
    np.testing.assert_allclose(c_xy, centre[:2])
    assert w_xy == pytest.approx(face_frame(frontal)[1])
    with pytest.raises(InputError, match="eye and mouth"):
        face_frame(np.full((68, 2), np.nan))


def test_a_face_mesh_fit_is_cropped_like_its_68_points(synthetic, sfm):
    # the FFHQ framing takes iBUG-68's eyes and mouth: a fit to the face mesh's 478 points is
    # framed by its fitted face, not by the 478 points' rows 36-67 (which are elsewhere)
    from morphable.fitting import simulate_landmarks
    from morphable.fitting.schemes import load_scheme
    from morphable.refinement.problem import set_up

    image, fit68, verts = synthetic
    pts = simulate_landmarks(sfm, fit68.cameras[0], vertices=verts, scheme=load_scheme(sfm))
    fit478 = fit_landmarks(sfm, pts[None], np.array([[200.0, 200.0]]))
    expect = np.array(set_up(image, fit68, 0, 64).crop)
    got = np.array(set_up(image, fit478, 0, 64).crop)
    assert np.abs(got - expect).max() < 0.05 * expect[2], (got, expect)


def test_crop_camera_maps_pixels():
    cam = Camera.looking_at_face((300, 200), yaw=10)
    pts = np.array([[10.0, 20, 30], [-40, 5, 60]])
    crop = (50.5, 20.0, 120.0)
    sub = crop_camera(cam, crop, 64)
    k = 64 / 120
    expect = (cam.project(pts) + 0.5 - np.array(crop[:2])) * k - 0.5
    np.testing.assert_allclose(sub.project(pts), expect, atol=1e-9)
    # a crop reaching past the border is padded with the photo's mirrored background, not
    # refused and not black
    img = np.full((40, 30, 3), 255, np.uint8)
    img[:, :, 2] = 0
    out = crop_image(img, (-10.0, -10.0, 60.0), 16)
    assert out.shape == (16, 16, 3)
    np.testing.assert_allclose(out[..., :2], 1.0)
    np.testing.assert_allclose(out[..., 2], 0.0)


def test_classical_refinement_lowers_photometric_loss(synthetic, sfm):
    image, fit, verts = synthetic
    new, report, state = refine(image, fit, "classical", steps=40, resolution=48,
                                return_state=True)
    photo = report["photometric_loss"]
    assert len(photo) == 41 and np.isfinite(photo).all()
    # the closed-form appearance explains the render from the start (a uniform albedo under
    # a white light left 5e-3 here); the steps do not make it worse
    assert photo[0] < 1e-3 and photo[-1] <= 1.1 * photo[0], photo
    assert np.isfinite(new.frame_identity).all() and np.isfinite(new.expression).all()
    # the landmark term and priors keep the geometry where the landmarks put it
    assert report["landmark_rmse_px_after"] < report["landmark_rmse_px_before"] + 2.0
    err_before = np.linalg.norm(fit.vertices(0) - verts, axis=1).mean()
    err_after = np.linalg.norm(new.vertices(0) - verts, axis=1).mean()
    assert err_after < err_before + 1.0
    # the recovered albedo ratio follows the true one (0.8 : 0.6 : 0.5 under a warm light)
    alb = state.appearance["albedo"][0].numpy()[:, state.coverage > 0.5].mean(1)
    assert alb[0] > alb[1] > alb[2]
    out = edit(state, yaw=-20, expression={"happiness": 0.9})
    assert out.shape == (48, 48, 3) and np.isfinite(out).all()
    assert np.abs(out - state.rendered).mean() > 0.01
    with pytest.raises(InputError, match="unknown expression"):
        edit(state, expression={"smile": 1.0})


def test_gar_refinement_runs_untrained(synthetic):
    image, fit, _ = synthetic
    torch.manual_seed(0)
    V = Inverter(get_config("tiny")).eval()
    r = GARRenderer(allow_untrained=True, inverter=V)
    new, report, state = refine(image, fit, r, steps=3, return_state=True)
    assert report["latent_init"] == "inverter" and len(report["photometric_loss"]) == 4
    assert np.isfinite(report["loss"]).all() and np.isfinite(new.expression).all()
    assert state.rendered.shape == (64, 64, 3)
    assert np.isfinite(edit(state, yaw=20)).all()


def test_inverter_training_smoke(tmp_path):
    from neural.gar.train_inverter import train

    torch.manual_seed(0)
    cfg = get_config("tiny", resolution=16, channel_base=256, channel_max=32, z_dim=16,
                     w_dim=16, mapping_layers=2)
    G = Generator(cfg).eval().requires_grad_(False)
    V, metrics, history = train(G, steps=3, batch_size=2, pool=3, held_out=2, progress=False)
    assert len(history) == 3 and all(np.isfinite(h["z"]) for h in history)
    assert {"z_mse", "z_cosine", "image_l1"} <= set(metrics)
    assert 0 <= metrics["z_mse"] < 4 and np.isfinite(metrics["z_cosine"])
    # the starting latent: V's direction where it knows (c = 1), the prior where not (c = 0)
    assert 0 <= metrics["direction_cosine"] <= 1 and float(V.direction_cosine) == metrics["direction_cosine"]
    img = torch.zeros(2, 3, 16, 16)
    V.direction_cosine.fill_(1.0)
    torch.testing.assert_close(V.latent(img), pixel_norm(V(img)[0]))
    V.direction_cosine.fill_(0.0)
    torch.testing.assert_close(V.latent(img, generator=torch.Generator().manual_seed(3)),
                               torch.randn(2, cfg.z_dim, generator=torch.Generator().manual_seed(3)))
    # G sees only the direction of z, and so does the latent term of the loss
    z = torch.randn(2, cfg.z_dim)
    torch.testing.assert_close(G.mapping(3 * z), G.mapping(z))
    n = torch.zeros(2, 3, 16, 16)
    n[:, 2] = 1
    assert float(inverter_loss(V, G, n, 3 * z)[1]["z"]) == pytest.approx(
        float(inverter_loss(V, G, n, z)[1]["z"]))
    V2 = load_inverter(save_inverter(V, tmp_path / "v.pt", metrics=metrics))
    img = torch.rand(1, 3, 16, 16) * 2 - 1
    torch.testing.assert_close(V2(img)[0], V(img)[0])


def test_inverter_on_real_pack_reports_photo_reconstruction(tiny_pack):
    from neural.gar.train_inverter import train

    torch.manual_seed(0)
    cfg = get_config("tiny", resolution=16, channel_base=256, channel_max=32, z_dim=16,
                     w_dim=16, mapping_layers=2)
    G = Generator(cfg).eval().requires_grad_(False)
    V, metrics, history = train(G, steps=2, batch_size=2, pool=4, held_out=4, progress=False,
                                data=tiny_pack)
    real = metrics["real"]
    assert real["n_photos"] == 2 and metrics["n_held_out"] == 2       # the pack's test split
    assert all(np.isfinite(real[k]) and real[k] > 0 for k in
               ("image_l1_v", "image_l1_mean", "image_l1_optimised"))
    # optimising the latent per photo, from V's, lowers the photo's error
    assert real["image_l1_optimised"] < real["image_l1_v"]
    assert real["v_over_optimised"] == pytest.approx(real["image_l1_v"] / real["image_l1_optimised"])


def test_cli_fit_refine_and_edit(data_dir, tmp_path, capsys, sfm):
    img = data_dir / "images" / "image_0010.png"
    pts = data_dir / "images" / "image_0010.pts"
    report, mesh, png = tmp_path / "fit.json", tmp_path / "fit.obj", tmp_path / "r.png"
    assert main(["fit", str(img), "--landmarks", str(pts), "--refine", "classical", "--steps", "5",
                 "--report", str(report), "--out-mesh", str(mesh), "--refine-render", str(png)]) == 0
    rep = json.loads(report.read_text())
    assert len(rep["refine"][0]["photometric_loss"]) == 6 and png.is_file()
    # the mesh is the refined face: the report's identity and expression, read back
    from mesh_check import assert_mesh_holds, report_vertices

    assert_mesh_holds(mesh, report_vertices(rep, sfm), sfm.triangles)
    # loss weight overrides reach the refinement; without --refine, or wrong, a one-line error
    assert main(["fit", str(img), "--landmarks", str(pts), "--refine", "classical", "--steps", "1",
                 "--loss-weight", "lmk=10", "photo=0", "--report", str(report)]) == 0
    w = json.loads(report.read_text())["refine"][0]["loss_weights"]
    assert w["lmk"] == pytest.approx(10.0) and w["photo"] == 0.0     # annotated: full trust
    capsys.readouterr()
    for extra in (["--loss-weight", "lmk=10"], ["--refine", "classical", "--loss-weight", "hair=1"]):
        assert main(["fit", str(img), "--landmarks", str(pts), *extra,
                     "--report", str(tmp_path / "no.json")]) == 2
        err = capsys.readouterr().err
        assert "--loss-weight" in err and len(err.strip().splitlines()) == 1
        assert not (tmp_path / "no.json").exists()
    out = tmp_path / "edit.png"
    assert main(["edit", str(img), "--landmarks", str(pts), "--renderer", "classical",
                 "--steps", "3", "--yaw", "20", "--expression", "happiness=0.8",
                 "--out", str(out), "--zoom", "1", "--loss-weight", "lmk=10"]) == 0
    from PIL import Image

    assert Image.open(out).size == (3 * 256, 256)         # the classical crop: 256 px
    # bad input: one-line error, exit 2, nothing written
    bad = tmp_path / "bad.png"
    assert main(["edit", str(img), "--landmarks", str(pts), "--expression", "smile=1",
                 "--out", str(bad)]) == 2
    assert "smile" in capsys.readouterr().err and not bad.exists()


def test_ablation_smoke(tmp_path):
    from evaluation.gar_ablation import held_out_faces, plot_curves, run_ablation

    torch.manual_seed(0)
    G = Generator(get_config("tiny"))
    path = tmp_path / "g.pt"
    torch.save({"config": G.config.to_dict(), "G_ema": G.state_dict()}, path)
    model, faces = held_out_faces(1, image_size=96)
    rep = run_ablation(faces, model, steps=2, generator=path, generator_n0=path, inverter=None,
                       progress=False)
    assert set(rep["variants"]) == {"landmark-only", "landmarks-refit", "classical", "gar",
                                    "gar-no-initial", "gar-no-norm-cycle"}
    for v in rep["variants"].values():
        assert set(v) == {"vertex_mm", "normal_deg", "s_per_image"}
        assert all(np.isfinite(x) for x in v.values())
    assert 0 < rep["variants"]["landmark-only"]["vertex_mm"] < 10
    # error against steps: the first traced point is the landmark fit, the last the result
    c = rep["curves"]["classical"]
    assert c["step"] == [0, 1, 2] and len(c["vertex_mm"]) == 3 and c["seconds"] == sorted(c["seconds"])
    assert c["vertex_mm"][0] == pytest.approx(rep["variants"]["landmark-only"]["vertex_mm"], abs=1e-3)
    assert c["vertex_mm"][-1] == pytest.approx(rep["variants"]["classical"]["vertex_mm"], abs=1e-3)
    plot_curves(rep, tmp_path / "curves.png")
    assert (tmp_path / "curves.png").stat().st_size > 1000


def test_corrupt_weight_files_give_one_line_errors(tmp_path):
    from morphable import InputError
    from neural.gar.networks import load_generator
    from neural.gar.inverter import load_inverter

    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    for load, text in ((load_generator, "not a GAR checkpoint"), (load_inverter, "not an inverter checkpoint")):
        with pytest.raises(InputError, match=text) as e:
            load(bad)
        assert str(e.value).startswith(str(bad)) and "\n" not in str(e.value)


def test_refine_frames_one_mesh_per_frame(tmp_path):
    from evaluation.gar_ablation import held_out_faces
    from morphable.refinement import refine_frames

    model, faces = held_out_faces(2, image_size=96)
    images = np.stack([f["image"] for f in faces])
    lms = np.stack([f["landmarks"] for f in faces])
    verts, reports = refine_frames(model, images, lms, "classical", steps=2)
    assert verts.shape == (2, model.n_vertices, 3) and np.isfinite(verts).all()
    assert len(reports) == 2 and all(len(r["photometric_loss"]) == 3 for r in reports)
    # each frame's mesh is near its own face, not the other one
    d = [[np.linalg.norm(v - f["vertices"], axis=1).mean() for f in faces] for v in verts]
    assert d[0][0] < d[0][1] and d[1][1] < d[1][0]


def test_refine_frames_takes_the_face_meshs_478_points():
    # a face-mesh video is refined from the 478-point fit itself, not from its 68 (the
    # Florence gar method's start is then ours-independent's fit of the same points)
    from evaluation.gar_ablation import held_out_faces
    from morphable.fitting.schemes import load_scheme
    from morphable.refinement import refine_frames

    model, faces = held_out_faces(2, image_size=96)
    images = np.stack([f["image"] for f in faces])
    fit68 = fit_landmarks(model, np.stack([f["landmarks"] for f in faces]), [96, 96],
                          shared_identity=False)
    scheme = load_scheme(model)
    lms = np.stack([cam.project(scheme.points(f["vertices"]))
                    for cam, f in zip(fit68.cameras, faces)])
    assert lms.shape == (2, 478, 2)
    verts, reports = refine_frames(model, images, lms, "classical", steps=2)
    assert verts.shape == (2, model.n_vertices, 3) and np.isfinite(verts).all()
    # the classical renderer's own photometric weight (ClassicalRenderer.default_weights)
    from morphable.raster.classical_renderer import ClassicalRenderer
    assert all(r["loss_weights"]["photo"] == ClassicalRenderer.default_weights["photo"] for r in reports)
    d = [[np.linalg.norm(v - f["vertices"], axis=1).mean() for f in faces] for v in verts]
    assert d[0][0] < d[0][1] and d[1][1] < d[1][0]
    # weight overrides reach every frame's refinement
    _, reports = refine_frames(model, images, lms, "classical", steps=1, weights={"photo": 0.0})
    assert all(r["loss_weights"]["photo"] == 0.0 for r in reports)


def test_loss_weights_parse_from_the_command_line():
    from morphable.refinement import DEFAULT_WEIGHTS, parse_loss_weights

    assert parse_loss_weights(["photo=0", "lmk=10", "alpha=1e-2"]) == {
        "photo": 0.0, "lmk": 10.0, "alpha": 0.01}
    assert parse_loss_weights(None) == {}
    for bad, text in ((["hair=1"], "KEY one of photo"), (["photo"], "expected KEY=VALUE"),
                      (["photo=1", "photo=2"], "photo given twice"),
                      (["feat=-1"], "finite number >= 0"), (["feat=nan"], "finite number >= 0"),
                      (["feat=x"], "finite number >= 0")):
        with pytest.raises(InputError, match=text) as e:
            parse_loss_weights(bad, "--gar-loss-weight")
        assert str(e.value).startswith("--gar-loss-weight") and "\n" not in str(e.value)
    assert set(parse_loss_weights([f"{k}=1" for k in DEFAULT_WEIGHTS])) == set(DEFAULT_WEIGHTS)


def test_landmark_trust_follows_the_fits_noise_model(synthetic, sfm):
    """Refinement weighs a frame's landmarks as the landmark fit did: annotated ones fully,
    detected ones (a detector's model error) far less, on either camera."""
    import dataclasses

    from morphable.fitting.noise import DETECTED_MODEL_STD_MM
    from morphable.refinement import landmark_trust

    _, fit, _ = synthetic
    assert landmark_trust(fit) == pytest.approx(1.0)
    lm = fit.landmarks
    for camera, opts in (("affine", {}), ("perspective", {"focal_px": 600.0})):
        det = fit_landmarks(sfm, lm, np.array([[200.0, 200.0]]), camera=camera,
                            model_std_mm=DETECTED_MODEL_STD_MM, **opts)
        t = landmark_trust(det)
        assert 0.01 < t < 0.1, (camera, t)
    # a result that does not record its noise model is trusted as annotated
    assert landmark_trust(dataclasses.replace(fit, model_std_mm=np.zeros(0))) == 1.0
    _, report = refine(synthetic[0], det, "classical", steps=1, resolution=32)
    assert report["loss_weights"]["lmk"] == pytest.approx(t)


def test_gar_renderer_takes_the_inverter_beside_its_weights(tmp_path):
    """A weights folder is a set: the generator with the V trained against it."""
    from neural.gar.paths import default_inverter_path

    cfg = get_config("tiny", resolution=16, channel_base=256, channel_max=32, z_dim=16,
                     w_dim=16, mapping_layers=2)
    torch.manual_seed(0)
    torch.save({"config": cfg.to_dict(), "step": 0, "G": Generator(cfg).state_dict()},
               tmp_path / "generator.pt")
    alone = GARRenderer(weights=tmp_path / "generator.pt")
    expected = default_inverter_path()
    assert (alone.inverter is None) if expected is None else alone.inverter.source == str(expected)
    save_inverter(Inverter(cfg), tmp_path / "inverter_tiny.pt")
    paired = GARRenderer(weights=tmp_path / "generator.pt")
    assert paired.inverter.source == str(tmp_path / "inverter_tiny.pt")
    assert GARRenderer(weights=tmp_path / "generator.pt", inverter=None).inverter is None


def test_a_wide_padding_blur_is_the_gaussian_to_a_grey_level(monkeypatch):
    # the padding of a 1000-px crop blurs by 20 px on a copy reduced 5 times: within a grey level
    # of the full-resolution Gaussian it replaces
    from scipy.ndimage import gaussian_filter

    import morphable.refinement.crop as crop_module

    rng = np.random.default_rng(3)
    photo = rng.integers(0, 256, size=(300, 420, 3), dtype=np.uint8)
    photo[:, :200] = (220, 60, 30)
    box = (-300.0, -350.0, 700.0, 650.0)
    fast, shift = crop_module.pad_like_ffhq(photo, box)
    monkeypatch.setattr(crop_module, "_wide_blur",
                        lambda f, sigma: gaussian_filter(f, [sigma, sigma, 0]))
    exact, exact_shift = crop_module.pad_like_ffhq(photo, box)
    assert shift == exact_shift and fast.shape == exact.shape
    assert np.abs(fast.astype(int) - exact.astype(int)).max() <= 1
    assert np.abs(fast.astype(int) - exact.astype(int)).mean() < 0.1
