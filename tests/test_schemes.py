"""Landmark schemes: the iBUG-68 scheme of a model, sidecar round trip and refusal of another model's."""
import numpy as np
import pytest

from morphable import load_model
from morphable.errors import InputError
from morphable.fitting.schemes import LandmarkScheme, ibug68_scheme, load_scheme, save_scheme


@pytest.fixture(scope="module")
def sfm():
    return load_model("sfm")


def test_ibug68_points_are_the_landmark_vertices(sfm):
    s = ibug68_scheme(sfm)
    P = s.points(sfm.mean)
    ids = np.asarray(sfm.landmark_ids)
    assert s.n == 68
    np.testing.assert_array_equal(np.isnan(P[:, 0]), ids < 0)
    np.testing.assert_allclose(P[ids >= 0], sfm.mean[ids[ids >= 0]])
    assert s.sliding[:17].sum() == 16 and not s.sliding[8] and not s.sliding[17:].any()
    # batched vertices give the same points per frame
    PN = s.points(np.stack([sfm.mean, sfm.mean + 1.0]))
    np.testing.assert_allclose(PN[1][ids >= 0], P[ids >= 0] + 1.0)


def test_sidecar_round_trip_and_other_model(sfm, tmp_path):
    rng = np.random.default_rng(0)
    tri = rng.integers(0, len(sfm.triangles), 10)
    w = rng.dirichlet(np.ones(3), 10)
    s = LandmarkScheme("facemesh478", "sfm", sfm.triangles[tri].astype(np.int64), w,
                       np.array([0, 1]), np.array([2, 3]), 4, np.full(10, 2.0),
                       np.array([2, 3, 0, 1, 4, 5, 6, 7, 8, 9]), np.full(68, -1))
    path = save_scheme(s, tmp_path / "x.npz", sfm)
    back = load_scheme(sfm, "facemesh478", path)
    np.testing.assert_allclose(back.points(sfm.mean), s.points(sfm.mean))
    np.testing.assert_array_equal(back.mirror, s.mirror)
    other = load_model("ict")
    with pytest.raises(InputError, match="another model"):
        load_scheme(other, "facemesh478", path)


def test_bad_scheme_rejected(sfm, tmp_path):
    with pytest.raises(InputError, match="sum to 1"):
        LandmarkScheme("x", "sfm", np.zeros((2, 3), np.int64), np.ones((2, 3)), np.array([], np.int64),
                       np.array([], np.int64), -1, np.ones(2), np.array([1, 0]), np.full(68, -1))
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="bad.npz"):
        load_scheme(sfm, "facemesh478", tmp_path / "bad.npz")
