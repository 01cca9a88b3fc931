"""GAR training: a few-step smoke run, sample grids, checkpoints, kill and resume."""
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("open3d")

REPO = Path(__file__).resolve().parents[1]
ARGS = ["--config", "tiny", "--set", "resolution=32", "channel_base=256", "channel_max=32",
        "z_dim=16", "w_dim=16", "aux_width=4", "batch_size=2", "sample_every=3",
        "checkpoint_every=2", "r1_every=2", "--untrained-aux", "--threads", "1", "--quiet"]
STEPS = 8


def _steps(out: Path) -> list:
    log = out / "log.jsonl"
    return [json.loads(line)["step"] for line in log.read_text().splitlines()] if log.exists() else []


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory, data_dir):
    from neural.gar.train import main

    out = tmp_path_factory.mktemp("full")
    threads = torch.get_num_threads()
    try:
        assert main(ARGS + ["--out", str(out), "--steps", str(STEPS)]) == 0
    finally:
        torch.set_num_threads(threads)
    return out


def test_smoke_run_outputs(uninterrupted):
    out = uninterrupted
    assert _steps(out) == list(range(1, STEPS + 1))
    rows = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert {"n", "ldmk", "id", "adv", "d", "g_total"} <= set(rows[0]) and "r1" in rows[0]
    assert all(all(v == v for v in r.values()) for r in rows)          # no NaN
    samples = sorted(p.name for p in (out / "samples").iterdir())
    assert samples == ["step-000003.png", "step-000006.png", "step-000008.png"]
    from PIL import Image

    grid = Image.open(out / "samples" / "step-000008.png")
    assert grid.size == (7 * 32, 4 * 32)  # rows: 4 normal maps, each followed by 6 latents
    ckpt = torch.load(out / "checkpoint.pt", weights_only=True)
    assert ckpt["step"] == STEPS and ckpt["config"]["resolution"] == 32
    gen = torch.load(out / "generator.pt", weights_only=True)
    from neural.gar.config import GARConfig
    from neural.gar.networks import Generator

    G = Generator(GARConfig.from_dict(gen["config"]))
    G.load_state_dict(gen["G"])
    n = torch.zeros(1, 3, 32, 32)
    n[:, 2] = 1
    assert torch.isfinite(G(n, torch.randn(1, 16))).all()


def test_kill_and_resume_matches_uninterrupted(uninterrupted, tmp_path):
    out = tmp_path / "run"
    args = [*ARGS, "--out", str(out), "--steps", str(STEPS)]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    # kill -9 as step 4 is done and not yet logged, the checkpoint of step 2 on disk
    # (tests/killed.py: a kill at a known point, no race between a poll and the steps)
    proc = subprocess.run([sys.executable, str(REPO / "tests" / "killed.py"), "neural.gar.train:Trainer.train_step",
                           "4", "neural.gar.train", *args], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=180)
    assert proc.returncode == -signal.SIGKILL, proc.stderr[-2000:]
    assert _steps(out) == [1, 2, 3]
    saved = torch.load(out / "checkpoint.pt", weights_only=True)["step"]
    assert saved == 2
    # rerunning the same command resumes from the checkpoint and finishes (without --quiet,
    # which keeps warnings only: the resume is an info line)
    cmd = [sys.executable, "-m", "neural.gar.train", *(a for a in args if a != "--quiet")]
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "resuming from" in done.stderr
    steps = _steps(out)
    assert steps[-1] == STEPS and steps[steps.index(saved) + 1:].count(saved + 1) >= 1
    a = torch.load(out / "checkpoint.pt", weights_only=True)
    b = torch.load(uninterrupted / "checkpoint.pt", weights_only=True)
    for key in ("G", "D", "G_ema"):
        for name, value in a[key].items():
            torch.testing.assert_close(value, b[key][name], atol=1e-5, rtol=1e-4,
                                       msg=f"{key}.{name} differs after resume")


def test_lazy_contrastive_terms(tmp_path, data_dir):
    from neural.gar.train import main

    out = tmp_path / "lazy"
    threads = torch.get_num_threads()
    try:
        at = ARGS.index("--untrained-aux")
        assert main(ARGS[:at] + ["contrastive_every=3"] + ARGS[at:]
                    + ["--out", str(out), "--steps", "7"]) == 0
        assert main(ARGS[:at] + ["contrastive_every=0"] + ARGS[at:]
                    + ["--out", str(tmp_path / "zero"), "--steps", "1"]) == 2
    finally:
        torch.set_num_threads(threads)
    rows = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    # step k (logged as k + 1) has the terms when k % 3 == 0
    assert [r["step"] for r in rows if "ldmk" in r and "id" in r] == [1, 4, 7]
    assert all({"n", "adv", "d"} <= set(r) for r in rows)
    cfg = torch.load(out / "generator.pt", weights_only=True)["config"]
    assert cfg["contrastive_every"] == 3


def test_bad_arguments_one_line_error(tmp_path, capsys):
    from neural.gar.train import main

    assert main(["--out", str(tmp_path / "x"), "--config", "huge"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "huge" in err
    assert main(["--out", str(tmp_path / "y"), "--set", "resolution"]) == 2
    assert "key=value" in capsys.readouterr().err
    assert not (tmp_path / "y").exists()


def test_time_budget_stops_with_checkpoint(tmp_path, data_dir):
    from neural.gar.train import main

    out = tmp_path / "budget"
    threads = torch.get_num_threads()
    try:
        assert main(ARGS + ["--out", str(out), "--steps", "5", "--max-minutes", "0"]) == 0
    finally:
        torch.set_num_threads(threads)
    assert torch.load(out / "checkpoint.pt", weights_only=True)["step"] == 0
    assert (out / "samples" / "step-000000.png").is_file() and _steps(out) == []


def test_resume_with_another_architecture_one_line_error(uninterrupted, tmp_path, capsys):
    import shutil

    from neural.gar.train import main

    out = tmp_path / "other"
    shutil.copytree(uninterrupted, out)
    before = (out / "checkpoint.pt").read_bytes()
    threads = torch.get_num_threads()
    try:
        at = ARGS.index("--untrained-aux")        # one more --set item
        rc = main(ARGS[:at] + ["nim_background=false"] + ARGS[at:]
                  + ["--out", str(out), "--steps", str(STEPS + 2)])
    finally:
        torch.set_num_threads(threads)
    err = capsys.readouterr().err.strip().splitlines()[-1]     # after the untrained-aux warning
    assert rc == 2 and f"error: {out / 'checkpoint.pt'}: " in err, err
    assert "nim_background True, not False" in err and "--set nim_background=true" in err
    assert (out / "checkpoint.pt").read_bytes() == before
