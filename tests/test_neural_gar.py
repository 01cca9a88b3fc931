"""GAR architecture, losses and auxiliary networks (torch CPU, small sizes)."""
import math

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from morphable.errors import InputError  # noqa: E402
from neural.gar.auxnets import load_aux, save_aux  # noqa: E402
from neural.gar.auxnets.nets import soft_argmax  # noqa: E402
from neural.gar.config import GARConfig, get_config  # noqa: E402
from neural.gar.networks import (Discriminator, Generator, MinibatchStd, ModulatedConv2d,
    NormalInjection, RenderBlock)
from neural.gar.losses import (DEFAULT_LAMBDAS, discriminator_loss, generator_adversarial_loss,
    generator_losses, identity_loss, landmark_loss, normal_loss, r1_penalty, total_loss)

SMALL = dict(resolution=32, channel_base=256, channel_max=32, z_dim=16, w_dim=16)


def sphere_normals(B, R):
    """Normal maps of a sphere filling the image: unit inside, zero outside."""
    y, x = torch.meshgrid(torch.linspace(-1, 1, R), torch.linspace(-1, 1, R), indexing="ij")
    z2 = 1 - x ** 2 - y ** 2
    inside = z2 > 0
    n = torch.stack([x, -y, z2.clamp_min(0).sqrt()]) * inside
    return n[None].expand(B, 3, R, R).clone()


@pytest.mark.parametrize("name,batch", [("tiny", 2), ("tiny128-gpu", 1), ("base", 1)])
def test_forward_backward_shapes(name, batch):
    torch.manual_seed(0)
    cfg = get_config(name)
    G, D = Generator(cfg), Discriminator(cfg)
    R = cfg.resolution
    img = G(sphere_normals(batch, R), torch.randn(batch, cfg.z_dim))
    assert img.shape == (batch, 3, R, R)
    assert torch.isfinite(img).all() and img.std() > 1e-3
    logits = D(img)
    assert logits.shape == (batch, 1)
    (logits.sum() + img.mean()).backward()
    for net in (G, D):
        missing = [k for k, p in net.named_parameters() if p.grad is None]
        assert not missing, missing
        assert all(torch.isfinite(p.grad).all() for p in net.parameters())
    # every block injects normals and the mapping network has 8 layers
    assert len(G.blocks) == int(math.log2(R)) - 1
    assert len(G.mapping.layers) == 8


def test_demodulation_formula_and_unit_variance():
    torch.manual_seed(0)
    conv = ModulatedConv2d(64, 48, 3, w_dim=8)
    w = torch.randn(4, 8)
    with torch.no_grad():
        conv.affine.weight.mul_(30)          # styles far from 1: demodulation must undo them
    k = conv.kernels(w)
    s = conv.affine(w)
    manual = conv.weight[None] * conv.scale * s[:, None, :, None, None]
    manual = manual / torch.sqrt(manual.pow(2).sum(dim=(2, 3, 4), keepdim=True) + 1e-8)
    torch.testing.assert_close(k, manual)
    torch.testing.assert_close(k.pow(2).sum(dim=(2, 3, 4)), torch.ones(4, 48))
    # i.i.d. unit-variance input -> unit-variance output per sample (interior pixels)
    x = torch.randn(4, 64, 40, 40)
    y = conv(x, w)[..., 1:-1, 1:-1]
    std = y.std(dim=(1, 2, 3))
    assert torch.all((std - 1).abs() < 0.05), std
    # without demodulation the output scale follows the style
    plain = ModulatedConv2d(64, 48, 3, w_dim=8, demodulate=False)
    with torch.no_grad():
        plain.affine.weight.zero_()
        plain.affine.bias.fill_(5.0)
    assert plain(x, w).std() > 3


def test_modulated_conv_upsample_and_per_sample_kernels():
    torch.manual_seed(1)
    conv = ModulatedConv2d(8, 4, 3, w_dim=6, upsample=True)
    x = torch.randn(2, 8, 5, 5)
    w = torch.randn(2, 6)
    y = conv(x, w)
    assert y.shape == (2, 4, 10, 10)
    # the grouped convolution equals running each sample alone
    y1 = conv(x[1:], w[1:])
    torch.testing.assert_close(y[1:], y1, atol=1e-5, rtol=1e-5)


