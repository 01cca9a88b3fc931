"""The landmark network: crop geometry, its loss, the batches it trains on, its trainer and
both recipes of its one script (the GPU recipe for a few steps on the CPU)."""
import json
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from morphable.errors import InputError  # noqa: E402
from neural.landmarks.data import LandmarkSource, draw_batch, validation_batch  # noqa: E402
from neural.landmarks.cropping import crop_theta, crop_to_image, image_to_crop  # noqa: E402
from neural.landmarks.network import (LandmarkConfig, LandmarkNet, crop_images,  # noqa: E402
    gaussian_nll, load_landmark_net, points_in_crop_px, save_landmark_net)
from neural.faces.points import IBUG_START, N_POINTS, face_box, mirror_index  # noqa: E402

TINY = dict(resolution=32, widths=(8, 8, 8, 8, 8), blocks=(0, 0, 1, 0, 0), hidden=16)


def _dot_image(H, W, x, y):
    img = torch.zeros(1, 3, H, W)
    img[0, :, y, x] = 1.0
    return img


@pytest.mark.parametrize("angle,flip", [(0.0, False), (0.4, False), (-0.7, True)])
def test_crop_geometry_round_trip(angle, flip):
    H, W, R = 90, 130, 64
    img = _dot_image(H, W, 57, 33)
    theta = crop_theta(np.array([[20.0, 5.0, 100.0, 85.0]]), (W, H), [angle], [flip])
    crop = crop_images(img, theta, R)
    q = image_to_crop(np.array([[[57.0, 33.0]]]), theta, (W, H))
    px = points_in_crop_px(q, R)[0, 0]
    peak = divmod(int(crop[0, 0].flatten().argmax()), R)
    assert abs(peak[1] - float(px[0])) <= 1 and abs(peak[0] - float(px[1])) <= 1
    back = crop_to_image(q, theta, (W, H))
    np.testing.assert_allclose(back, [[[57.0, 33.0]]], atol=1e-9)


def test_gaussian_nll_minimum_and_unlabelled_nan():
    pred = torch.zeros(1, 2, 2)
    target = torch.tensor([[[3.0, 4.0], [np.nan, np.nan]]])
    weight = torch.tensor([[1.0, 0.0]])
    sig = torch.linspace(0.5, 10, 400)
    nll = torch.stack([gaussian_nll(pred, torch.full((1, 2), float(s)).log(), target, weight)
                       for s in sig])
    assert torch.isfinite(nll).all()
    best = float(sig[int(nll.argmin())])
    assert abs(best - 5 / math.sqrt(2)) < 0.05          # σ² = d² / 2 for 2-D points


def test_config_round_trip_and_checks():
    cfg = LandmarkConfig(**TINY, mix=(("synthetic", 1.0),))
    assert LandmarkConfig.from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg
    with pytest.raises(ValueError):
        LandmarkConfig(widths=(8, 8), blocks=(0,))
    with pytest.raises(ValueError):
        LandmarkConfig(resolution=48)


def test_net_outputs_save_load(tmp_path):
    torch.manual_seed(0)
    net = LandmarkNet(LandmarkConfig(**TINY)).eval()
    with torch.no_grad():
        out = net(torch.randn(3, 3, 32, 32))
    assert out["points"].shape == (3, N_POINTS, 2) and out["score"].shape == (3,)
    lo, hi = math.log(net.config.sigma_min_px), math.log(net.config.sigma_max_px)
    assert float(out["log_sigma"].min()) >= lo - 1e-6 and float(out["log_sigma"].max()) <= hi + 1e-6
    net.meta = {"note": "test"}
    save_landmark_net(net, tmp_path / "l.pt")
    again = load_landmark_net(tmp_path / "l.pt")
    assert again.meta == {"note": "test"}
    x = torch.randn(2, 3, 32, 32)
    assert torch.allclose(again(x)["points"], net(x)["points"])
    with pytest.raises(InputError, match="not found"):
        load_landmark_net(tmp_path / "missing.pt")
    (tmp_path / "bad.pt").write_bytes(b"not a torch file")
    with pytest.raises(InputError, match="bad.pt"):
        load_landmark_net(tmp_path / "bad.pt")


