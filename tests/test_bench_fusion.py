"""evaluation.bench_fusion: the rules it compares, and that its Florence runs use the rule asked
for (the packs' table needs the landmark packs and the weights: run by hand, docs/landmark_net.md)."""
import numpy as np
import pytest

from morphable.detection import Detection


def _pair(offset, sigma=2.0, seed=0):
    rng = np.random.default_rng(seed)
    p = rng.uniform(0, 200, (478, 2))
    net = Detection(p, np.full(478, sigma), p[:68], np.full(68, sigma), "facemesh478", "3d", "network box")
    q = p + offset
    return net, Detection(q, None, q[:68], None, "facemesh478", "3d", "facemesh auto")


def test_the_independent_rule_is_the_librarys_and_the_others_bracket_it():
    from evaluation.bench_fusion import RULES, rule
    from morphable.detection.fusion import other_std_px

    for offset in (0.0, 3.0, 30.0):
        net, mesh = _pair(offset)
        got = {name: rule(name)(net, mesh) for name in RULES}
        assert got["independent"] == pytest.approx(other_std_px(net, mesh))
        if offset == 30.0:      # far apart: double > independent > half
            assert got["double"] > got["independent"] > got["half"]
        if offset == 0.0:       # agreeing exactly: every rule gives the floor
            assert len({round(v, 12) for v in got.values()}) == 1


def test_florence_runs_with_the_rule_asked_for(monkeypatch):
    from evaluation import bench_fusion
    from evaluation.florence import cli
    from morphable.detection import fusion

    seen = {}

    def florence(argv):
        net, mesh = _pair(30.0)
        seen["argv"], seen["sigma"] = argv, fusion.other_std_px(net, mesh)
        return 0

    monkeypatch.setattr(cli, "main", florence)
    assert bench_fusion.main(["florence", "half", "--", "--synthetic-scan", "sfm"]) == 0
    net, mesh = _pair(30.0)
    assert seen["argv"] == ["--synthetic-scan", "sfm"]
    assert seen["sigma"] == pytest.approx(bench_fusion.rule("half")(net, mesh))
    assert fusion.other_std_px(net, mesh) != seen["sigma"]      # the library's rule is back


def test_an_unknown_rule_is_one_line(capsys):
    from evaluation.bench_fusion import main

    with pytest.raises(SystemExit) as e:
        main(["florence", "triple", "--", "--synthetic-scan", "sfm"])
    assert e.value.code == 2
    assert "invalid choice: 'triple'" in capsys.readouterr().err
