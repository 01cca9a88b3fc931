"""Landmark fitting: recovery on synthetic faces, masks, multi-frame, stability, CLI."""
import json

import numpy as np
import pytest

from morphable import FitError, InputError
from morphable.camera import Camera
from morphable.fitting import estimate_affine_pose, fit_landmarks, project, simulate_landmarks
from morphable.fitting import landmark_bank
from morphable.fitting.options import FitOptions
from morphable.fitting.schemes import LandmarkScheme, ibug68_scheme


def synth(model, yaw=0.0, pitch=0.0, roll=0.0, identity=None, expression=None, kind="affine",
          size=(512, 512), face_px=None, distance=600.0):
    """Detector-like landmarks of a model face, the camera and the true vertices."""
    cam = Camera.looking_at_face(image_size=size, yaw=yaw, pitch=pitch, roll=roll, kind=kind,
                                 face_width_px=face_px, distance_mm=distance)
    verts = model.vertices(identity, expression)
    return simulate_landmarks(model, cam, vertices=verts), cam, verts


def aligned_error(a, b):
    """Mean vertex distance (mm) after a similarity alignment of a onto b."""
    A, B = a - a.mean(0), b - b.mean(0)
    U, S, Vt = np.linalg.svd(B.T @ A)
    D = np.diag([1, 1, np.sign(np.linalg.det(U @ Vt))])
    s = (S * np.diag(D)).sum() / (A ** 2).sum()
    return np.linalg.norm(s * A @ (U @ D @ Vt).T - B, axis=1).mean()


@pytest.fixture(scope="module")
def face(sfm):
    rng = np.random.default_rng(3)
    alpha = rng.standard_normal(sfm.n_identity)
    beta = np.array([0.0, 0.0, 0.0, 0.6, 0.0, 0.2])
    return alpha, beta


# --- building blocks --------------------------------------------------------------------
def test_affine_pose_recovers_a_known_camera(sfm):
    ids = sfm.landmark_ids[17:]
    X = sfm.mean[ids[ids >= 0]][None].astype(float)
    cam = Camera.looking_at_face(yaw=35, pitch=-10, roll=20)
    y = cam.project(X[0])[None]
    R, t, s = estimate_affine_pose(X, y, np.ones((1, len(X[0]))), np.array([[255.5, 255.5]]))
    np.testing.assert_allclose(R[0], cam.rotation, atol=1e-6)
    np.testing.assert_allclose(s[0], cam.scale, rtol=1e-6)
    np.testing.assert_allclose(t[0, :2], cam.translation[:2], atol=1e-4)


def test_camera_image_scale():
    """px_per_mm is the projection's local scale: a 1 mm step across the view moves the point
    by that many pixels; NaN behind a pinhole camera."""
    for kind in ("affine", "perspective"):
        cam = Camera.looking_at_face((512, 512), yaw=20, kind=kind, distance_mm=500.0)
        p = np.array([[10.0, -20, 30], [0, 0, 0]])
        step = cam.rotation.T @ np.array([1e-3, 0, 0])       # along the camera's x axis
        moved = np.linalg.norm(cam.project(p + step) - cam.project(p), axis=1) / 1e-3
        np.testing.assert_allclose(cam.px_per_mm(p), moved, rtol=1e-5)
    assert np.isnan(cam.px_per_mm(np.array([0.0, 0.0, 600.0]) @ cam.rotation))
    # view directions lead to the pinhole (perspective) or along the camera's axis (affine)
    d = cam.view_directions(p)
    far = p + np.linalg.norm(cam.centre - p, axis=1, keepdims=True) * d
    np.testing.assert_allclose(far, np.broadcast_to(cam.centre, p.shape), atol=1e-9)
    axis = Camera.looking_at_face(yaw=20).view_directions(p)
    np.testing.assert_allclose(axis, np.broadcast_to(cam.rotation[2], p.shape), atol=1e-12)


@pytest.mark.parametrize("perspective", [False, True])
def test_projection_jacobian_matches_finite_differences(perspective):
    rng = np.random.default_rng(0)
    X = rng.normal(size=(2, 5, 3)) * 50
    R = Camera.looking_at_face(yaw=20, pitch=10).rotation[None].repeat(2, 0)
    t = np.array([[3.0, -2.0, -500.0]] * 2)
    k = np.array([800.0, 900.0]) if perspective else np.array([1.5, 2.0])
    c = np.array([[100.0, 120.0]] * 2)
    uv, Xc, J, _ = project(X, R, t, k, c, perspective)
    eps = 1e-6
    for j in range(3):
        dt = np.zeros(3)
        dt[j] = eps
        uv2, *_ = project(X, R, t + dt, k, c, perspective, jacobian=False)
        np.testing.assert_allclose((uv2 - uv) / eps, J[..., j], atol=1e-4)


# --- recovery -------------------------------------------------------------------------------
@pytest.mark.parametrize("yaw", [-45, 0, 30])
def test_affine_fit_recovers_pose_and_shape(sfm, face, yaw):
    alpha, beta = face
    lms, cam, verts = synth(sfm, yaw=yaw, pitch=10, roll=-5, identity=alpha, expression=beta)
    # the model's own landmark vertices: no definition error to allow for
    res = fit_landmarks(sfm, lms, (512, 512), definition_std_mm=0.0)
    assert res.landmark_rmse_px[0] < 3.0        # a regularised fit of a ~200 px face
    np.testing.assert_allclose(res.euler_deg[0], [yaw, 10, -5], atol=4)
    fitted = res.vertices(0)
    assert fitted.shape == (sfm.n_vertices, 3) and np.isfinite(fitted).all()
    # much closer to the truth than the mean face is
    assert aligned_error(fitted, verts) < 0.6 * aligned_error(sfm.mean.astype(float), verts)
    # the landmarks project where they were given
    used = np.isfinite(res.fitted_landmarks[0, :, 0])
    assert used.sum() >= 60
    np.testing.assert_allclose(res.fitted_landmarks[0, 17:][used[17:]], lms[17:][used[17:]], atol=5)


def test_perspective_fit_recovers_pose(sfm, face):
    alpha, beta = face
    lms, cam, verts = synth(sfm, yaw=25, pitch=-5, identity=alpha, expression=beta,
                            kind="perspective", distance=400)
    res = fit_landmarks(sfm, lms, (512, 512), camera="perspective", focal_px=cam.focal,
                        definition_std_mm=0.0)
    assert res.cameras[0].kind == "perspective"
    assert res.landmark_rmse_px[0] < 1.5
    np.testing.assert_allclose(res.euler_deg[0], [25, -5, 0], atol=4)
    assert res.cameras[0].depth(res.vertices(0)).min() > 0


def test_more_iterations_do_not_increase_the_cost(sfm, face):
    alpha, beta = face
    lms, _, _ = synth(sfm, yaw=20, identity=alpha, expression=beta)
    lms = lms + np.random.default_rng(1).normal(size=lms.shape) * 2
    costs = [fit_landmarks(sfm, lms, (512, 512), n_iterations=n).cost[0] for n in (0, 4)]
    assert costs[1] <= costs[0] + 1e-9