def test_normal_injection_mapping():
    torch.manual_seed(0)
    nim = NormalInjection(6, background=False)
    f = torch.randn(2, 6, 8, 8)
    zero = torch.zeros(2, 3, 8, 8)
    assert torch.equal(nim(f, zero), torch.zeros_like(f))
    n = sphere_normals(2, 8)
    out = nim(f, n)
    # f''_{l,x,y} = f'_{l,x,y} * sum_k P_{l,k} n_{k,x,y}
    x, y = 4, 3
    expected = f[1, :, y, x] * (nim.projection @ n[1, :, y, x])
    torch.testing.assert_close(out[1, :, y, x], expected)
    # linear in n; the normal map is resized to the features (16 -> 8 by area averaging)
    torch.testing.assert_close(nim(f, -2 * n), -2 * out)
    big = sphere_normals(2, 16)
    torch.testing.assert_close(nim(f, big), f * nim.normal_features(big, 8))
    assert torch.equal(nim(f, torch.zeros(2, 3, 16, 16)), torch.zeros_like(f))
    # unit normals give unit-variance projections at initialisation
    nim = NormalInjection(4096)
    p = nim.normal_features(torch.nn.functional.normalize(torch.randn(1, 3, 4, 4), dim=1), 4)
    assert abs(float(p.detach().var()) - 1) < 0.1


def test_normal_injection_background_gain():
    torch.manual_seed(0)
    nim = NormalInjection(6)
    literal = NormalInjection(6, background=False)
    literal.projection.data.copy_(nim.projection.data)
    with torch.no_grad():
        nim.background.copy_(torch.linspace(0.5, 2.0, 6))
    f = torch.randn(2, 6, 8, 8)
    n = sphere_normals(2, 8)
    out = nim(f, n)
    # background pixels: f * b; unit normals on the face: exactly the paper-literal product
    torch.testing.assert_close(out[:, :, 0, 0], f[:, :, 0, 0] * nim.background)
    face = n.norm(dim=1) > 0.99
    torch.testing.assert_close(out.permute(0, 2, 3, 1)[face],
                               literal(f, n).permute(0, 2, 3, 1)[face])
    torch.testing.assert_close(nim(f, torch.zeros(2, 3, 8, 8)), f * nim.background[:, None, None])
    # the refinement differentiates through n: finite gradients in the empty background too
    n = n.clone().requires_grad_(True)
    nim(f, n).square().sum().backward()
    assert torch.isfinite(n.grad).all()


def test_generators_saved_before_the_background_gain_load_as_such():
    cfg = get_config("tiny", **SMALL)
    assert cfg.nim_background
    old = {k: v for k, v in cfg.to_dict().items() if k != "nim_background"}
    assert not GARConfig.from_dict(old).nim_background
    assert GARConfig.from_dict(cfg.to_dict()).nim_background
    G = Generator(GARConfig.from_dict(old))
    assert all(b.nim0.background is None for b in G.blocks)
    assert "blocks.0.nim0.background" in Generator(cfg).state_dict()


def test_zero_normal_map_zeroes_block_features():
    torch.manual_seed(0)
    block = RenderBlock(8, 8, w_dim=4, background=False)
    x = torch.randn(2, 8, 4, 4)
    ws = torch.randn(2, 3, 4)
    with torch.no_grad():
        block.noise0.strength.fill_(0.5)
        block.noise1.strength.fill_(0.5)
    zero_noise = [torch.zeros(()), torch.zeros(())]
    out, rgb = block(x, None, torch.zeros(2, 3, 8, 8), ws, zero_noise)
    assert torch.equal(out, torch.zeros_like(out))          # biases start at zero
    out, _ = block(x, None, sphere_normals(2, 8), ws, zero_noise)
    assert out.abs().sum() > 0
    # background pixels (zero normals) carry no injected features, the face does
    n = sphere_normals(2, 8)
    f = block.nim0(torch.randn(2, 8, 8, 8), n)
    assert torch.equal(f[:, :, 0, 0], torch.zeros(2, 8)) and f[:, :, 4, 4].abs().sum() > 0
    # with the background gain the empty normal map still carries the features
    out, _ = RenderBlock(8, 8, w_dim=4)(x, None, torch.zeros(2, 3, 8, 8), ws, zero_noise)
    assert out.abs().sum() > 0


