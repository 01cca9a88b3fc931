"""Synthetic faces with exact labels (neural/faces/synthetic.py) and the pack builder
(neural/faces/build_synthetic.py), on tiny renders."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("torch")
pytest.importorskip("open3d")

from neural.faces.synthetic import LIGHTS, SyntheticEngine, label_exactness  # noqa: E402

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def engine():
    return SyntheticEngine("sfm", resolution=32, degrade=False, occluders=False)


def test_labels_land_on_their_surface(engine):
    parts = []
    for k in range(4):
        f = engine.sample(np.random.default_rng([1, k]))
        assert f["image"].shape == (32, 32, 3) and f["image"].dtype == np.uint8
        assert f["points68"].shape == (68, 2) and f["points478"].shape == (478, 2)
        assert np.isfinite(f["points478"]).all()
        # undefined iBUG rows are NaN and flagged, never silently
        assert np.isnan(f["points68"][~f["defined68"]]).all()
        assert np.isfinite(f["points68"][f["defined68"]]).all()
        parts.append(label_exactness(engine, f["params"], f, supersample=8))
    ex = {k: np.concatenate([q[k] for q in parts]) for k in parts[0]}
    assert len(ex["in_front_mm"]) > 300
    # a camera ray through each visible label's exact position reaches its point
    assert np.mean(ex["in_front_mm"] <= 0.01) > 0.98
    # the raster sample at the label shows the label's own surface, sub-pixel
    hit = np.isfinite(ex["offset_px"])
    assert hit.mean() > 0.97
    assert ex["offset_px"][hit].max() < 0.71 / 8 + 1e-6
    assert ex["own_raster"][hit].mean() > 0.9
    assert ex["hidden_blocked"].mean() > 0.9


@pytest.mark.parametrize("yaw", [90.0, -90.0])
def test_far_side_hidden_at_profile(engine, yaw):
    rng = np.random.default_rng(3)
    p = engine.draw(rng)
    p.update(pose=np.array([yaw, 0.0, 0.0]), distance_mm=1000.0, shift_px=np.zeros(2))
    f = engine.render(p)
    depth = f["camera"].depth(engine.schemes["478"].points(
        engine.model.vertices(p["identity"], p["expression"])))
    # the outer eye corners: the far one is hidden, the near one seen
    ibug = engine.schemes["68"]
    P = ibug.points(engine.model.vertices(p["identity"], p["expression"]))
    d = f["camera"].depth(P)
    far, near = (36, 45) if d[36] > d[45] else (45, 36)
    assert not f["visible68"][far] and f["visible68"][near]
    # the face-mesh points of the far half (20 mm or more beyond the middle) are all hidden
    far_half = depth > np.median(depth) + 20
    assert far_half.sum() > 50 and not f["visible478"][far_half].any()


def test_draw_covers_lights_and_poses():
    eng = SyntheticEngine("sfm", resolution=16)
    ps = [eng.draw(np.random.default_rng([0, k])) for k in range(40)]
    assert {p["light"] for p in ps} == set(LIGHTS)
    poses = np.array([p["pose"] for p in ps])
    assert np.abs(poses).max(0)[0] > 60 and (np.abs(poses) <= [90, 40, 30]).all()


def test_ict_engine():
    eng = SyntheticEngine("ict", resolution=24, degrade=True)
    f = eng.sample(0)
    assert f["visible478"].any() and f["defined68"].all()
    assert f["params"]["expression"].shape == (53,)


def _build(out, *extra):
    cmd = [sys.executable, "-m", "neural.faces.build_synthetic", "--out", str(out), "--n", "5",
           "--resolution", "16", "--shard-size", "2", "--textures", "0", "--backgrounds", "none",
           "--seed", "7", *extra]
    r = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    return r


def test_builder_resumes(tmp_path):
    from neural.faces.build_synthetic import load_pack

    out = tmp_path / "pack"
    r = _build(out)
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout.strip().splitlines()[-1])
    assert rep["faces"] == 5 and rep["shards_built_now"] == 3
    first = load_pack(out)
    assert first["image"].shape == (5, 16, 16, 3) and first["points478"].shape == (5, 478, 2)
    kept = (out / "shard_00000.npz").stat().st_mtime_ns
    (out / "shard_00001.npz").unlink()           # as if killed while writing it
    r = _build(out)
    rep = json.loads(r.stdout.strip().splitlines()[-1])
    assert rep["shards_built_now"] == 1 and rep["shards_skipped"] == 2 and rep["faces"] == 5
    assert (out / "shard_00000.npz").stat().st_mtime_ns == kept
    again = load_pack(out)
    for k in ("image", "points68", "visible478", "pose", "seed"):
        np.testing.assert_array_equal(np.nan_to_num(again[k]), np.nan_to_num(first[k]))
    # other settings in the same folder: refused, nothing changed
    r = _build(out, "--resolution", "24")
    assert r.returncode == 2 and "other settings" in r.stderr and len(r.stderr.splitlines()) == 1
    assert load_pack(out)["image"].shape == (5, 16, 16, 3)


def test_validation_faces_give_the_mean_identitys_points(engine):
    # the same face with the mean identity: same camera and expression, so the offsets are
    # the identity's own, a few percent of the face
    from evaluation.facemesh_synthetic import validation_faces

    faces = validation_faces(engine, 3, seed=5)
    off = faces["mean68"] - faces["points68"]
    size = np.ptp(np.nan_to_num(faces["points68"][:, :17]), axis=1).max(1)
    rms = np.sqrt(np.nanmean((off ** 2).sum(-1), 1)) / size
    assert faces["mean68"].shape == (3, 68, 2) and ((0.005 < rms) & (rms < 0.15)).all(), rms
    # a fit to the exact points comes nearer the true identity than the mean face; a face not
    # found is left out
    from evaluation.facemesh_synthetic import identity_fit_error

    exact = np.where(faces["defined68"][..., None], faces["points68"], np.nan)
    exact[1] = np.nan
    r = identity_fit_error(engine.model, exact, faces, 32)
    assert r["faces"] == 2 and r["fit_mm"] < r["mean_face_mm"], r


def test_identity_signal_measures_the_share_of_the_identity_the_points_carry():
    from evaluation.facemesh_synthetic import identity_signal

    rng = np.random.default_rng(0)
    n = 200
    mean = rng.uniform(40, 60, (n, 68, 2))
    mean[:, 0], mean[:, 1] = [10, 10], [90, 90]         # every face's box: 80 px
    ident = rng.normal(0, 1.0, (n, 68, 2))
    ident[:, :2] = 0
    faces = {"points68": mean + ident, "mean68": mean, "defined68": np.ones((n, 68), bool),
             "visible68": np.ones((n, 68), bool)}
    faces["defined68"][:, 60] = False                   # a point the model does not define
    bias = rng.normal(0, 3.0, (68, 2))                  # a definition every face shares
    for share in (0.0, 0.5, 1.0):
        pred = mean + share * ident + bias + rng.normal(0, 0.5, ident.shape)
        pred[:5] = np.nan                               # faces not found are left out
        r = identity_signal(pred, faces)
        assert r["faces"] == n - 5 and abs(r["reproduced"] - share) < 0.05, (share, r)
        assert 0.8 * 100 * np.sqrt(2) / 80 < r["identity_rms_percent"] < 1.2 * 100 * np.sqrt(2) / 80
    assert r["correlation"] > 0.85 and r["rest_rms_percent"] < 1.0
    exact = identity_signal(faces["points68"], faces)  # the true points: all of it, nothing else
    assert np.isclose(exact["reproduced"], 1) and np.isclose(exact["correlation"], 1)
