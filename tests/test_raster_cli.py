"""``morphable bake`` and ``morphable render`` end to end (small images)."""
import json
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from morphable.camera import Camera


def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "morphable.cli", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd)


def decode_normals(path):
    rgb = np.asarray(Image.open(path)).astype(np.float64)
    fg = rgb.sum(-1) > 0
    return rgb / 255 * 2 - 1, fg


def test_bake_screen_with_depth_and_mask(tmp_path, data_dir):
    out = run("bake", "--model", "sfm", "--size", 64, "--yaw", 20, "--out", tmp_path / "n.png",
              "--depth", tmp_path / "d.png", "--mask", tmp_path / "m.png")
    assert out.returncode == 0, out.stderr
    n, fg = decode_normals(tmp_path / "n.png")
    assert n.shape == (64, 64, 3) and 0.2 < fg.mean() < 0.9
    assert np.abs(np.linalg.norm(n[fg], axis=-1) - 1).max() < 0.02
    assert np.median(n[fg][:, 2]) > 0.6  # camera frame: the face looks at the viewer
    mask = np.asarray(Image.open(tmp_path / "m.png")) > 0
    assert (mask == fg).mean() > 0.99
    depth = np.asarray(Image.open(tmp_path / "d.png"))
    assert depth.dtype.itemsize == 2 or Image.open(tmp_path / "d.png").mode.startswith("I")
    assert ((depth > 0) == mask).all()


def test_bake_uv_and_scan(tmp_path, data_dir):
    out = run("bake", "--model", "ict", "--space", "uv", "--size", 64, "--out", tmp_path / "uv.png")
    assert out.returncode == 0, out.stderr
    n, fg = decode_normals(tmp_path / "uv.png")
    assert fg.mean() > 0.5
    scan = data_dir / "scans/james/james.obj"
    out = run("bake", scan, "--camera", "perspective", "--size", 48, "--out", tmp_path / "s.png")
    assert out.returncode == 0, out.stderr
    assert decode_normals(tmp_path / "s.png")[1].mean() > 0.2


def test_bake_from_fit_report(tmp_path, sfm):
    cam = Camera.looking_at_face((80, 60), yaw=-15, kind="affine")
    report = {"model": "sfm", "identity": [0.5, -1.0],
              "frames": [{"yaw_deg": -15.0, "pitch_deg": 0.0, "roll_deg": 0.0,
                          "translation": cam.translation.tolist(), "camera": "affine",
                          "scale": cam.scale, "image_size": [80, 60],
                          "expression": {"happiness": 0.7}}]}
    fit = tmp_path / "fit.json"
    fit.write_text(json.dumps(report))
    out = run("bake", "--fit", fit, "--out", tmp_path / "n.png", "--mask", tmp_path / "m.png")
    assert out.returncode == 0, out.stderr
    mask = np.asarray(Image.open(tmp_path / "m.png")) > 0
    assert mask.shape == (60, 80)
    from morphable.raster import visibility

    v = sfm.vertices([0.5, -1.0], np.eye(6)[3] * 0.7)
    assert (mask == visibility(v, sfm.triangles, cam).mask).mean() > 0.995
    # the Camera.to_dict form works too, and --size rescales the view
    fit.write_text(json.dumps({"model": "sfm", "cameras": [cam.to_dict()]}))
    out = run("bake", "--fit", fit, "--size", 160, "--out", tmp_path / "n2.png",
              "--mask", tmp_path / "m2.png")
    assert out.returncode == 0, out.stderr
    m2 = np.asarray(Image.open(tmp_path / "m2.png")) > 0
    assert m2.shape == (120, 160)
    assert abs(m2.sum() / 4 - visibility(sfm.mean, sfm.triangles, cam).mask.sum()) < 40