def test_generator_latent_noise_and_determinism():
    torch.manual_seed(0)
    cfg = get_config("tiny", **SMALL)
    G = Generator(cfg).eval()
    for m in G.modules():
        if hasattr(m, "strength"):
            torch.nn.init.constant_(m.strength, 0.3)
    n = sphere_normals(2, 32)
    z = torch.randn(2, cfg.z_dim)
    noise = G.make_noise(2, torch.Generator().manual_seed(3))
    a, b = G(n, z, noise=noise), G(n, z, noise=noise)
    assert torch.equal(a, b)
    assert not torch.allclose(a, G(n, z, noise=G.make_noise(2)))
    assert not torch.allclose(a, G(n, torch.randn(2, cfg.z_dim), noise=noise))
    assert torch.equal(G(n, z, noise="zero"), G(n, z, noise="zero"))
    # truncation 0 maps every latent to w_avg: the images no longer depend on z
    t0 = G(n, z, noise="zero", truncation=0.0)
    torch.testing.assert_close(t0[0], t0[1])
    # normal maps of another size are resized to each block
    assert G(sphere_normals(2, 64), z).shape == (2, 3, 32, 32)


def test_minibatch_std_and_discriminator():
    x = torch.randn(1, 5, 4, 4).expand(4, 5, 4, 4)
    assert torch.allclose(MinibatchStd()(x)[:, -1], torch.full((4, 4, 4), 1e-4), atol=1e-4)
    y = MinibatchStd()(torch.randn(6, 5, 4, 4))
    assert y.shape == (6, 6, 4, 4) and (y[:, -1] > 0.5).all()
    D = Discriminator(get_config("tiny", **SMALL))
    assert D(torch.randn(3, 3, 32, 32)).shape == (3, 1)


# --- losses ----------------------------------------------------------------------------
def test_normal_loss_toy():
    n = sphere_normals(2, 8)
    mask = (n.abs().sum(1, keepdim=True) > 0).float()
    assert float(normal_loss(n, n, mask)) == 0.0
    # flipping z on the face: |diff| = 2 |n_z| per pixel
    flipped = n * torch.tensor([1.0, 1.0, -1.0])[:, None, None]
    expected = (2 * n[:, 2].abs() * mask[:, 0]).sum() / (3 * mask.sum())
    torch.testing.assert_close(normal_loss(n, flipped, mask), expected)
    # errors outside the mask do not count; an empty mask gives 0, not NaN
    noisy = n + (1 - mask) * 5
    assert float(normal_loss(n, noisy, mask)) == 0.0
    assert float(normal_loss(n, flipped, torch.zeros_like(mask))) == 0.0
    # targets of another size are resized to the prediction
    assert float(normal_loss(sphere_normals(2, 16), n, mask)) < 0.05


def test_landmark_identity_adversarial_losses_toy():
    a = torch.rand(3, 68, 2) * 64
    assert float(landmark_loss(a, a)) < 1e-3
    torch.testing.assert_close(landmark_loss(a, a + torch.tensor([3.0, 4.0]), image_size=64),
                               torch.tensor(5.0 / 64))
    a.requires_grad_(True)
    landmark_loss(a, a.detach()).backward()
    assert torch.isfinite(a.grad).all()
    e = torch.randn(4, 16)
    assert float(identity_loss(e, 3 * e)) < 1e-6
    torch.testing.assert_close(identity_loss(e, -e), torch.tensor(2.0))
    # non-saturating: the generator loss falls as D believes the fakes
    assert generator_adversarial_loss(torch.full((4, 1), 3.0)) < \
        generator_adversarial_loss(torch.zeros(4, 1))
    torch.testing.assert_close(generator_adversarial_loss(torch.zeros(4, 1)),
                               torch.tensor(math.log(2)))
    torch.testing.assert_close(discriminator_loss(torch.zeros(4, 1), torch.zeros(4, 1)),
                               torch.tensor(2 * math.log(2)))
    assert discriminator_loss(torch.full((4, 1), 5.0), torch.full((4, 1), -5.0)) < 0.02


