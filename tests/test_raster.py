"""Rasterisation core: analytic scenes (sphere, plane, cube, flat square), shading, PNGs,
degenerate input."""
import numpy as np
import pytest

from morphable.camera import Camera
from morphable.errors import InputError
from morphable.raster import (DirectionalLight, interpolate, normal_map, read_depth_png, render,
                              save_depth_png, save_image_png, save_mask_png, save_normal_png,
                              sh_from_lights, shade_directional, shade_sh, uv_normal_map,
                              uv_visibility, visibility)

SQUARE = np.array([[-50.0, -50, 0], [50, -50, 0], [50, 50, 0], [-50, 50, 0]])
SQUARE_T = np.array([[0, 1, 2], [0, 2, 3]])


def icosphere(radius=50.0, subdivisions=4):
    import trimesh

    s = trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius)
    return np.asarray(s.vertices), np.asarray(s.faces, dtype=np.int64)


def cube(side=100.0):
    import trimesh

    b = trimesh.creation.box(extents=(side, side, side))
    return np.asarray(b.vertices), np.asarray(b.faces, dtype=np.int64)


def angle_deg(a, b):
    return np.degrees(np.arccos(np.clip((a * b).sum(-1), -1, 1)))


@pytest.mark.parametrize("kind", ["affine", "perspective"])
def test_sphere_normal_map_matches_analytic_normals(kind):
    v, t = icosphere()
    cam = Camera.looking_at_face((256, 256), yaw=25, pitch=-10, kind=kind, face_width_px=300)
    vis = visibility(v, t, cam)
    nmap = normal_map(v, t, cam, frame="world", vis=vis)
    # analytic: intersect every pixel ray with the exact sphere
    o, d = cam.rays()
    b = (o * d).sum(-1)
    disc = b * b - ((o * o).sum(-1) - 50.0 ** 2)
    hit = disc > 0
    tt = -b - np.sqrt(np.where(hit, disc, 0))
    n_true = (o + tt[..., None] * d) / 50.0
    both = hit & vis.mask
    # the silhouettes agree up to the polygonal outline
    assert abs(int(hit.sum()) - int(vis.mask.sum())) < 0.01 * hit.sum()
    err = angle_deg(nmap[both], n_true[both])
    assert err.mean() < 0.5, err.mean()
    # the camera frame is the world frame rotated
    ncam = normal_map(v, t, cam, frame="camera", vis=vis)
    np.testing.assert_allclose(ncam[both], nmap[both] @ cam.rotation.T, atol=1e-6)
    assert (ncam[both][:, 2] > -0.05).all()  # visible normals face the viewer
    np.testing.assert_allclose(np.linalg.norm(nmap[vis.mask], axis=-1), 1, atol=1e-6)
    assert (nmap[~vis.mask] == 0).all()
    # depth: the exact sphere's depth within the polygon's sagitta (away from grazing rays,
    # along which a sub-millimetre sagitta becomes a long distance)
    depth_true = cam.depth((o + tt[..., None] * d).reshape(-1, 3)).reshape(hit.shape)
    facing = both & (-(d * n_true).sum(-1) > 0.3)
    assert facing.sum() > 0.8 * both.sum()
    sagitta = 50.0 - np.linalg.norm(v[t].mean(1), axis=1).min()
    assert np.abs(vis.depth[facing] - depth_true[facing]).max() < sagitta / 0.3
    assert np.isinf(vis.depth[~vis.mask]).all()