def _source(n=6, side=96, seed=0):
    """Faces of one bright 3 x 3 dot at the subject's right outer eye corner (iBUG 37, row
    478 + 36); its mirror row (iBUG 46) labelled elsewhere, where the image is dark."""
    rng = np.random.default_rng(seed)
    images = np.zeros((n, side, side, 3), np.uint8)
    points = np.full((n, N_POINTS, 2), np.nan, np.float32)
    weight = np.zeros((n, N_POINTS), np.float32)
    for i in range(n):
        x, y = rng.integers(35, 45), rng.integers(40, 50)
        images[i, y - 1:y + 2, x - 1:x + 2] = 255       # 3 x 3: bright after down-sampling
        points[i, IBUG_START + 36] = (x, y)
        points[i, IBUG_START + 45] = (x + 25, y)
        weight[i, [IBUG_START + 36, IBUG_START + 45]] = 1
    boxes = np.tile(np.array([[20, 20, 76, 76]], np.float32), (n, 1))
    return LandmarkSource("synthetic", "mem", images, points, weight, boxes, np.zeros(n))


def test_batches_mirror_rows_with_the_image():
    # little box jitter: the dot stays well inside the crop (this is about mirroring)
    cfg = LandmarkConfig(resolution=64, widths=(8,) * 6, blocks=(0,) * 6, hidden=16,
                         batch_size=6, negatives=0.0, mix=(("synthetic", 1.0),),
                         scale_jitter=0.05, shift_jitter=0.05)
    src = _source()
    seen_flipped = seen_plain = 0
    for step in range(6):
        b = draw_batch({"synthetic": src}, cfg, step)
        again = draw_batch({"synthetic": src}, cfg, step)
        assert torch.equal(b["image"], again["image"])          # (seed, step) reproducible
        for i in range(len(b["image"])):
            # the dot: the centroid of the (colour-jittered, maybe saturated) crop's bright blob
            lum = b["image"][i].mean(0)
            w = (lum - lum.median()).clamp_min(0)
            w = torch.where(w > 0.5 * w.max(), w, torch.zeros_like(w))
            yy, xx = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
            x, y = float((w * xx).sum() / w.sum()), float((w * yy).sum() / w.sum())
            rows = {r: points_in_crop_px(b["points"][i, r], 64) for r in (IBUG_START + 36,
                                                                          IBUG_START + 45)}
            if not all(bool(((p > 1) & (p < 62)).all()) for p in rows.values()):
                continue                         # the jitter moved a labelled point out of the crop
            d = {r: float(np.hypot(*(p.numpy() - (x, y)))) for r, p in rows.items()}
            if d[IBUG_START + 45] < 1.5:     # flipped: the dot is now the left eye's corner
                seen_flipped += 1
            else:
                assert d[IBUG_START + 36] < 1.5
                seen_plain += 1
    assert seen_flipped and seen_plain
    assert (mirror_index()[mirror_index()] == np.arange(N_POINTS)).all()


def test_negatives_carry_no_point_weight_and_validation_is_unjittered():
    cfg = LandmarkConfig(**TINY, batch_size=16, negatives=0.5, mix=(("synthetic", 1.0),))
    b = draw_batch({"synthetic": _source(8)}, cfg, 3)
    neg = b["face"] == 0
    assert neg.any() and (~neg).any()
    assert float(b["weight"][neg].sum()) == 0 and float(b["weight"][~neg].sum()) > 0
    v = validation_batch(_source(8), cfg, n=4)
    # without jitter the crop is the face box (centre 48, side 56): q = (p - 48) / 28
    q = v["points"][0, IBUG_START + 36]
    p = _source(8).points[v["index"][0], IBUG_START + 36]
    assert torch.allclose(q, (p - 48) / 28, atol=1e-4)


