"""Calibrating a landmark scheme on renders: a detector with known offsets gives them back."""
import numpy as np
import pytest

from morphable.errors import FitError
from morphable.fitting.schemes import LandmarkScheme

pytest.importorskip("open3d")


def test_calibration_recovers_a_detectors_offsets(sfm):
    from evaluation.scheme_calibration import calibrate
    from morphable.fitting.scheme_build import project_to_surface

    rng = np.random.default_rng(1)
    skin = sfm.skin_vertices()
    front = skin[(sfm.mean[skin, 2] > sfm.mean[skin, 2].max() - 25)
                 & (sfm.mean[skin, 0] > 3) & (sfm.mean[skin, 0] < 30)]
    # 15 points on the subject's left and their mirror images: a symmetric scheme
    half = sfm.mean[rng.choice(front, 15, replace=False)] + rng.normal(0, 0.3, (15, 3))
    flip = np.array([-1.0, 1.0, 1.0])
    v, b, P = project_to_surface(np.r_[half, half * flip], sfm)
    mirror = np.r_[np.arange(15, 30), np.arange(15)]
    none = np.array([], np.int64)
    start = LandmarkScheme("test30", "sfm", v, b, none, none, -1, np.full(30, 2.0),
                           mirror, np.full(68, -1))
    # the "detector" puts each point 2 mm off the scheme's, the same on every face (mirrored
    # on the other side), plus noise
    offset = rng.normal(0, 1, (15, 3))
    offset[:, 2] = 0
    offset *= 2.0 / np.linalg.norm(offset, axis=1, keepdims=True)
    tv, tb, truth = project_to_surface(P + np.r_[offset, offset * flip], sfm)
    true_scheme = LandmarkScheme("t", "sfm", tv, tb, none, none, -1, np.ones(30), mirror,
                                 np.full(68, -1))
    state = {}

    def detect(img):
        verts, cam = state["verts"], state["cam"]
        uv = cam.project(true_scheme.points(verts))
        return uv + rng.normal(0, 0.5, uv.shape)

    import evaluation.scheme_calibration as sc
    render = sc.render_subject

    def spy(verts, tri, colors, yaw, pitch, image_size=256):
        img, cam, vis = render(verts, tri, colors, yaw, pitch, image_size)
        state.update(verts=verts, cam=cam)
        return img, cam, vis

    sc.render_subject = spy
    try:
        cal, rep = calibrate(sfm, start, [np.full((sfm.n_vertices, 3), 0.7)], n_subjects=3,
                             views=((-20, 0), (0, 0), (20, 0), (0, 10)), detect=detect)
    finally:
        sc.render_subject = render
    got = cal.points(sfm.mean)
    err = np.linalg.norm(got - truth, axis=1)
    before = np.linalg.norm(start.points(sfm.mean) - truth, axis=1)
    assert rep["calibrated_points"] == 30 and rep["renders"] == 12
    assert np.median(before) > 1.5 and np.median(err) < 0.5
    # the spread: 0.5 px detector noise and pixel rounding, well under the 2 mm offsets
    assert np.median(cal.definition_std_mm) <= 1.0


def test_no_face_anywhere_is_an_error(sfm):
    from evaluation.scheme_calibration import calibrate
    from morphable.fitting.schemes import ibug68_scheme

    def nothing(img):
        raise FitError("no face")

    with pytest.raises(FitError, match="no face in any render"):
        calibrate(sfm, ibug68_scheme(sfm), [np.full((sfm.n_vertices, 3), 0.7)], n_subjects=1,
                  views=((0, 0),), detect=nothing)
