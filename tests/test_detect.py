"""dlib face and landmark detection (the 'detect' extra)."""
import numpy as np
import pytest

from morphable import FitError, InputError

pytest.importorskip("dlib")


@pytest.fixture(scope="module")
def takeo(data_dir):
    return data_dir / "images" / "takeo.ppm"


def test_detected_landmarks_match_the_annotation(takeo):
    from morphable.fitting.detect import detect_faces, detect_landmarks
    from morphable.io.landmark_files import read_pts

    boxes = detect_faces(takeo)
    assert boxes.shape[1] == 4 and len(boxes) >= 1
    pts = detect_landmarks(takeo)
    truth = read_pts(takeo.with_suffix(".pts"))
    assert pts.shape == (68, 2)
    assert np.sqrt(((pts - truth) ** 2).sum(1).mean()) < 10
    # a given box skips detection and gives the same points
    np.testing.assert_allclose(detect_landmarks(takeo, box=boxes[0]), pts)


def test_no_face_is_reported():
    from morphable.fitting.detect import detect_landmarks

    with pytest.raises(FitError, match="no face"):
        detect_landmarks(np.full((120, 160, 3), 128, np.uint8))


@pytest.mark.parametrize("box", [(10, 10, 5, 50), (0, 0, 1)])
def test_bad_box_and_image(box):
    from morphable.fitting.detect import detect_landmarks

    with pytest.raises(InputError):
        detect_landmarks(np.zeros((50, 50, 3), np.uint8), box=box)
    with pytest.raises(InputError):
        detect_landmarks(np.zeros((50,)), box=(0, 0, 10, 10))


def test_unreadable_image(tmp_path):
    from morphable.fitting.detect import read_image

    bad = tmp_path / "x.png"
    bad.write_bytes(b"not a png")
    with pytest.raises(InputError, match="x.png"):
        read_image(bad)


def test_cli_fit_detects_when_no_landmarks_given(takeo, tmp_path):
    import json

    from morphable.cli import main

    report = tmp_path / "fit.json"
    assert main(["fit", str(takeo), "--report", str(report)]) == 0
    rep = json.loads(report.read_text())
    assert "dlib hog" in str(rep["landmarks"]) and rep["frames"][0]["landmark_rmse_px"] < 10
    # detected landmarks are fitted with the detector's error, annotated ones with the default
    from morphable.fitting.noise import DETECTED_MODEL_STD_MM, MODEL_STD_MM

    assert rep["frames"][0]["model_std_mm"] == DETECTED_MODEL_STD_MM
    assert main(["fit", str(takeo), "--landmarks", str(takeo.with_suffix(".pts")),
                 "--report", str(report)]) == 0
    assert json.loads(report.read_text())["frames"][0]["model_std_mm"] == MODEL_STD_MM
