import subprocess
import sys

import numpy as np
import pytest

pytest.importorskip("pyvista")
from PIL import Image  # noqa: E402

from morphable import InputError  # noqa: E402
from morphable.viewer import parse_size, show_mesh  # noqa: E402


def _foreground(path):
    img = np.asarray(Image.open(path).convert("RGB")).astype(int)
    return img, (np.abs(img - 255).sum(-1) > 30)


def test_screenshot_shows_the_mesh(tmp_path, sfm):
    out = show_mesh(sfm.mean, sfm.triangles, landmarks=sfm.landmark_positions(), size=(320, 240),
                    screenshot=tmp_path / "s.png")
    img, fg = _foreground(out)
    assert img.shape == (240, 320, 3)
    assert 0.05 < fg.mean() < 0.9
    ys, xs = np.nonzero(fg)
    assert abs(xs.mean() - 160) < 40 and abs(ys.mean() - 120) < 40  # centred
    # landmarks are red spheres
    red = (img[..., 0] > 150) & (img[..., 1] < 80) & (img[..., 2] < 80)
    assert red.sum() > 20


def test_error_map_uses_colours(tmp_path, sfm):
    e = np.linspace(0, 5, sfm.n_vertices)
    show_mesh(sfm.mean, sfm.triangles, errors=e, size=(320, 240), screenshot=tmp_path / "e.png")
    img, fg = _foreground(tmp_path / "e.png")
    colours = np.unique(img[fg] // 32, axis=0)
    assert len(colours) > 10  # a colour map, not one flat colour
    with pytest.raises(InputError, match="errors: 3 values"):
        show_mesh(sfm.mean, sfm.triangles, errors=np.zeros(3), screenshot=tmp_path / "x.png")
    assert not (tmp_path / "x.png").exists()


def test_views_differ(tmp_path, sfm):
    a = show_mesh(sfm.mean, sfm.triangles, view="left", size=(200, 200), screenshot=tmp_path / "l.png")
    b = show_mesh(sfm.mean, sfm.triangles, view="right", size=(200, 200), screenshot=tmp_path / "r.png")
    la, lb = _foreground(a)[1], _foreground(b)[1]
    # left and right profiles are near mirror images of each other
    assert (la ^ lb).mean() > 0.02 and (la ^ lb[:, ::-1]).mean() < (la ^ lb).mean()


def test_cli_show_and_errors(tmp_path):
    run = lambda *a: subprocess.run([sys.executable, "-m", "morphable.cli", *map(str, a)],  # noqa: E731
                                    capture_output=True, text=True, cwd=tmp_path)
    assert run("sample", "--out", "m.obj").returncode == 0
    out = run("show", "m.obj", "--landmarks", "--screenshot", "m.png", "--size", "300x200")
    assert out.returncode == 0, out.stderr
    assert Image.open(tmp_path / "m.png").size == (300, 200)
    bad = run("show", "m.obj", "--size", "big", "--screenshot", "n.png")
    assert bad.returncode == 2 and "expected WIDTHxHEIGHT" in bad.stderr
    bad = run("show", "m.obj", "--landmarks", "--model", "ict", "--screenshot", "n.png")
    assert bad.returncode == 2 and "landmarks need a mesh of the model" in bad.stderr
    assert not (tmp_path / "n.png").exists()


def test_parse_size():
    assert parse_size("1024x768") == (1024, 768)
    with pytest.raises(InputError):
        parse_size("0x10")
