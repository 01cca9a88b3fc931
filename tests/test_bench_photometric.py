import json

import numpy as np

from evaluation.bench_photometric import main


def test_the_bench_has_every_row_and_the_gar_row_on_request(tmp_path):
    report = tmp_path / "bench.json"
    assert main(["--people", "1", "--frames", "1", "--steps", "2", "--image-size", "96", "--gar",
                 "--report", str(report)]) == 0
    rows = json.loads(report.read_text())["results"]["1 frames"]
    assert list(rows) == ["mean face", "landmark-only", "landmarks-refit", "photometric",
                          "photometric + GAR"]
    assert all(np.isfinite(r["neutral_mm"]) and 0 < r["neutral_mm"] < 20 for r in rows.values())
    # each refinement moved the landmark fit (a row that only copied it would be equal)
    start = rows["landmark-only"]["neutral_mm"]
    assert all(rows[k]["neutral_mm"] != start for k in ("photometric", "photometric + GAR"))
    assert rows["photometric + GAR"]["s_per_frame"] > 0
