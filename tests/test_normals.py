import numpy as np
import pytest

from morphable import InputError, vertex_normals
from morphable.io import read_mesh
from morphable.normals import face_normals


def _angle(a, b):
    return np.arccos(np.clip((a * b).sum(-1), -1, 1))


@pytest.fixture(scope="module")
def meshes(sfm, ict, data_dir):
    james = read_mesh(data_dir / "scans/james/james.obj")
    return {"sfm": (sfm.mean.astype(np.float64), sfm.triangles),
            "ict": (ict.mean.astype(np.float64), ict.triangles),
            "james": (np.asarray(james.vertices, dtype=np.float64), np.asarray(james.faces))}


@pytest.mark.parametrize("name", ["sfm", "ict", "james"])
@pytest.mark.parametrize("weighting", ["area", "angle"])
def test_matches_libigl(meshes, name, weighting):
    igl = pytest.importorskip("igl")
    v, f = meshes[name]
    kind = {"area": igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA,
            "angle": igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_ANGLE}[weighting]
    ref = igl.per_vertex_normals(v, f, kind)
    ours = vertex_normals(v, f, weighting)
    used = np.zeros(len(v), bool)
    used[f.ravel()] = True
    ok = used & np.isfinite(ref).all(1) & (np.linalg.norm(ref, axis=1) > 0.5)
    assert _angle(ours[ok], ref[ok]).max() < 1e-4
    assert np.isfinite(ours).all()
    np.testing.assert_allclose(np.linalg.norm(ours, axis=1), 1, atol=1e-12)


@pytest.mark.parametrize("name", ["sfm", "james"])
def test_angle_weighting_matches_trimesh(meshes, name):
    trimesh = pytest.importorskip("trimesh")
    v, f = meshes[name]
    ref = trimesh.Trimesh(v, f, process=False).vertex_normals
    ours = vertex_normals(v, f, "angle")
    used = np.zeros(len(v), bool)
    used[f.ravel()] = True
    assert _angle(ours[used], ref[used]).max() < 1e-4


@pytest.mark.parametrize("weighting", ["area", "angle"])
def test_torch_matches_numpy_and_is_differentiable(sfm, weighting):
    torch = pytest.importorskip("torch")
    rng = np.random.default_rng(0)
    v = sfm.vertices(rng.standard_normal((2, 63)))
    ours = vertex_normals(v, sfm.triangles, weighting)
    tv = torch.tensor(v, requires_grad=True)
    tn = vertex_normals(tv, sfm.triangles, weighting)
    np.testing.assert_allclose(tn.detach().numpy(), ours, atol=1e-10)
    tn[..., 2].sum().backward()
    assert torch.isfinite(tv.grad).all() and tv.grad.abs().sum() > 0


def test_gradcheck_on_small_mesh():
    torch = pytest.importorskip("torch")
    v = torch.tensor([[0, 0, 0], [1, 0, 0.2], [0, 1, 0.1], [1, 1, 0.5]], dtype=torch.float64,
                     requires_grad=True)
    f = np.array([[0, 1, 2], [1, 3, 2]])
    for w in ("area", "angle"):
        assert torch.autograd.gradcheck(lambda x: vertex_normals(x, f, w), (v,))


def test_degenerate_input_stays_finite():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],      # a good triangle
                  [2, 2, 2], [2, 2, 2], [2, 2, 2],       # collapsed to a point
                  [5, 0, 0], [6, 0, 0], [7, 0, 0],       # collinear
                  [9, 9, 9],                             # isolated
                  [0, 0, 0]], dtype=np.float64)          # duplicate of vertex 0
    f = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8], [10, 1, 2], [0, 0, 1]])
    for w in ("area", "angle"):
        n = vertex_normals(v, f, w)
        assert np.isfinite(n).all()
        np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1, atol=1e-12)
        np.testing.assert_allclose(n[[0, 1, 2, 10]], [[0, 0, 1]] * 4, atol=1e-12)
    fn = face_normals(v, f)
    assert np.isfinite(fn).all() and np.allclose(fn[1:3], 0) and np.allclose(fn[4], 0)


def test_float32_and_tiny_triangles():
    v = np.array([[0, 0, 0], [1e-20, 0, 0], [0, 1e-20, 0]], dtype=np.float32)
    n = vertex_normals(v, [[0, 1, 2]])
    assert n.dtype == np.float32 and np.isfinite(n).all()
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1, atol=1e-6)


def test_bad_arguments():
    with pytest.raises(InputError, match="weighting"):
        vertex_normals(np.eye(3), [[0, 1, 2]], "uniform")
    with pytest.raises(InputError, match="out of range"):
        vertex_normals(np.eye(3), [[0, 1, 3]])
    with pytest.raises(InputError, match=r"\(\.\.\., V, 3\)"):
        vertex_normals(np.zeros((3, 2)), [[0, 1, 2]])
