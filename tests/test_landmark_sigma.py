"""Fitting with a noise per landmark (``landmark_std_px`` arrays) and the 3D convention."""
import re
from pathlib import Path

import numpy as np
import pytest

from morphable import InputError
from morphable.camera import Camera
from morphable.fitting import fit_landmarks, simulate_landmarks
from morphable.fitting.noise import MISSING_STD_PX
from morphable.labels import label_schemes, project_labels

DOC = Path(__file__).resolve().parents[1] / "docs" / "bad_input.md"
GROSS = [30, 33, 48, 54, 57]      # nose tip, nose base, mouth corners, lower lip


@pytest.fixture(scope="module")
def scene(sfm):
    """A face, its true vertices and clean 68 landmarks in two views (affine, 512 px)."""
    rng = np.random.default_rng(5)
    alpha = 0.8 * rng.standard_normal(sfm.n_identity)
    verts = sfm.vertices(alpha)
    cams = [Camera.looking_at_face((512, 512), yaw=y) for y in (-20, 25)]
    lm = np.stack([simulate_landmarks(sfm, c, vertices=verts) for c in cams])
    return verts, lm


def err(res, verts, frame=0):
    return float(np.linalg.norm(res.vertices(frame) - verts, axis=1).mean())


def gross(lm, frames=(0,)):
    out = lm.copy()
    for f in frames:
        out[f, GROSS] += [25.0, -30.0]
    return out


def test_an_array_of_one_value_is_that_number(sfm, scene):
    _, lm = scene
    a = fit_landmarks(sfm, lm, (512, 512), landmark_std_px=2.0)
    b = fit_landmarks(sfm, lm, (512, 512), landmark_std_px=np.full(68, 2.0))
    c = fit_landmarks(sfm, lm, (512, 512), landmark_std_px=np.full((2, 68), 2.0))
    np.testing.assert_allclose(b.vertices(), a.vertices(), atol=1e-9)
    np.testing.assert_allclose(c.vertices(), a.vertices(), atol=1e-9)
    np.testing.assert_allclose(b.landmark_std_px, 2.0)
    assert b.point_std_px.shape == (2, 68)
    # SFM has no inner mouth corners (60, 64): not used, no noise
    assert np.isnan(b.point_std_px[:, 60]).all() and (b.point_std_px[:, 30] == 2.0).all()


def test_a_gross_error_with_a_large_sigma_barely_moves_the_fit(sfm, scene):
    verts, lm = scene
    clean = err(fit_landmarks(sfm, lm[:1], (512, 512)), verts)
    bad = gross(lm[:1])
    trusted = err(fit_landmarks(sfm, bad, (512, 512), landmark_std_px=1.0), verts)
    std = np.ones(68)
    std[GROSS] = 500.0
    doubted = fit_landmarks(sfm, bad, (512, 512), landmark_std_px=std)
    assert trusted > clean + 0.5, (trusted, clean)
    assert err(doubted, verts) < clean + 0.05, (err(doubted, verts), clean)
    # the reported noise: the points' own, and one per frame of the same total weight
    assert doubted.point_std_px[0, GROSS[0]] == 500.0
    used = np.isfinite(doubted.point_std_px[0])
    np.testing.assert_allclose(doubted.landmark_std_px[0],
                               1 / np.sqrt(np.mean(1 / doubted.point_std_px[0, used] ** 2)))


def test_per_frame_sigma(sfm, scene):
    """The gross errors are in frame 1 only: a large sigma there, per frame, keeps the shared
    fit; the same sigma given for frame 0's (good) points instead does not."""
    verts, lm = scene
    bad = gross(lm, frames=(1,))
    clean = err(fit_landmarks(sfm, lm, (512, 512)), verts)
    right, wrong = np.ones((2, 68)), np.ones((2, 68))
    right[1, GROSS] = 500.0
    wrong[0, GROSS] = 500.0
    e_right = err(fit_landmarks(sfm, bad, (512, 512), landmark_std_px=right), verts)
    e_wrong = err(fit_landmarks(sfm, bad, (512, 512), landmark_std_px=wrong), verts)
    assert e_right < clean + 0.05, (e_right, clean)
    assert e_wrong > clean + 0.5, (e_wrong, clean)


@pytest.mark.parametrize("shared", [True, False])
def test_a_huge_sigma_is_a_missing_point(sfm, scene, shared):
    _, lm = scene
    bad = gross(lm, frames=(0, 1))
    missing = bad.copy()
    missing[:, GROSS] = np.nan
    ref = fit_landmarks(sfm, missing, (512, 512), shared_identity=shared)
    for huge, atol in ((np.inf, 1e-9), (MISSING_STD_PX, 1e-9), (1e5, 1e-3)):
        std = np.ones(68)
        std[GROSS] = huge
        res = fit_landmarks(sfm, bad, (512, 512), landmark_std_px=std, shared_identity=shared)
        assert np.isfinite(res.vertices()).all()
        np.testing.assert_allclose(res.vertices(), ref.vertices(), atol=atol)
    # a point nobody is sure of does not count towards a frame's four usable points
    std = np.full(68, np.inf)
    std[[36, 45, 30]] = 1.0
    with pytest.raises(Exception, match="3 usable landmarks"):
        fit_landmarks(sfm, lm[:1], (512, 512), landmark_std_px=std)


