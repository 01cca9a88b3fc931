"""Renderer plugins: discovery through entry points, the classical SH renderer, the gar one."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from morphable.errors import InputError  # noqa: E402
from morphable.raster import DirectionalLight, sh_from_lights  # noqa: E402
from morphable.renderer_plugins import Renderer, available_renderers, get_renderer  # noqa: E402


def sphere_normals(size=48):
    """(1, 3, size, size) camera-frame normals of a sphere filling the image (zero outside)."""
    c = (size - 1) / 2
    v, u = np.mgrid[0:size, 0:size]
    x, y = (u - c) / (0.45 * size), -(v - c) / (0.45 * size)   # image y down, camera y up
    r2 = x * x + y * y
    n = np.stack([x, y, np.sqrt(np.clip(1 - r2, 0, None))], 0) * (r2 < 1)
    return torch.tensor(n[None], dtype=torch.float32), r2 < 1


def test_discovery():
    names = available_renderers()
    assert "classical" in names and "gar" in names
    with pytest.raises(InputError, match="not installed"):
        get_renderer("no-such-renderer")
    # an option the renderer does not take: a one-line error, not a TypeError
    with pytest.raises(InputError, match="'classical'.*inverter"):
        get_renderer("classical", inverter="v.pt")


def test_classical_brightness_follows_n_dot_l():
    light = np.array([0.5, 0.3, 1.0]) / np.linalg.norm([0.5, 0.3, 1.0])
    r = get_renderer("classical")
    assert isinstance(r, Renderer) and r.resolution is None
    n, face = sphere_normals()
    app = r.default_appearance(1)
    app["sh"] = torch.tensor(sh_from_lights([DirectionalLight(light, 1.0)], ambient=0.0),
                             dtype=torch.float32)[None]
    app["albedo"] = torch.tensor([[0.8, 0.6, 0.4]])
    app["background"] = torch.tensor([[0.1, 0.2, 0.3]])
    img = r.render(n, app)[0].numpy()                        # (3, H, W)
    ndotl = np.einsum("khw,k->hw", n[0].numpy(), light)
    lit = face & (ndotl > 0.2)
    grey = img[0] / 0.8
    # band-2 SH approximates the clamped cosine: nearly linear in n.l on the lit side
    assert np.corrcoef(grey[lit], ndotl[lit])[0, 1] > 0.99
    np.testing.assert_allclose(grey[lit], ndotl[lit], atol=0.12)
    # colour = albedo ratio, background untouched
    np.testing.assert_allclose(img[1][lit] / img[0][lit], 0.75, rtol=1e-4)
    np.testing.assert_allclose(img[:, 0, 0], [0.1, 0.2, 0.3], atol=1e-6)
    # the brightest pixel faces the light
    k = np.unravel_index(np.argmax(np.where(face, grey, -1)), grey.shape)
    assert np.degrees(np.arccos(np.clip(n[0, :, k[0], k[1]].numpy() @ light, -1, 1))) < 10


def test_classical_is_differentiable():
    r = get_renderer("classical")
    n, _ = sphere_normals(16)
    app = {k: v.requires_grad_(True) for k, v in r.default_appearance(2).items()}
    n = n.expand(2, -1, -1, -1).clone().requires_grad_(True)
    r.render(n, app).mean().backward()
    assert all(float(t.grad.abs().sum()) > 0 for t in (n, app["sh"], app["albedo"]))


def test_gar_needs_weights(monkeypatch, tmp_path):
    import neural.gar.renderer as nr
    from neural.gar.paths import WEIGHTS_ENV

    monkeypatch.setenv(WEIGHTS_ENV, str(tmp_path / "missing.pt"))
    with pytest.raises(InputError, match="missing.pt"):
        get_renderer("gar")
    monkeypatch.delenv(WEIGHTS_ENV)
    monkeypatch.setattr(nr, "default_generator_path", lambda: None)
    with pytest.raises(InputError, match="no generator weights"):
        get_renderer("gar")
    r = get_renderer("gar", allow_untrained=True)
    assert r.resolution == 64
    n, _ = sphere_normals(64)
    app = r.default_appearance(1)
    app["z"].requires_grad_(True)
    img = r.render(n, app)
    assert img.shape == (1, 3, 64, 64) and torch.isfinite(img).all()
    assert 0 <= float(img.detach().min()) and float(img.detach().max()) <= 1
    img.mean().backward()
    assert float(app["z"].grad.abs().sum()) > 0



def test_committed_gar_follows_the_normals_it_is_given():
    """The GAR through the plugin with its committed weights draws the face of the normal map it
    is given, by the aux normal network N (normal consistency, the metric of
    evaluation.gar_quality; the model card: 14.7 degrees on 64 held-out faces), and not its
    mirror image (the map flipped left-right, its x component negated), which N tells apart.
    Measured on these 8 faces: 16.0 degrees from the map, 42.4 from its mirror image."""
    from evaluation.gar_quality import normal_consistency, synthetic_faces
    from neural.gar.auxnets import load_aux
    from neural.gar.paths import default_generator_path

    r = get_renderer("gar")
    assert r.weights == str(default_generator_path())
    n = synthetic_faces(r.generator.config, n_faces=8, seed=12345)[0]["normals"]
    with torch.no_grad():
        image = r.render(n, r.default_appearance(len(n))) * 2 - 1
    aux = {name: load_aux(name) for name in "NP"}
    mirrored = torch.flip(n, dims=[-1]) * torch.tensor([-1.0, 1.0, 1.0])[:, None, None]
    follows, against = normal_consistency(image, n, aux), normal_consistency(image, mirrored, aux)
    assert follows < 20.0, follows
    assert against > follows + 15.0, (follows, against)


def test_inversion_hooks():
    """What refinement asks a renderer: the start, the pixels compared, the prior, the
    constraint and the features; the defaults for a renderer that says nothing."""
    from morphable.renderer_plugins import RendererBase, plugin_feature_network
    from neural.gar.inverter import Inverter

    image = torch.rand(1, 3, 64, 64)
    cover = torch.zeros(1, 1, 64, 64)
    cover[..., 20:40, 20:40] = 1.0
    classical = get_renderer("classical")
    app, init = classical.initial_appearance(image, cover)
    assert init is None and set(app) == {"sh", "albedo", "background"}
    torch.testing.assert_close(app["albedo"][0], image[0, :, 20:40, 20:40].mean((1, 2)))
    assert app["sh"][0, 0].tolist() == [1.0, 1.0, 1.0] and not app["sh"][0, 1:].any()
    assert classical.photometric_mask(cover) is cover and classical.appearance_prior(app) == {}
    app["albedo"] += 2
    classical.constrain_appearance(app)
    assert float(app["albedo"].max()) == 1.0
    assert set(classical.learning_rates) == {"sh", "albedo"}

    gar = get_renderer("gar", allow_untrained=True, inverter=None)
    app, init = gar.initial_appearance(image, cover)
    assert init == "default" and torch.equal(app["z"], gar.default_appearance(1)["z"])
    gar.inverter = Inverter(gar.generator.config).eval()
    app, init = gar.initial_appearance(image, cover, seed=3)
    assert init == "inverter" and not torch.equal(app["z"], gar.default_appearance(1)["z"])
    assert bool((gar.photometric_mask(cover) == 1).all())
    face = get_renderer("gar", allow_untrained=True, inverter=None, photometric_region="face")
    assert face.photometric_mask(cover) is cover
    with pytest.raises(InputError, match="photometric_region 'hair'"):
        get_renderer("gar", allow_untrained=True, photometric_region="hair")
    app["noise"][0] += 0.5
    prior = gar.appearance_prior(app)
    assert set(prior) == {"eps"} and float(prior["eps"]) == pytest.approx(0.25 * app["noise"][0].numel())

    # the classical renderer has no features of its own; the installed gar plugin offers N's
    assert classical.feature_network() is None
    fn, name = plugin_feature_network()
    assert name.startswith("aux N encoder") and isinstance(fn(image), list)

    class Minimal(RendererBase):
        def default_appearance(self, batch_size=1):
            return {"colour": torch.ones(batch_size, 3)}

    app, init = Minimal().initial_appearance(image, cover)
    assert init is None and torch.equal(app["colour"], torch.ones(1, 3))
    assert Minimal().photometric_mask(cover) is cover and Minimal.learning_rates == {}


def test_import_does_not_load_torch():
    import subprocess
    import sys

    code = ("import sys, morphable, morphable.renderer_plugins; "
            "print('torch' in sys.modules, morphable.renderer_plugins.available_renderers())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.startswith("False")