@pytest.mark.parametrize("jaw", [True, False])
def test_estimated_convergence_test_ends_where_the_full_one_does(sfm, monkeypatch, jaw):
    # the estimate only skips normal equations whose test would have ended the fit: with it
    # disabled (every convergence test from new normal equations) the fits are the same
    from morphable.fitting import nonlinear

    rng = np.random.default_rng(4)
    frames = []
    for yaw in (-40, -10, 25, 45):
        lms, _, _ = synth(sfm, yaw=yaw, pitch=rng.uniform(-15, 15),
                          identity=rng.standard_normal(sfm.n_identity),
                          expression=np.abs(rng.standard_normal(sfm.n_expression)) * 0.5)
        lms = lms + rng.normal(size=lms.shape)
        if not jaw:
            lms[:17] = np.nan
        frames.append(lms)
    frames = np.stack(frames)
    settings = [dict(), dict(camera="perspective"), dict(shared_identity=False)]
    runs, calls = {}, []
    estimate = nonlinear._predicted_decrease
    monkeypatch.setattr(nonlinear, "_predicted_decrease",
                        lambda *a: calls.append(1) or estimate(*a))
    for gain in (nonlinear.ESTIMATE_BELOW_GAIN, 0.0):
        monkeypatch.setattr(nonlinear, "ESTIMATE_BELOW_GAIN", gain)
        runs[gain] = ([fit_landmarks(sfm, f, (512, 512)) for f in frames]
                      + [fit_landmarks(sfm, frames, (512, 512), **kw) for kw in settings[1:]])
        if gain:
            assert calls                      # the estimate was tried
    for a, b in zip(*runs.values()):
        assert a.iterations == b.iterations
        for i in range(a.n_frames):
            assert np.abs(a.vertices(i) - b.vertices(i)).max() < 1e-9


def test_expression_is_recovered(sfm):
    beta = np.zeros(sfm.n_expression)
    beta[sfm.expression_index("surprise")] = 1.0
    lms, _, _ = synth(sfm, yaw=10, expression=beta)
    res = fit_landmarks(sfm, lms, (512, 512))
    assert int(np.argmax(res.expression[0])) == sfm.expression_index("surprise")
    assert (res.expression >= 0).all()      # blendshape weights stay non-negative


# --- masks and frames -------------------------------------------------------------------
def test_missing_landmarks_by_nan_or_mask(sfm, face):
    alpha, beta = face
    lms, _, verts = synth(sfm, yaw=15, identity=alpha, expression=beta)
    inner = lms.copy()
    inner[:17] = np.nan
    r1 = fit_landmarks(sfm, inner, (512, 512))
    mask = np.ones(68, bool)
    mask[:17] = False
    r2 = fit_landmarks(sfm, lms, (512, 512), mask=mask)
    np.testing.assert_allclose(r1.identity, r2.identity)
    assert np.all(r1.landmark_vertices[0, :17] == -1)
    one_eye = lms.copy()
    one_eye[42:48] = np.nan
    r3 = fit_landmarks(sfm, one_eye, (512, 512))
    full = fit_landmarks(sfm, lms, (512, 512))
    # losing an eye costs little: the other landmarks still fit about as well
    assert r3.landmark_rmse_px[0] < 1.2 * full.landmark_rmse_px[0]
    assert np.isfinite(r3.vertices(0)).all()


def test_multi_frame_shares_identity(sfm, face):
    alpha, _ = face
    frames = [synth(sfm, yaw=y, identity=alpha, expression=b)
              for y, b in ((-30, [0, 0, 0, 0.8, 0, 0]), (0, None), (40, [0, 0, 0, 0, 0, 0.7]))]
    lms = np.stack([f[0] for f in frames])
    res = fit_landmarks(sfm, lms, (512, 512))
    assert res.n_frames == 3 and res.expression.shape == (3, sfm.n_expression)
    np.testing.assert_allclose(res.frame_identity, res.identity[None].repeat(3, 0))
    assert res.vertices().shape == (3, sfm.n_vertices, 3)
    np.testing.assert_allclose(res.euler_deg[:, 0], [-30, 0, 40], atol=4)
    assert res.expression[0, 3] > 0.4 and res.expression[2, 5] > 0.4
    neutral = sfm.vertices(alpha)
    single = fit_landmarks(sfm, lms[1], (512, 512)).neutral_vertices()
    assert aligned_error(res.neutral_vertices(), neutral) < aligned_error(single, neutral)
    json.dumps(res.to_dict(images=["a", "b", "c"]))


def test_independent_frames_average_identity(sfm, face):
    alpha, _ = face
    lms = np.stack([synth(sfm, yaw=y, identity=alpha)[0] for y in (-20, 25)])
    res = fit_landmarks(sfm, lms, [(512, 512), (512, 512)], shared_identity=False)
    assert not np.allclose(res.frame_identity[0], res.frame_identity[1])
    np.testing.assert_allclose(res.identity, res.frame_identity.mean(0))
    np.testing.assert_allclose(res.neutral_vertices(), sfm.vertices(res.frame_identity).mean(0), atol=1e-9)
    # a batch fit equals fitting every frame alone
    alone = fit_landmarks(sfm, lms[1], (512, 512))
    np.testing.assert_allclose(res.frame_identity[1], alone.identity, atol=1e-6)


def definition_error_frames(model, alpha, rng, n=10, offset_mm=4.0, kind="affine"):
    """Landmarks of ``n`` views whose inner points carry one fixed 3D offset each (an
    annotation that defines them differently from the model), plus 1 px noise."""
    verts = model.vertices(alpha)
    ids = model.landmark_ids
    inner = np.arange(17, 68)[ids[17:] >= 0]
    off = rng.normal(0.0, offset_mm, (68, 3))
    frames = []
    for yaw in np.linspace(-30, 30, n):
        cam = Camera.looking_at_face(image_size=(512, 512), yaw=yaw, pitch=5 * np.sin(yaw),
                                     kind=kind)
        lm = simulate_landmarks(model, cam, vertices=verts)
        lm[inner] = cam.project(verts[ids[inner]] + off[inner])
        frames.append(lm + rng.normal(0.0, 1.0, lm.shape))
    return np.stack(frames), verts


def test_shared_definition_error_is_not_fitted_into_the_identity(sfm):
    rng = np.random.default_rng(0)
    lms, truth = definition_error_frames(sfm, rng.standard_normal(sfm.n_identity), rng)

    def error(frames, d):
        res = fit_landmarks(sfm, frames, (512, 512), definition_std_mm=d, n_expression=0)
        return aligned_error(res.neutral_vertices(), truth)

    naive, one, many = error(lms, 0.0), error(lms[4], 4.0), error(lms, 4.0)
    # 10 frames as 10 independent looks at the same offsets bend the identity; with the
    # offsets modelled, more frames help instead of hurting
    assert many < 0.75 * naive and many < one, (naive, one, many)