@pytest.mark.parametrize("kind", ["affine", "perspective"])
def test_plane_depth_is_exact(kind):
    # a tilted plane through (0, 0, 10) with normal n
    n = np.array([0.3, -0.2, 1.0])
    n /= np.linalg.norm(n)
    u = np.cross(n, [0, 1, 0.0])
    u /= np.linalg.norm(u)
    w = np.cross(n, u)
    p0 = np.array([0, 0, 10.0])
    v = np.array([p0 + 400 * (a * u + b * w) for a, b in [(-1, -1), (1, -1), (1, 1), (-1, 1)]])
    cam = Camera.looking_at_face((96, 64), yaw=10, pitch=5, kind=kind)
    vis = visibility(v, SQUARE_T, cam)
    assert vis.mask.all()
    o, d = cam.rays()
    tt = ((p0 - o) @ n) / (d @ n)
    expected = cam.depth((o + tt[..., None] * d).reshape(-1, 3)).reshape(vis.shape)
    assert np.abs(vis.depth - expected).max() < 2e-3  # mm, float32 ray casting
    # the interpolated surface point projects back onto its pixel centre
    p = interpolate(vis, v)
    px = cam.project(p.reshape(-1, 3)).reshape(vis.shape + (2,))
    jj, ii = np.meshgrid(np.arange(96), np.arange(64))
    assert np.abs(px - np.stack([jj, ii], -1)).max() < 1e-2


