"""evaluation.bench_scan_photos: splitting the scanner's photos, bad input (no fits: fast)."""
import numpy as np
import pytest
from PIL import Image

from morphable.errors import InputError


def test_split_photos_gives_the_two_halves(tmp_path):
    from evaluation.bench_scan_photos import split_photos

    a = np.random.default_rng(0).integers(0, 255, (6, 8, 3), dtype=np.uint8)
    Image.fromarray(a).save(tmp_path / "two.png")
    left, right = split_photos(tmp_path / "two.png", tmp_path)
    np.testing.assert_array_equal(np.asarray(Image.open(left)), a[:, :4])
    np.testing.assert_array_equal(np.asarray(Image.open(right)), a[:, 4:])


def test_bad_input(tmp_path, capsys):
    from evaluation.bench_scan_photos import main, split_photos

    Image.fromarray(np.zeros((4, 7, 3), np.uint8)).save(tmp_path / "odd.png")
    with pytest.raises(InputError, match="odd.png: width 7 is odd"):
        split_photos(tmp_path / "odd.png", tmp_path)
    (tmp_path / "bad.jpg").write_text("not a picture")
    with pytest.raises(InputError, match="bad.jpg: cannot read image"):
        split_photos(tmp_path / "bad.jpg", tmp_path)
    assert main(["--work", str(tmp_path / "nowhere")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "nowhere" in err[0]
