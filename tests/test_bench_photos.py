"""The real-photo benchmarks' scoring: NME, |yaw| bins with failures, pose angles, identity consistency."""
import json
import numpy as np
import pytest

from evaluation.bench_alignment import (aflw_angles, box_size, eye_distance, load_300w,
                                        load_aflw2000, nme, yaw_table)
from evaluation.bench_identity import consistency, london_pairs
from morphable.errors import InputError


def test_nme_and_normalisers():
    gt = np.zeros((2, 68, 2))
    gt[:, :, 0] = np.linspace(0, 40, 68)
    gt[:, :, 1] = np.linspace(0, 10, 68)
    np.testing.assert_allclose(box_size(gt), 20.0)
    np.testing.assert_allclose(eye_distance(gt), np.hypot(*(gt[0, 45] - gt[0, 36])))
    pred = gt + [3.0, 4.0]
    pred[1] = np.nan
    e = nme(pred, gt, box_size(gt))
    assert e[0] == pytest.approx(25.0) and np.isnan(e[1])
    pred[0, [60, 64]] = np.nan          # SFM fits lack the inner mouth corners: scored on 66
    assert nme(pred, gt, box_size(gt))[0] == pytest.approx(25.0)


def test_yaw_table_counts_failures_in_their_bin():
    yaw = np.array([5.0, -29.0, 45.0, -80.0, 95.0, 61.0])
    err = np.array([1.0, 3.0, np.nan, 4.0, 6.0, np.nan])
    t = yaw_table(err, yaw)
    assert [b["photos"] for b in t["bins"]] == [2, 1, 3]
    assert [b["failures"] for b in t["bins"]] == [0, 1, 1]
    assert t["bins"][0]["nme_percent"] == pytest.approx(2.0)
    assert t["bins"][1]["nme_percent"] is None and t["mean_percent"] is None
    t = yaw_table(np.array([1.0, 2.0, 3.0]), np.array([0.0, 31.0, 70.0]))
    assert t["mean_percent"] == pytest.approx(2.0)


def test_aflw_angles_reorder_and_flip():
    np.testing.assert_allclose(aflw_angles([[10.0, 20.0, 30.0]]), [[-20.0, -10.0, -30.0]])


def test_consistency_identifies_identical_pairs():
    rng = np.random.default_rng(0)
    base = rng.normal(0, 30, (50, 3))
    people = [base + rng.normal(0, 3, base.shape) for _ in range(4)]
    neutral = np.stack(people)
    # the smiling photo's identity: the same person, moved, turned and scaled, a little off
    c, s = np.cos(0.3), np.sin(0.3)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    smiling = np.stack([1.1 * p @ R.T + 5 + rng.normal(0, 0.1, p.shape) for p in people])
    r = consistency(neutral, smiling)
    assert r["identification_rate"] == 1.0
    assert r["within_mm"] < 0.3 < r["between_median_mm"]
    smiling[2] = np.nan            # a failed fit drops out of the comparisons it is part of
    r = consistency(neutral, smiling)
    assert r["pairs_fitted"] == 3 and r["identification_rate"] == 1.0


def test_real_sets_load(data_dir):
    a = load_aflw2000(data_dir, 3)
    assert a["gt"].shape == (3, 68, 2) and np.isfinite(a["gt"]).all() and len(a["paths"]) == 3
    assert all(p.is_file() for p in a["paths"])
    w = load_300w(data_dir, 4)
    assert w["gt"].shape == (4, 68, 2) and set(w["subset"]) == {"afw", "helen"}
    pairs = london_pairs(data_dir)
    assert len(pairs) == 102 and all(n.is_file() and s.is_file() for _, n, s in pairs)


def test_iou():
    from morphable.detection.boxes import iou

    np.testing.assert_allclose(iou([[0, 0, 10, 10], [5, 0, 15, 10], [20, 20, 30, 30]], np.array([0, 0, 10, 10])),
                               [1.0, 50 / 150, 0.0])


