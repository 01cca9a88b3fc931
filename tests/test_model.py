import subprocess
import sys

import numpy as np
import pytest

from morphable import InputError, MorphableModel


def test_sfm_sizes_and_units(sfm):
    assert (sfm.n_vertices, sfm.n_identity, sfm.n_expression) == (3448, 63, 6)
    assert sfm.expression_names == ["anger", "disgust", "fear", "happiness", "sadness", "surprise"]
    # a face is 12-18 cm wide in millimetres
    width = np.ptp(sfm.mean[:, 0])
    assert 120 < width < 180
    # eigenvalue scaling: the first mode moves vertices by centimetres, not metres or microns
    assert 50 < sfm.identity_std[0] < 1000
    assert np.all(np.diff(sfm.identity_std) <= 1e-3)  # PCA order


def test_ict_in_millimetres(ict):
    assert (ict.n_vertices, ict.n_identity, ict.n_expression) == (26719, 100, 53)
    face = ict.mean[ict.segments["face"]]
    assert 120 < np.ptp(face[:, 0]) < 250
    assert (ict.landmark_ids >= 0).all()


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_vertices_batched_and_rows(sfm, dtype):
    rng = np.random.default_rng(0)
    a = rng.standard_normal((4, 63))
    b = rng.uniform(0, 1, (4, 6))
    full = sfm.vertices(a, b, dtype=dtype)
    assert full.shape == (4, 3448, 3) and full.dtype == dtype
    ids = np.array([5, 100, 3000, 5])
    rows = sfm.vertices_at(ids, a, b, dtype=dtype)
    tol = 1e-3 if dtype == np.float32 else 1e-9
    np.testing.assert_allclose(rows, full[:, ids], atol=tol)
    # explicit definition: mean + sum of scaled modes
    ref = sfm.mean + np.tensordot(a[0], sfm.identity_basis, 1) + np.tensordot(b[0], sfm.expression_basis, 1)
    np.testing.assert_allclose(full[0], ref, atol=tol * 10)


def test_vertices_torch_forward_pass(sfm):
    """Torch coefficients in: torch vertices out, batch first, the numpy values, and gradients
    equal to the bases (the forward pass is linear)."""
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(1)
    a, b = rng.standard_normal((2, 10)), rng.uniform(0, 1, (2, 6))
    at = torch.tensor(a, requires_grad=True)
    v = sfm.vertices(at, torch.tensor(b))
    assert isinstance(v, torch.Tensor) and v.shape == (2, 3448, 3) and v.dtype == torch.float64
    np.testing.assert_allclose(v.detach().numpy(), sfm.vertices(a, b), atol=1e-9)
    v[1, 7, 2].backward()
    np.testing.assert_allclose(at.grad[1].numpy(), sfm.identity_basis[:10, 7, 2], atol=1e-12)
    assert not at.grad[0].any()
    # float32 in, float32 out; numpy or no expression alongside
    one = sfm.vertices(torch.tensor(a[0], dtype=torch.float32), b[0])
    assert one.dtype == torch.float32 and one.shape == (3448, 3)
    np.testing.assert_allclose(one.numpy(), sfm.vertices(a[0], b[0]), atol=1e-3)
    assert torch.equal(sfm.vertices(torch.zeros(0)), torch.as_tensor(sfm.mean, dtype=torch.float32))
    with pytest.raises(InputError, match="64 coefficients"):
        sfm.vertices(torch.zeros(64))


def test_partial_coefficients_and_mean(sfm):
    np.testing.assert_allclose(sfm.vertices(), sfm.mean)
    v = sfm.vertices([1.0, 0.0])
    np.testing.assert_allclose(v - sfm.mean, sfm.identity_basis[0], atol=1e-5)


def test_vertices_at_never_builds_the_mesh(ict):
    import tracemalloc

    a, b = np.ones(100), np.full(53, 0.1)
    tracemalloc.start()
    out = ict.vertices_at(ict.landmark_ids, a, b)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert out.shape == (68, 3)
    # a full mesh is 26719*3*8 = 641 kB, one basis copy 32 MB; landmark rows need ~100 kB
    assert peak < 300_000


def test_bad_coefficients(sfm):
    with pytest.raises(InputError, match="64 coefficients"):
        sfm.vertices(np.zeros(64))
    with pytest.raises(InputError, match="NaN"):
        sfm.vertices([np.nan])
    with pytest.raises(InputError, match="vertex ids"):
        sfm.vertices_at([4000])


def test_model_validation():
    with pytest.raises(InputError, match="triangles"):
        MorphableModel.from_arrays(mean=np.zeros((3, 3)), triangles=[[0, 1, 5]])
    with pytest.raises(InputError, match=r"\(V, 3\)"):
        MorphableModel.from_arrays(mean=np.zeros((0, 3)), triangles=np.zeros((0, 3)))
    with pytest.raises(InputError, match="NaN"):
        MorphableModel.from_arrays(mean=np.full((3, 3), np.nan), triangles=[[0, 1, 2]])


def test_expression_index(sfm):
    assert sfm.expression_index("happiness") == 3
    with pytest.raises(InputError, match="choose from anger"):
        sfm.expression_index("joy")


def test_import_is_light():
    code = ("import sys, morphable; morphable.load_model('sfm'); "
            "heavy = [m for m in ('torch', 'open3d', 'pyvista', 'trimesh', 'igl', 'scipy', 'mediapipe', 'cv2', 'dlib', 'av') "
            "if m in sys.modules]; print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