def test_r1_penalty_and_total():
    a = torch.randn(3, 4, 4)
    x = torch.randn(5, 3, 4, 4, requires_grad=True)
    logits = (x * a).sum(dim=(1, 2, 3))[:, None]          # gradient = a for every sample
    torch.testing.assert_close(r1_penalty(x, logits), a.pow(2).sum())
    assert DEFAULT_LAMBDAS == {"n": 2.0, "ldmk": 2.0, "id": 1.0, "adv": 1.0}
    terms = {k: torch.tensor(1.0) for k in DEFAULT_LAMBDAS}
    assert float(total_loss(terms)) == 6.0
    assert float(total_loss(terms, {"n": 0.0})) == 4.0
    with pytest.raises(KeyError):
        total_loss({"bogus": torch.tensor(1.0)})


def small_gar_batch():
    """A small untrained G, D, untrained aux networks, and a batch of 2: normals, z1, z2."""
    torch.manual_seed(0)
    cfg = get_config("tiny", **SMALL)
    G, D = Generator(cfg), Discriminator(cfg)
    aux = {k: load_aux(k, pretrained=False, width=4, resolution=32) for k in "NPLR"}
    return G, D, aux, sphere_normals(2, 32), torch.randn(2, cfg.z_dim), torch.randn(2, cfg.z_dim)


def test_generator_losses_gradients():
    G, D, aux, n, z1, z2 = small_gar_batch()
    total, terms, fake = generator_losses(G, D, aux, n, n.flip(-1), z1, z2,
                                          landmark_index=torch.arange(17, 68))
    assert set(terms) == {"n", "ldmk", "id", "adv"} and fake.shape == (2, 3, 32, 32)
    torch.testing.assert_close(total, torch.tensor(sum(DEFAULT_LAMBDAS[k] * v
                                                       for k, v in terms.items())))
    total.backward()
    assert G.mapping.layers[0].weight.grad.abs().sum() > 0
    assert all(p.grad is None for net in aux.values() for p in net.parameters())
    # lambda = 0 drops a term entirely
    _, terms, _ = generator_losses(G, D, aux, n, n, z1, z2, {"n": 0.0, "id": 0.0})
    assert set(terms) == {"ldmk", "adv"}


def test_generator_losses_render_only_what_the_terms_need():
    G, D, aux, n, z1, z2 = small_gar_batch()
    rendered = []
    G.register_forward_hook(lambda module, args, out: rendered.append(out.shape[0]))
    for lambdas, images in (({}, 6), ({"ldmk": 0.0}, 4), ({"id": 0.0}, 4),
                            ({"ldmk": 0.0, "id": 0.0}, 2)):
        torch.manual_seed(1)
        _, terms, fake = generator_losses(G, D, aux, n, n.flip(-1), z1, z2, lambdas)
        assert rendered.pop() == images and fake.shape == (2, 3, 32, 32)
        assert {"n", "adv"} <= set(terms)
        assert ("ldmk" in terms) == (lambdas.get("ldmk", 1) != 0)
        assert ("id" in terms) == (lambdas.get("id", 1) != 0)


def test_generator_losses_take_aux_networks_of_a_lower_resolution():
    """A 32-px G judged by 16-px aux networks: each aux network sees (B, 3, 16, 16) images,
    L_n compares 16-px normal maps, and the terms equal those of G's renders downsampled by
    hand."""
    from neural.gar.losses import area_downsample

    G, D, _, n, z1, z2 = small_gar_batch()
    aux = {k: load_aux(k, pretrained=False, width=4, resolution=16) for k in "NPLR"}
    seen = []
    for net in aux.values():
        net.register_forward_pre_hook(lambda module, args: seen.append(tuple(args[0].shape[-2:])))
    torch.manual_seed(1)
    total, terms, fake = generator_losses(G, D, aux, n, n.flip(-1), z1, z2, aux_size=16)
    assert set(seen) == {(16, 16)} and fake.shape == (2, 3, 32, 32)
    assert all(torch.isfinite(torch.tensor(v)) for v in terms.values())
    total.backward()
    assert G.mapping.layers[0].weight.grad.abs().sum() > 0
    with torch.no_grad():
        torch.manual_seed(1)
        img = G(torch.cat([n, n, n.flip(-1)]), torch.cat([z1, z2, z1]))[:2]
        small, n16 = area_downsample(img, 16), area_downsample(n, 16, unit=True)
        expect = normal_loss(n16, aux["N"](small), aux["P"](small))
    assert abs(terms["n"] - float(expect)) < 1e-5
    norms = n16.norm(dim=1)
    assert torch.allclose(norms[norms > 0], torch.ones(()), atol=1e-5)
    assert area_downsample(img, None) is img and area_downsample(img, 32) is img


