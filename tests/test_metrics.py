"""Checks of the mesh-to-scan metric itself (morphable.metrics)."""
import numpy as np
import pytest

from morphable.errors import FitError, InputError
from morphable.metrics import (Similarity, align_landmarks, compare_to_scan, crop_mesh,
                               crop_sphere, point_to_plane, point_to_surface, umeyama)


@pytest.fixture(scope="module")
def james(data_dir):
    from evaluation.scans import load_scan

    d = data_dir / "scans" / "james"
    return load_scan(d / "james.obj", d / "james.ljson")


def random_similarity(rng, scale_range=(0.5, 2.0)):
    from scipy.spatial.transform import Rotation

    return Similarity(scale=rng.uniform(*scale_range), rotation=Rotation.random(random_state=rng).as_matrix(),
                      translation=rng.uniform(-300, 300, 3))


def test_similarity_compose_and_inverse():
    rng = np.random.default_rng(1)
    A, B = random_similarity(rng), random_similarity(rng)
    x = rng.normal(size=(7, 3)) * 50
    np.testing.assert_allclose((A @ B).apply(x), A.apply(B.apply(x)), atol=1e-9)
    np.testing.assert_allclose(A.inverse().apply(A.apply(x)), x, atol=1e-9)


def test_align_landmarks_recovers_similarity_and_ignores_nan():
    rng = np.random.default_rng(2)
    src = rng.normal(size=(68, 3)) * 40
    T = random_similarity(rng)
    dst = T.apply(src)
    src[[3, 10]] = np.nan
    dst[20] = np.nan
    S = align_landmarks(src, dst)
    assert S.scale == pytest.approx(T.scale, rel=1e-9)
    np.testing.assert_allclose(S.rotation, T.rotation, atol=1e-9)
    R = align_landmarks(src, dst, scale=False)
    assert R.scale == pytest.approx(1.0)


def test_align_landmarks_degenerate():
    line = np.c_[np.arange(10.0), np.zeros(10), np.zeros(10)]
    with pytest.raises(FitError, match="collinear"):
        align_landmarks(line, line + 1)
    with pytest.raises(FitError, match="3 corresponding"):
        align_landmarks(np.full((68, 3), np.nan), np.zeros((68, 3)))
    with pytest.raises(InputError):
        align_landmarks(np.zeros((5, 2)), np.zeros((5, 2)))


def test_umeyama_3d_is_a_proper_rotation_even_for_a_mirrored_target():
    rng = np.random.default_rng(4)
    T = random_similarity(rng)
    src = rng.normal(size=(12, 3)) * 40
    s, R, t = umeyama(src, T.apply(src), scale=False)
    assert s == 1.0 and np.isclose(np.linalg.det(R), 1.0)
    s, R, t = umeyama(src, T.apply(src))
    np.testing.assert_allclose(s * src @ R.T + t, T.apply(src), atol=1e-9)
    # a mirror image has no exact similarity: the best proper rotation, never a reflection
    s, R, _ = umeyama(src, src * [-1, 1, 1])
    assert np.isclose(np.linalg.det(R), 1.0) and s < 1.0
    with pytest.raises(InputError, match="one shape"):
        umeyama(src, src[:, :2])


def test_crop_sphere_and_mesh():
    import trimesh

    s = trimesh.creation.icosphere(3, radius=50.0)
    inside = crop_sphere(s.vertices, [0, 0, 50], 50.0)
    assert 0 < inside.sum() < len(s.vertices)
    v, f, ids = crop_mesh(s.vertices, s.faces, [0, 0, 50], 50.0)
    assert f.max() < len(v) and np.all(np.linalg.norm(v - [0, 0, 50], axis=1) <= 50.0)
    np.testing.assert_array_equal(v, s.vertices[ids])


def test_scan_against_itself_under_random_similarity(james):
    rng = np.random.default_rng(3)
    for _ in range(3):
        T = random_similarity(rng)
        c = compare_to_scan(T.apply(james.vertices), james.triangles, james.vertices, james.triangles,
                            T.apply(james.landmarks), james.landmarks)
        s = c.summary()
        assert s["point_to_plane"]["mean_mm"] < 0.01
        assert s["point_to_surface"]["mean_mm"] < 0.01
        assert s["scan_to_recon"]["mean_mm"] < 0.01
        assert c.alignment["icp"]["fitness"] == pytest.approx(1.0)
        assert 500 < c.vertex_ids.size < len(james.vertices)  # the crop really cut the head


# with ICP the whole spheres are compared: ICP rightly slides a cap of the larger sphere
# into the smaller one, a full sphere stays concentric
@pytest.mark.parametrize("icp,radius", [(False, 95.0), (True, 200.0)])
def test_sphere_against_larger_sphere_is_one_mm(icp, radius):
    import trimesh

    s = trimesh.creation.icosphere(5, radius=50.0)
    c = compare_to_scan(s.vertices * 51 / 50, s.faces, s.vertices, s.faces, radius=radius,
                        nose_tip=[0, 0, 51], scan_nose_tip=[0, 0, 50], icp=icp)
    sm = c.summary()
    assert sm["point_to_plane"]["mean_mm"] == pytest.approx(1.0, abs=0.01)
    assert sm["point_to_plane"]["std_mm"] < 0.01
    assert sm["point_to_surface"]["mean_mm"] == pytest.approx(1.0, abs=0.02)
    assert sm["scan_to_recon"]["mean_mm"] == pytest.approx(1.0, abs=0.02)


