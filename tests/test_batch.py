import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from morphable import InputError
from morphable.batch import RESULTS, read_manifest, read_results, run_batch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import batch_worker  # noqa: E402


def _images(folder, n):
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        (folder / f"img{i:03d}.png").write_bytes(b"")
    return folder


def _lines(out):
    return [json.loads(x) for x in (out / RESULTS).read_text().splitlines()]


def test_manifests(tmp_path):
    d = _images(tmp_path / "imgs", 3)
    (d / "img001.pts").write_text("")
    items = read_manifest(d)
    assert [it.id for it in items] == ["img000", "img001", "img002"]
    assert items[1].landmarks == [str(d / "img001.pts")] and items[0].landmarks == [None]
    assert len(read_manifest(str(d / "img00[01].png"))) == 2
    (tmp_path / "m.csv").write_text("image,landmarks,subject\nimgs/img000.png,,anna\n"
                                    "imgs/img001.png,,anna\nimgs/img002.png,x.pts,bob\n")
    items = read_manifest(tmp_path / "m.csv")
    assert [(it.id, len(it.images)) for it in items] == [("anna", 2), ("bob", 1)]
    assert items[1].landmarks == [str(tmp_path / "x.pts")]
    (tmp_path / "m.jsonl").write_text('{"image": "imgs/img000.png", "subject": "s"}\n\n'
                                      '{"image": "imgs/img001.png"}\n')
    assert [it.id for it in read_manifest(tmp_path / "m.jsonl")] == ["s", "img001"]
    (tmp_path / "bad.jsonl").write_text('{"image": "a.png"}\n[1, 2]\n')
    with pytest.raises(InputError, match="bad.jsonl: line 2 is not a JSON object"):
        read_manifest(tmp_path / "bad.jsonl")
    with pytest.raises(InputError, match="no images found"):
        read_manifest(tmp_path / "nothing*")


def test_failed_items_are_recorded_and_the_batch_goes_on(tmp_path):
    items = read_manifest(_images(tmp_path / "imgs", 4))
    out = tmp_path / "out"
    counts = run_batch(items, out, batch_worker.work, {"fail": ["img002"]}, progress=False)
    assert counts == {"done": 4, "skipped": 0, "ok": 3, "error": 1}
    recs = {r["id"]: r for r in _lines(out)}
    assert recs["img002"]["status"] == "error" and "made to fail" in recs["img002"]["error"]
    assert not (out / "items/img002").exists()  # no partial output folder
    assert (out / "items/img003/out.txt").is_file()
    assert not [p for p in (out / "items").iterdir() if p.name.startswith(".")]
    # a second run skips everything that is recorded
    assert run_batch(items, out, batch_worker.work, progress=False)["skipped"] == 4
    assert len(_lines(out)) == 4


def test_torn_last_line_is_dropped(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    (out / RESULTS).write_text('{"id": "a", "status": "ok"}\n{"id": "b", "sta')
    assert list(read_results(out)) == ["a"]
    assert (out / RESULTS).read_text() == '{"id": "a", "status": "ok"}\n'


def test_process_pool_matches_serial(tmp_path):
    items = read_manifest(_images(tmp_path / "imgs", 6))
    run_batch(items, tmp_path / "serial", batch_worker.work, progress=False)
    run_batch(items, tmp_path / "pool", batch_worker.work, workers=2, progress=False)
    ids = lambda out: sorted(r["id"] for r in _lines(out))  # noqa: E731
    assert ids(tmp_path / "serial") == ids(tmp_path / "pool") == [it.id for it in items]


def test_kill_and_resume(tmp_path):
    # killed (SIGKILL) as the 5th item's work returns, its file written in its temporary folder
    # and not yet recorded (killed.py: a kill at a known point of the run, no race)
    d = _images(tmp_path / "imgs", 12)
    out = tmp_path / "out"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE), str(HERE.parent)])}
    cmd = [sys.executable, str(HERE / "killed.py"), "batch_worker:work", "5", "batch_worker", str(d), str(out)]
    assert subprocess.run(cmd, env=env).returncode == -signal.SIGKILL
    assert [r["id"] for r in _lines(out)] == [f"img{i:03d}" for i in range(4)]
    stale = list((out / "items").glob(".img004.*"))
    assert len(stale) == 1 and (stale[0] / "out.txt").is_file()
    subprocess.run([sys.executable, str(HERE / "batch_worker.py"), str(d), str(out)], env=env, check=True)
    recs = _lines(out)
    assert sorted(r["id"] for r in recs) == [f"img{i:03d}" for i in range(12)]  # none lost, none twice
    for r in recs:
        assert (out / "items" / r["id"] / "out.txt").is_file()
    assert sorted(p.name for p in (out / "items").iterdir()) == [r["id"] for r in recs]  # no leftovers


def test_dask_local_cluster(tmp_path, monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(HERE), str(HERE.parent)]))
    items = read_manifest(_images(tmp_path / "imgs", 5))
    counts = run_batch(items, tmp_path / "out", batch_worker.work, {"fail": ["img004"]},
                       workers=2, scheduler="local", progress=False)
    assert counts["ok"] == 4 and counts["error"] == 1
    assert sorted(r["id"] for r in _lines(tmp_path / "out")) == [it.id for it in items]