@pytest.mark.parametrize("kind", ["affine", "perspective"])
def test_shared_offsets_do_not_shrink_the_face(sfm, kind):
    # landmarks fix a face's shape, not its size (the camera's distance trades against it):
    # offsets of a fixed size in mm would be cheaper on a smaller face, so they grow and
    # shrink with it, and a shared fit keeps the size that frames fitted alone find
    def size(v):
        return np.sqrt(((v - v.mean(0)) ** 2).sum(1).mean())

    focal = Camera.looking_at_face(kind="perspective").focal
    rng = np.random.default_rng(5)
    ratios = []
    for _ in range(3):
        lms, _ = definition_error_frames(sfm, rng.standard_normal(sfm.n_identity), rng,
                                         offset_mm=2.5, kind=kind)
        shared, alone = (fit_landmarks(sfm, lms, (512, 512), camera=kind, focal_px=focal,
                                       definition_std_mm=2.5, shared_identity=s)
                         for s in (True, False))
        ratios.append(size(shared.neutral_vertices()) / size(alone.neutral_vertices()))
    assert abs(np.mean(ratios) - 1.0) < 0.04, ratios


def test_shared_rows_are_the_derivatives_of_the_points(sfm, face):
    # the offsets scale with the face: the identity's derivatives gain the offsets' growth;
    # an offset coefficient moves its landmark along its coordinate by face_size * offset_std
    from morphable.fitting.correspondences import landmark_bank
    from morphable.fitting.linear_stage import linear_stage
    from morphable.fitting.options import FitOptions
    from morphable.fitting.problem import Problem, as_frames
    from morphable.fitting.rows import face_size, points, shared_rows

    y, given, size = as_frames(np.stack([synth(sfm, yaw=a, identity=face[0])[0] for a in (-20, 25)]),
                               None, (512, 512))
    pb = Problem(sfm, landmark_bank(sfm), FitOptions(definition_std_mm=2.0), y, given, size)
    assert pb.D > 0                                                 # the offsets are fitted
    st = linear_stage(pb, 1)
    st.alpha = st.alpha + np.random.default_rng(0).normal(0.0, 0.5, st.alpha.shape)
    rows = shared_rows(pb, st)                                      # (N, 3, 68, K identity)
    assert rows.shape[-1] == sfm.n_identity
    eps = 1e-6
    n = sfm.n_identity
    for k in (0, 1, n, n + 4, pb.K - 1):
        up, down = st.copy(), st.copy()
        up.alpha[:, k] += eps
        down.alpha[:, k] -= eps
        d = (points(pb, up) - points(pb, down)) / (2 * eps)         # (N, 68, 3)
        if k < n:
            expected = rows[..., k].transpose(0, 2, 1)
        else:
            i, a = divmod(k - n, 3)
            expected = np.zeros_like(d)
            expected[:, pb.offset_landmarks[i], a] = face_size(pb, st.alpha)[0] * pb.offset_std[i]
        np.testing.assert_allclose(expected, d, atol=1e-6)


def test_definition_error_of_one_frame_is_extra_variance(sfm, face):
    # alone, a frame cannot tell the shared offset from per-frame error: the two are one variance
    lm = synth(sfm, yaw=25, identity=face[0])[0] + np.random.default_rng(1).normal(0, 2, (68, 2))
    a = fit_landmarks(sfm, lm, (512, 512), definition_std_mm=4.0, model_std_mm=1.5)
    b = fit_landmarks(sfm, lm, (512, 512), definition_std_mm=0.0, model_std_mm=np.hypot(4.0, 1.5))
    np.testing.assert_allclose(a.identity, b.identity, atol=1e-8)
    with pytest.raises(InputError, match="definition_std_mm"):
        fit_landmarks(sfm, lm, (512, 512), definition_std_mm=-1.0)


def test_model_std_per_frame(sfm, face):
    # one value per frame: the same fit as the number when they agree; a detector's larger
    # error (DETECTED_MODEL_STD_MM) leaves the identity nearer the mean
    from morphable.fitting.noise import DETECTED_MODEL_STD_MM

    rng = np.random.default_rng(2)
    lm = np.stack([synth(sfm, yaw=y, identity=face[0])[0] for y in (-20, 5, 25)])
    lm = lm + rng.normal(0, 1, lm.shape)
    a = fit_landmarks(sfm, lm, (512, 512), model_std_mm=2.0)
    b = fit_landmarks(sfm, lm, (512, 512), model_std_mm=[2.0, 2.0, 2.0])
    np.testing.assert_allclose(a.identity, b.identity, atol=1e-8)
    c = fit_landmarks(sfm, lm, (512, 512), model_std_mm=[2.0, DETECTED_MODEL_STD_MM, 2.0])
    d = fit_landmarks(sfm, lm, (512, 512), model_std_mm=DETECTED_MODEL_STD_MM)
    norms = [np.linalg.norm(r.identity) for r in (a, c, d)]
    assert norms[0] > norms[1] > norms[2] > 0
    with pytest.raises(InputError, match="one per frame"):
        fit_landmarks(sfm, lm, (512, 512), model_std_mm=[1.0, 2.0])
    with pytest.raises(InputError, match="model_std_mm"):
        fit_landmarks(sfm, lm, (512, 512), model_std_mm=[1.0, -2.0, 1.0])


def test_definition_std_per_landmark(sfm, face):
    lm = synth(sfm, yaw=25, identity=face[0])[0]
    a = fit_landmarks(sfm, lm, (512, 512), definition_std_mm=3.0)
    b = fit_landmarks(sfm, lm, (512, 512), definition_std_mm=np.full(68, 3.0))
    np.testing.assert_allclose(a.identity, b.identity)
    loose = np.full(68, 3.0)
    loose[17:27] = 30.0              # eyebrows no longer pull the fit
    c = fit_landmarks(sfm, lm, (512, 512), definition_std_mm=loose)
    r = c.fitted_landmarks[0] - c.landmarks[0]
    r0 = a.fitted_landmarks[0] - a.landmarks[0]
    assert np.abs(r[17:27]).mean() > np.abs(r0[17:27]).mean()
    with pytest.raises(InputError, match="definition_std_mm"):
        fit_landmarks(sfm, lm, (512, 512), definition_std_mm=np.ones(5))


@pytest.mark.parametrize("sigma", [1.0, 3.0])
def test_auto_landmark_noise_is_estimated(sfm, sigma):
    rng = np.random.default_rng(5)
    alpha = rng.standard_normal(sfm.n_identity)
    frames = np.stack([synth(sfm, yaw=y, pitch=p, identity=alpha)[0]
                       for y, p in ((-30, 5), (-10, -5), (0, 10), (15, 0), (35, -8))])
    frames = frames + rng.normal(0.0, sigma, frames.shape)
    res = fit_landmarks(sfm, frames, (512, 512), landmark_std_px="auto", definition_std_mm=0.0,
                        model_std_mm=0.1)
    assert res.landmark_std_px.shape == (5,)
    assert abs(res.landmark_std_px[0] - sigma) < 0.2 * sigma, res.landmark_std_px
    # independent frames: one estimate per frame
    each = fit_landmarks(sfm, frames, (512, 512), landmark_std_px="auto", shared_identity=False,
                         definition_std_mm=0.0, model_std_mm=0.1)
    assert np.all(np.abs(each.landmark_std_px - sigma) < 0.35 * sigma), each.landmark_std_px
    with pytest.raises(InputError, match="landmark_std_px"):
        fit_landmarks(sfm, frames, (512, 512), landmark_std_px="guess")


