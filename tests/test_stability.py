"""Numerical stability, property-based (hypothesis): fitting at random poses (profiles,
upside-down), identities with coefficients up to ±4σ, expression extremes, landmark dropout
up to 60% and noise; normals and baking on random meshes with degenerate triangles; ICP
recovering random rigid transforms of a scan.

Example counts are small so that the file runs in well under a minute on two busy cores;
``derandomize=True`` makes every run test the same examples (a failure reproduces).

Known limitation, not tested here: identities far outside the prior (every coefficient drawn
with a standard deviation of 4) combined with steep pitch (> 50°) can end in a wrong pose
(landmark RMSE of tens of pixels on a 200 px face); see the report of issue 9.
"""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from morphable.camera import Camera, euler_to_matrix
from morphable.errors import InputError

SETTINGS = dict(deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])

SIZE = 400
FACE_PX = SIZE / 2  # Camera.looking_at_face: 150 mm of face span half the image


# --- fitting -------------------------------------------------------------------------------
@st.composite
def scenes(draw):
    """A random face, pose, camera, noise and dropout -> (landmarks, clean landmarks, scene)."""
    seed = draw(st.integers(0, 2**32 - 1))
    scene = dict(
        yaw=draw(st.floats(-90, 90)), pitch=draw(st.floats(-60, 60)),
        roll=draw(st.floats(-180, 180)),  # includes upside-down faces
        kind=draw(st.sampled_from(["affine", "perspective"])),
        n_extreme=draw(st.integers(0, 3)),  # identity coefficients pushed to 2..4 sigma
        expression=draw(st.floats(0, 1)),  # weight of one full blendshape
        noise=draw(st.floats(0, 2)),  # px
        dropout=draw(st.floats(0, 0.6)),
        seed=seed)
    return scene


def make_landmarks(model, s):
    from morphable.fitting import simulate_landmarks

    rng = np.random.default_rng(s["seed"])
    alpha = rng.normal(size=model.n_identity)
    idx = rng.choice(model.n_identity, s["n_extreme"], replace=False)
    alpha[idx] = rng.choice([-1, 1], len(idx)) * rng.uniform(2, 4, len(idx))
    alpha = np.clip(alpha, -4, 4)
    beta = np.zeros(model.n_expression)
    beta[rng.integers(model.n_expression)] = s["expression"]
    cam = Camera.looking_at_face(image_size=(SIZE, SIZE), yaw=s["yaw"], pitch=s["pitch"],
                                 roll=s["roll"], kind=s["kind"])
    clean = simulate_landmarks(model, cam, identity=alpha, expression=beta)
    lms = clean + rng.normal(scale=s["noise"], size=clean.shape)
    lms[rng.uniform(size=68) < s["dropout"]] = np.nan
    return lms, clean


def _fit(model, lms, s, dtype=np.float64):
    from morphable.fitting import fit_landmarks

    return fit_landmarks(model, lms.astype(dtype), (SIZE, SIZE), camera=s["kind"], dtype=dtype)


@settings(max_examples=30, **SETTINGS)
@given(s=scenes())
def test_fit_is_finite_bounded_deterministic_and_precision_independent(sfm, s):
    lms, clean = make_landmarks(sfm, s)
    res = _fit(sfm, lms, s)
    verts = res.vertices(0)
    for a in (res.identity, res.expression, res.landmark_rmse_px, verts, res.euler_deg,
              res.cameras[0].translation, res.cameras[0].rotation):
        assert np.all(np.isfinite(a))
    # the residual is the noise plus what the model cannot reproduce (jaw points between
    # vertices, the prior pulling extreme identities in): a few percent of the face's size
    rmse = res.landmark_rmse_px[0]
    assert rmse <= 2.0 * s["noise"] + 0.05 * FACE_PX, (rmse, s)
    # against the noise-free landmarks the fit is no worse than against the noisy ones (it
    # does not fit the noise)
    used = np.isfinite(res.fitted_landmarks[0, :, 0])
    clean_err = np.sqrt(((res.fitted_landmarks[0, used] - clean[used]) ** 2).sum(-1).mean())
    assert clean_err <= rmse + 0.5 * s["noise"] + 0.5, (clean_err, rmse, s)
    # the same input gives the same result, bit for bit
    again = _fit(sfm, lms, s)
    np.testing.assert_array_equal(again.vertices(0), verts)
    np.testing.assert_array_equal(again.landmark_rmse_px, res.landmark_rmse_px)
    # float32 landmarks and meshes agree with float64 to far below a millimetre / pixel
    r32 = _fit(sfm, lms, s, dtype=np.float32)
    assert r32.vertices(0).dtype == np.float32
    assert np.abs(r32.vertices(0) - verts).max() < 1e-2
    assert abs(r32.landmark_rmse_px[0] - rmse) < 1e-2


@settings(max_examples=6, **SETTINGS)
@given(s=scenes(), keep=st.integers(0, 3))
def test_too_few_landmarks_is_a_clear_error_not_nan(sfm, s, keep):
    from morphable.errors import FitError

    lms, _ = make_landmarks(sfm, dict(s, dropout=0.0, noise=0.0))
    inner = np.arange(17, 68)
    rng = np.random.default_rng(s["seed"])
    kept = rng.choice(inner[np.isfinite(lms[inner, 0])], keep, replace=False)
    sparse = np.full_like(lms, np.nan)
    sparse[kept] = lms[kept]
    with pytest.raises(FitError, match="need at least 4"):
        _fit(sfm, sparse, s)


