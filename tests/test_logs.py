"""Our commands print only our own lines on stderr unless asked (morphable.logs)."""
import io
import logging
import warnings
from pathlib import Path

import pytest

from morphable import logs


@pytest.fixture
def stream():
    out = io.StringIO()
    yield out
    root = logging.getLogger()
    for h in list(root.handlers):
        if getattr(h, "_morphable", False):
            root.removeHandler(h)
    logging.captureWarnings(False)


def _speak():
    logging.getLogger("morphable.fitting").info("our info")
    logging.getLogger("morphable.batch").warning("our warning")
    logging.getLogger("matplotlib.font_manager").info("generated new fontManager")
    logging.getLogger("some.library").warning("library warning")
    logging.getLogger("some.library").debug("library debug")
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        warnings.warn("a library's UserWarning")


@pytest.mark.parametrize("verbosity, shown", [
    (-1, ["WARNING: our warning"]),
    (0, ["INFO: our info", "WARNING: our warning"]),
    (1, ["INFO: our info", "WARNING: our warning", "WARNING: library warning", "UserWarning"]),
    (2, ["INFO: our info", "generated new fontManager", "library debug", "UserWarning"]),
])
def test_verbosity_decides_who_speaks(stream, verbosity, shown):
    logs.configure(verbosity, stream=stream)
    _speak()
    text = stream.getvalue()
    for line in shown:
        assert line in text
    if verbosity <= 0:
        for chatter in ("fontManager", "library warning", "UserWarning", "library debug"):
            assert chatter not in text
    if verbosity < 0:
        assert "our info" not in text


def test_configure_twice_keeps_one_handler(stream):
    logs.configure(0, stream=stream)
    logs.configure(0, stream=stream)
    logging.getLogger("morphable").info("once")
    assert stream.getvalue().count("once") == 1


def test_fresh_matplotlib_cache_is_silent(tmp_path, data_dir):
    """matplotlib's first run on a machine logs 'generated new fontManager' at INFO: a command
    must not show it (it turned one-line errors into two on fresh machines)."""
    import os
    import subprocess
    import sys

    env = dict(os.environ, HOME=str(tmp_path), MPLCONFIGDIR=str(tmp_path / "mpl"),
               XDG_CACHE_HOME=str(tmp_path / "cache"))
    report = tmp_path / "r.json"
    report.write_text('{"sigma_px": 1, "n": 1, "curves": {"n_identity=5": '
                      '[{"n_iterations": 0, "ms": 1.0, "mean_mm": 2.0}]}}')
    run = subprocess.run([sys.executable, "-m", "evaluation.plots", str(report),
                          "--kind", "sweep", "--out", str(tmp_path / "p.png")],
                         capture_output=True, text=True, env=env, timeout=300,
                         cwd=Path(__file__).resolve().parents[1])
    assert run.returncode == 0, run.stderr
    assert (tmp_path / "mpl").is_dir()            # matplotlib did build its cache here
    assert run.stderr == ""


@pytest.mark.parametrize("argv, expected", [
    (["info"], 0), (["-q", "info"], -1), (["info", "-q"], -1), (["info", "--quiet"], -1),
    (["-v", "info"], 1), (["info", "-vv"], 2), (["fit", "a.png", "-q"], -1),
    (["fit", "a.png", "--frames", "3", "-v"], 1),
])
def test_verbosity_before_or_after_the_command(argv, expected):
    from morphable.cli import build_parser

    assert logs.verbosity(build_parser().parse_args(argv)) == expected