def test_ict_model(ict):
    rng = np.random.default_rng(0)
    alpha = rng.standard_normal(20)
    lms, _, verts = synth(ict, yaw=25, identity=alpha)
    res = fit_landmarks(ict, lms, (512, 512), n_identity=40)
    assert res.landmark_rmse_px[0] < 2.0
    np.testing.assert_allclose(res.euler_deg[0, 0], 25, atol=5)
    assert res.vertices(0).shape == (ict.n_vertices, 3)


def test_expression_prior_scales_with_the_number_of_blendshapes(ict, sfm):
    """53 blendshapes share an expression the SFM splits into 6: each weight gets 53 / 6 of
    the prior. A neutral ICT face then keeps its shape in the identity, not in blendshapes."""
    from morphable.fitting.noise import expression_precision

    assert expression_precision(sfm) == 1.0
    assert expression_precision(ict) == pytest.approx(53 / 6)
    rng = np.random.default_rng(5)
    alpha = rng.standard_normal(ict.n_identity)
    lms = np.stack([synth(ict, yaw=y, identity=alpha)[0] for y in (-20, 0, 20)])
    lms += rng.normal(0.0, 1.0, lms.shape)
    face = ict.segments["narrow_face"]
    err, energy = [], []
    for w in (1.0, 1.0 / expression_precision(ict)):     # now, and the SFM's weight per shape
        res = fit_landmarks(ict, lms, (512, 512), expression_weight=w)
        err.append(aligned_error(res.neutral_vertices()[face], ict.vertices(alpha)[face]))
        energy.append((res.expression ** 2).sum(1).mean())
    assert energy[0] < energy[1] / 3 and err[0] < err[1], (err, energy)


# --- landmark schemes ---------------------------------------------------------------------
def custom_scheme(model, name, vertices, barycentric, right=(), left=(), chin=-1, ibug68=None,
                  definition_std_mm=1.0):
    L = len(vertices)
    return LandmarkScheme(
        name=name, model_name=model.name, vertices=np.asarray(vertices, np.int64),
        barycentric=np.asarray(barycentric, np.float64), outline_right=np.asarray(right, np.int64),
        outline_left=np.asarray(left, np.int64), chin=chin,
        definition_std_mm=np.full(L, definition_std_mm), mirror=np.arange(L),
        ibug68=np.full(68, -1) if ibug68 is None else np.asarray(ibug68, np.int64))


def oval_scheme(model, per_side=10):
    """iBUG's 51 inner points, then ``per_side`` outline points a side (no vertex: they slide,
    top to chin) and the chin."""
    ibug = ibug68_scheme(model)
    inner = np.arange(17, 68)
    J = 2 * per_side
    vertices = np.r_[ibug.vertices[inner], np.full((J, 3), -1), ibug.vertices[[8]]]
    bary = np.r_[ibug.barycentric[inner], np.tile([1.0, 0, 0], (J + 1, 1))]
    ibug68 = np.full(68, -1)
    ibug68[inner] = np.arange(51)
    return custom_scheme(model, "oval", vertices, bary, 51 + np.arange(per_side),
                         51 + per_side + np.arange(per_side), 51 + J, ibug68)


def surface_scheme(model, n=478, seed=0):
    """iBUG's 17 jaw points (sliding, the chin fixed) and its outer eye corners, then random
    points on forward-facing triangles of the face inside the inner landmarks' box: ``n`` in all."""
    from morphable.normals import vertex_normals

    ibug = ibug68_scheme(model)
    keep = np.r_[0:17, 36, 45]
    mean = model.mean.astype(float)
    ids = model.landmark_ids[17:][model.landmark_ids[17:] >= 0]
    lo, hi = mean[ids, :2].min(0) - 5.0, mean[ids, :2].max(0) + 5.0
    tri = np.asarray(model.triangles)
    c = mean[tri].mean(1)
    nz = vertex_normals(mean, model.triangles)[tri].mean(1)[:, 2]
    ok = np.flatnonzero(((c[:, :2] > lo) & (c[:, :2] < hi)).all(1) & (nz > 0.3))
    rng = np.random.default_rng(seed)
    m = n - len(keep)
    pick = rng.choice(ok, m, replace=False)
    vertices = np.r_[ibug.vertices[keep], tri[pick]]
    bary = np.r_[ibug.barycentric[keep], rng.dirichlet(np.ones(3), m)]
    ibug68 = np.full(68, -1)
    ibug68[keep] = np.arange(len(keep))
    return custom_scheme(model, "surface", vertices, bary, ibug.outline_right, ibug.outline_left,
                         8, ibug68)


def test_surface_points_get_rows_combined_from_their_triangle(sfm):
    # the fit evaluates the landmark rows only: a surface point's row is its triangle's rows
    # combined, for the mean, identity and expression alike
    from morphable.fitting import landmark_bank

    scheme = surface_scheme(sfm)
    bank = landmark_bank(sfm, scheme)
    rows = bank.fixed_row[scheme.defined]
    alpha = np.random.default_rng(1).standard_normal(sfm.n_identity)
    beta = np.linspace(0.0, 1.0, sfm.n_expression)
    X = bank.mean[rows] + bank.identity[rows] @ alpha + bank.expression[rows] @ beta
    np.testing.assert_allclose(X, scheme.points(sfm.vertices(alpha, beta))[scheme.defined], atol=1e-9)
    assert landmark_bank(sfm, scheme) is bank                        # built once per scheme


def test_dense_surface_points_recover_the_face_better_than_68(sfm):
    """478 surface points, 1 px noise, fit the same faces better than iBUG's 68 points (the
    same outline rule for both, the same definition error)."""
    dense = surface_scheme(sfm)
    rng = np.random.default_rng(7)
    err, pose = {"68": [], "478": []}, {"68": [], "478": []}
    for yaw in (-40, -15, 10, 35):
        alpha = rng.standard_normal(sfm.n_identity)
        cam = Camera.looking_at_face(image_size=(512, 512), yaw=yaw, pitch=rng.uniform(-10, 10))
        verts = sfm.vertices(alpha)
        for key, scheme in (("68", None), ("478", dense)):
            lm = simulate_landmarks(sfm, cam, vertices=verts, scheme=scheme)
            res = fit_landmarks(sfm, lm + rng.normal(0.0, 1.0, lm.shape), (512, 512),
                                scheme=scheme, definition_std_mm=1.0)
            err[key].append(aligned_error(res.vertices(0), verts))
            pose[key].append(np.abs(res.euler_deg[0] - cam.euler_deg).max())
    e68, e478 = np.mean(err["68"]), np.mean(err["478"])
    assert e478 < 0.8 * e68, (err, pose)
    assert np.mean(pose["478"]) < np.mean(pose["68"]) + 1.0, pose