# --- normals and baking on degenerate meshes -----------------------------------------------
@st.composite
def degenerate_meshes(draw):
    """Random meshes where many triangles are degenerate: repeated indices, coincident or
    collinear vertices, vertices at 1e6 mm and unreferenced vertices."""
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    n = draw(st.integers(3, 40))
    v = rng.normal(scale=draw(st.sampled_from([1e-3, 1.0, 50.0])), size=(n, 3))
    if n > 4 and draw(st.booleans()):
        v[1] = v[0]  # coincident
        v[2] = v[0] + 0.5 * (v[3] - v[0])  # collinear with 0 and 3
    if draw(st.booleans()):
        v[-1] = 1e6  # far away
    f = rng.integers(0, n, size=(draw(st.integers(1, 60)), 3))
    f[: len(f) // 3, 1] = f[: len(f) // 3, 0]  # a third have a repeated index
    return v, f


@settings(max_examples=25, **SETTINGS)
@given(mesh=degenerate_meshes(), weighting=st.sampled_from(["area", "angle"]),
       dtype=st.sampled_from([np.float32, np.float64]))
def test_vertex_normals_stay_finite_and_unit(mesh, weighting, dtype):
    from morphable.normals import face_normals, vertex_normals

    v, f = mesh
    n = vertex_normals(v.astype(dtype), f, weighting=weighting)
    assert n.dtype == dtype and np.all(np.isfinite(n))
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-3)
    assert np.all(np.isfinite(face_normals(v.astype(dtype), f)))


@settings(max_examples=8, **SETTINGS)
@given(mesh=degenerate_meshes())
def test_torch_normals_and_gradients_stay_finite(mesh):
    torch = pytest.importorskip("torch")
    from morphable.normals import vertex_normals

    v, f = mesh
    t = torch.tensor(v, dtype=torch.float64, requires_grad=True)
    n = vertex_normals(t, torch.as_tensor(f))
    (n * torch.linspace(-1, 1, n.numel(), dtype=n.dtype).reshape(n.shape)).sum().backward()
    assert torch.isfinite(n).all() and torch.isfinite(t.grad).all()


@settings(max_examples=8, **SETTINGS)
@given(mesh=degenerate_meshes(), yaw=st.floats(-180, 180), pitch=st.floats(-90, 90),
       kind=st.sampled_from(["affine", "perspective"]))
def test_baking_and_rendering_stay_finite(mesh, yaw, pitch, kind):
    from morphable.raster import frame_mesh, normal_map, render, visibility

    v, f = mesh
    v = v[:-1] if np.abs(v[-1]).max() >= 1e6 else v  # a 1e6 mm outlier would frame a dot
    f = f[(f < len(v)).all(1)]
    if len(f) == 0:
        return
    try:
        cam = frame_mesh(v, (32, 32), yaw=yaw, pitch=pitch, kind=kind)
    except InputError:
        return  # a clear error (e.g. all vertices coincide) is an acceptable answer
    try:
        vis = visibility(v, f, cam)
    except InputError:
        return
    nmap = normal_map(v, f, vis=vis)
    assert np.all(np.isfinite(nmap))
    norms = np.linalg.norm(nmap, axis=-1)
    assert np.all((np.abs(norms - 1) < 1e-3) | (norms == 0))
    img = render(v, f, vis=vis)
    assert np.all(np.isfinite(img)) and img.min() >= 0 and img.max() <= 1


# --- ICP: random rigid transforms of a scan are recovered ----------------------------------
@pytest.fixture(scope="module")
def james(data_dir):
    from evaluation.scans import load_scan

    d = data_dir / "scans" / "james"
    return load_scan(d / "james.obj", d / "james.ljson")


def _rigid(seed, max_deg, max_mm):
    rng = np.random.default_rng(seed)
    R = euler_to_matrix(*rng.uniform(-max_deg, max_deg, 3))
    return R, rng.uniform(-max_mm, max_mm, 3)


@settings(max_examples=5, **SETTINGS)
@given(seed=st.integers(0, 2**32 - 1))
def test_landmarks_then_icp_recover_any_rigid_transform(james, seed):
    from morphable.metrics import compare_to_scan

    R, t = _rigid(seed, 180, 500)
    moved = james.vertices @ R.T + t
    c = compare_to_scan(moved, james.triangles, james.vertices, james.triangles,
                        landmarks=james.landmarks @ R.T + t, scan_landmarks=james.landmarks,
                        landmark_scale=False)
    assert np.abs(c.aligned_vertices - james.vertices).max() < 0.05  # mm
    assert c.summary()["point_to_surface"]["mean_mm"] < 0.01


@settings(max_examples=5, **SETTINGS)
@given(seed=st.integers(0, 2**32 - 1))
def test_icp_alone_recovers_small_rigid_transforms(james, seed):
    from morphable.metrics import icp_refine
    from morphable.normals import vertex_normals

    R, t = _rigid(seed, 4, 3)
    centre = james.vertices.mean(0)
    moved = (james.vertices - centre) @ R.T + centre + t
    T, info = icp_refine(moved, james.vertices, vertex_normals(james.vertices, james.triangles),
                         max_distance=15.0)
    err = np.linalg.norm(T.apply(moved) - james.vertices, axis=1)
    assert info["fitness"] > 0.95
    assert np.median(err) < 0.1 and err.max() < 1.0, (np.median(err), err.max())