def test_cube_face_mask_area_matches_projection():
    v, t = cube()
    cam = Camera(kind="affine", rotation=Camera.looking_at_face(yaw=30, pitch=20).rotation,
                 translation=[0, 0, -500], scale=1.5, image_size=(300, 300))
    vis = visibility(v, t, cam)
    fn = np.cross(v[t[:, 1]] - v[t[:, 0]], v[t[:, 2]] - v[t[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    for axis in range(3):
        for sign in (1, -1):
            faces = np.flatnonzero(fn[:, axis] * sign > 0.99)
            cos = (cam.rotation @ fn[faces[0]])[2]
            pixels = np.isin(vis.triangle_id, faces).sum()
            expected = max(cos, 0) * (100 * 1.5) ** 2
            assert abs(pixels - expected) <= 0.02 * (100 * 1.5) ** 2, (axis, sign, pixels, expected)
    from scipy.spatial import ConvexHull

    hull = ConvexHull(cam.project(v)).volume
    assert abs(vis.mask.sum() - hull) < 0.02 * hull


def test_uv_bake_of_flat_square_is_constant():
    R = Camera.looking_at_face(yaw=40, pitch=-30, roll=10).rotation
    v = SQUARE @ R.T + [5, 6, 7]
    layout = (SQUARE_T, (SQUARE[:, :2] + 50) / 100, None)
    m = uv_normal_map(layout, v, size=64)
    normal = R @ [0, 0, 1.0]
    assert m.shape == (64, 64, 3)
    np.testing.assert_allclose(m.reshape(-1, 3), np.broadcast_to(normal, (64 * 64, 3)), atol=1e-6)
    tangent = uv_normal_map(layout, v, size=64, tangent=True, base=v)
    np.testing.assert_allclose(tangent.reshape(-1, 3), [[0, 0, 1.0]] * 64 * 64, atol=1e-6)


def test_uv_table_is_cached_and_covers_half_a_triangle():
    a = uv_visibility([[0, 1, 2]], [[0.0, 0], [1, 0], [0, 1]], size=32)
    b = uv_visibility([[0, 1, 2]], [[0.0, 0], [1, 0], [0, 1]], size=32)
    assert a is b
    assert abs(a.mask.mean() - 0.5) < 2 / 32
    # barycentrics reproduce the texel centres' uv
    uv = interpolate(a, np.array([[0.0, 0], [1, 0], [0, 1]]))
    c = (np.arange(32) + 0.5) / 32
    uu, vv = np.meshgrid(c, 1 - c)
    np.testing.assert_allclose(uv[a.mask], np.stack([uu, vv], -1)[a.mask], atol=1e-5)
    # the foreground form gives the same values in the order of vis.pixels
    fg = interpolate(a, np.array([[0.0, 0], [1, 0], [0, 1]]), foreground=True)
    np.testing.assert_array_equal(fg, uv.reshape(-1, 2)[a.pixels])


def test_tangent_space_of_model_is_z_for_its_mean_and_tilts_for_a_sample(sfm):
    flat = uv_normal_map(sfm, sfm.mean, size=64, tangent=True)
    mask = np.abs(flat).sum(-1) > 0
    assert mask.mean() > 0.5
    assert np.abs(flat[mask] - [0, 0, 1]).max() < 1e-5
    other = uv_normal_map(sfm, sfm.vertices(np.full(10, 2.0)), size=64, tangent=True)
    assert np.abs(other[mask][:, :2]).max() > 0.05
    np.testing.assert_allclose(np.linalg.norm(other[mask], axis=-1), 1, atol=1e-6)


def test_model_normal_maps_face_the_viewer(sfm, ict):
    for m in (sfm, ict):
        cam = Camera.looking_at_face((128, 128), kind="perspective")
        nmap = normal_map(m.mean, m.triangles, cam)
        mask = np.abs(nmap).sum(-1) > 0
        assert mask.mean() > 0.1
        # most of a frontal face looks at the camera
        assert np.median(nmap[mask][:, 2]) > 0.7


def test_supersampling_gives_coverage_and_unit_normals():
    v, t = icosphere(subdivisions=3)
    cam = Camera.looking_at_face((64, 64))
    vis = visibility(v, t, cam, supersample=3)
    assert vis.shape == (192, 192) and vis.image_shape == (64, 64)
    cov = vis.coverage()
    assert ((cov > 0) & (cov < 1)).any() and cov.min() >= 0 and cov.max() <= 1
    nmap = normal_map(v, t, cam, vis=vis)
    assert nmap.shape == (64, 64, 3)
    fg = cov >= 0.5
    np.testing.assert_allclose(np.linalg.norm(nmap[fg], axis=-1), 1, atol=1e-6)
    assert (nmap[~fg] == 0).all()
    img = render(v, t, cam, supersample=3, background=(0, 0, 0))
    edge = (cov > 0.2) & (cov < 0.8)
    assert edge.any() and (img[edge].max(-1) < img[cov == 1].max()).all()


def test_float32_extreme_pose_is_finite(sfm):
    v = sfm.mean.astype(np.float32)
    for yaw, pitch in [(90, 0), (0, 89.9), (179, -60)]:
        cam = Camera.looking_at_face((64, 64), yaw=yaw, pitch=pitch, kind="perspective")
        nmap = normal_map(v, sfm.triangles, cam)
        assert nmap.dtype == np.float32 and np.isfinite(nmap).all()


def test_degenerate_inputs_raise_input_error():
    cam = Camera.looking_at_face((32, 32), kind="perspective")
    with pytest.raises(InputError, match="non-empty"):
        visibility(np.zeros((0, 3)), np.zeros((0, 3), dtype=int), cam)
    with pytest.raises(InputError, match="non-empty"):
        visibility(SQUARE, np.zeros((0, 3), dtype=int), cam)
    bad = SQUARE.copy()
    bad[1, 2] = np.nan
    with pytest.raises(InputError, match="NaN"):
        normal_map(bad, SQUARE_T, cam)
    with pytest.raises(InputError, match="behind the camera"):
        visibility(SQUARE + [0, 0, 700], SQUARE_T, cam)
    with pytest.raises(InputError, match="behind the camera"):
        visibility(SQUARE + [0, 0, 700], SQUARE_T, Camera.looking_at_face((32, 32)))
    with pytest.raises(InputError, match="image size"):
        visibility(SQUARE, SQUARE_T, Camera.looking_at_face((0, 0)))
    with pytest.raises(InputError, match="supersample"):
        visibility(SQUARE, SQUARE_T, cam, supersample=0)
    with pytest.raises(InputError, match="samples"):
        visibility(SQUARE, SQUARE_T, Camera.looking_at_face((40000, 40000)), supersample=1)
    with pytest.raises(InputError, match="out of range"):
        visibility(SQUARE, SQUARE_T + 2, cam)
    with pytest.raises(InputError, match="focal length must be positive"):
        visibility(SQUARE, SQUARE_T, Camera(kind="perspective", focal=0.0, translation=[0, 0, -500]))
    with pytest.raises(InputError, match="size"):
        uv_visibility(SQUARE_T, SQUARE[:, :2], size=0)
    with pytest.raises(InputError, match="SH coefficients"):
        shade_sh(np.zeros((2, 3)), 1.0, np.ones(4))
    with pytest.raises(InputError, match="colors contain NaN"):
        render(SQUARE, SQUARE_T, cam, colors=np.full((4, 3), np.nan))
    with pytest.raises(InputError, match="uv contain NaN"):
        render(SQUARE, SQUARE_T, cam, texture=(np.full((4, 2), np.nan), None, np.ones((2, 2, 3))))


def test_partially_behind_perspective_camera_clips():
    # a long strip running from in front of the camera to behind it
    v = np.array([[-20.0, -20, -1000], [20, -20, -1000], [20, -20, 1000], [-20, -20, 1000]])
    cam = Camera.looking_at_face((64, 64), kind="perspective")
    vis = visibility(v, SQUARE_T, cam)
    assert vis.mask.any() and (vis.depth[vis.mask] > 0).all()


@pytest.mark.parametrize("kind", ["affine", "perspective"])
@pytest.mark.parametrize("supersample", [1, 2])
@pytest.mark.parametrize("case", ["inside", "partly outside", "partly behind"])
def test_window_casting_matches_full_frame(sfm, monkeypatch, kind, supersample, case):
    """Only the samples in the projected bounding box are cast; casting every sample gives
    the same triangles, barycentrics and depths, bit for bit."""
    import importlib

    # the package's `visibility` function hides the module of the same name
    vis_module = importlib.import_module("morphable.raster.visibility")
    if case == "partly behind" and kind == "affine":
        pytest.skip("an affine camera sits at infinity")
    cam = Camera.looking_at_face((48, 40), yaw=25, kind=kind, face_width_px=30)
    towards_camera = -cam.rotation.T @ cam.translation / 600
    shift = {"inside": 0, "partly outside": np.array([-70, 60, 0]),
             "partly behind": 600 * towards_camera}
    v = sfm.mean.astype(np.float64) + shift[case]
    vis = visibility(v, sfm.triangles, cam, supersample=supersample)
    window = vis_module._window(cam, cam.to_camera(v), 48, 40)
    if case == "partly behind":
        assert (cam.depth(v) <= 0).any() and window == (0, 48, 0, 40)
    else:
        assert window != (0, 48, 0, 40)
    if case == "partly outside":
        assert vis.mask[0].any() and vis.mask[:, 0].any()  # cut by the top left corner
    monkeypatch.setattr(vis_module, "_window", lambda camera, points, w, h: (0, w, 0, h))
    full = visibility(v, sfm.triangles, cam, supersample=supersample)
    assert vis.mask.sum() > 50
    np.testing.assert_array_equal(vis.triangle_id, full.triangle_id)
    np.testing.assert_array_equal(vis.barycentric, full.barycentric)
    np.testing.assert_array_equal(vis.depth, full.depth)
    np.testing.assert_array_equal(vis.pixels, np.flatnonzero(full.triangle_id >= 0))


def test_mesh_cache_follows_the_vertices(sfm):
    """The scene and vertex normals are reused for equal arrays, rebuilt for changed ones
    (also when changed in place)."""
    import importlib

    from morphable.normals import vertex_normals

    vis_module = importlib.import_module("morphable.raster.visibility")
    v, t = sfm.mean.astype(np.float64), sfm.triangles
    cam = Camera.looking_at_face((64, 64), yaw=20, kind="perspective")
    first = vis_module.scene(v, t)
    assert vis_module.scene(v.copy(), t.copy()) is first
    fresh = normal_map(v, t, cam, vis=visibility(v, t, cam))
    np.testing.assert_array_equal(normal_map(v, t, cam), fresh)
    v[:, 2] *= 1.5  # in place: a deeper face
    assert vis_module.scene(v, t) is not first
    vis = visibility(v, t, cam)
    n = vertex_normals(v, t) @ cam.rotation.T
    ref = interpolate(vis, n)
    ref /= np.maximum(np.linalg.norm(ref, axis=-1, keepdims=True), 1e-300)
    np.testing.assert_allclose(normal_map(v, t, cam), ref, atol=1e-6)
    assert np.abs(normal_map(v, t, cam) - fresh).max() > 0.1


def test_lambertian_plane_and_texture():
    cam = Camera(kind="affine", translation=[0, 0, -300], scale=8 / 100, image_size=(8, 8))
    light = DirectionalLight(direction=(0, 1, 1), color=0.5)
    img = render(SQUARE, SQUARE_T, cam, colors=(1.0, 0.5, 0.25), light=light, ambient=0.2)
    np.testing.assert_allclose(img, np.broadcast_to([1.0, 0.5, 0.25], (8, 8, 3)) *
                               (0.2 + 0.5 * np.sqrt(0.5)), atol=1e-6)
    tex = np.random.default_rng(0).random((8, 8, 3))
    uv = (SQUARE[:, :2] + 50) / 100
    out = render(SQUARE, SQUARE_T, cam, texture=(uv, None, tex), light=np.eye(9)[0])
    np.testing.assert_allclose(out, tex, atol=1e-5)
    # per-vertex colours interpolate linearly
    colors = np.array([[0.0, 0, 0], [1, 0, 0], [1, 0, 0], [0, 0, 0]])
    red = render(SQUARE, SQUARE_T, cam, colors=colors, light=np.eye(9)[0])[..., 0]
    np.testing.assert_allclose(red[0], (np.arange(8) + 0.5) / 8, atol=1e-5)


def test_cast_shadows():
    plane = SQUARE * 4
    small = SQUARE * 0.2 + [0, 0, 20]
    v = np.concatenate([plane, small])
    t = np.concatenate([SQUARE_T, SQUARE_T + 4])
    cam = Camera(kind="affine", translation=[0, 0, -300], scale=1.0, image_size=(101, 101))
    light = DirectionalLight(direction=(1, 0, 1), color=0.6)
    lit = render(v, t, cam, light=light, ambient=0.2, colors=(1, 1, 1))
    shadowed = render(v, t, cam, light=light, ambient=0.2, colors=(1, 1, 1), shadows=True)
    c = 50  # pixel of x = 0, y = 0
    # the small square's shadow lies 20 mm towards -x on the plane
    assert shadowed[c, c - 20, 0] == pytest.approx(0.2, abs=1e-6)
    assert lit[c, c - 20, 0] == pytest.approx(0.2 + 0.6 * np.sqrt(0.5), abs=1e-6)
    assert shadowed[c, c + 25, 0] == pytest.approx(lit[c, c + 25, 0])
    assert shadowed[c, c, 0] == pytest.approx(lit[c, c, 0])  # the occluder itself is lit
    dark = (shadowed[..., 0] < lit[..., 0] - 0.1).sum()
    assert abs(dark - 20 * 20) < 2 * 20 * 2 + 4


def test_sh_conventions():
    rng = np.random.default_rng(1)
    n = rng.normal(size=(500, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    light = DirectionalLight(direction=(0.2, 0.5, 1.0), color=(0.8, 0.6, 0.4))
    exact = shade_directional(n, 1.0, light, ambient=0.1)
    approx = shade_sh(n, 1.0, sh_from_lights(light, ambient=0.1))
    # band-limited clamped cosine: close, not equal
    assert np.abs(approx - exact).max() < 0.15 and np.abs(approx - exact).mean() < 0.05
    facing = shade_sh(light.direction, 1.0, sh_from_lights(light))
    np.testing.assert_allclose(facing, 1.0625 * light.color, rtol=1e-6)
    # an SH environment is linear in its coefficients
    a, b = rng.normal(size=(2, 9, 3))
    np.testing.assert_allclose(shade_sh(n, 0.5, a + b), shade_sh(n, 0.5, a) + shade_sh(n, 0.5, b),
                               atol=1e-12)


def test_png_round_trips(tmp_path):
    from PIL import Image

    v, t = icosphere(subdivisions=3)
    cam = Camera.looking_at_face((48, 40), kind="perspective")
    vis = visibility(v, t, cam)
    nmap = normal_map(v, t, cam, vis=vis)
    save_normal_png(tmp_path / "n.png", nmap)
    rgb = np.asarray(Image.open(tmp_path / "n.png"))
    assert rgb.shape == (40, 48, 3) and rgb.dtype == np.uint8
    assert (rgb[~vis.mask] == 0).all()
    decoded = rgb[vis.mask] / 255.0 * 2 - 1
    assert np.abs(decoded - nmap[vis.mask]).max() <= 1 / 255 + 1e-9
    near, far = save_depth_png(tmp_path / "d.png", vis.depth)
    im = Image.open(tmp_path / "d.png")
    assert im.mode.startswith("I") and np.asarray(im).max() == 65535
    back = read_depth_png(tmp_path / "d.png")
    assert np.isinf(back[~vis.mask]).all()
    assert np.abs(back[vis.mask] - vis.depth[vis.mask]).max() <= (far - near) / 65534
    save_mask_png(tmp_path / "m.png", vis.mask)
    assert (np.asarray(Image.open(tmp_path / "m.png")) > 0).sum() == vis.mask.sum()
    with pytest.raises(InputError, match="NaN"):
        save_image_png(tmp_path / "x.png", np.full((4, 4, 3), np.nan))
    assert not (tmp_path / "x.png").exists()


def test_textured_scan_renders(data_dir):
    from morphable.raster import frame_mesh
    from morphable.raster.inputs import load_mesh

    scan = load_mesh(data_dir / "scans/james/james.obj")
    assert scan.texture is not None and scan.triangle_uv is not None
    cam = frame_mesh(scan.vertices, (96, 96), kind="perspective")
    img = render(scan.vertices, scan.triangles, cam, texture=(scan.uv, scan.triangle_uv, scan.texture),
                 light=np.eye(9)[0], background=(0, 1, 0))
    vis = visibility(scan.vertices, scan.triangles, cam)
    face = img[vis.mask]
    # skin and dark hair, not the green background nor the texture atlas' black padding
    assert face.mean(0)[0] > face.mean(0)[2] and (face.sum(-1) > 0.15).mean() > 0.8
    assert np.allclose(img[~vis.mask], [0, 1, 0])


@pytest.mark.parametrize("kind", ["affine", "perspective"])
def test_vertex_colors_read_back_a_rendered_sphere(kind):
    from morphable.raster import vertex_colors

    v, t = icosphere(subdivisions=4)
    colors = 0.5 + 0.4 * np.sin(v / 15.0)               # smooth, different in each channel
    cam = Camera.looking_at_face((256, 256), kind=kind)
    img = render(v, t, cam, colors=colors, light=np.eye(9)[0], background=(0, 0, 0))
    got, seen = vertex_colors(v, t, cam, img)
    toward = v[:, 2] > 0                       # the camera sits on +z, looking down -z
    assert seen[toward & (v[:, 2] > 25)].all() and not seen[v[:, 2] < 0].any()
    assert np.abs(got[seen] - colors[seen]).max() < 0.05
    # unseen vertices: the seen median, or the mirror's colour when it is seen
    assert np.allclose(got[~seen], np.median(got[seen], 0))
    mirror = np.array([np.argmin(np.linalg.norm(v - p * [1, 1, -1], axis=1)) for p in v])
    got2, _ = vertex_colors(v, t, cam, img, symmetry=mirror)
    back = ~seen & seen[mirror]
    assert back.sum() > 100 and np.allclose(got2[back], got2[mirror[back]])
    with pytest.raises(InputError, match="camera's is 256x256"):
        vertex_colors(v, t, cam, img[:100])
    with pytest.raises(InputError, match="no vertex"):
        vertex_colors(v + [0, 0, 5000], t, Camera.looking_at_face((256, 256), kind="perspective"),
                      img)