@pytest.mark.parametrize("frames", [1, 2])
def test_landmark_order_does_not_matter(sfm, face, frames):
    # outline points scattered among the others (as the face mesh's oval is) slide as indices,
    # not a slice: the same fit as in iBUG's order, one frame (the Gram shortcut) or two
    # (the definition offsets)
    import morphable.fitting.problem as problem

    scheme = surface_scheme(sfm, n=150)
    perm = np.random.default_rng(4).permutation(scheme.n)
    inv = np.argsort(perm)
    shuffled = custom_scheme(sfm, "shuffled", scheme.vertices[perm], scheme.barycentric[perm],
                             inv[scheme.outline_right], inv[scheme.outline_left],
                             int(inv[scheme.chin]), np.where(scheme.ibug68 >= 0, inv[scheme.ibug68], -1))
    lm = np.stack([simulate_landmarks(sfm, Camera.looking_at_face(image_size=(512, 512), yaw=y),
                                      vertices=sfm.vertices(face[0]), scheme=scheme)
                   for y in (35, -20)[:frames]])
    lm += np.random.default_rng(0).normal(0.0, 1.0, lm.shape)
    a = fit_landmarks(sfm, lm, (512, 512), scheme=scheme)
    b = fit_landmarks(sfm, lm[:, perm], (512, 512), scheme=shuffled)
    assert isinstance(problem.Problem(sfm, landmark_bank(sfm, shuffled), FitOptions(), lm[:, perm],
                                      np.ones(lm.shape[:2], bool),
                                      np.full((frames, 2), 512.0)).sliding, np.ndarray)
    np.testing.assert_allclose(b.identity, a.identity, atol=1e-7)
    np.testing.assert_allclose(b.fitted_landmarks, a.fitted_landmarks[:, perm], atol=1e-6)


def test_scheme_fit_with_missing_points_and_mask(sfm, face):
    scheme = surface_scheme(sfm)
    cam = Camera.looking_at_face(image_size=(512, 512), yaw=25)
    lm = simulate_landmarks(sfm, cam, vertices=sfm.vertices(face[0]), scheme=scheme)
    gone = np.zeros(scheme.n, bool)
    gone[np.random.default_rng(2).choice(np.arange(19, scheme.n), 150, replace=False)] = True
    holes = lm.copy()
    holes[gone] = np.nan
    a = fit_landmarks(sfm, holes, (512, 512), scheme=scheme)
    b = fit_landmarks(sfm, lm, (512, 512), scheme=scheme, mask=~gone)
    np.testing.assert_allclose(a.identity, b.identity)
    assert a.fitted_landmarks.shape == (1, scheme.n, 2) and a.landmark_vertices.shape == (1, scheme.n)
    assert np.isnan(a.fitted_landmarks[0, gone]).all() and (a.landmark_vertices[0, gone] == -1).all()
    assert np.isfinite(a.fitted_landmarks[0, ~gone & scheme.defined]).all()
    assert a.landmark_rmse_px[0] < 1.0
    assert abs(a.euler_deg[0, 0] - 25) < 2.0


def dense_offset_rows(pb, scale):
    """(N, 3, L, 3M) the offsets' columns written out: landmark ``offset_landmarks[i]`` moves
    along coordinate a by ``scale * offset_std[i]`` per unit of coefficient ``3 i + a``
    (``scale`` (N,) or a number)."""
    lms = pb.offset_landmarks
    O = np.zeros((pb.N, 3, pb.y.shape[1], pb.D))
    for a in range(3):
        O[:, a, lms, 3 * np.arange(len(lms)) + a] = np.multiply.outer(
            np.broadcast_to(scale, (pb.N,)), pb.offset_std)
    return O


@pytest.mark.parametrize("model_name, settings", [
    ("sfm", {}), ("sfm", {"landmark_std_px": "auto"}), ("sfm", {"robust": "huber"}),
    ("sfm", {"camera": "perspective"}), ("ict", {"landmark_std_px": "auto"})])
def test_offsets_solved_by_structure_equal_the_dense_fit(sfm, ict, model_name, settings,
                                                          monkeypatch):
    # the offsets' columns are never materialised and their block is eliminated first: the
    # fit must be the one of the plain dense system (the offsets' columns written out, the
    # shared block solved by its Schur complement), here on 40 surface points and 3 frames
    # (SFM: the offsets eliminated first; ICT's 53 blendshapes: the frames)
    from morphable.fitting import linear_stage, nonlinear
    from morphable.fitting.linear import gram_hessian, solve_identity
    from morphable.fitting.rows import face_size, shared_rows

    model = {"sfm": sfm, "ict": ict}[model_name]
    scheme = surface_scheme(model, n=40, seed=3)
    rng = np.random.default_rng(4)
    alpha = rng.standard_normal(model.n_identity) * 0.7
    kind = settings.get("camera", "affine")
    cams = [Camera.looking_at_face(kind=kind, image_size=(512, 512), yaw=y) for y in (-25, 5, 30)]
    verts = model.vertices(alpha)
    lms = np.stack([simulate_landmarks(model, c, vertices=verts, scheme=scheme) for c in cams])
    lms += rng.normal(0.0, 1.0, lms.shape)
    kw = dict(scheme=scheme, definition_std_mm=2.0, **settings)
    if kind == "perspective":
        kw["focal_px"] = cams[0].focal
    fast = fit_landmarks(model, lms, (512, 512), **kw)

    def dense_rows(pb, st):
        O = dense_offset_rows(pb, face_size(pb, st.alpha))
        return np.concatenate([shared_rows(pb, st), O], -1)

    def dense_identity(pb, P, target, W, A):
        A = np.concatenate([A, dense_offset_rows(pb, 1.0)], -1)
        return solve_identity(P, target, W, A, pb.prior, True)

    monkeypatch.setattr(nonlinear, "shared_rows", dense_rows)
    monkeypatch.setattr(nonlinear, "offset_normal", lambda *args: None)
    monkeypatch.setattr(nonlinear, "gram_hessian",
                        lambda P, W, Q, gram, shift: gram_hessian(P, W, Q, None))
    monkeypatch.setattr(linear_stage, "solve_identity_offsets", dense_identity)
    slow = fit_landmarks(model, lms, (512, 512), **kw)
    assert fast.iterations == slow.iterations
    for i in range(3):
        np.testing.assert_allclose(fast.vertices(i), slow.vertices(i), rtol=0, atol=1e-6)
    np.testing.assert_allclose(fast.landmark_std_px, slow.landmark_std_px, rtol=1e-9)
    np.testing.assert_allclose(fast.landmark_rmse_px, slow.landmark_rmse_px, rtol=1e-9)


