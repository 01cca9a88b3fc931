"""The hard-case makers of evaluation.photometric_stability do what they say, and a grey and an
over-exposed face stay finite through the photometric fit (small synthetic images)."""
import numpy as np
import pytest

from evaluation import photometric_stability as ps
from morphable.camera import Camera
from morphable.detection.images import read_image
from morphable.refinement.mask import CLIP_LOW


@pytest.fixture(scope="module")
def face(sfm):
    """A 96-px SFM face rendered by our Lambertian renderer (dark enough that x3 clips only
    its highlights), its 68 projected landmarks and its landmark fit."""
    from morphable.fitting import fit_landmarks
    from morphable.raster import DirectionalLight, render, sh_from_lights

    cam = Camera.looking_at_face((96, 96), yaw=10, face_width_px=60)
    verts = sfm.vertices(np.zeros(sfm.n_identity))
    light = sh_from_lights([DirectionalLight((0.5, 0.3, 1.0), 0.7)], ambient=0.35)
    image = render(verts, sfm.triangles, cam, colors=np.array([0.3, 0.22, 0.18]), light=light,
                   background=(0.2, 0.3, 0.4), supersample=2)
    image = np.round(np.clip(image, 0, 1) * 255).astype(np.uint8)
    points = cam.project(sfm.landmark_positions(np.zeros(sfm.n_identity)))
    fit = fit_landmarks(sfm, points[None], np.array([[96.0, 96.0]]), n_iterations=2)
    return image, points, fit


def test_grey_and_saturated(face):
    image, _, _ = face
    g = ps.grey(image)
    assert (g[..., 0] == g[..., 1]).all() and (g[..., 1] == g[..., 2]).all()
    assert abs(int(g[48, 48, 0]) - image[48, 48] @ [0.299, 0.587, 0.114]) <= 0.5
    s = ps.saturated(image)
    np.testing.assert_array_equal(s, np.minimum(image.astype(int) * 3, 255))


def test_16_bit_png_round_trips_through_fit_s_reader(face, tmp_path):
    image, _, _ = face
    path = ps.write_png16(tmp_path / "face16.png", image)
    assert path.read_bytes()[24] == 16          # the IHDR's bit depth
    np.testing.assert_array_equal(read_image(path), image)


def test_occluders_cover_the_regions_they_claim(face):
    image, points, _ = face
    shape = image.shape[:2]
    changes = {"shadow": (ps.hard_shadow(image, points), ps.shadow_region(points, shape)),
               "hand": (ps.hand(image, points), ps.hand_region(points, shape)),
               "glasses": (ps.sunglasses(image, points), ps.glasses_region(points, shape))}
    for name, (out, region) in changes.items():
        changed = (out != image).any(-1)
        assert not changed[~region].any(), name           # nothing outside the region
        assert changed[region].mean() > 0.9, name        # nearly all of it changed
    inside = lambda region, i: region[int(points[i, 1]), int(points[i, 0])]  # noqa: E731
    shadow, hand, glasses = (changes[k][1] for k in ("shadow", "hand", "glasses"))
    assert inside(shadow, 36) and not inside(shadow, 45)            # the image-left half
    assert np.allclose(changes["shadow"][0][shadow], np.round(image[shadow] * ps.SHADOW_GAIN))
    assert inside(hand, 62) and inside(hand, 66) and not inside(hand, 37)
    assert inside(glasses, 37) and inside(glasses, 44) and not inside(glasses, 62)
    assert (changes["glasses"][0][glasses] > 255 * CLIP_LOW).all()
    # the hand wears the photo's own skin colour: its chromaticity is the cheeks'
    hand_colour, skin = np.median(changes["hand"][0][hand], 0), ps.skin_colour(image, points)
    assert np.abs(hand_colour[:2] / hand_colour.sum() - skin[:2] / skin.sum()).max() < 0.02
    np.testing.assert_array_equal(ps.hand(image, points), changes["hand"][0])   # seeded


@pytest.mark.parametrize("make", [ps.grey, ps.saturated])
def test_grey_and_over_exposed_faces_stay_finite(face, make):
    pytest.importorskip("torch")
    from morphable.refinement import refine

    image, _, fit = face
    new, report = refine(make(image), fit, "classical", steps=3, resolution=64)
    assert not report["fallback"] and report["mask_coverage"] > 0.05
    assert np.isfinite(new.identity).all() and np.isfinite(new.expression).all()
    assert np.isfinite(report["loss"]).all() and np.isfinite(report["photometric_residual"])
