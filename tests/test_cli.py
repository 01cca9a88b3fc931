import json
import subprocess
import sys

import numpy as np
import pytest

from morphable.io import read_mesh


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "morphable.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd)


@pytest.mark.parametrize("model,expected", [("sfm", (3448, 63, 6)), ("ict", (26719, 100, 53))])
def test_info_json(model, expected, data_dir):
    out = run("info", "--model", model, "--json")
    assert out.returncode == 0, out.stderr
    info = json.loads(out.stdout)
    assert (info["n_vertices"], info["n_identity"], info["n_expression"]) == expected
    assert info["units"] == "mm" and info["n_landmarks"] > 40


def test_sample_writes_mesh_with_expression(tmp_path, sfm):
    a, b = tmp_path / "a.obj", tmp_path / "b.obj"
    assert run("sample", "--identity-std", "0", "--out", a).returncode == 0
    assert run("sample", "--identity-std", "0", "--expression", "surprise=1", "--out", b).returncode == 0
    va, vb = read_mesh(a).vertices, read_mesh(b).vertices
    np.testing.assert_allclose(va, sfm.mean, atol=1e-5)
    np.testing.assert_allclose(vb - va, sfm.expression_basis[5], atol=1e-4)


def test_convert_then_info(tmp_path):
    out = run("convert", "--model", "sfm", "--out", tmp_path / "m.npz")
    assert out.returncode == 0, out.stderr
    info = json.loads(run("info", "--model", tmp_path / "m.npz", "--json").stdout)
    assert info["n_vertices"] == 3448 and info["expression_names"][3] == "happiness"


@pytest.mark.parametrize("args,message", [
    (("info", "--model", "nosuchmodel"), "nosuchmodel: unknown model"),
    (("sample", "--expression", "joy=1", "--out", "x.obj"), "no expression 'joy'"),
    (("sample", "--expression", "happiness", "--out", "x.obj"), "expected NAME=WEIGHT"),
    (("sample", "--out", "missing_dir/x.obj"), "output folder missing_dir does not exist"),
    (("sample", "--out", "x.xyz"), "unknown mesh format"),
])
def test_errors_are_one_line(tmp_path, args, message):
    out = run(*args, cwd=tmp_path)
    assert out.returncode == 2
    assert "Traceback" not in out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0]
    assert not list(tmp_path.iterdir())  # no partial outputs


def test_corrupt_model_file(tmp_path, data_dir):
    bad = tmp_path / "broken.bin"
    bad.write_bytes((data_dir / "models/sfm/sfm_shape_3448.bin").read_bytes()[:100000])
    out = run("info", "--model", bad)
    assert out.returncode == 2 and "broken.bin: corrupt matrix header" in out.stderr
    assert "Traceback" not in out.stderr