def test_landmark_count_must_match_the_scheme(sfm, ict):
    from morphable.fitting.schemes import scheme_path

    lm68 = synth(sfm, yaw=10)[0]
    with pytest.raises(InputError, match="5 points"):
        fit_landmarks(sfm, np.zeros((5, 2)), (512, 512))
    with pytest.raises(InputError, match="68 points for the 478-point scheme"):
        fit_landmarks(sfm, lm68, (512, 512), scheme=surface_scheme(sfm))
    with pytest.raises(InputError, match="made for model 'ict'"):
        fit_landmarks(sfm, lm68[:68], (512, 512), scheme=ibug68_scheme(ict))
    with pytest.raises(InputError, match="expected a number or 478 numbers"):
        fit_landmarks(sfm, np.zeros((478, 2)), (512, 512), scheme=surface_scheme(sfm),
                      definition_std_mm=np.ones(68))
    with pytest.raises(InputError, match=r"mask: expected \(478,\)"):
        fit_landmarks(sfm, np.zeros((478, 2)), (512, 512), scheme=surface_scheme(sfm),
                      mask=np.ones(68, bool))
    if not scheme_path(sfm, "facemesh478").is_file():
        # 478 points mean the face mesh: without the model's sidecar, one line says so
        with pytest.raises(InputError, match="no facemesh478 landmark scheme"):
            fit_landmarks(sfm, np.zeros((478, 2)), (512, 512))


@pytest.mark.parametrize("camera", ["affine", "perspective"])
def test_landmarks_68_of_any_fit(sfm, face, camera):
    """A fit's projected iBUG-68 landmarks: where fixed, the 68-point fit's own projected
    landmarks; for a fit of other points, near the face's true iBUG-68 points."""
    cam = Camera.looking_at_face(image_size=(512, 512), yaw=30, kind=camera)
    verts = sfm.vertices(face[0])
    truth = simulate_landmarks(sfm, cam, vertices=verts)
    focal = cam.focal if camera == "perspective" else None
    res = fit_landmarks(sfm, truth, (512, 512), camera=camera, focal_px=focal)
    lm68 = res.landmarks_68_px()
    fixed = np.isfinite(res.fitted_landmarks[0, :, 0])
    fixed[:17] = False
    fixed[8] = True                                                   # the chin is fixed
    np.testing.assert_allclose(lm68[0, fixed], res.fitted_landmarks[0, fixed], atol=1e-6)
    assert np.isfinite(lm68[0, :17]).all() and np.isnan(lm68[0, [60, 64]]).all()   # SFM: none
    dense = fit_landmarks(sfm, simulate_landmarks(sfm, cam, vertices=verts, scheme=surface_scheme(sfm)),
                          (512, 512), scheme=surface_scheme(sfm), camera=camera, focal_px=focal)
    d = np.linalg.norm(dense.landmarks_68_px()[0] - truth, axis=1)
    assert np.nanmedian(d[17:]) < 2.0 and np.nanmedian(d[:17]) < 5.0, d
    frame = res.to_dict()["frames"][0]
    assert len(frame["landmarks_68_px"]) == 68 and frame["landmarks_68_px"][60] is None
    np.testing.assert_allclose(frame["landmarks_68_px"][30], lm68[0, 30])


@pytest.mark.parametrize("kind", ["ibug68", "oval"])
def test_outline_points_count_only_across_the_outline(sfm, face, kind):
    # a detector puts outline points (iBUG's jaw, a custom scheme's oval) on the face's
    # outline, at heights of its own: sliding them along the outline changes little, moving
    # them across it does
    from morphable.fitting import landmark_bank
    from morphable.fitting.correspondences import outline_points

    scheme = ibug68_scheme(sfm) if kind == "ibug68" else oval_scheme(sfm)
    cam = Camera.looking_at_face(image_size=(512, 512), yaw=40)
    verts = sfm.vertices(face[0])
    lm = simulate_landmarks(sfm, cam, vertices=verts, scheme=scheme)
    bank = landmark_bank(sfm, scheme)
    assert sorted(j for lms, _ in bank.polylines for j in lms) == sorted(
        np.r_[scheme.outline_right, scheme.outline_left].tolist())
    along, across = lm.copy(), lm.copy()
    a, b, w = (x[0] for x in outline_points(bank, cam.rotation[None, 2]))
    ends = np.cumsum([0] + [len(o) for o in bank.outlines])
    for (lms, _), lo, hi in zip(bank.polylines, ends[:-1], ends[1:]):
        sel = slice(lo, hi)                             # this side's outline lines
        X = (1 - w[sel, None]) * verts[bank.vertex_ids[a[sel]]] + w[sel, None] * verts[bank.vertex_ids[b[sel]]]
        uv = cam.project(X)                             # the outline, top to chin
        for j, k in zip(lms, np.linspace(2, len(uv) - 3, len(lms)).astype(int)):
            t = uv[k + 1] - uv[k - 1]
            if np.linalg.norm(t) < 1e-6:
                continue                                # no direction where lines coincide
            t /= np.linalg.norm(t)
            lm[j] = along[j] = across[j] = uv[k]
            along[j] += 4.0 * t
            across[j] += 4.0 * np.array([-t[1], t[0]])
    fits = {k: fit_landmarks(sfm, v, (512, 512), scheme=scheme, n_expression=0) for k, v in
            (("base", lm), ("along", along), ("across", across))}
    d = {k: np.abs(fits[k].vertices(0) - fits["base"].vertices(0)).max() for k in ("along", "across")}
    assert d["along"] < 0.35 * d["across"], d


# --- stability ---------------------------------------------------------------------------
@pytest.mark.parametrize("yaw,pitch,roll", [(90, 0, 0), (-90, 0, 0), (0, 60, 0), (0, -60, 0),
                                            (10, 0, 180), (0, 0, -150)])
def test_extreme_poses_give_finite_fits(sfm, face, yaw, pitch, roll):
    alpha, beta = face
    lms, cam, verts = synth(sfm, yaw=yaw, pitch=pitch, roll=roll, identity=alpha, expression=beta)
    if abs(yaw) == 90:
        # profile: the landmarks of the hidden half are unusable
        hidden = (cam.rotation @ np.array([1.0, 0, 0]))[2] * np.sign(yaw)
        side = np.array([sfm.mean[i, 0] if i >= 0 else 0 for i in sfm.landmark_ids])
        lms[(side * np.sign(yaw) > 5) | (np.arange(68) >= 9) & (np.arange(68) < 17) * (yaw > 0)
            | (np.arange(68) < 8) * (yaw < 0)] = np.nan
        assert hidden != 0
    res = fit_landmarks(sfm, lms, (512, 512))
    assert np.isfinite(res.vertices(0)).all() and np.isfinite(res.landmark_rmse_px).all()
    assert res.landmark_rmse_px[0] < 8
    R_err = np.degrees(np.arccos(np.clip((np.trace(res.cameras[0].rotation.T @ cam.rotation) - 1) / 2, -1, 1)))
    assert R_err < 8


def test_extreme_expression(sfm):
    lms, _, _ = synth(sfm, yaw=20, expression=np.full(sfm.n_expression, 1.5))
    res = fit_landmarks(sfm, lms, (512, 512))
    assert np.isfinite(res.vertices(0)).all() and res.landmark_rmse_px[0] < 10
    assert res.expression.mean() > 0.5      # the prior shrinks, but the expression is found