def test_refined_method_scores_the_refined_fit(data_dir, tmp_path):
    pytest.importorskip("torch")
    pytest.importorskip("mediapipe")
    from evaluation.bench_alignment import main

    main(["--set", "aflw2000", "--n", "1", "--methods", "ours-facemesh", "ours-facemesh+classical",
          "--steps", "3", "--report", str(tmp_path / "r.json"), "-q"])
    rows = json.loads((tmp_path / "r.json").read_text())["aflw2000"]["methods"]
    plain, refined = rows["ours-facemesh"], rows["ours-facemesh+classical"]
    assert refined["failures"] == plain["failures"] == 0
    assert refined["pose_mae_deg"].keys() == plain["pose_mae_deg"].keys()      # a fit: its pose scored
    # three Adam steps move the fit a little: a different, nearby score
    assert refined["mean_percent"] is None or np.isfinite(refined["mean_percent"])
    a = [b["nme_percent"] for b in plain["bins"] if b["nme_percent"] is not None]
    b = [b["nme_percent"] for b in refined["bins"] if b["nme_percent"] is not None]
    assert len(a) == len(b) == 1 and a != b and abs(a[0] - b[0]) < 1.0


def test_ours_is_the_fit_with_the_default_detector(data_dir, tmp_path):
    pytest.importorskip("mediapipe")
    from evaluation.bench_alignment import main
    from morphable.detection import resolve_detectors

    default = resolve_detectors()[0]          # "fused" where the network can run
    main(["--set", "aflw2000", "--n", "2", "--methods", "ours", f"ours-{default}",
          "--report", str(tmp_path / "r.json"), "-q"])
    rows = json.loads((tmp_path / "r.json").read_text())["aflw2000"]["methods"]
    # both faces found: "auto" fits the default detector's points, pose and all
    assert rows["ours"]["failures"] == rows[f"ours-{default}"]["failures"] == 0
    assert rows["ours"]["bins"] == rows[f"ours-{default}"]["bins"]
    assert rows["ours"]["pose_mae_deg"] == rows[f"ours-{default}"]["pose_mae_deg"]


def test_refine_options_carry_the_gar_region(tmp_path):
    import argparse

    from evaluation.bench_alignment import add_refine_arguments, refine_options

    p = argparse.ArgumentParser()
    add_refine_arguments(p)
    assert refine_options(p.parse_args([])) == {"steps": 100, "renderer_options": None,
                                                "loss_weights": None}
    w = tmp_path / "g.pt"
    w.write_bytes(b"")
    opts = refine_options(p.parse_args(["--gar-weights", str(w), "--gar-region", "face", "--steps", "5",
                                        "--loss-weight", "lmk=10", "photo=0"]))
    assert opts == {"steps": 5, "renderer_options": {"gar": {"weights": str(w),
                                                             "photometric_region": "face"}},
                    "loss_weights": {"lmk": 10.0, "photo": 0.0}}
    with pytest.raises(SystemExit):
        p.parse_args(["--gar-region", "hair"])
    with pytest.raises(InputError, match="--loss-weight 'lmk=-1'"):
        refine_options(p.parse_args(["--loss-weight", "lmk=-1"]))


def test_refined_methods_refine_as_the_cli_does(monkeypatch):
    from evaluation.bench_alignment import REFINED, _fitted, refiner

    assert {"ours+photometric", "ours-fused+photometric", "ours-dlib+gar"} <= set(REFINED)
    assert not any(m.startswith(("dlib+", "fused+")) for m in REFINED)    # detectors: no fit to refine
    assert _fitted("ours+photometric") and not _fitted("fused")
    calls = []

    def refine_fit(fit, pictures, method, **options):
        calls.append((fit, pictures, method, options))
        return "refined fit", [], []
    monkeypatch.setattr("morphable.pipeline.refine.refine_fit", refine_fit)
    img = np.zeros((4, 6, 3), np.uint8)
    assert refiner("")(img, "fit") == "fit"
    assert refiner("photometric", 7, {"classical": {"a": 1}}, {"photo": 100.0})(img, "fit") == "refined fit"
    (fit, pictures, method, options), = calls
    assert fit == "fit" and method == "photometric" and pictures[0].size == (6, 4)
    assert pictures[0].pixels() is img
    assert options == {"steps": 7, "weights": {"photo": 100.0}, "renderer_options": {"a": 1}}
