"""The example notebooks run top to bottom (nbclient), and the committed files are stripped and
match ``notebooks/build.py``."""
import importlib.util
import json
import sys
from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat")
nbclient = pytest.importorskip("nbclient")
pytest.importorskip("ipykernel")

NOTEBOOKS = Path(__file__).resolve().parents[1] / "notebooks"
NAMES = ["01_fit_a_photo.ipynb", "02_scan_evaluation.ipynb", "03_neural_renderer.ipynb"]


def _build_module():
    spec = importlib.util.spec_from_file_location("notebooks_build", NOTEBOOKS / "build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def kernel(tmp_path_factory):
    """A kernelspec for this interpreter, so the notebooks run in the same environment
    whatever kernels the user has installed elsewhere."""
    root = tmp_path_factory.mktemp("jupyter")
    spec = root / "kernels" / "morphable-test"
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(json.dumps({
        "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
        "display_name": "morphable tests", "language": "python"}))
    return root


@pytest.mark.parametrize("name", NAMES)
def test_committed_notebooks_are_stripped_and_current(name):
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    code = [c for c in nb.cells if c.cell_type == "code"]
    assert code and all(not c.outputs and c.execution_count is None for c in code)
    built = _build_module().build(name)
    assert [c.source for c in nb.cells] == [c.source for c in built.cells], \
        "notebook differs from notebooks/build.py: run .venv/bin/python notebooks/build.py"


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_notebook_runs(name, kernel, data_dir, tmp_path, monkeypatch):
    if name.startswith("03"):
        pytest.importorskip("torch")
    monkeypatch.setenv("JUPYTER_PATH", str(kernel))
    monkeypatch.setenv("MORPHABLE_SHARED_DATA", str(data_dir))
    monkeypatch.setenv("MORPHABLE_NOTEBOOK_OUT", str(tmp_path))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    # one thread: torch's thread pool oversubscribed on a busy 2-core machine runs ~30x slower
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    nb = nbformat.read(NOTEBOOKS / name, as_version=4)
    client = nbclient.NotebookClient(nb, kernel_name="morphable-test", timeout=240,
                                     resources={"metadata": {"path": str(NOTEBOOKS)}})
    client.execute()  # raises CellExecutionError with the failing cell's traceback
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.outputs
              if o.output_type == "error"]
    assert not errors
    written = {p.name for p in tmp_path.iterdir()}
    expected = {"01": {"overlay.png", "fit.obj", "fit.json"},
                "02": {"florence_bars.png", "heatmap_ours_cooperative.png"},
                "03": set()}[name[:2]]
    assert expected <= written