@pytest.mark.parametrize("size,face_px", [((100000, 100000), 40000), ((64, 64), 20)])
def test_huge_and_tiny_images(sfm, face, size, face_px):
    alpha, _ = face
    lms, cam, _ = synth(sfm, yaw=20, identity=alpha, size=size, face_px=face_px)
    res = fit_landmarks(sfm, lms, size)
    assert np.isfinite(res.vertices(0)).all()
    assert res.landmark_rmse_px[0] < 0.01 * face_px + 0.5
    np.testing.assert_allclose(res.cameras[0].scale, cam.scale, rtol=0.1)


def test_float32_input_and_output(sfm, face):
    alpha, _ = face
    lms, _, _ = synth(sfm, yaw=20, identity=alpha)
    r64 = fit_landmarks(sfm, lms, (512, 512))
    r32 = fit_landmarks(sfm, lms.astype(np.float32), (512, 512), dtype=np.float32)
    assert r32.vertices(0).dtype == np.float32
    np.testing.assert_allclose(r32.vertices(0), r64.vertices(0), atol=0.05)


def test_prior_weight_zero_stays_finite(sfm, face):
    alpha, _ = face
    lms, _, _ = synth(sfm, yaw=20, identity=alpha)
    lms = lms + np.random.default_rng(0).normal(size=lms.shape)
    res = fit_landmarks(sfm, lms, (512, 512), prior_weight=0.0, expression_weight=0.0)
    assert np.isfinite(res.identity).all() and np.isfinite(res.vertices(0)).all()


def test_robust_loss_resists_an_outlier(sfm, face):
    alpha, _ = face
    lms, cam, verts = synth(sfm, yaw=20, identity=alpha)
    bad = lms.copy()
    bad[30] += [120.0, -80.0]       # nose tip far off
    plain = fit_landmarks(sfm, bad, (512, 512))
    robust = fit_landmarks(sfm, bad, (512, 512), robust="huber")
    assert aligned_error(robust.vertices(0), verts) < aligned_error(plain.vertices(0), verts)


@pytest.mark.parametrize("case", ["one", "collinear", "coincident", "all_nan"])
def test_degenerate_landmarks_raise_fit_error(sfm, case):
    lms = np.full((68, 2), np.nan)
    if case == "one":
        lms[30] = [100, 100]
    elif case == "collinear":
        lms[17:] = np.stack([np.linspace(100, 400, 51), np.linspace(100, 400, 51) * 0.5 + 1e-9], -1)
    elif case == "coincident":
        lms[17:] = [200.0, 200.0]
    with pytest.raises(FitError):
        fit_landmarks(sfm, lms, (512, 512))


@pytest.mark.parametrize("kwargs,landmarks", [
    (dict(camera="fisheye"), None), (dict(prior_weight=-1), None), (dict(robust="cauchy"), None),
    (dict(n_identity=1000), None), ({}, np.zeros((5, 2))), ({}, np.full((68, 2), np.inf)),
    (dict(image_size=(0, 512)), None)])
def test_bad_arguments_raise_input_error(sfm, kwargs, landmarks):
    lms = synth(sfm, yaw=10)[0] if landmarks is None else landmarks
    size = kwargs.pop("image_size", (512, 512))
    with pytest.raises(InputError):
        fit_landmarks(sfm, lms, size, **kwargs)


# --- command line --------------------------------------------------------------------------
def test_cli_fit_writes_mesh_and_report(tmp_path, data_dir, sfm):
    from morphable.cli import main

    img = data_dir / "images" / "image_0010.png"
    pts = data_dir / "images" / "image_0010.pts"
    mesh, report = tmp_path / "fit.obj", tmp_path / "fit.json"
    assert main(["fit", str(img), "--landmarks", str(pts), "--out-mesh", str(mesh),
                 "--report", str(report)]) == 0
    rep = json.loads(report.read_text())
    frame = rep["frames"][0]
    assert rep["model"] == "sfm" and 0 < frame["landmark_rmse_px"] < 10
    assert -40 < frame["yaw_deg"] < -10 and "scale" in frame and len(rep["identity"]) == 63
    assert set(frame["expression"]) == {"anger", "disgust", "fear", "happiness", "sadness", "surprise"}
    assert frame["landmark_std_px"] == 1.0
    # the mesh read back is the face of the report's identity and expression (with UVs)
    from mesh_check import assert_mesh_holds, report_vertices

    assert_mesh_holds(mesh, report_vertices(rep, sfm), sfm.triangles)
    assert "\nvt " in mesh.read_text()
    # the landmark noise estimated from the fit, in the report
    assert main(["fit", str(img), "--landmarks", str(pts), "--report", str(report),
                 "--landmark-std", "auto"]) == 0
    assert 0 < json.loads(report.read_text())["frames"][0]["landmark_std_px"] < 10


def test_fit_settings_have_one_name_in_the_api_cli_and_batch_options(tmp_path, data_dir, sfm):
    """``--n-iterations``, ``--robust huber`` and ``--focal-px`` are the keywords
    ``n_iterations``, ``robust`` and ``focal_px`` of the fit, of ``fit_images`` and of a
    fit-batch item's options, and give the same fit."""
    from morphable.batch import BatchItem
    from morphable.cli import main
    from morphable.pipeline import fit_images, fit_item

    img = data_dir / "images" / "image_0010.png"
    pts = data_dir / "images" / "image_0010.pts"
    settings = dict(camera="perspective", focal_px=900.0, n_iterations=1, robust="huber")
    report = tmp_path / "fit.json"
    assert main(["fit", str(img), "--landmarks", str(pts), "--report", str(report),
                 "--camera", "perspective", "--focal-px", "900", "--n-iterations", "1",
                 "--robust", "huber"]) == 0
    cli = json.loads(report.read_text())
    api = fit_images([img], [pts], model=sfm, **settings).fit
    folder = tmp_path / "item"
    folder.mkdir()
    fit_item(BatchItem("a", [str(img)], [str(pts)]), folder, {"model": "sfm", **settings})
    batch = json.loads((folder / "fit.json").read_text())
    for rep in (cli, batch):
        assert rep["iterations"] == api.iterations == 1
        assert rep["frames"][0]["focal_px"] == 900.0
        np.testing.assert_allclose(rep["identity"], api.identity, atol=1e-9)
    plain = fit_images([img], [pts], model=sfm, **{**settings, "robust": None}).fit
    assert not np.allclose(plain.identity, api.identity)  # robust="huber" took effect
    with pytest.raises(InputError, match="robust"):
        fit_images([img], [pts], model=sfm, robust=True)


def test_cli_fit_bad_input_writes_nothing(tmp_path, data_dir, capsys):
    from morphable.cli import main

    img = data_dir / "images" / "image_0010.png"
    bad_pts = tmp_path / "bad.pts"
    bad_pts.write_text("version: 1\nn_points: 2\n{\n1 2\n3 4\n}\n")
    out = tmp_path / "fit.obj"
    assert main(["fit", str(img), "--landmarks", str(bad_pts), "--out-mesh", str(out)]) == 2
    err = capsys.readouterr().err
    assert "bad.pts" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert main(["fit", str(tmp_path / "missing.png"), "--landmarks", str(bad_pts)]) == 2
    assert "missing.png" in capsys.readouterr().err
    assert not out.exists() and list(tmp_path.iterdir()) == [bad_pts]


