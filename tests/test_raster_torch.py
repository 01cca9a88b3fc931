"""The differentiable path: interpolation, normal maps, shading and texture look-ups in torch,
checked against numpy and with torch.autograd.gradcheck in float64."""
import numpy as np
import pytest

torch = pytest.importorskip("torch")

from morphable.camera import Camera  # noqa: E402
from morphable.errors import InputError  # noqa: E402
from morphable.raster import (DirectionalLight, interpolate, normal_map, render,  # noqa: E402
                              sample_texture, sh_from_lights, shade_directional, shade_sh_torch,
                              uv_normal_map, visibility)


def bumpy_patch(n=5):
    """A small non-planar grid mesh (n x n vertices) in mm."""
    x, y = np.meshgrid(np.linspace(-40, 40, n), np.linspace(-40, 40, n))
    z = 10 * np.sin(x / 20) * np.cos(y / 25)
    v = np.stack([x, y, z], -1).reshape(-1, 3)
    i = np.arange(n * n).reshape(n, n)
    a, b, c, d = i[:-1, :-1].ravel(), i[:-1, 1:].ravel(), i[1:, 1:].ravel(), i[1:, :-1].ravel()
    t = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return v, t


def test_torch_matches_numpy(sfm):
    cam = Camera.looking_at_face((64, 64), yaw=20, kind="perspective")
    mean = sfm.mean.astype(np.float64)
    vis = visibility(mean, sfm.triangles, cam)
    ref = normal_map(mean, sfm.triangles, cam, vis=vis)
    v = torch.tensor(mean)
    out = normal_map(v, sfm.triangles, vis=vis)
    np.testing.assert_allclose(out.numpy(), ref, atol=1e-10)
    batch = normal_map(torch.stack([v, v]), sfm.triangles, vis=[vis, vis])
    assert batch.shape == (2, 64, 64, 3)
    np.testing.assert_allclose(batch[1].numpy(), ref, atol=1e-10)
    # supersampled, two cameras in one batch
    cam2 = Camera.looking_at_face((64, 64), yaw=-30, kind="perspective")
    vis2 = [visibility(mean, sfm.triangles, c, supersample=2) for c in (cam, cam2)]
    batch = normal_map(torch.stack([v, v]), sfm.triangles, vis=vis2)
    for b in range(2):
        np.testing.assert_allclose(batch[b].numpy(), normal_map(mean, sfm.triangles, vis=vis2[b]),
                                   atol=1e-10)
    # a numpy rotation override matches the camera's own
    np.testing.assert_allclose(normal_map(mean, sfm.triangles, vis=vis, rotation=cam.rotation), ref,
                               atol=1e-12)
    uv_ref = uv_normal_map(sfm, mean, size=32, tangent=True)
    uv_t = uv_normal_map(sfm, v, size=32, tangent=True)
    np.testing.assert_allclose(uv_t.numpy(), uv_ref, atol=1e-10)
    img = render(mean, sfm.triangles, cam, vis=vis, light=sh_from_lights(DirectionalLight()))
    img_t = render(v, sfm.triangles, cam, vis=vis, light=torch.tensor(sh_from_lights(DirectionalLight())))
    np.testing.assert_allclose(img_t.numpy(), img, atol=1e-10)


