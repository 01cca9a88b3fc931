"""Every row of the table in docs/bad_input.md: one stderr line, exit 2, nothing written.

The table is parsed from the document, so the document and the behaviour cannot drift apart.
"""
import json
import os
import pickle
import re
import shlex
import struct
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
DATA = REPO.parent / "shared" / "data"
DOC = REPO / "docs" / "bad_input.md"
ENV = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}


def table(heading_columns):
    """Rows of the markdown table whose header is ``| a | b | c |`` -> list of cell tuples
    with the backticks of code cells removed."""
    lines = DOC.read_text().splitlines()
    header = "| " + " | ".join(heading_columns) + " |"
    start = lines.index(header) + 2
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
        rows.append(tuple(re.sub(r"^`(.*)`$", r"\1", c) for c in cells))
    return rows


ROWS = table(["input", "command", "message"])


def _png_header(w, h):
    """A valid PNG claiming w x h pixels with a tiny body: size checks see a huge image,
    nothing large is written or decoded."""
    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\0" * 100)) + chunk(b"IEND", b""))


def make_fixtures(d: Path) -> None:
    from PIL import Image

    from morphable.io.landmark_files import read_pts, write_pts

    face_png, face_pts = DATA / "images" / "image_0010.png", DATA / "images" / "image_0010.pts"
    (d / "truncated.bin").write_bytes((DATA / "models/sfm/sfm_shape_3448.bin").read_bytes()[:1000])
    (d / "corrupt.npz").write_bytes(b"PK\x03\x04" + np.random.default_rng(0).bytes(1024))
    np.savez(d / "full.npz", a=np.zeros(10000))
    full = (d / "full.npz").read_bytes()
    (d / "truncated.npz").write_bytes(full[:len(full) // 2])
    (d / "full.npz").unlink()
    (d / "truncated.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n")
    (d / "tri.obj").write_text("v 0 0 0\nv 10 0 0\nv 0 10 0\nf 1 2 3\n")
    (d / "empty.obj").write_text("")
    (d / "nan.obj").write_text("v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n")
    (d / "corrupt.ply").write_bytes(
        b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\n"
        b"property float y\nproperty float z\nelement face 50\n"
        b"property list uchar int vertex_indices\nend_header\n" + b"\x01\x02" * 10)
    (d / "file.txt").write_text("a regular file\n")
    (d / "short.pts").write_text("version: 1\nn_points: 3\n{\n1 2\n3 4\n5 6\n}\n")
    text = face_pts.read_text()
    head, body = text.split("{", 1)
    (d / "nan.pts").write_text(head + "{" + body.replace(body.split()[0], "nan", 1))
    (d / "inf.ljson").write_text('{"version": 2, "landmarks": {"points": [[Infinity, 1.0]]}}')
    pts = read_pts(face_pts)
    pts[:, 0] += 5000
    write_pts(d / "outside.pts", pts)
    (d / "face.png").symlink_to(face_png)
    (d / "face.pts").symlink_to(face_pts)
    png = face_png.read_bytes()
    (d / "truncated.png").write_bytes(png[:len(png) // 3])
    (d / "huge.png").write_bytes(_png_header(8000, 6250))
    (d / "bomb.png").write_bytes(_png_header(20000, 10000))
    Image.new("RGB", (320, 240), (128, 128, 128)).save(d / "grey.png")
    rng = np.random.default_rng(2)
    Image.fromarray(rng.integers(0, 256, (240, 320, 3), dtype=np.uint8)).save(d / "noise.png")
    tiny = Image.new("RGB", (1500, 1000), (200, 200, 200))
    with Image.open(face_png) as im:
        tiny.paste(im.convert("RGB").resize((16, 13)), (900, 500))   # a face of ~6 px
    tiny.save(d / "tiny.png")
    mesh = rng.uniform(300, 700, (478, 2))
    np.save(d / "short.npy", mesh[:10])
    (d / "nan.json").write_text(json.dumps({"landmarks": [[float("nan"), 1.0]] + mesh[1:].tolist()}))
    (d / "mesh3d.json").write_text(json.dumps(np.c_[mesh, mesh[:, :1]].tolist()))
    (d / "emptydir").mkdir()
    (d / "corrupt.json").write_text('{"model": "sfm", "frames": [')
    (d / "bad.jsonl").write_text('{"image": "face.png"}\n[1, 2]\n')
    (d / "nocol.csv").write_text("path,subject\nface.png,x\n")
    (d / "truncated.ljson").write_text((DATA / "scans/james/james.ljson").read_text()[:2000])
    (d / "corrupt.h5").write_bytes(np.random.default_rng(1).bytes(3000))
    import h5py

    with h5py.File(d / "other.h5", "w") as f:
        f["x"] = [1, 2]
    (d / "truncated.pkl").write_bytes(pickle.dumps({"v_template": [1.0] * 1000})[:100])
    (d / "other.pkl").write_bytes(pickle.dumps({"a": 1}))
    from morphable.io.native import save_model_npz
    from morphable.model import MorphableModel

    save_model_npz(MorphableModel.from_arrays(mean=np.eye(3), triangles=[[0, 1, 2]], name="nouv"),
                   d / "nouv.npz")
    (d / "fit1.json").write_text(json.dumps({"model": "sfm", "frames": [{"image": "face.png"}]}))
    (d / "ictdir").mkdir()
    (d / "ictdir" / "generic_neutral_mesh.obj").write_text("")
    make_video_fixtures(d)


def make_video_fixtures(d: Path) -> None:
    """``text.mp4``, ``cut.mp4``, ``noframes.mp4``, ``grey.mp4`` (docs/bad_input.md)."""
    import av

    from morphable.video import write_video

    (d / "text.mp4").write_text("not a video\n")
    # the index first (as cameras write it), so that the cut file still opens and counts 60 frames
    out = av.open(str(d / "full.mp4"), "w", options={"movflags": "faststart"})
    s = out.add_stream("libx264", rate=30)
    s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
    rng = np.random.default_rng(3)
    for _ in range(60):
        for p in s.encode(av.VideoFrame.from_ndarray(rng.integers(0, 256, (48, 64, 3), dtype=np.uint8),
                                                     format="rgb24")):
            out.mux(p)
    for p in s.encode():
        out.mux(p)
    out.close()
    full = (d / "full.mp4").read_bytes()
    (d / "cut.mp4").write_bytes(full[:len(full) // 2])
    (d / "full.mp4").unlink()
    out = av.open(str(d / "noframes.mp4"), "w")   # a writer that got no frame: no video stream
    s = out.add_stream("libx264", rate=30)
    s.width, s.height, s.pix_fmt = 64, 48, "yuv420p"
    out.start_encoding()
    out.close()
    write_video(d / "grey.mp4", [np.full((240, 320, 3), 128, np.uint8)] * 10)


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory, data_dir):
    d = tmp_path_factory.mktemp("bad_input")
    make_fixtures(d)
    return d


def snapshot(d: Path) -> set:
    return {str(p.relative_to(d)) for p in d.rglob("*")}


def command(text: str) -> list:
    args = shlex.split(text.replace("$DATA", str(DATA)))
    if args[0] == "morphable":
        return [sys.executable, "-m", "morphable.cli", *args[1:]]
    assert args[0] == "python"
    return [sys.executable, *args[1:]]


@pytest.fixture(scope="module")
def outcomes(fixtures, tmp_path_factory):
    """Run every row, three at a time (they mostly wait for imports and I/O), each in its own
    copy of the fixture folder -> {row: (exit status, stderr, files before, files after)}."""
    import shutil
    from concurrent.futures import ThreadPoolExecutor

    root = tmp_path_factory.mktemp("rows")

    def run(i_row):
        i, (_, cmd, _) = i_row
        d = root / f"row{i:02d}"
        shutil.copytree(fixtures, d, symlinks=True)
        before = snapshot(d)
        r = subprocess.run(command(cmd), cwd=d, env=ENV, capture_output=True, text=True, timeout=180)
        return ROWS[i], (r.returncode, r.stderr, before, snapshot(d))

    with ThreadPoolExecutor(3) as pool:
        return dict(pool.map(run, enumerate(ROWS)))


def test_table_covers_every_entry_point():
    from morphable.cli import COMMANDS

    used = {shlex.split(cmd)[1] if cmd.startswith("morphable") else shlex.split(cmd)[2]
            for _, cmd, _ in ROWS}
    assert set(COMMANDS) - {"plot"} <= used
    assert {"evaluation.florence", "evaluation.report"} <= used
    assert len(ROWS) >= 60 and len(set(ROWS)) == len(ROWS)


@pytest.mark.parametrize("row", ROWS, ids=[f"{i:02d}-{r[1].split()[1]}" for i, r in enumerate(ROWS)])
def test_bad_input_row(outcomes, row):
    _, _, message = row
    code, stderr, before, after = outcomes[row]
    lines = [ln for ln in stderr.splitlines() if ln.strip()]
    assert code == 2, (code, stderr[-2000:])
    assert "Traceback" not in stderr
    assert len(lines) == 1, stderr
    assert message in lines[0], lines[0]
    assert after == before, f"output written despite the error: {sorted(after - before)}"


# --- accepted inputs (second table of the document) -----------------------------------------
ACCEPTED = table(["input", "command", "outcome"])


def _florence(d, scan, report):
    cmd = [sys.executable, "-m", "evaluation.florence", "--scan", str(scan),
           "--scan-landmarks", str(DATA / "scans/james/james.ljson"), "--methods", "mean-face",
           "--conditions", "cooperative", "--frames", "1", "--video-frames", "1",
           "--report", str(d / report)]
    r = subprocess.run(cmd, cwd=d, env=ENV, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads((d / report).read_text())["methods"]["mean-face"]["cooperative"]


def test_non_manifold_and_unreferenced_scans_give_the_clean_scans_numbers(tmp_path, data_dir):
    assert len(ACCEPTED) == 5
    lines = (DATA / "scans/james/james.obj").read_text().splitlines()
    lines = [ln for ln in lines if not ln.startswith(("mtllib", "usemtl"))]
    verts = [ln for ln in lines if ln.startswith("v ")]
    a, b = (int(x.split("/")[0]) for x in next(ln for ln in lines if ln.startswith("f ")).split()[1:3])
    p = np.array(verts[a - 1].split()[1:4], dtype=float)
    fan = [f"v {p[0] + k:.3f} {p[1] + k:.3f} {p[2] + 2 * k:.3f}" for k in (1.0, 2.0, 3.0)]
    fan += [f"f {a} {b} {len(verts) + 1 + i}" for i in range(3)]  # an edge shared by 5 triangles
    (tmp_path / "nonmanifold.obj").write_text("\n".join(lines + fan) + "\n")
    far = [f"v {1e4 + i} 1e4 1e4" for i in range(50)]
    (tmp_path / "unreferenced.obj").write_text("\n".join(lines + far) + "\n")
    import igl

    import trimesh
    nm = trimesh.load(tmp_path / "nonmanifold.obj", force="mesh", process=False)
    assert not igl.is_edge_manifold(np.asarray(nm.faces))[0]

    clean = _florence(tmp_path, DATA / "scans/james/james.obj", "clean.json")
    for name in ("nonmanifold", "unreferenced"):
        cell = _florence(tmp_path, tmp_path / f"{name}.obj", f"{name}.json")
        assert cell["mean_mm"] == pytest.approx(clean["mean_mm"], rel=1e-6), name
        assert np.isfinite(cell["mean_mm"]) and 0 < cell["mean_mm"] < 10


def test_huge_image_with_landmarks_is_fitted(fixtures, tmp_path):
    r = subprocess.run(command(f"morphable -q fit {fixtures / 'huge.png'} --landmarks "
                               f"{fixtures / 'face.pts'} --report {tmp_path / 'fit.json'}"),
                       env=ENV, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    rep = json.loads((tmp_path / "fit.json").read_text())
    assert rep["frames"][0]["image_size"] == [8000, 6250]
