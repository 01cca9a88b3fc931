"""GPU runs prepared on the CPU (docs/gpu_runs.md): loss terms read every few steps with the
same log, runs continued from committed weights (--init), the wide landmark network, what
travels to the GPU machine, the recipe for two steps, the step benchmark."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from morphable.errors import InputError, MorphableError  # noqa: E402
from neural.landmarks.network import ARCHES, LandmarkConfig, LandmarkNet, save_landmark_net  # noqa: E402
from neural.training import read_terms  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
TINY = dict(resolution=32, widths=(8, 8, 8, 8, 8), blocks=(0, 0, 1, 0, 0), hidden=16)


def _source(n=8, side=64, seed=0):
    from neural.faces.points import N_POINTS
    from neural.landmarks.data import LandmarkSource

    rng = np.random.default_rng(seed)
    points = rng.uniform(20, 44, (n, N_POINTS, 2)).astype(np.float32)
    return LandmarkSource("synthetic", "mem", rng.integers(0, 256, (n, side, side, 3), dtype=np.uint8),
                          points, np.ones((n, N_POINTS), np.float32),
                          np.tile(np.array([[12, 12, 52, 52]], np.float32), (n, 1)), np.zeros(n))


def _trainer(out, sync_every=None, **kw):
    from neural.landmarks.train import LandmarkTrainer

    cfg = LandmarkConfig(**{**TINY, **kw}, batch_size=4, steps=50, print_every=100,
                         sample_every=100, checkpoint_every=100, mix=(("synthetic", 1.0),))
    return LandmarkTrainer(cfg, out, {"synthetic": _source()}, {}, {}, sync_every=sync_every)


def _log(out):
    return [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]


def test_read_terms_reads_tensors_in_one_go():
    rows = [{"a": torch.tensor(1.5), "lr": 0.1}, {"a": torch.tensor(2.0, dtype=torch.bfloat16)}]
    assert read_terms(rows) == [{"a": 1.5, "lr": 0.1}, {"a": 2.0}]
    assert read_terms([{"lr": 1.0}]) == [{"lr": 1.0}]


def test_deferred_reads_log_every_step_the_same(tmp_path):
    """Read every 3 steps (a GPU's way) or every step (the CPU's): the same per-step log
    lines, the same weights; the CPU reads every step by default."""
    a, b = _trainer(tmp_path / "a"), _trainer(tmp_path / "b", sync_every=3)
    assert a.sync_every == 1 and b.sync_every == 3
    a.fit(progress=False, max_steps=7)
    b.fit(progress=False, max_steps=7)
    la, lb = _log(tmp_path / "a"), _log(tmp_path / "b")
    assert [r["step"] for r in lb] == list(range(1, 8))
    for ra, rb in zip(la, lb):
        assert {k: v for k, v in ra.items() if k != "seconds"} == \
            {k: v for k, v in rb.items() if k != "seconds"}
    for k, v in a.net.state_dict().items():
        assert torch.equal(v, b.net.state_dict()[k])


def test_divergence_found_at_the_read_names_its_step(tmp_path):
    t = _trainer(tmp_path / "nan", sync_every=4)
    losses = t.losses

    def poisoned(batch):
        loss, terms = losses(batch)
        if t.step == 2:          # the third step's loss is NaN
            terms["nll"] = torch.tensor(float("nan"))
        return loss, terms

    t.losses = poisoned
    with pytest.raises(MorphableError, match="diverged at step 3"):
        t.fit(progress=False, max_steps=6)
    assert not (tmp_path / "nan" / "checkpoint.pt").exists()


def test_landmark_init_continues_committed_weights(tmp_path, capsys):
    first = _trainer(tmp_path / "first")
    first.fit(progress=False, max_steps=2)
    weights = tmp_path / "first" / "landmarks.pt"
    t = _trainer(tmp_path / "second")
    assert t.init_from(weights) == {"path": str(weights), "images_seen": 8}
    for k, v in first.net.state_dict().items():
        assert torch.equal(v, t.net.state_dict()[k])
    assert t.opt.state == {}              # AdamW starts again, under the warm-up
    assert t.lr_at(0) < t.config.lr / 100
    t.fit(progress=False, max_steps=1)
    from neural.landmarks.network import load_landmark_net

    meta = load_landmark_net(tmp_path / "second" / "landmarks.pt").meta
    assert meta["images_seen"] == 8 + 4 and meta["init"]["path"] == str(weights)
    other = _trainer(tmp_path / "third", hidden=8)
    with pytest.raises(InputError, match="different network"):
        other.init_from(weights)
    with pytest.raises(InputError, match="cannot read"):
        other.init_from(tmp_path / "none.pt")


def test_wide_arch_loads_in_the_detector(tmp_path):
    """The GPU-sized network: 160 px, 3.67 M parameters, under 20 MB of weights; a weights
    file holds its config, so the detector runs it at its own resolution."""
    from neural.landmarks.detector import NetworkDetector

    cfg = LandmarkConfig(**ARCHES["wide"])
    net = LandmarkNet(cfg).eval()
    n = sum(p.numel() for p in net.parameters())
    assert cfg.resolution == 160 and 3.5e6 < n < 3.8e6
    assert n > 1.3 * sum(p.numel() for p in LandmarkNet(LandmarkConfig()).parameters())
    save_landmark_net(net, tmp_path / "wide.pt")
    assert (tmp_path / "wide.pt").stat().st_size < 20e6
    det = NetworkDetector(weights=tmp_path / "wide.pt", backend="torch")
    out = det.run(np.zeros((200, 200, 3), np.uint8), [[40, 40, 160, 160]])
    assert det.resolution == 160 and out["points"].shape == (1, 546, 2)


def test_landmark_script_arch_and_init_options(tmp_path, capsys):
    from neural.landmarks.train import build_parser, config_from

    cfg, _ = config_from(build_parser().parse_args(["--out", "x", "--arch", "wide"]))
    assert cfg.resolution == 160 and cfg.widths == ARCHES["wide"]["widths"]
    cfg, _ = config_from(build_parser().parse_args(["--out", "x", "--arch", "wide", "--set",
                                                    "hidden=64"]))
    assert cfg.hidden == 64 and cfg.resolution == 160


def test_gar_init_and_warm_up(tmp_path, data_dir):
    """A GAR run from a generator.pt: G, G_ema and D start at its weights, the learning
    rates ramp up over the warm-up, generator.pt counts the images seen before."""
    pytest.importorskip("open3d")
    from neural.gar.train import main

    args = ["--config", "tiny", "--set", "resolution=32", "channel_base=256", "channel_max=32",
            "z_dim=16", "w_dim=16", "aux_width=4", "batch_size=2", "--untrained-aux",
            "--threads", "1", "--quiet", "--steps", "2"]
    threads = torch.get_num_threads()
    try:
        assert main(args + ["--out", str(tmp_path / "a")]) == 0
        from neural.gar.config import get_config
        from neural.gar.auxnets import NAMES, load_aux
        from neural.gar.train import Trainer

        cfg = get_config("tiny", resolution=32, channel_base=256, channel_max=32, z_dim=16,
                         w_dim=16, aux_width=4, batch_size=2, steps=4)
        aux = {n: load_aux(n, pretrained=False, width=4) for n in NAMES}
        t = Trainer(cfg, tmp_path / "b", aux=aux)
        init = t.init_from(tmp_path / "a" / "generator.pt", warmup=4)
        assert init["images_seen"] == 4 and init["warmup"] == 4
        saved = torch.load(tmp_path / "a" / "generator.pt", weights_only=True)
        for k, v in saved["G"].items():
            assert torch.equal(t.G.state_dict()[k], v) and torch.equal(t.G_ema.state_dict()[k], v)
        t.fit(progress=False, max_steps=1)          # step 0 of the warm-up: 1/4 of the rate
        assert t.opt_g.param_groups[0]["lr"] == pytest.approx(cfg.g_lr / 4)
        assert main(args + ["--out", str(tmp_path / "c"), "--init",
                            str(tmp_path / "a" / "generator.pt"), "--init-warmup", "3"]) == 0
        done = torch.load(tmp_path / "c" / "generator.pt", weights_only=True)
        assert done["images_seen"] == 4 + 4 and done["init"]["warmup"] == 3
        bad = args + ["--out", str(tmp_path / "d"), "--init", str(tmp_path / "nothing.pt")]
        assert main(bad) == 2
    finally:
        torch.set_num_threads(threads)


def _git_tree(path: Path) -> Path:
    path.mkdir()
    run = lambda *a: subprocess.run(["git", *a], cwd=path, check=True, capture_output=True)  # noqa: E731
    run("init", "-q")
    (path / "code.py").write_text("x = 1\n")
    (path / "neural" / "landmarks" / "weights").mkdir(parents=True)
    (path / "neural" / "landmarks" / "weights" / "landmarks.pt").write_bytes(b"w" * 300_000)
    (path / "big.onnx").write_bytes(b"o" * 400_000)
    (path / ".gitignore").write_text("landmark_data/\n")
    (path / "landmark_data").mkdir()
    (path / "landmark_data" / "profiled_128.npz").write_bytes(b"p" * 100_000)
    run("add", "-A")
    run("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "tree")
    return path


def test_travel_plan_park_and_restore(tmp_path):
    from neural import gpu_travel

    root = _git_tree(tmp_path / "repo")
    plan = gpu_travel.travel_plan("landmarks", root)
    assert plan["park"] == ["big.onnx"] and plan["fits"]
    assert plan["carry"] == {"landmark_data/profiled_128.npz": 0.1}
    assert "gpu_kit" in plan["missing"]
    assert plan["total_mib"] == pytest.approx((300_000 + 100_000 + 6 + 17) / 2**20, abs=0.01)
    park = tmp_path / "park"
    gpu_travel.park("landmarks", root, park)
    assert not (root / "big.onnx").exists() and (park / "big.onnx").is_file()
    listed = subprocess.run(["git", "ls-files"], cwd=root, capture_output=True, text=True).stdout
    assert "big.onnx" not in listed and "landmarks.pt" in listed
    with pytest.raises(InputError, match="parked already"):
        gpu_travel.park("landmarks", root, park)
    assert gpu_travel.restore(root, park) == ["big.onnx"]
    status = subprocess.run(["git", "status", "--porcelain"], cwd=root, capture_output=True,
                            text=True).stdout
    assert status == "" and (root / "big.onnx").stat().st_size == 400_000
    with pytest.raises(InputError, match="nothing parked"):
        gpu_travel.restore(root, park)
    with pytest.raises(InputError, match="over 0.1 MiB"):
        gpu_travel.park("landmarks", root, park, budget_mib=0.1)
    assert (root / "big.onnx").exists()


def test_landmark_gpu_recipe_generates_and_continues_on_cpu(tmp_path, data_dir):
    """The landmark recipe for two steps on the CPU: synthetic faces rendered first from the
    travel kit, then the training, started from given weights."""
    pytest.importorskip("morphable.raster")
    from neural import gpu_travel

    try:
        kit = gpu_travel.copy_kit(data_dir, tmp_path / "kit")
    except InputError as e:
        pytest.skip(str(e))
    net = LandmarkNet(LandmarkConfig(**TINY))
    save_landmark_net(net, tmp_path / "init.pt")
    sizes = ["resolution=32", "widths=[8,8,8,8,8]", "blocks=[0,0,1,0,0]", "hidden=16"]
    out = tmp_path / "back"
    run = subprocess.run([sys.executable, "-m", "neural.gpu_recipe", "landmarks", "--generate", "6",
                          "--generate-px", "48", "--kit", str(kit), "--workers", "1",
                          "--init", str(tmp_path / "init.pt"),
                          "--out", str(out), "--runs", str(tmp_path / "runs"), "--device", "cpu",
                          "--max-steps", "2", "--batch-size", "4", "--set", *sizes],
                         capture_output=True, text=True, timeout=600, cwd=REPO)
    assert run.returncode == 0, run.stderr + (out / "log.txt").read_text()[-3000:]
    report = json.loads((out / "recipe.json").read_text())
    assert report["jobs"]["generate"]["returncode"] == 0
    summary = report["jobs"]["landmarks"]["summary"]
    assert summary["step"] == 2 and summary["images_per_second"] > 0
    from neural.landmarks.network import load_landmark_net

    meta = load_landmark_net(out / "landmarks_gpu.pt").meta
    assert meta["init"]["path"] == str(tmp_path / "init.pt")
    assert meta["packs"]["synthetic"][0]["faces"] == 6


def test_bench_training_step_shares_add_up(tmp_path):
    from evaluation.bench_training_step import main

    report = tmp_path / "r.json"
    threads = torch.get_num_threads()
    try:
        assert main(["--recipes", "landmarks", "--steps", "4", "--batch-size", "4",
                     "--sync-every", "4", "--report", str(report)]) == 0
    finally:
        torch.set_num_threads(threads)
    r = json.loads(report.read_text())["recipes"]["landmarks"]
    assert r["batch_size"] == 4 and r["steps"] == 4
    assert sum(r["ms"].values()) == pytest.approx(r["ms_per_step"], abs=0.5)
    assert {"data", "network", "rest"} <= set(r["ms"])
    # the loop's one read (.cpu() and .tolist()) every 4 steps, none in the steps
    assert r["reads_per_step"] == pytest.approx(0.5)
    assert main(["--recipes", "nothing"]) == 2


def test_gar_recipe_continues_committed_gars_one_at_a_time():
    from neural.gpu_recipe import CONTINUE, gar_recipe

    stages = gar_recipe("pack.npz", "runs", init=CONTINUE)
    assert [[j["name"] for j in s] for s in stages] == [["gar64"], ["gar128"], ["gar64_n0"],
                                                       ["inv64"], ["inv128"]]
    args = {s[0]["name"]: s[0]["args"] for s in stages}
    assert args["gar64"][args["gar64"].index("--init") + 1] == CONTINUE["gar64"]
    assert args["gar128"][args["gar128"].index("--init") + 1] == CONTINUE["gar128"]
    assert "--init" not in args["gar64_n0"]       # the ablation starts from scratch
    together = gar_recipe("pack.npz", "runs", side_by_side=True, compile=True)
    assert [len(s) for s in together] == [3, 2] and "--compile" in together[0][0]["args"]
    assert all((REPO / p).is_file() for p in CONTINUE.values())