def test_gradcheck_interpolate_and_normal_map():
    v, t = bumpy_patch()
    cam = Camera.looking_at_face((12, 12), yaw=15, pitch=10, kind="perspective", face_width_px=20)
    vis = visibility(v, t, cam)
    assert vis.mask.sum() > 50
    attrs = torch.rand(len(v), 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a: interpolate(vis, a), (attrs,))
    # the backward pass is itself differentiable (second-order methods, gradient penalties)
    assert torch.autograd.gradgradcheck(lambda a: interpolate(vis, a) ** 2, (attrs,), fast_mode=True)
    batch = torch.rand(2, len(v), 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda a: interpolate(vis, a), (batch,), fast_mode=True)
    full = interpolate(vis, batch).detach().reshape(2, -1, 2)[:, vis.pixels]
    assert torch.equal(interpolate(vis, batch, foreground=True).detach(), full)
    verts = torch.tensor(v, requires_grad=True)
    tiny = visibility(v, t, Camera.looking_at_face((5, 5), kind="perspective", face_width_px=8))
    assert tiny.mask.sum() >= 9
    assert torch.autograd.gradcheck(lambda x: normal_map(x, t, vis=tiny), (verts,))  # full Jacobian
    for weighting in ("area", "angle"):
        assert torch.autograd.gradcheck(
            lambda x: normal_map(x, t, vis=vis, weighting=weighting), (verts,), atol=1e-6,
            fast_mode=True)
    # a differentiable pose: gradients reach an axis-angle rotation
    def with_pose(w):
        theta = torch.sqrt((w * w).sum() + 1e-30)
        k = w / theta
        K = torch.zeros(3, 3, dtype=w.dtype)
        K[0, 1], K[0, 2], K[1, 2] = -k[2], k[1], -k[0]
        K = K - K.T
        R = torch.eye(3, dtype=w.dtype) + torch.sin(theta) * K + (1 - torch.cos(theta)) * K @ K
        return normal_map(verts, t, vis=vis, rotation=R @ torch.as_tensor(cam.rotation))
    w = torch.tensor([0.1, -0.2, 0.05], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(with_pose, (w,), fast_mode=True)


def test_gradcheck_model_coefficients(sfm):
    cam = Camera.looking_at_face((24, 24), kind="perspective")
    vis = visibility(sfm.mean, sfm.triangles, cam)
    mean = torch.tensor(sfm.mean, dtype=torch.float64)
    basis = torch.tensor(sfm.identity_basis[:3].reshape(3, -1), dtype=torch.float64)
    expr = torch.tensor(sfm.expression_basis[:2].reshape(2, -1), dtype=torch.float64)

    def nmap(alpha, beta):
        v = mean + ((alpha @ basis) + (beta @ expr)).reshape(-1, 3)
        return normal_map(v, sfm.triangles, vis=vis)

    alpha = torch.tensor([0.3, -0.5, 0.2], dtype=torch.float64, requires_grad=True)
    beta = torch.tensor([0.2, 0.4], dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(nmap, (alpha, beta), atol=1e-6, fast_mode=True)
    # and the gradient is not trivially zero
    nmap(alpha, beta)[..., 2].sum().backward()
    assert alpha.grad.abs().max() > 1e-4


def test_gradcheck_shading_and_texture():
    n = torch.nn.functional.normalize(torch.randn(2, 3, 4, 3, dtype=torch.float64), dim=-1)
    n.requires_grad_(True)
    albedo = torch.rand(2, 3, 4, 3, dtype=torch.float64, requires_grad=True)
    sh = torch.randn(2, 9, 3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(shade_sh_torch, (n, albedo, sh))
    sh1 = torch.randn(9, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(shade_sh_torch, (n, albedo, sh1))
    lights = [DirectionalLight((0.3, 0.2, 1), 0.7), DirectionalLight((-1, 0, 0.5), (0.2, 0.3, 0.4))]
    assert torch.autograd.gradcheck(lambda a, b: shade_directional(a, b, lights, 0.2), (n, albedo))
    np.testing.assert_allclose(shade_directional(n, albedo, lights, 0.2).detach().numpy(),
                               shade_directional(n.detach().numpy(), albedo.detach().numpy(),
                                                 lights, 0.2), atol=1e-12)
    tex = torch.rand(5, 6, 3, dtype=torch.float64, requires_grad=True)
    uv = (torch.rand(7, 2, dtype=torch.float64) * 0.8 + 0.1).requires_grad_(True)
    assert torch.autograd.gradcheck(sample_texture, (tex, uv))
    np.testing.assert_allclose(sample_texture(tex, uv).detach().numpy(),
                               sample_texture(tex.detach().numpy(), uv.detach().numpy()), atol=1e-12)


def test_render_gradient_reaches_vertices_and_colours():
    v, t = bumpy_patch()
    cam = Camera.looking_at_face((16, 16), kind="perspective", face_width_px=25)
    vis = visibility(v, t, cam)
    verts = torch.tensor(v, requires_grad=True)
    colors = torch.full((len(v), 3), 0.5, dtype=torch.float64, requires_grad=True)
    sh = torch.tensor(sh_from_lights(DirectionalLight((0.5, 0.2, 1), 0.5), ambient=0.2),
                      requires_grad=True)
    img = render(verts, t, vis=vis, colors=colors, light=sh, background=(0, 0, 0))
    img.sum().backward()
    for g in (verts.grad, colors.grad, sh.grad):
        assert torch.isfinite(g).all() and g.abs().max() > 0
    # a texture through the patch's UVs gets gradients too
    uv = (v[:, :2] - v[:, :2].min(0)) / np.ptp(v[:, :2], 0)
    tex = torch.rand(8, 8, 3, dtype=torch.float64, requires_grad=True)
    render(verts, t, vis=vis, texture=(uv, None, tex), light=sh).sum().backward()
    assert torch.isfinite(tex.grad).all() and (tex.grad != 0).sum() > 20


def test_torch_errors():
    v, t = bumpy_patch()
    cam = Camera.looking_at_face((8, 8), kind="perspective")
    vis = visibility(v, t, cam)
    bad = torch.tensor(v)
    bad[0, 0] = float("nan")
    with pytest.raises(InputError, match="NaN"):
        normal_map(bad, t, vis=vis)
    with pytest.raises(InputError, match="list of visibilities"):
        normal_map(torch.tensor(np.stack([v, v])), t, cam)
    with pytest.raises(InputError, match="rows"):
        interpolate(vis, torch.zeros(3, 2, dtype=torch.float64))