def test_face_box_framing():
    p = np.zeros((68, 2))
    p[:, 0] = np.linspace(10, 50, 68)
    p[:, 1] = np.linspace(20, 100, 68)
    x0, y0, x1, y1 = face_box(p)
    assert np.isclose(x1 - x0, 1.4 * 80) and np.isclose(y1 - y0, 1.4 * 80)
    assert np.isclose((x0 + x1) / 2, 30) and np.isclose((y0 + y1) / 2, 60 - 8)


def _tiny_trainer(tmp_path, **kw):
    from neural.landmarks.train import LandmarkTrainer

    cfg = LandmarkConfig(**{**TINY, **kw}, batch_size=4, steps=4, print_every=1,
                         sample_every=2, checkpoint_every=2, mix=(("synthetic", 1.0),))
    return LandmarkTrainer(cfg, tmp_path / "run", {"synthetic": _source(8)},
                           {"synthetic": _source(4, seed=1)},
                           {"synthetic": [{"path": "mem", "kind": "synthetic", "faces": 8}]})


def test_trainer_steps_checkpoint_resume(tmp_path):
    t = _tiny_trainer(tmp_path)
    assert t.fit(progress=False, max_steps=3) == 3
    run = tmp_path / "run"
    assert {"checkpoint.pt", "landmarks.pt", "summary.json", "log.jsonl",
            "validation.jsonl"} <= {p.name for p in run.iterdir()}
    val = [json.loads(line) for line in (run / "validation.jsonl").read_text().splitlines()]
    assert val[-1]["synthetic"]["n"] == 4 and np.isfinite(val[-1]["synthetic"]["nme_all_percent"])
    net = load_landmark_net(run / "landmarks.pt")
    assert net.meta["step"] == 3 and net.meta["images_seen"] == 12
    t2 = _tiny_trainer(tmp_path)
    assert t2.load() == 3
    assert t2.fit(progress=False) == 4
    t3 = _tiny_trainer(tmp_path, hidden=8)
    with pytest.raises(InputError, match="different network"):
        t3.load()