def test_aux_resolution_must_divide_the_resolution():
    assert get_config("tiny128-gpu").aux_size == 64 and get_config("tiny").aux_size == 64
    with pytest.raises(ValueError, match="aux_resolution"):
        get_config("tiny", aux_resolution=48)
    with pytest.raises(ValueError, match="aux_resolution"):
        get_config("tiny", aux_resolution=128)


# --- auxiliary networks ------------------------------------------------------------------
def test_soft_argmax_finds_peaks():
    heat = torch.full((1, 2, 16, 16), -50.0)
    heat[0, 0, 3, 11] = 50.0
    heat[0, 1, 12, 2] = 50.0
    torch.testing.assert_close(soft_argmax(heat), torch.tensor([[[11.0, 3.0], [2.0, 12.0]]]))


def test_aux_shapes_and_frozen():
    x = torch.rand(2, 3, 64, 64) * 2 - 1
    nets = {k: load_aux(k, pretrained=False) for k in "NPLR"}
    n = nets["N"](x)
    torch.testing.assert_close(n.norm(dim=1), torch.ones(2, 64, 64))
    p = nets["P"](x)
    assert p.shape == (2, 1, 64, 64) and 0 <= float(p.min()) and float(p.max()) <= 1
    assert nets["L"](x).shape == (2, 68, 64, 64)
    lm = nets["L"].landmarks(x)
    assert lm.shape == (2, 68, 2) and (lm >= 0).all() and (lm <= 63).all()
    assert nets["R"](x).shape == (2, 16) and nets["R"].predict(x).shape == (2, 16)
    for net in nets.values():
        assert not net.training and not any(p.requires_grad for p in net.parameters())


def test_aux_user_weights(tmp_path):
    torch.manual_seed(0)
    net = load_aux("P", pretrained=False, width=8)
    path = save_aux(net, "P", tmp_path / "p.pt", width=8, steps=0)
    again = load_aux("P", weights=path)
    x = torch.randn(1, 3, 64, 64)
    torch.testing.assert_close(again(x), net(x))
    with pytest.raises(InputError, match="holds aux network 'P'"):
        load_aux("N", weights=path)
    # a stronger model of the same interface, as TorchScript; heatmaps at 1/4 resolution
    class Heat(torch.nn.Module):
        def forward(self, image):
            return torch.nn.functional.avg_pool2d(image[:, :1].expand(-1, 68, -1, -1), 4)

    script = tmp_path / "heat.ts"
    torch.jit.script(Heat()).save(str(script))
    L = load_aux("L", weights=script)
    img = torch.full((1, 3, 64, 64), -20.0)
    img[0, 0, 40:44, 8:12] = 20.0                 # one bright 4x4 block = heatmap pixel (10, 2)
    torch.testing.assert_close(L.landmarks(img)[0, 0], torch.tensor([9.5, 41.5]), atol=0.05, rtol=0)
    with pytest.raises(InputError, match="returns shape"):
        load_aux("N", weights=torch.nn.Conv2d(3, 2, 1))
    with pytest.raises(InputError, match="not found"):
        load_aux("R", weights=tmp_path / "missing.pt")
    with pytest.raises(InputError, match="unknown aux network"):
        load_aux("Q")


def test_inverter_name_pairs_each_generator_file_with_its_inverter(tmp_path):
    from neural.gar.paths import companion_path, inverter_name

    assert inverter_name("w/gpu/gar_64.pt") == "inverter_64.pt"
    assert inverter_name("w/real/gar_tiny.pt") == "inverter_tiny.pt"
    assert inverter_name("runs/x/generator.pt") == "inverter_tiny.pt"
    (tmp_path / "inverter_128.pt").write_bytes(b"")
    assert companion_path(tmp_path / "gar_128.pt", "inverter_128.pt") == tmp_path / "inverter_128.pt"
    assert companion_path(tmp_path / "gar_64.pt", "inverter_64.pt") is None