def test_float32_inputs(sfm, scene):
    verts, lm = scene
    std = np.ones(68)
    std[GROSS] = 500.0
    a = fit_landmarks(sfm, gross(lm), (512, 512), landmark_std_px=std)
    b = fit_landmarks(sfm, gross(lm).astype(np.float32), np.float32([512, 512]),
                      landmark_std_px=std.astype(np.float32))
    np.testing.assert_allclose(b.vertices(), a.vertices(), atol=1e-3)


@pytest.mark.parametrize("std, match", [
    (np.full(68, np.nan), r"NaN at 0"),
    (np.r_[np.ones(67), 0.0], r"must be > 0, got 0 at 67"),
    (np.r_[np.ones(67), -1.0], r"must be > 0, got -1 at 67"),
    (np.ones(67), r"expected one number, \(68,\) or \(2, 68\) px, got shape \(67,\)"),
    (np.ones((3, 68)), r"got shape \(3, 68\)"),
    (np.ones((2, 68, 1)), r"got shape \(2, 68, 1\)"),
    (["a"] * 68, r"expected numbers"),
    ("guess", r"expected a number, an array or 'auto'"),
])
def test_bad_sigma(sfm, scene, std, match):
    _, lm = scene
    with pytest.raises(InputError, match="landmark_std_px: .*" + match) as e:
        fit_landmarks(sfm, lm, (512, 512), landmark_std_px=std)
    assert "\n" not in str(e.value)


def api_rows():
    """The rows of docs/bad_input.md's table of fit_landmarks calls -> [(call, message)]."""
    lines = DOC.read_text().splitlines()
    start = lines.index("| call | message |") + 2
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        cells = [c.strip().strip("`") for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
        rows.append((cells[0], cells[1]))
    return rows


@pytest.mark.parametrize("call, message", api_rows())
def test_bad_input_table_of_calls(sfm, scene, call, message):
    _, lm = scene
    ns = {"np": np, "fit_landmarks": fit_landmarks, "sfm": sfm, "lm": lm}
    with pytest.raises(InputError) as e:
        eval(call, ns)
    assert message in str(e.value) and "\n" not in str(e.value)


def test_3d_convention(sfm):
    """Labels in the 3D convention (the landmark network's: hidden jaw points where they
    project) at 60 degrees of yaw: the 3D convention fits them, the sliding outline does not;
    ``contour`` is the older name of the same choice."""
    rng = np.random.default_rng(2)
    alpha = 0.8 * rng.standard_normal(sfm.n_identity)
    verts = sfm.vertices(alpha)
    cam = Camera.looking_at_face((512, 512), yaw=60)
    lab = project_labels(verts, sfm.triangles, cam, label_schemes(sfm))
    e3 = err(fit_landmarks(sfm, lab["points68"], (512, 512), convention="3d"), verts)
    e2 = err(fit_landmarks(sfm, lab["points68"], (512, 512), convention="2d"), verts)
    assert e3 < 1.5 and e2 > 2 * e3, (e3, e2)
    a = fit_landmarks(sfm, lab["points478"], (512, 512), convention="3d")
    b = fit_landmarks(sfm, lab["points478"], (512, 512), contour="fixed")
    np.testing.assert_array_equal(a.vertices(), b.vertices())
    assert err(a, verts) < 2.0
    # hidden points count with their noise: doubting the far side's hidden points
    hidden = ~lab["visible478"]
    std = np.where(hidden, 5.0, 1.0)
    c = fit_landmarks(sfm, lab["points478"], (512, 512), convention="3d", landmark_std_px=std)
    assert err(c, verts) < 2.0 and np.isfinite(c.point_std_px[0, hidden]).all()


def test_detected_frames_are_one_look_at_the_face(sfm, scene):
    """A shared fit of N detected frames weighs its identity prior N times (one look at the
    face's shape); annotated frames count in full, independent fits do not change."""
    from morphable.fitting.options import detected_settings
    from morphable.fitting.problem import detector_looks

    _, lm = scene
    a = fit_landmarks(sfm, lm, (512, 512), detected=True)
    b = fit_landmarks(sfm, lm, (512, 512), prior_weight=2.0)
    np.testing.assert_allclose(a.vertices(), b.vertices(), atol=1e-9)
    c = fit_landmarks(sfm, lm, (512, 512), detected=[False, True])
    d = fit_landmarks(sfm, lm, (512, 512))
    np.testing.assert_allclose(c.vertices(), d.vertices(), atol=1e-9)     # 2 / (1 + 1)
    e = fit_landmarks(sfm, lm, (512, 512), detected=True, shared_identity=False)
    f = fit_landmarks(sfm, lm, (512, 512), shared_identity=False)
    np.testing.assert_allclose(e.vertices(), f.vertices(), atol=1e-12)
    assert detector_looks(np.array([True, True, False, False]), True) == 4 / 3
    s = detected_settings([True] * 3, 478)
    assert s["convention"] == "3d" and s["model_std_mm"].tolist() == [10.0] * 3
    assert s["detected"].all()
    assert detected_settings([True, False], 478).keys() == {"model_std_mm"}
    assert detected_settings([True], 68).keys() == {"model_std_mm"}


def test_bench_sigma_per_point_beats_one_sigma():
    """The benchmark's own claim on two faces: their own sigma fits better than their RMS."""
    from evaluation.bench_sigma import run

    table = run(2, [1], seed=0)["1"]
    assert set(table) == {"one sigma", "auto", "per point"}
    assert table["per point"]["mean_mm"] < table["one sigma"]["mean_mm"]