def test_render_textured_scan_and_model(tmp_path, data_dir):
    out = run("render", data_dir / "scans/james/james.obj", "--yaw", 30, "--size", 64,
              "--supersample", 2, "--background", "0,0,1", "--out", tmp_path / "j.png")
    assert out.returncode == 0, out.stderr
    img = np.asarray(Image.open(tmp_path / "j.png")).astype(float)
    bg = (img == [0, 0, 255]).all(-1)
    assert 0.2 < (~bg).mean() < 0.9
    assert img[~bg][:, 0].mean() > img[~bg][:, 2].mean()  # skin tones from the texture
    out = run("render", "sfm", "--size", 48, "--light=-1,0,1,0.8", "--shadows",
              "--out", tmp_path / "s.png")
    assert out.returncode == 0, out.stderr
    img = np.asarray(Image.open(tmp_path / "s.png")).astype(float)
    fg = ~(img == 255).all(-1)
    cols = np.nonzero(fg.any(0))[0]
    left = slice(cols[0], cols[0] + 8)
    right = slice(cols[-1] - 7, cols[-1] + 1)
    # lit from the image's left
    assert img[:, left][fg[:, left]].mean() > img[:, right][fg[:, right]].mean() + 20
    # --sh: the constant term alone lights every pixel of the face alike (the colour as it is,
    # 0.75 -> 191); the x band lights the side facing +x (the image's right); 27 numbers are
    # r, g, b per coefficient
    for name, sh in (("uniform", "1" + ",0" * 8), ("x", "0.6,0,0,0.6" + ",0" * 5),
                     ("red", "1" + ",0" * 26)):
        out = run("render", "ict", "--size", 48, "--sh", sh, "--out", tmp_path / f"{name}.png")
        assert out.returncode == 0, out.stderr
    face = lambda name: np.asarray(Image.open(tmp_path / f"{name}.png")).astype(float)    # noqa: E731
    uniform = face("uniform")
    fg = ~(uniform == 255).all(-1)
    assert fg.mean() > 0.25 and (uniform[fg] == 191).all()
    assert (face("red")[fg] == [191, 0, 0]).all() and (face("red")[~fg] == 255).all()
    x = face("x")[..., 0]
    cols = np.flatnonzero(fg.any(0))
    left, right = (x[:, c:c + 8][fg[:, c:c + 8]].mean() for c in (cols[0], cols[-1] - 7))
    assert right > left + 80, (left, right)


@pytest.mark.parametrize("args,message", [
    (("bake", "nosuch.obj", "--out", "x.png"), "nosuch.obj: no such file"),
    (("bake", "--out", "x.jpg"), "x.jpg: output must be a .png"),
    (("bake", "--out", "nodir/x.png"), "output folder nodir does not exist"),
    (("bake", "--size", "0", "--out", "x.png"), "--size must be a positive"),
    (("bake", "--fit", "missing.json", "--out", "x.png"), "missing.json: cannot read"),
    (("bake", "--space", "uv", "--depth", "d.png", "--out", "x.png"), "--depth is for --space screen"),
    (("render", "--sh", "1,2", "--out", "x.png"), "expected 9 or 27 numbers"),
    (("render", "--light", "a,b,c", "--out", "x.png"), "expected numbers"),
    (("render", "--texture", "none.png", "--out", "x.png"), "none.png: no such texture file"),
    (("render", "--supersample", "0", "--out", "x.png"), "--supersample must be >= 1"),
    (("render", "--background", "bg.png", "--out", "x.png"), "bg.png: no such background image"),
    (("render", "--size", "64", "--background", "0,0", "--out", "x.png"), "expected 3 numbers"),
])
def test_errors_are_one_line_without_output(tmp_path, args, message):
    out = run(*args, cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and "Traceback" not in out.stderr
    assert not list(tmp_path.iterdir())


def test_bad_fit_report(tmp_path):
    (tmp_path / "f.json").write_text(json.dumps({"model": "sfm", "frames": [{"yaw_deg": 1}]}))
    out = run("bake", "--fit", "f.json", "--out", "x.png", cwd=tmp_path)
    assert out.returncode == 2 and "no usable camera" in out.stderr
    out = run("bake", "--fit", "f.json", "--frame", "3", "--out", "x.png", cwd=tmp_path)
    assert out.returncode == 2 and "frame 3 requested" in out.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.json"]