def test_cli_fit_several_images(tmp_path, data_dir):
    from morphable.cli import main

    imgs = [data_dir / "images" / n for n in ("image_0010.png", "takeo.ppm")]
    pts = [p.with_suffix(".pts") for p in imgs]
    report = tmp_path / "fit.json"
    args = ["fit", *map(str, imgs), "--landmarks", *map(str, pts), "--report", str(report)]
    assert main(args + ["--camera", "perspective"]) == 0
    rep = json.loads(report.read_text())
    assert rep["n_frames"] == 2 and rep["shared_identity"]
    assert [f["image_size"] for f in rep["frames"]] == [[1280, 1024], list(_size(imgs[1]))]
    assert all("focal_px" in f for f in rep["frames"])
    assert main(args + ["--independent"]) == 0
    rep = json.loads(report.read_text())
    assert not rep["shared_identity"] and all(len(f["identity"]) == 63 for f in rep["frames"])
    assert main(["fit", *map(str, imgs), "--landmarks", str(pts[0])]) == 2   # one file, two images


def _size(path):
    from PIL import Image

    with Image.open(path) as im:
        return im.size


@pytest.mark.parametrize("model_name", ["sfm", "ict"])
def test_gram_shortcut_equals_the_plain_hessian(request, monkeypatch, model_name):
    # one Gram block per group of fixed landmarks of one definition error (the face mesh's
    # 478 calibrated points: a dozen values), the same Hessian as the plain product
    import morphable.fitting.problem as problem
    from morphable.fitting.schemes import load_scheme

    model = request.getfixturevalue(model_name)
    rng = np.random.default_rng(5)
    scheme = load_scheme(model)
    verts = model.vertices(rng.standard_normal(10))
    lms = np.stack([simulate_landmarks(model, Camera.looking_at_face(image_size=(512, 512), yaw=y),
                                       vertices=verts, scheme=scheme) for y in (-35, 10, 50)])
    lms += rng.normal(0.0, 1.0, lms.shape)
    gram = problem.fixed_gram
    used = []
    monkeypatch.setattr(problem, "fixed_gram", lambda *args: used.append(gram(*args)) or used[-1])
    missing = lms.copy()
    missing[1, 40] = np.nan          # a missing fixed landmark: that batch takes the plain path
    cases = [(x, s) for x in (lms, missing) for s in (True, False)]
    fast = [fit_landmarks(model, x, (512, 512), shared_identity=s, n_identity=30) for x, s in cases]
    # alone, a frame's landmarks carry their definition error: one group per value; shared,
    # the offsets carry it: one group
    assert all(g is not None for g in used)
    fixed = ~scheme.sliding & scheme.defined
    n_values = len(np.unique(scheme.definition_std_mm[fixed]))
    assert n_values > 2 and sorted({len(g[2]) for g in used}) == [1, n_values]
    monkeypatch.setattr(problem, "fixed_gram", lambda bank, K, jaw, std: None)
    plain = [fit_landmarks(model, x, (512, 512), shared_identity=s, n_identity=30) for x, s in cases]
    for f, p in zip(fast, plain):
        np.testing.assert_allclose(f.frame_identity, p.frame_identity, atol=1e-8)
        np.testing.assert_allclose(f.expression, p.expression, atol=1e-8)


def test_fit_without_jaw_points_never_computes_the_outline(sfm, monkeypatch):
    """51-point annotations (the jaw missing) have nothing to slide: the outline is never
    built, and the fit still recovers the pose."""
    from morphable.fitting import sliding

    cam = Camera.looking_at_face(image_size=(512, 512), yaw=30, pitch=-10)
    full = simulate_landmarks(sfm, cam)
    lms = full.copy()
    lms[:17] = np.nan

    def no_outline(*args, **kwargs):
        raise AssertionError("outline computed without jaw points")

    monkeypatch.setattr(sliding, "outline_points", no_outline)
    res = fit_landmarks(sfm, lms, (512, 512))
    assert res.landmark_rmse_px[0] < 0.5
    assert abs(res.euler_deg[0, 0] - 30) < 1.0
    with pytest.raises(AssertionError, match="outline computed"):
        fit_landmarks(sfm, full, (512, 512))


@pytest.mark.parametrize("n_expression", [0, None])
def test_a_fit_without_identity_modes_still_slides_the_jaw(sfm, n_expression):
    # n_identity=0: the mean face's shape (and its expressions), posed; the jaw still slides
    cam = Camera.looking_at_face(image_size=(512, 512), yaw=30)
    lm = simulate_landmarks(sfm, cam)
    res = fit_landmarks(sfm, lm, (512, 512), n_identity=0, n_expression=n_expression)
    assert res.landmark_rmse_px[0] < 0.5
    assert abs(res.euler_deg[0, 0] - 30) < 1.0
    assert np.isfinite(res.vertices(0)).all()


def test_fit_options_carry_the_defaults_of_fit_landmarks():
    # fit_landmarks' keyword arguments build FitOptions: one set of settings, the same defaults
    import dataclasses
    import inspect

    from morphable.fitting.options import FitOptions

    params = inspect.signature(fit_landmarks).parameters
    fields = {f.name: f for f in dataclasses.fields(FitOptions)}
    assert set(fields) == {n for n, p in params.items()
                           if p.kind is p.KEYWORD_ONLY} - {"mask", "scheme"}
    for name, f in fields.items():
        default = f.default_factory() if f.default is dataclasses.MISSING else f.default
        assert np.array_equal(default, params[name].default), name
    with pytest.raises(InputError, match="focal_px"):
        FitOptions(focal_px=[500.0, -1.0])
    with pytest.raises(dataclasses.FrozenInstanceError):
        FitOptions().camera = "perspective"


def test_outline_points_follow_each_models_mean_shape(sfm):
    # the march lines depend on a model's mean shape alone and are made once per model: a
    # tracked identity baked into the mean (morphable.tracking) gets its own, not SFM's
    import dataclasses

    from morphable.camera import Camera
    from morphable.tracking import fixed_identity_model

    cam = Camera.looking_at_face(image_size=(512, 512), yaw=40.0)
    identity = np.zeros(sfm.n_identity)
    identity[:3] = 3.0
    fixed = fixed_identity_model(sfm, identity)
    simulate_landmarks(sfm, cam, vertices=fixed.mean)          # SFM's lines made first
    first = simulate_landmarks(fixed, cam)
    again = simulate_landmarks(fixed, cam)                     # from the model's cache
    fresh = simulate_landmarks(dataclasses.replace(fixed), cam)  # another model: made anew
    np.testing.assert_array_equal(first, again)
    np.testing.assert_array_equal(first, fresh)
    sfm_lines = simulate_landmarks(sfm, cam, vertices=fixed.mean)
    assert np.nanmax(np.abs(first - sfm_lines)) > 0.5          # the lines did differ
