"""The identity prior's mean in fit_landmarks and the descriptor -> identity map of
evaluation.bench_descriptor_prior."""
import numpy as np
import pytest

from evaluation.bench_descriptor_prior import RIDGES, fit_ridge, predict, rms_error
from morphable import load_model
from morphable.camera import Camera
from morphable.errors import InputError
from morphable.fitting import fit_landmarks


@pytest.fixture(scope="module")
def sfm():
    return load_model("sfm")


def _views(model, alpha, yaws, noise_px=0.0, seed=0):
    pts = model.vertices(alpha)[np.maximum(model.landmark_ids, 0)]
    out = np.stack([Camera.looking_at_face(image_size=(512, 512), yaw=y).project(pts) for y in yaws])
    out[:, model.landmark_ids < 0] = np.nan
    return out + np.random.default_rng(seed).normal(0, noise_px, out.shape)


def test_ridge_map_recovers_a_linear_map():
    rng = np.random.default_rng(0)
    D = rng.normal(0, 0.1, (300, 128))
    W = rng.normal(0, 1, (128, 5))
    A = D @ W + 0.3 + rng.normal(0, 0.05, (300, 5))
    m = fit_ridge(D, A)
    assert m["ridge"] in RIDGES and m["cv_mse"].shape == (len(RIDGES),)
    assert predict(m, D[:7]).shape == (7, 5)
    test = rng.normal(0, 0.1, (50, 128))
    # a cross-validated ridge keeps most of the signal: far below the coefficients' variance
    assert np.mean((predict(m, test) - (test @ W + 0.3)) ** 2) < 0.1 * np.var(test @ W)
    assert m["residual_var"].shape == (5,) and m["residual_var"].mean() < 0.1 * np.var(A)


def test_zero_prior_mean_is_the_default(sfm):
    alpha = np.random.default_rng(1).normal(0, 1, sfm.n_identity)
    for yaws in ((20,), (-25, 0, 25)):
        lms = _views(sfm, alpha, yaws, noise_px=1.0)
        a = fit_landmarks(sfm, lms, (512, 512))
        b = fit_landmarks(sfm, lms, (512, 512), identity_prior_mean=np.zeros(sfm.n_identity))
        np.testing.assert_array_equal(a.identity, b.identity)


def test_true_prior_mean_pulls_towards_the_truth(sfm):
    alpha = np.random.default_rng(2).normal(0, 1, sfm.n_identity)
    lms = _views(sfm, alpha, (15,), noise_px=1.0)
    truth = sfm.vertices(alpha)
    plain = rms_error(fit_landmarks(sfm, lms, (512, 512)).neutral_vertices(), truth)
    guided = rms_error(fit_landmarks(sfm, lms, (512, 512), identity_prior_mean=alpha).neutral_vertices(), truth)
    assert guided < 0.5 * plain
    # a narrower prior around the truth pulls harder
    tight = fit_landmarks(sfm, lms, (512, 512), identity_prior_mean=alpha,
                          identity_prior_std=np.full(sfm.n_identity, 0.3)).neutral_vertices()
    assert rms_error(tight, truth) < guided
    # n_identity: only the first values are used
    res = fit_landmarks(sfm, lms, (512, 512), n_identity=10, identity_prior_mean=alpha)
    assert res.identity.shape == (10,)


def test_bad_prior_mean(sfm):
    lms = _views(sfm, np.zeros(sfm.n_identity), (0,))
    with pytest.raises(InputError, match="identity_prior_mean"):
        fit_landmarks(sfm, lms, (512, 512), identity_prior_mean=np.zeros(5))
    with pytest.raises(InputError, match="identity_prior_mean"):
        fit_landmarks(sfm, lms, (512, 512), identity_prior_mean=np.full(sfm.n_identity, np.nan))
    with pytest.raises(InputError, match="identity_prior_std"):
        fit_landmarks(sfm, lms, (512, 512), identity_prior_std=np.zeros(sfm.n_identity))
