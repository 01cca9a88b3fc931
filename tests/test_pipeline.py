"""``morphable.fit_images``: photos and arrays in, a fit and its files out, all or nothing."""
import json
import subprocess
import sys

import numpy as np
import pytest

import morphable
from morphable.errors import InputError


@pytest.fixture(scope="module")
def photo(data_dir):
    """image_0010 (1280 x 1024) and its 68 annotated points."""
    return data_dir / "images" / "image_0010.png", data_dir / "images" / "image_0010.pts"


@pytest.fixture(scope="module")
def by_path(photo, sfm):
    return morphable.fit_images(photo[0], photo[1], model=sfm)


@pytest.fixture(scope="module")
def two_frames(photo, sfm):
    """One fit of image_0010 and its mirror image (the same points mirrored) as one person."""
    from morphable.detection import read_image
    from morphable.ibug68 import MIRROR
    from morphable.io.landmark_files import read_pts

    pixels, points = read_image(photo[0]), read_pts(photo[1])
    mirrored = points[MIRROR] * [-1, 1] + [pixels.shape[1] - 1, 0]
    return morphable.fit_images([pixels, pixels[:, ::-1]], [points, mirrored], model=sfm)


def test_a_photo_and_its_points_are_fitted(by_path, photo):
    from morphable.io.landmark_files import read_pts

    res = by_path.fit
    assert res.n_frames == 1 and res.model.name == "sfm"
    # the fit lies on the annotation: within a few pixels on a face ~400 px wide
    assert 0 < res.landmark_rmse_px[0] < 7.0
    np.testing.assert_allclose(res.landmarks[0], read_pts(photo[1]))
    yaw, pitch, roll = res.euler_deg[0]
    assert -35 < yaw < -20 and abs(pitch) < 15 and abs(roll) < 10       # turned to its right
    frame = by_path.report["frames"][0]
    assert frame["image"] == str(photo[0]) and frame["landmark_rmse_px"] == pytest.approx(res.landmark_rmse_px[0])
    assert by_path.report["landmarks"] == [str(photo[1])]
    assert [p.size for p in by_path.pictures] == [(1280, 1024)]


def test_arrays_give_the_fit_of_the_file(by_path, photo, sfm):
    from morphable.detection import read_image
    from morphable.io.landmark_files import read_pts

    pixels, points = read_image(photo[0]), read_pts(photo[1])
    for image in (pixels, pixels / 255.0):          # uint8 and float in [0, 1]
        result = morphable.fit_images(image, points, model=sfm)
        np.testing.assert_allclose(result.vertices(0), by_path.vertices(0), atol=1e-4)
        np.testing.assert_allclose(result.fit.landmark_rmse_px, by_path.fit.landmark_rmse_px, rtol=1e-6)
        assert result.report["frames"][0]["image"] == "<array 0>"
        assert result.report["landmarks"] == ["array"]
        np.testing.assert_array_equal(result.pictures[0].pixels(), pixels)
    # a list of two: one identity for both, each frame named by its place among the inputs
    both = morphable.fit_images([pixels, photo[0]], [points, photo[1]], model=sfm)
    assert both.n_frames == 2 and both.report["shared_identity"]
    assert [f["image"] for f in both.report["frames"]] == ["<array 0>", str(photo[0])]


def test_written_files_read_back(by_path, tmp_path):
    from mesh_check import assert_mesh_holds

    written = by_path.write(mesh=tmp_path / "fit.obj", report=tmp_path / "fit.json",
                            overlay=tmp_path / "overlay.png", texture=tmp_path / "face.png",
                            texture_size=64)
    assert sorted(p.name for p in written) == ["face.png", "fit.json", "fit.mtl", "fit.obj", "overlay.png"]
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in written)
    assert_mesh_holds(tmp_path / "fit.obj", by_path.fit.neutral_vertices(), by_path.fit.model.triangles)
    report = json.loads((tmp_path / "fit.json").read_text())
    assert report["mesh"] == {"kind": "neutral", "paths": [str(tmp_path / "fit.obj")]}
    assert report["frames"] == json.loads(json.dumps(by_path.report["frames"]))
    assert report["overlays"] == [str(tmp_path / "overlay.png")]
    assert report["texture"]["size"] == 64 and 0.3 < report["texture"]["observed"] <= 1
    assert "overlays" not in by_path.report          # the result's report stays the fit's


