"""The API reference (docs/api, ``make docs``): Sphinx builds it from the docstrings without a
warning, with a page for every module and every public docstring example shown; a reference to
nothing, a section numpydoc cannot parse and a module that does not import each fail the build."""
import doctest
import html
import importlib
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

REASON = "the API reference needs sphinx and numpydoc (the dev extra: pip install -e '.[dev]')"
pytest.importorskip("sphinx", reason=REASON)
pytest.importorskip("numpydoc", reason=REASON)

REPO = Path(__file__).resolve().parents[1]
BUILD = REPO / "docs" / "api" / "build.py"


def _build_module():
    spec = importlib.util.spec_from_file_location("api_build", BUILD)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _build(out, *args, path=()):
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([*map(str, path), str(REPO),
                                                        os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, str(BUILD), str(out), *args], capture_output=True,
                          text=True, env=env, timeout=900)


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    out = tmp_path_factory.mktemp("api")
    return out / "html", _build(out)


def _text(page: Path) -> str:
    return html.unescape(re.sub(r"<[^>]+>", "", page.read_text()))


@pytest.mark.slow
def test_the_reference_builds_without_a_warning(reference):
    _, run = reference
    assert run.returncode == 0, run.stderr[-6000:]


@pytest.mark.slow
def test_every_module_has_its_page(reference):
    html_dir, _ = reference
    build = _build_module()
    names = [n for p in build.PACKAGES for n in build.modules(p)]
    assert {"morphable.pipeline.fit", "neural.gar.networks", "neural.landmarks.network",
            "neural.faces.points", "neural.training", "evaluation.florence.cli"} <= set(names)
    missing = [n for n in names if not (html_dir / f"{n}.html").is_file()
               or f'id="module-{n}"' not in (html_dir / f"{n}.html").read_text()]
    assert not missing


@pytest.mark.slow
def test_every_public_docstring_example_is_shown(reference):
    html_dir, _ = reference
    build = _build_module()
    finder, shown, hidden = doctest.DocTestFinder(), 0, []
    flags = re.compile(r"\s*#\s*doctest:.*$")
    for name in (n for p in build.PACKAGES for n in build.modules(p)):
        module = importlib.import_module(name)
        page = None
        for test in finder.find(module):
            if not test.examples or any(p.startswith("_") for p in test.name[len(name):].split(".")):
                continue                               # private ones are not in the reference
            page = page or _text(html_dir / f"{name}.html")
            first = ">>> " + flags.sub("", test.examples[0].source.splitlines()[0])
            shown += first in page
            hidden += [] if first in page else [f"{test.name}: {first}"]
    assert not hidden
    assert shown > 50                                  # 87 when this test was written


def test_a_broken_docstring_fails_the_build(tmp_path):
    (tmp_path / "broken_docs.py").write_text('''"""A module with docstrings the reference refuses."""


def f(x):
    """Names :func:`no_such_function`.

    Parameters
    ----------
    x : int

    Result
    ------
    nothing
    """
''')
    run = _build(tmp_path / "out", "--modules", "broken_docs", "no_such_module", path=[tmp_path])
    assert run.returncode != 0
    assert "reference target not found: no_such_function" in run.stderr
    assert "numpydoc: Unknown section Result" in run.stderr
    assert "failed to import 'no_such_module'" in run.stderr
