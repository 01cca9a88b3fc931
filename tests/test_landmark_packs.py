"""The landmark packs (neural/faces/build_annotated.py, neural/faces/build_profiled.py, neural/faces/shards.py,
neural/faces/annotations.py, neural/faces/packs.py) on a tiny copy of the shared data."""
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import DATA

REPO = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.skipif(not (DATA / "faces" / "aflw_crops" / "index.npz").is_file()
                                or not (DATA / "aflw2000").is_dir(), reason="no shared data")


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    """3 AFLW crops, 2 London photos, 2 300-W photos, 2 AFLW2000-3D photos."""
    root = tmp_path_factory.mktemp("data")
    a = root / "faces" / "aflw_crops"
    (a / "crops").mkdir(parents=True)
    with np.load(DATA / "faces" / "aflw_crops" / "index.npz") as z:
        d = {k: z[k][[0, 1, 2]] for k in z.files}
    np.savez(a / "index.npz", **d)
    for n in d["names"]:
        shutil.copy(DATA / "faces" / "aflw_crops" / "crops" / n, a / "crops" / n)
    lo = root / "faces" / "frl_london" / "neutral_front"
    lo.mkdir(parents=True)
    for s in ("001_03", "002_03"):
        for ext in (".jpg", ".tem"):
            shutil.copy(DATA / "faces" / "frl_london" / "neutral_front" / (s + ext), lo)
    w = root / "images" / "300w" / "afw"
    w.mkdir(parents=True)
    for p in sorted((DATA / "images" / "300w" / "afw").glob("*.pts"))[:2]:
        shutil.copy(p, w)
        shutil.copy(p.with_suffix(".jpg"), w)
    f = root / "aflw2000"
    f.mkdir()
    with np.load(DATA / "aflw2000" / "landmarks.npz") as z:
        d = {k: (z[k][:2] if z[k].ndim else z[k]) for k in z.files}
    np.savez(f / "landmarks.npz", **d)
    for n in d["names"]:
        shutil.copy(DATA / "aflw2000" / n, f)
    return root


def _run(module, *args):
    r = subprocess.run([sys.executable, "-m", module, *map(str, args)], cwd=REPO,
                       capture_output=True, text=True, timeout=300)
    return r


def _report(r):
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1])


def test_annotated_pack_layout_resume_refusal(tiny, tmp_path):
    from neural.faces.packs import load_pack
    from neural.faces.points import N_POINTS

    out = tmp_path / "ann"
    rep = _report(_run("neural.faces.build_annotated", "--data", tiny, "--out", out, "--resolution", 48,
                       "--shard-size", 4))
    assert rep["shards_built_now"] == 3 and rep["shards_skipped"] == 0
    fails = sum(sum(v.values()) for v in rep["failures_by_source"].values())
    assert rep["faces"] + fails == 9
    by = rep["faces_by_source"]
    # the benchmark sets are test data only
    assert by["300w"]["test"] + sum(rep["failures_by_source"]["300w"].values()) == 2
    assert by["aflw2000"] == {"train": 0, "validation": 0, "test": 2}
    assert by["london"]["test"] == by["aflw"]["test"] == 0
    d = load_pack(out)
    n = rep["faces"]
    assert d["image"].shape == (n, 48, 48, 3) and d["image"].dtype == np.uint8
    assert d["points"].shape == (n, N_POINTS, 2) and d["labelled"].shape == (n, N_POINTS)
    assert (np.isfinite(d["points"]).all(-1) == d["labelled"]).all()
    assert not (d["visible"] & ~d["labelled"]).any()
    # annotated points are seen ones, except AFLW2000-3D's, which label hidden points too
    seen = np.isin(d["source"], [0, 1, 2])
    np.testing.assert_array_equal(d["visible"][seen], d["labelled"][seen])
    src = np.array(d["sources"])[d["source"]]
    assert (d["labelled"][src == "aflw"].sum(1) <= 19).all()
    assert (d["labelled"][src == "300w"].sum(1) == 68).all()
    assert (d["convention"][src == "300w"] == 1).all() and (d["convention"][src == "aflw2000"] == 0).all()
    # the face box sits in the middle of the crop, 1 / 1.5 of its side
    side = d["box"][:, 2] - d["box"][:, 0]
    np.testing.assert_allclose(side, 48 / 1.5, rtol=1e-3)
    np.testing.assert_allclose((d["box"][:, 0] + d["box"][:, 2]) / 2, 23.5, atol=1e-3)
    manifest = json.loads((out / "pack.json").read_text())
    assert manifest["settings"]["format"] == "landmarks-1" and manifest["kind"] == "annotated"
    assert [s["name"] for s in manifest["sources"]] == ["aflw", "london", "300w", "aflw2000"]
    # resume: a lost shard is rebuilt, the others are kept
    kept = (out / "shard_00000.npz").stat().st_mtime_ns
    (out / "shard_00001.npz").unlink()
    rep2 = _report(_run("neural.faces.build_annotated", "--data", tiny, "--out", out, "--resolution", 48,
                        "--shard-size", 4))
    assert rep2["shards_built_now"] == 1 and rep2["shards_skipped"] == 2 and rep2["faces"] == n
    assert (out / "shard_00000.npz").stat().st_mtime_ns == kept
    np.testing.assert_array_equal(load_pack(out)["image"], d["image"])
    # other settings: refused in one line, nothing changed
    r = _run("neural.faces.build_annotated", "--data", tiny, "--out", out, "--resolution", 64,
             "--shard-size", 4)
    assert r.returncode == 2 and "other settings" in r.stderr and len(r.stderr.splitlines()) == 1
    assert load_pack(out)["image"].shape[1] == 48
    # a compact copy reads back to the same labels
    from neural.faces.packs import compact

    info = compact(out, tmp_path / "c.npz", resolution=24)
    c = load_pack(tmp_path / "c.npz")
    assert info["faces"] == n and c["image"].shape == (n, 24, 24, 3)
    np.testing.assert_array_equal(c["labelled"], d["labelled"])
    np.testing.assert_allclose(c["points"], (d["points"] + 0.5) / 2 - 0.5, atol=0.02)


