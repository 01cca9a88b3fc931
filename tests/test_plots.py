"""Plots of evaluation reports: bar heights follow the numbers, curves, report kinds, errors."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from morphable import InputError

pytest.importorskip("matplotlib")
from evaluation.plots import (check_plot_path, condition_bars, error_vs_runtime,  # noqa: E402
                              fitting_sweep, plot_report, report_kind)

BLUE, ORANGE = (0x1F, 0x77, 0xB4), (0xFF, 0x7F, 0x0E)  # matplotlib's first two colours

FLORENCE = {"methods": {
    "ours": {"indoor": {"mean_mm": 2.0, "std_mm": 0.0}, "outdoor": {"mean_mm": 1.0, "std_mm": 0.0}},
    "eos": {"indoor": {"mean_mm": 1.0, "std_mm": 0.0}, "outdoor": {"error": "no landmarks"}}},
    "settings": {"frames": 5, "model": "sfm"}}

RUNTIME = {"scan": "james.obj", "conditions": ["indoor", "outdoor"], "methods": ["ours", "mean-face"],
           "points": [
               {"method": "ours", "label": "1 frames", "frames": 1, "s_per_video": 0.05, "mean_mm": 1.6,
                "per_condition": {"indoor": {"mean_mm": 1.5, "std_mm": 0.5},
                                  "outdoor": {"mean_mm": 1.7, "std_mm": 0.5}}},
               {"method": "ours", "label": "5 frames", "frames": 5, "s_per_video": 0.3, "mean_mm": 1.2,
                "per_condition": {"indoor": {"mean_mm": 1.1, "std_mm": 0.4},
                                  "outdoor": {"mean_mm": 1.3, "std_mm": 0.4}}},
               {"method": "mean-face", "label": "no fitting", "frames": 1, "s_per_video": 0.0,
                "mean_mm": 1.4, "per_condition": {"indoor": {"mean_mm": 1.4, "std_mm": 0.8},
                                                  "outdoor": {"mean_mm": 1.4, "std_mm": 0.8}}}]}

SWEEP = {"curves": {"sigma 1": [{"ms": 1.0, "mean_mm": 3.0}, {"ms": 4.0, "mean_mm": 2.0}]},
         "sigma_px": 1.0, "n": 10, "eos": {"ms": 8.0, "mean_mm": 2.5}}


def _pixels(path):
    return np.asarray(Image.open(path).convert("RGB")).astype(int)


def _mask(img, colour, tol=12):
    return np.abs(img - np.array(colour)).max(-1) <= tol


def _bar_heights(mask):
    """Heights (px) of the solid bars of one colour, left to right (blobs taller than the
    legend's patch)."""
    from scipy import ndimage

    boxes = ndimage.find_objects(ndimage.label(mask)[0])
    return [b[0].stop - b[0].start for b in sorted(boxes, key=lambda b: b[1].start)
            if b[0].stop - b[0].start > 12]


def test_bar_heights_follow_the_errors(tmp_path):
    img = _pixels(condition_bars(FLORENCE, tmp_path / "bars.png"))
    ours, eos = _bar_heights(_mask(img, BLUE)), _bar_heights(_mask(img, ORANGE))
    # ours: 2 mm indoor, 1 mm outdoor; eos: 1 mm indoor and a failed (empty) outdoor cell
    assert len(ours) == 2 and len(eos) == 1 and eos[0] > 10
    assert ours[0] == pytest.approx(2 * ours[1], rel=0.05)
    assert ours[1] == pytest.approx(eos[0], rel=0.05)


def test_runtime_plot_and_its_bars(tmp_path):
    img = _pixels(error_vs_runtime(RUNTIME, tmp_path / "rt.png"))
    assert _mask(img, BLUE).sum() > 50  # the curve of ours
    grey = _mask(img, (128, 128, 128), tol=4)
    assert grey.sum() > 100  # the mean face's dashed floor
    # bars of a runtime result: the best level of each method (ours: 5 frames, 1.1 / 1.3 mm)
    img = _pixels(condition_bars(RUNTIME, tmp_path / "b.png"))
    ours, floor = _bar_heights(_mask(img, BLUE)), _bar_heights(_mask(img, ORANGE))
    assert ours[1] / ours[0] == pytest.approx(1.3 / 1.1, rel=0.05)
    assert floor[0] == pytest.approx(floor[1], abs=1)


def test_report_kinds_and_files(tmp_path):
    assert [report_kind(r) for r in (RUNTIME, FLORENCE, SWEEP)] == ["runtime", "florence", "sweep"]
    for name, rep in (("r", RUNTIME), ("f", FLORENCE), ("s", SWEEP)):
        (tmp_path / f"{name}.json").write_text(json.dumps(rep))
        out = plot_report(tmp_path / f"{name}.json", tmp_path / f"{name}.png")
        img = _pixels(out)
        assert img.shape[0] > 300 and (img < 250).any(-1).mean() > 0.02  # drawn, not blank
    assert fitting_sweep(SWEEP, tmp_path / "s.svg").read_text().startswith("<?xml")
    (tmp_path / "bad.json").write_text("{\"x\": 1}")
    with pytest.raises(InputError, match="bad.json: not an evaluation report"):
        plot_report(tmp_path / "bad.json", tmp_path / "x.png")
    (tmp_path / "broken.json").write_text("{")
    with pytest.raises(InputError, match="broken.json: not JSON"):
        plot_report(tmp_path / "broken.json", tmp_path / "x.png")
    with pytest.raises(InputError, match="cannot be drawn as 'sweep'"):
        plot_report(tmp_path / "f.json", tmp_path / "x.png", kind="sweep")
    with pytest.raises(InputError, match="plots are written as"):
        check_plot_path(tmp_path / "x.gif")
    with pytest.raises(InputError, match="no methods"):
        condition_bars({"methods": {}}, tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_cli_plot(tmp_path):
    (tmp_path / "f.json").write_text(json.dumps(FLORENCE))
    repo = Path(__file__).resolve().parents[1]
    run = lambda *a: subprocess.run([sys.executable, "-m", "evaluation.plots", *map(str, a)],  # noqa: E731
                                    capture_output=True, text=True, cwd=tmp_path,
                                    env={**os.environ, "PYTHONPATH": str(repo)})
    out = run("f.json", "--out", "f.png")
    assert out.returncode == 0, out.stderr
    assert Image.open(tmp_path / "f.png").size[0] >= 500
    bad = run("missing.json", "--out", "m.png")
    assert bad.returncode == 2 and "missing.json: no such report" in bad.stderr
    assert bad.stderr.count("\n") == 1
    bad = run("f.json", "--out", "m.bmp")
    assert bad.returncode == 2 and "Traceback" not in bad.stderr
    assert not (tmp_path / "m.png").exists() and not (tmp_path / "m.bmp").exists()


def test_readme_pictures_are_committed_small_and_drawn():
    import re
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    names = set(re.findall(r"docs/img/[\w.-]+\.png", (repo / "README.md").read_text()))
    assert len(names) >= 4
    for name in names:
        path = repo / name
        assert path.is_file() and path.stat().st_size < 300_000, name
        img = _pixels(path)
        # not blank: a good share of non-white pixels and more than a handful of colours
        assert (img < 240).any(-1).mean() > 0.05 and len(np.unique(img.reshape(-1, 3) // 16, axis=0)) > 20
