"""The physically based rendering of the Florence protocol (evaluation.pbr), small frames."""
import numpy as np
import pytest

from morphable.errors import InputError

pytest.importorskip("pyvista")

SIZE = (128, 128)


@pytest.fixture(scope="module")
def subject(sfm):
    from evaluation.scans import model_scan

    return model_scan(sfm, 3, colors=np.tile([0.75, 0.55, 0.45], (sfm.n_vertices, 1)))


@pytest.fixture(scope="module")
def video(subject, sfm):
    from evaluation.videos import synthetic_video

    v = synthetic_video(subject, "indoor", sfm.landmark_positions(), n_frames=6, n_sampled=2, seed=1)
    for c in v.cameras:
        c.image_size = SIZE
        c.principal = np.array([(SIZE[0] - 1) / 2, (SIZE[1] - 1) / 2])
        c.focal /= 4.0
    return v


@pytest.fixture(scope="module")
def frames(subject, video):
    from evaluation.pbr import render_frames

    return render_frames(subject, video, frames=[0, 3], seed=5)


def face_mask(subject, camera):
    """(H, W) bool: the pixels the subject's projected vertices fill."""
    from scipy.ndimage import binary_closing, binary_fill_holes

    uv = np.round(camera.project(subject.vertices)).astype(int)
    W, H = camera.image_size
    ok = (uv >= 0).all(1) & (uv[:, 0] < W) & (uv[:, 1] < H)
    m = np.zeros((H, W), bool)
    m[uv[ok, 1], uv[ok, 0]] = True
    return binary_fill_holes(binary_closing(m, iterations=2))


def test_frames_render(frames):
    assert frames.shape == (2, *SIZE[::-1], 3) and frames.dtype == np.float64
    assert 0.0 <= frames.min() and frames.max() <= 1.0
    assert frames.std() > 0.05          # a face over a photo, not a blank frame


def test_not_the_lambertian_rendering(subject, video, frames):
    from evaluation.videos import render_frames

    lambert = render_frames(subject, video, frames=[0, 3], seed=5)
    inside = face_mask(subject, video.cameras[0])
    diff = np.abs(frames[0] - lambert[0]).mean(-1)
    assert diff[~inside].mean() > 0.1          # a photo behind, not the flat grey
    assert diff[inside].mean() > 0.03          # other shading and sensor


@pytest.fixture(scope="module")
def black_photos(tmp_path_factory):
    """Background photos: one black photo with a tiny annotated face in a corner."""
    from PIL import Image

    from evaluation.pbr import background_photos

    d = tmp_path_factory.mktemp("black")
    Image.fromarray(np.zeros((96, 96, 3), np.uint8)).save(d / "black.jpg")
    (d / "black.pts").write_text("version: 1\nn_points: 2\n{\n1 1\n3 3\n}\n")
    return background_photos(d)


@pytest.mark.parametrize("principal_shift, kind", [((0.0, 0.0), "perspective"),
                                                   ((9.0, -6.0), "perspective"),
                                                   ((0.0, 0.0), "affine")])
def test_face_lands_where_the_camera_says(subject, black_photos, principal_shift, kind):
    """Over a black background the lit pixels are the face; they must be those the camera
    projects the subject's vertices and its inner landmarks onto."""
    from morphable.camera import Camera
    from evaluation.pbr import render_view

    cam = Camera.looking_at_face(image_size=SIZE, yaw=25.0, pitch=-8.0, kind=kind,
                                 center=np.nanmean(subject.landmarks, 0))
    cam.principal = cam.principal + np.asarray(principal_shift)
    lit = render_view(subject, cam, "cooperative", photos=black_photos).mean(-1) > 25
    inside = face_mask(subject, cam)
    assert inside.sum() > 500
    assert lit[inside].mean() > 0.95
    assert lit[~inside].mean() < 0.02
    inner = subject.landmarks[17:]
    lm = np.round(cam.project(inner[np.isfinite(inner).all(1)])).astype(int)
    assert lit[lm[:, 1], lm[:, 0]].mean() > 0.9     # a brow end may sit off the face segment


def test_deterministic_per_frame(subject, video, frames):
    from evaluation.pbr import render_frames

    again = render_frames(subject, video, frames=[3], seed=5)
    np.testing.assert_array_equal(again[0], frames[1])       # frame 3 alone, the same
    assert np.abs(frames[0] - frames[1]).mean() > 0.01        # another pose, another frame
    other = render_frames(subject, video, frames=[3], seed=6)
    assert np.abs(other[0] - frames[1]).mean() > 0.01


def test_bad_input(subject, video, tmp_path):
    import dataclasses

    from evaluation.florence.protocol import frame_renderer
    from evaluation.pbr import background_photos, render_frames, render_view

    with pytest.raises(InputError, match="unknown condition"):
        render_view(subject, video.cameras[0], "underwater")
    empty = dataclasses.replace(subject, triangles=np.zeros((0, 3), int))
    with pytest.raises(InputError, match="empty mesh"):
        render_frames(empty, video, frames=[0])
    with pytest.raises(InputError, match="no such folder"):
        background_photos(tmp_path / "nowhere")
    with pytest.raises(InputError, match="no photos"):
        background_photos(tmp_path)
    with pytest.raises(InputError, match="unknown renderer 'povray'"):
        frame_renderer("povray")


def test_cli_renderer_choice_bad():
    from evaluation.florence.cli import main

    with pytest.raises(SystemExit) as e:
        main(["--synthetic-scan", "ict", "--renderer", "povray", "--report", "x.json"])
    assert e.value.code == 2


def test_photometric_method_on_pbr_frames(subject, sfm):
    """ours-photometric runs on physically based frames: every frame refined (no fallback),
    its mask covering part of the face, and the mesh moved from the landmark fit's."""
    from evaluation.florence.protocol import run_protocol

    report, maps = run_protocol(subject, sfm, ["ours", "ours-photometric"], ["outdoor"],
                                n_sampled=2, n_frames=4, renderer="pbr",
                                efforts={"ours-photometric": {"steps": 3}})
    cell = report["methods"]["ours-photometric"]["outdoor"]
    assert report["settings"]["renderer"] == "pbr" and report["videos"]["outdoor"]["renderer"] == "pbr"
    assert np.isfinite(cell["mean_mm"]) and not any(cell["fallback"])
    assert all(0.05 < c <= 1.0 for c in cell["mask_coverage"])
    ours, photometric = (m.vertices for m in maps)
    assert np.abs(ours - photometric).max() > 1e-3