def test_known_normal_noise_gives_expected_mean(james):
    from morphable.normals import vertex_normals

    rng = np.random.default_rng(4)
    sigma = 0.5
    n = vertex_normals(james.vertices, james.triangles)
    noisy = james.vertices + sigma * rng.standard_normal((len(n), 1)) * n
    c = compare_to_scan(noisy, james.triangles, james.vertices, james.triangles,
                        nose_tip=james.nose_tip, scan_nose_tip=james.nose_tip, icp=False)
    # |N(0, sigma)| has mean sigma * sqrt(2 / pi)
    assert c.summary()["point_to_plane"]["mean_mm"] == pytest.approx(sigma * np.sqrt(2 / np.pi), rel=0.05)
    # the point-to-surface distance can only be smaller (the surface is closer than the plane
    # of one vertex only where it curves towards the point), and close to it
    assert c.summary()["point_to_surface"]["mean_mm"] < 1.1 * sigma * np.sqrt(2 / np.pi)


def test_metric_ranks_identity_over_mean(sfm):
    """On a scan made from the model, the true identity scores ~0 and the mean face worst."""
    rng = np.random.default_rng(5)
    alpha = rng.standard_normal(sfm.n_identity) * 1.5
    scan_v, scan_lm = sfm.vertices(alpha), sfm.landmark_positions(alpha)
    errs = []
    for k in (1.0, 0.5, 0.0):
        c = compare_to_scan(sfm.vertices(k * alpha), sfm.triangles, scan_v, sfm.triangles,
                            sfm.landmark_positions(k * alpha), scan_lm)
        errs.append(c.summary()["point_to_plane"]["mean_mm"])
    assert errs[0] < 0.01 < errs[1] < errs[2]


def test_holes_nonmanifold_and_units_give_the_same_answer(james, sfm, tmp_path):
    import trimesh

    from evaluation.scans import load_scan

    def score(scan_v, scan_f, scan_lm):
        c = compare_to_scan(sfm.mean, sfm.triangles, scan_v, scan_f, sfm.landmark_positions(), scan_lm)
        return c.summary()["point_to_plane"]["mean_mm"]

    ref = score(james.vertices, james.triangles, james.landmarks)
    assert 0.3 < ref < 5.0

    # metres on disk, detected and converted on load
    path = tmp_path / "james_m.ply"
    trimesh.Trimesh(james.vertices / 1000.0, james.triangles, process=False).export(path)
    np.save(tmp_path / "lm_m.npy", james.landmarks / 1000.0)
    metres = load_scan(path, tmp_path / "lm_m.npy", units="auto")
    assert metres.units == "m"
    assert score(metres.vertices, metres.triangles, metres.landmarks) == pytest.approx(ref, abs=1e-6)

    # holes: 5% of the triangles removed
    rng = np.random.default_rng(6)
    keep = rng.random(len(james.triangles)) > 0.05
    holes = james.triangles[keep]
    assert not trimesh.Trimesh(james.vertices, holes, process=False).is_watertight
    assert score(james.vertices, holes, james.landmarks) == pytest.approx(ref, abs=0.03)

    # non-manifold: duplicated triangles and fins (an extra triangle on existing edges)
    dup = james.triangles[rng.choice(len(james.triangles), 200, replace=False)]
    extra_v = james.vertices[dup[:, :2]].mean(1) + 0.5
    fin = np.c_[dup[:, :2], len(james.vertices) + np.arange(len(dup))]
    nm_v = np.vstack([james.vertices, extra_v])
    nm_f = np.vstack([james.triangles, dup, fin])
    assert score(nm_v, nm_f, james.landmarks) == pytest.approx(ref, abs=0.03)


def test_float32_and_bad_inputs(james, sfm):
    c = compare_to_scan(sfm.mean.astype(np.float32), sfm.triangles, james.vertices.astype(np.float32),
                        james.triangles, sfm.landmark_positions().astype(np.float32), james.landmarks)
    assert np.isfinite(c.point_to_plane_mm).all()
    bad = sfm.mean.copy()
    bad[0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        compare_to_scan(bad, sfm.triangles, james.vertices, james.triangles,
                        sfm.landmark_positions(), james.landmarks)
    with pytest.raises(InputError, match="nose tips"):
        compare_to_scan(sfm.mean, sfm.triangles, james.vertices, james.triangles)
    with pytest.raises(FitError, match="no scan triangle"):  # a scan far away from its nose tip
        compare_to_scan(sfm.mean, sfm.triangles, james.vertices + 1e4, james.triangles,
                        nose_tip=[0, 0, 0], scan_nose_tip=[0, 0, 0], icp=False)


def test_point_distances_agree_on_a_plane():
    rng = np.random.default_rng(7)
    g = np.stack(np.meshgrid(np.linspace(-50, 50, 41), np.linspace(-50, 50, 41)), -1).reshape(-1, 2)
    v = np.c_[g, np.zeros(len(g))]
    import scipy.spatial

    f = scipy.spatial.Delaunay(g).simplices
    p = np.c_[rng.uniform(-40, 40, (100, 2)), rng.normal(0, 2, 100)]
    n = np.tile([0.0, 0.0, 1.0], (len(v), 1))
    np.testing.assert_allclose(point_to_plane(p, v, n), np.abs(p[:, 2]), atol=1e-9)
    np.testing.assert_allclose(point_to_surface(p, v, f), np.abs(p[:, 2]), atol=1e-9)