@pytest.mark.parametrize("module", ["neural.faces.build_annotated", "neural.faces.build_profiled"])
def test_folder_without_data(tmp_path, module):
    (tmp_path / "empty").mkdir()
    r = _run(module, "--data", tmp_path / "empty", "--out", tmp_path / "p")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1
    assert "no london data" in r.stderr or "no aflw data" in r.stderr
    assert not (tmp_path / "p").exists()


def test_aflw_mapping_left_right(tiny):
    """The mapped AFLW points fit SFM with each point next to its own row's projection: the
    image-left eye's outer corner (AFLW 6) is nearer the fit's iBUG 36 than iBUG 45, and so on
    for every left/right pair."""
    import morphable
    from neural.faces.annotations import AFLW21_ROWS, fit_item, set_items
    from neural.faces.points import IBUG_START, mirror_index

    model = morphable.load_model("sfm")
    mirror = mirror_index()
    checked = 0
    for item in set_items(tiny, "aflw"):
        _, P, _ = fit_item(model, item, (120, 120))
        rows = item["rows"]
        ok = np.isfinite(item["points"]).all(1)
        own = np.linalg.norm(P[rows] - item["points"], axis=1)
        other = np.linalg.norm(P[mirror[rows]] - item["points"], axis=1)
        sided = ok & (mirror[rows] != rows)
        assert (own[sided] < other[sided]).all()
        checked += sided.sum()
    assert checked > 20
    assert AFLW21_ROWS[6] == IBUG_START + 36 and AFLW21_ROWS[7] == 468


def test_validation_split_fixed():
    from neural.faces.shards import validation_split

    keys = [f"k{i}" for i in range(4000)]
    v = validation_split(keys)
    assert 0.08 < v.mean() < 0.12
    np.testing.assert_array_equal(v, validation_split(keys))
    assert validation_split(["london/002"])[0] and not validation_split(["london/001"])[0]


def test_profiled_pack(tiny, tmp_path):
    from neural.faces.packs import load_pack

    out = tmp_path / "prof"
    args = ("--data", tiny, "--out", out, "--per-photo", 2, "--aflw", 1, "--resolution", 32,
            "--shard-size", 2)
    rep = _report(_run("neural.faces.build_profiled", *args))
    assert rep["shards_built_now"] == 2
    d = load_pack(out)
    src = np.array(d["sources"])[d["source"]]
    assert (src == "london").sum() == 4 and set(src) <= {"london", "aflw"}
    assert (d["convention"] == 0).all() and (d["split"] < 2).all()
    # dense labels: all 478 face-mesh rows and 66 of the iBUG rows on SFM; part of them hidden
    assert (d["labelled"][:, :478]).all() and (d["labelled"][:, 478:].sum(1) == 66).all()
    assert d["visible"].sum(1).min() > 100 and (~d["visible"] & d["labelled"]).sum(1).min() > 20
    # London persons are in the same split as in the annotated pack's rule
    from neural.faces.shards import validation_split

    lon = src == "london"
    keys = [f"london/{p:03d}" for p in d["person"][lon]]
    np.testing.assert_array_equal(d["split"][lon], validation_split(keys).astype(np.uint8))
    rep2 = _report(_run("neural.faces.build_profiled", *args))
    assert rep2["shards_built_now"] == 0 and rep2["shards_skipped"] == 2
