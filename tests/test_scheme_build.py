"""The facemesh478 schemes derived from mediapipe's canonical mesh (morphable.fitting.scheme_build):
the committed sidecars of SFM and ICT, their geometry, and the rebuild command."""
import subprocess
import sys

import numpy as np
import pytest

from morphable.fitting import scheme_build as sb
from morphable.fitting.schemes import DATA_DIR, load_scheme


@pytest.fixture(scope="module")
def canonical(data_dir):
    return sb.canonical_mesh()


@pytest.fixture(scope="module")
def sfm_build(sfm, canonical):
    return sb.build_scheme(sfm)


@pytest.mark.parametrize("name", ["sfm", "ict"])
def test_committed_sidecar_loads_and_lies_on_the_surface(name, request, canonical):
    model = request.getfixturevalue(name)
    V = canonical[0]
    s = load_scheme(model)
    assert s.name == "facemesh478" and s.n == 478 and s.defined.all()
    P = s.points(model.mean)
    # every point is inside one of the model's triangles: its three vertices form a triangle
    tri = {tuple(sorted(t)) for t in model.triangles.tolist()}
    assert all(tuple(sorted(v)) in tri for v in s.vertices.tolist())
    assert (s.barycentric >= 0).all()
    tri_ids, near = sb.closest_points(P, model.mean, model.triangles)
    np.testing.assert_allclose(near, P, atol=1e-6)
    # mirror: an involution that swaps the sides and keeps the midline
    np.testing.assert_array_equal(s.mirror[s.mirror], np.arange(478))
    mid = s.mirror == np.arange(478)
    assert np.abs(P[mid, 0]).max() < 3.0 and np.abs(P[~mid, 0]).min() > 0.0
    assert (np.sign(P[~mid, 0]) == -np.sign(P[s.mirror[~mid], 0])).all()
    # the sliding oval: right side at x < 0, left at x > 0, below the eyes (on the canonical
    # mesh), the chin the lowest point
    assert (P[s.outline_right, 0] < 0).all() and (P[s.outline_left, 0] > 0).all()
    assert len(s.outline_right) == len(s.outline_left) == 11 and s.chin == 152
    slides = np.r_[s.outline_right, s.outline_left]
    fixed_oval = np.setdiff1d(sb.FACE_OVAL, np.r_[slides, s.chin])
    eye_y = V[[468, 473], 1].mean()
    assert (V[slides, 1] < eye_y).all() and (V[fixed_oval, 1] > eye_y).all()
    assert P[s.chin, 1] < P[slides, 1].min() and abs(P[s.chin, 0]) < 1.0
    np.testing.assert_array_equal(s.mirror[s.outline_right], s.outline_left)
    # the forehead's oval points are fixed surface points
    assert not s.sliding[[10, 338, 109]].any() and s.sliding.sum() == 22 and not s.sliding[s.chin]


@pytest.mark.parametrize("name", ["sfm", "ict"])
def test_anchor_points_near_the_model_landmarks(name, request):
    model = request.getfixturevalue(name)
    s = load_scheme(model)
    P = s.points(model.mean)
    ids = np.asarray(model.landmark_ids)
    # eye corners, nose tip, mouth corners (and chin): near the iBUG landmark vertices. The
    # committed sidecars are calibrated to where the detector puts its points
    # (evaluation.scheme_calibration), a few mm from the registration's anchors (2 mm:
    # test_registration_close_to_the_placed_canonical_mesh)
    for k, i in zip(sb.ANCHOR_IBUG, sb.ANCHOR_MEDIAPIPE):
        if ids[k] >= 0:
            assert np.linalg.norm(P[i] - model.mean[ids[k]]) < 6.0, (k, i)
    # the iBUG counterparts of the inner points: near their landmark (the brows are defined
    # differently: on the brow's edge, within 8 mm; ICT measured 7.0; the nose ridge's points
    # have no height of their own along the ridge: after the calibration 7.8 mm on SFM; the
    # others within 7 mm: 6.6 mm at the nose wings)
    for k in range(17, 68):
        if ids[k] >= 0:
            limit = 9.0 if k < 31 else 7.0
            assert np.linalg.norm(P[s.ibug68[k]] - model.mean[ids[k]]) < limit, k
    assert s.ibug68[8] == s.chin
    assert set(s.ibug68[0:8]) <= set(s.outline_right) and set(s.ibug68[9:17]) <= set(s.outline_left)
    # jaw points run from the top of the outline down to the chin
    assert (np.diff(P[s.ibug68[0:9], 1]) < 0).all()