def test_script_gpu_recipe_on_cpu_and_bad_packs(tmp_path, capsys):
    """The one script with the GPU recipe's settings, run for two steps on the CPU on a tiny
    synthetic pack: the weights and summary.json it leaves are what a GPU run returns."""
    from neural.faces.build_synthetic import build
    from neural.landmarks.train import main

    pytest.importorskip("morphable.raster")
    try:
        build(tmp_path / "syn", n=6, resolution=48, seed=0, shard_size=3, textures=0,
              backgrounds="none")
    except InputError as e:           # no ../shared models on this machine
        pytest.skip(str(e))
    args = ["--out", str(tmp_path / "gpu"), "--synthetic", str(tmp_path / "syn"),
            "--recipe", "gpu", "--device", "cpu", "--max-steps", "2", "--hold-out", "0",
            "--set", "resolution=32", "widths=[8,8,8,8,8]", "blocks=[0,0,1,0,0]", "hidden=16",
            "batch_size=4", "-q"]
    assert main(args) == 0
    summary = json.loads((tmp_path / "gpu" / "summary.json").read_text())
    assert summary["step"] == 2 and summary["images_seen"] == 8
    assert summary["config"]["lr"] == pytest.approx(2 * LandmarkConfig().lr)   # gpu: lr x 2
    assert summary["amp"] == "bfloat16" and summary["images_per_second"] > 0
    assert load_landmark_net(tmp_path / "gpu" / "landmarks.pt").meta["packs"]["synthetic"]
    # the same through the GPU recipe runner: what comes back from the device machine
    import subprocess
    import sys

    run = subprocess.run([sys.executable, "-m", "neural.gpu_recipe", "landmarks", "--synthetic",
                          str(tmp_path / "syn"), "--out", str(tmp_path / "back"), "--runs",
                          str(tmp_path / "runs"), "--device", "cpu", "--max-steps", "1",
                          "--batch-size", "4", "--set", *args[args.index("--set") + 1:-2]],
                         capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr + (tmp_path / "back" / "log.txt").read_text()[-2000:]
    assert {p.name for p in (tmp_path / "back").iterdir()} == {
        "landmarks_gpu.pt", "validation_landmarks.jsonl", "recipe.json", "log.txt"}
    job = json.loads((tmp_path / "back" / "recipe.json").read_text())["jobs"]["landmarks"]
    assert job["returncode"] == 0 and job["summary"]["step"] == 1
    capsys.readouterr()
    rc = main(["--out", str(tmp_path / "x"), "--annotated", str(tmp_path / "nowhere"), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "nowhere" in err
    assert not (tmp_path / "x").exists()


def test_negative_crops_hold_no_whole_face():
    from neural.landmarks.data import NEGATIVE_KINDS, negative_crops

    cfg = LandmarkConfig(**TINY)
    src = _source(8)
    for kind in NEGATIVE_KINDS:
        x = negative_crops(None if kind == "texture" else src, cfg, 5, kind, seed=2)
        assert x.shape == (5, 3, 32, 32) and float(x.min()) >= -1 and float(x.max()) <= 1
        assert torch.equal(x, negative_crops(None if kind == "texture" else src, cfg, 5, kind, seed=2))
    # a part of the face is a crop inside its box, smaller than half of it: the dot (at
    # 35-45, 40-50 in a box of 20-76) fills much more of such a crop than of the face's crop
    part = negative_crops(src, cfg, 32, "part").mean(1)
    face = validation_batch(src, cfg, n=8)["image"].mean(1)
    assert float((part > 0.5).float().mean()) > 2 * float((face > 0.5).float().mean())
    with pytest.raises(InputError, match="kind must be one of"):
        negative_crops(src, cfg, 2, "sky")


def test_score_refit_changes_the_score_row_alone(tmp_path, monkeypatch):
    from neural.landmarks import train as train_landmarks
    from neural.landmarks.score import fit_logistic, main

    # logistic regression on separable features: the classes end on their sides
    h = torch.cat([torch.randn(40, 3) + 3, torch.randn(40, 3) - 3]).double()
    y = torch.cat([torch.ones(40), torch.zeros(40)])
    w, b = fit_logistic(h, y, torch.zeros(3), 0.0)
    assert bool(((h @ w + b > 0) == (y > 0.5)).all())
    # the script on a tiny net and faces: every weight but the score's row kept bit for bit
    save_landmark_net(LandmarkNet(LandmarkConfig(**TINY, mix=(("synthetic", 1.0),))), tmp_path / "in.pt")
    monkeypatch.setattr(train_landmarks, "load_sources",
                        lambda *a, **k: ({"synthetic": _source(12)}, {"synthetic": _source(6, seed=1)}, {}))
    assert main(["--weights", str(tmp_path / "in.pt"), "--synthetic", "mem", "--n", "24",
                 "--mining-photos", "2", "--threads", "1", "--out", str(tmp_path / "out.pt"),
                 "--report", str(tmp_path / "r.json")]) == 0
    a, b = (torch.load(tmp_path / f, weights_only=False) for f in ("in.pt", "out.pt"))
    changed = [k for k in a["state"] if not torch.equal(a["state"][k], b["state"][k])]
    assert changed and set(changed) <= {"head.3.weight", "head.3.bias"}
    rows = torch.nonzero((a["state"]["head.3.weight"] != b["state"]["head.3.weight"]).any(1)).ravel()
    assert rows.tolist() == [3 * N_POINTS]
    report = json.loads((tmp_path / "r.json").read_text())
    assert set(report["after"]) == {"recall synthetic", "false_positive away", "false_positive part",
                                    "false_positive texture", "noise photos with a face",
                                    "noise photos with a face, the detector"}
    assert report["mined_windows"] == 2 * 2 * 2 * 16      # 2 rounds, 2 photos, mirrored, top 16
    assert b["meta"]["score_refit"]["faces"] == 24
