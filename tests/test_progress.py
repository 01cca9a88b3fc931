"""Long runs show a tqdm progress bar and log through logging; --quiet turns both off."""
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _run(module, *args):
    return subprocess.run([sys.executable, "-m", module, *map(str, args)], capture_output=True,
                          text=True, cwd=REPO)


@pytest.fixture(scope="module")
def james(data_dir):
    pytest.importorskip("open3d")
    d = data_dir / "scans" / "james"
    return ["--scan", d / "james.obj", "--scan-landmarks", d / "james.ljson"]


def test_florence_progress_plot_and_quiet(james, tmp_path):
    small = [*james, "--methods", "mean-face", "--conditions", "outdoor", "indoor", "--frames", "1",
             "--video-frames", "2"]
    out = _run("evaluation.florence", *small, "--report", tmp_path / "r.json", "--plot", tmp_path / "b.png")
    assert out.returncode == 0, out.stderr
    assert "florence:" in out.stderr and "2/2" in out.stderr  # the bar reached the end
    assert "INFO:" in out.stderr and "mean-face outdoor" in out.stderr
    assert (tmp_path / "b.png").stat().st_size > 5000
    quiet = _run("evaluation.florence", *small, "--report", tmp_path / "q.json", "--quiet")
    assert quiet.returncode == 0, quiet.stderr
    assert quiet.stderr.strip() == "" and "mean-face" in quiet.stdout  # the table still prints
    bad = _run("evaluation.florence", *small, "--report", tmp_path / "x.json", "--plot", tmp_path / "x.gif")
    assert bad.returncode == 2 and "plots are written as" in bad.stderr
    assert not (tmp_path / "x.json").exists()  # refused before the run


def test_report_quiet(james, tmp_path):
    args = [*james, "--methods", "mean-face", "--conditions", "outdoor", "--video-frames", "10",
            "--out", tmp_path]
    out = _run("evaluation.report", *args)
    assert out.returncode == 0, out.stderr
    assert "error vs run time:" in out.stderr and "INFO:" in out.stderr
    quiet = _run("evaluation.report", *args, "--quiet")
    assert quiet.returncode == 0 and quiet.stderr.strip() == "", quiet.stderr
    assert (tmp_path / "error_vs_runtime.png").stat().st_size > 5000