def test_registration_close_to_the_placed_canonical_mesh(sfm_build):
    b = sfm_build
    # the non-rigid registration moves the canonical mesh by a few mm only (measured 2.5 mm RMS)
    assert b.rms_mm < 3.5 and np.percentile(b.residual_mm, 99) < 10.0
    assert b.anchor_rms_mm < 4.0
    np.testing.assert_array_equal(b.anchors, sb.ANCHOR_MEDIAPIPE)
    # irises on the eyes (SFM: on the eyelids), between the corners
    for iris, (outer, inner) in zip(sb.IRISES, ((33, 133), (263, 362))):
        c = b.surface[iris[0]]
        lo, hi = sorted([b.surface[outer, 0], b.surface[inner, 0]])
        assert lo < c[0] < hi


def test_rebuild_gives_the_committed_sidecar(sfm, sfm_build):
    # the committed sidecar is this build, calibrated: the outline points and the chin keep
    # the build's points and definition error, the fixed points moved a few mm
    committed = load_scheme(sfm)
    s = sfm_build.scheme
    for k in ("outline_right", "outline_left", "mirror", "ibug68"):
        np.testing.assert_array_equal(getattr(s, k), getattr(committed, k))
    assert s.chin == committed.chin
    outline = np.r_[s.outline_right, s.outline_left, s.chin]
    np.testing.assert_array_equal(s.vertices[outline], committed.vertices[outline])
    np.testing.assert_allclose(s.barycentric[outline], committed.barycentric[outline], atol=1e-9)
    np.testing.assert_allclose(s.definition_std_mm[outline], committed.definition_std_mm[outline])
    shift = np.linalg.norm(s.points(sfm.mean) - committed.points(sfm.mean), axis=1)
    assert np.median(shift) < 5.0 and shift.max() < 20.0


def test_registration_anchors_near_the_landmarks(sfm, sfm_build):
    P = sfm_build.surface
    ids = np.asarray(sfm.landmark_ids)
    for k, i in zip(sb.ANCHOR_IBUG, sb.ANCHOR_MEDIAPIPE):
        if ids[k] >= 0:
            assert np.linalg.norm(P[i] - sfm.mean[ids[k]]) < 2.0, (k, i)


def test_canonical_mesh_and_face_oval(canonical):
    V, F = canonical
    assert V.shape == (478, 3) and F.max() < sb.N_MESH
    # the oval is the mesh's only boundary loop: its edges are used by one triangle each
    e = np.sort(np.vstack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), 1)
    uniq, count = np.unique(e, axis=0, return_counts=True)
    boundary = {tuple(x) for x in uniq[count == 1]}
    loop = {tuple(sorted(p)) for p in zip(sb.FACE_OVAL, np.roll(sb.FACE_OVAL, -1))}
    assert boundary == loop
    m = sb.mirror_indices(V)
    np.testing.assert_array_equal(m[m], np.arange(478))
    assert m[468] == 473 and m[33] == 263 and m[4] == 4


def test_similarity_recovers_a_known_transform():
    rng = np.random.default_rng(1)
    X = rng.normal(size=(10, 3))
    a = 0.3
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    s, R2, t = sb.similarity(X, 2.5 * X @ R.T + [1, 2, 3])
    assert s == pytest.approx(2.5) and np.allclose(R2, R) and np.allclose(t, [1, 2, 3])


def test_bad_model_path_one_line_exit_2(tmp_path):
    r = subprocess.run([sys.executable, "-m", "morphable.fitting.scheme_build", "--model",
                        str(tmp_path / "missing.obj"), "--out", str(tmp_path / "x.npz")],
                       capture_output=True, text=True)
    assert r.returncode == 2 and r.stdout == ""
    assert r.stderr.count("\n") == 1 and "missing.obj" in r.stderr
    assert not (tmp_path / "x.npz").exists()


def test_sidecars_committed():
    assert {p.name for p in DATA_DIR.glob("facemesh478_*.npz")} >= {"facemesh478_sfm.npz",
                                                                     "facemesh478_ict.npz"}