@pytest.mark.parametrize("suffix", ["obj", "ply", "stl", "off", "glb"])
def test_every_mesh_format_holds_the_fitted_face(by_path, two_frames, sfm, tmp_path, suffix):
    # the fitted face, not the model's mean (which lies up to ~9 mm away), in every format;
    # by default the identity without expression, for one photo as for several (the photo and
    # its mirror image); mesh_kind="expressive": each frame's face with its expression
    from mesh_check import assert_mesh_holds

    by_path.write(mesh=tmp_path / f"one.{suffix}")
    assert_mesh_holds(tmp_path / f"one.{suffix}", by_path.fit.neutral_vertices(), sfm.triangles)
    assert np.abs(by_path.fit.neutral_vertices() - sfm.mean.reshape(-1, 3)).max() > 3.0
    by_path.write(mesh=tmp_path / f"onex.{suffix}", mesh_kind="expressive")
    assert_mesh_holds(tmp_path / f"onex.{suffix}", by_path.vertices(0), sfm.triangles)
    two_frames.write(mesh=tmp_path / f"two.{suffix}")
    assert_mesh_holds(tmp_path / f"two.{suffix}", two_frames.fit.neutral_vertices(), sfm.triangles)
    assert np.abs(two_frames.fit.neutral_vertices() - two_frames.vertices(0)).max() > 0.1
    written = two_frames.write(mesh=tmp_path / f"twox.{suffix}", mesh_kind="expressive")
    assert [p.name for p in written if p.suffix != ".mtl"] == [f"twox_0.{suffix}", f"twox_1.{suffix}"]
    for i in range(2):
        assert_mesh_holds(tmp_path / f"twox_{i}.{suffix}", two_frames.vertices(i), sfm.triangles)


def test_write_is_all_or_nothing(by_path, tmp_path):
    # a bad output is found before anything is written
    for kwargs, message in [({"report": tmp_path / "no" / "fit.json"}, "does not exist"),
                            ({"texture": tmp_path / "face.jpg"}, "must be a .png"),
                            ({"overlay": tmp_path / "o.gif"}, "overlay must be a .png or .jpg"),
                            ({"refine_render": tmp_path / "r.png"}, "was not refined")]:
        with pytest.raises(InputError, match=message):
            by_path.write(mesh=tmp_path / "fit.obj", **kwargs)
        assert not list(tmp_path.iterdir()), kwargs
    # a write that fails after others succeeded takes them back: the report's path is a folder
    (tmp_path / "taken.json").mkdir()
    with pytest.raises(InputError, match="cannot write"):
        by_path.write(mesh=tmp_path / "fit.ply", overlay=tmp_path / "o.png", report=tmp_path / "taken.json")
    assert [p.name for p in tmp_path.iterdir()] == ["taken.json"]


def test_bad_input_is_an_input_error(photo, sfm, tmp_path):
    (tmp_path / "short.pts").write_text("version: 1\nn_points: 3\n{\n1 2\n3 4\n5 6\n}\n")
    pixels = np.zeros((64, 48, 3), np.uint8)
    for args, kwargs, message in [
        (([],), {}, "no images given"),
        (([photo[0], photo[0]], [photo[1]]), {}, "landmarks: 1 given for 2 images"),
        ((photo[0], tmp_path / "short.pts"), {}, "short.pts: expected 68 iBUG landmarks, got 3"),
        ((pixels, np.zeros((10, 2))), {}, r"landmarks of <array 0>: expected 68 or 478 x 2 landmarks, got shape \(10, 2\)"),
        ((pixels, np.full((68, 2), 500.0)), {}, "landmark 1 at .* is outside the 48x64 image"),
        ((np.zeros((64, 48, 5)),), {}, r"<array 0>: expected \(H, W, 3\) pixels"),
        (([photo[0], 3],), {}, "input 1: expected a photo or video path or an .* array, got int"),
        ((tmp_path / "missing.png", photo[1]), {}, "missing.png: no such image"),
        ((photo[0], photo[1]), {"video_frames": 0}, "video frames must be >= 1"),
        ((photo[0], photo[1]), {"landmark_detector": "nosuch"}, "landmark detector: choose from"),
    ]:
        with pytest.raises(InputError, match=message):
            morphable.fit_images(*args, model=sfm, **kwargs)


def test_top_level_entries_are_lazy():
    import morphable.pipeline
    import morphable.tracking

    assert morphable.fit_images is morphable.pipeline.fit_images
    assert morphable.ImageFit is morphable.pipeline.ImageFit
    assert morphable.track_video is morphable.tracking.track_video
    code = ("import sys, morphable; morphable.fit_images, morphable.track_video; "
            "print([m for m in ('torch', 'open3d', 'pyvista', 'trimesh', 'scipy', 'mediapipe', 'cv2', "
            "'dlib', 'av', 'PIL') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
