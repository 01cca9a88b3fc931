"""morphable.io.gltf: an animated mesh as a glTF 2.0 binary, read back byte by byte."""
import numpy as np
import pytest

from glb_reader import animated_vertices, quaternion_matrix, read_glb
from morphable.camera import euler_to_matrix
from morphable.errors import InputError
from morphable.io.gltf import matrix_to_quaternion, write_animated_glb

VERTS = np.array([[0.0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10], [10, 10, 5]])   # mm
TRIS = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 4]])


def animation(n=6, e=2, seed=0):
    rng = np.random.default_rng(seed)
    euler = np.c_[np.linspace(-170, 170, n), rng.uniform(-40, 40, n), rng.uniform(-30, 30, n)]
    return dict(times_s=np.arange(n) / 25.0 + 0.04, rotations=euler_to_matrix(*euler.T),
                translations_mm=rng.normal(0, 50, (n, 3)), scales=rng.uniform(0.8, 1.2, n),
                targets=rng.normal(0, 3, (e, len(VERTS), 3)), weights=rng.normal(0, 1, (n, e)),
                target_names=[f"t{i}" for i in range(e)])


def test_quaternions_reproduce_the_rotations_in_every_branch():
    rng = np.random.default_rng(1)
    R = euler_to_matrix(*rng.uniform(-180, 180, (3, 500)))
    # the four branches of Shepperd's method: near the identity and half-turns about x, y, z
    R = np.concatenate([R, np.eye(3)[None], np.diag([1.0, -1, -1])[None], np.diag([-1.0, 1, -1])[None],
                        np.diag([-1.0, -1, 1])[None]])
    q = matrix_to_quaternion(R)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(quaternion_matrix(q), R, atol=1e-12)


def test_glb_round_trip(tmp_path):
    a = animation()
    path = write_animated_glb(tmp_path / "a.glb", VERTS, TRIS, orthographic_mm=(320, 240),
                              extras={"fps": 25.0}, **a)
    doc, acc = read_glb(path)
    prim = doc["meshes"][0]["primitives"][0]
    assert acc(prim["attributes"]["POSITION"]).shape == (5, 3)
    np.testing.assert_allclose(acc(prim["attributes"]["POSITION"]), VERTS / 1000, rtol=1e-6)  # metres
    np.testing.assert_allclose(np.linalg.norm(acc(prim["attributes"]["NORMAL"]), axis=1), 1, atol=1e-6)
    np.testing.assert_array_equal(acc(prim["indices"]).reshape(-1, 3), TRIS)
    assert len(prim["targets"]) == 2 and doc["meshes"][0]["extras"]["targetNames"] == ["t0", "t1"]
    anim = doc["animations"][0]
    assert {c["target"]["path"] for c in anim["channels"]} == {"rotation", "translation", "scale", "weights"}
    assert anim["extras"] == {"fps": 25.0}
    for s in anim["samplers"]:
        times = acc(s["input"])[:, 0]
        np.testing.assert_allclose(times, a["times_s"], rtol=1e-6)
        assert doc["accessors"][s["input"]]["min"] == [pytest.approx(0.04)] and s["interpolation"] == "LINEAR"
    # every keyframe: the scene's vertices are t + R (s (base + w . targets)), in metres
    for f in range(6):
        want = (a["translations_mm"][f] + a["scales"][f] * (VERTS + np.tensordot(a["weights"][f], a["targets"], 1))
                @ a["rotations"][f].T) / 1000
        np.testing.assert_allclose(animated_vertices(doc, acc, f), want, atol=2e-6)
    # the yaw sweeps through +-180: neighbouring quaternions are kept on one side (no long way round)
    rot = acc(anim["samplers"][[c["target"]["path"] for c in anim["channels"]].index("rotation")]["output"])
    assert (np.einsum("fi,fi->f", rot[1:], rot[:-1]) > 0).all()
    cam = doc["cameras"][0]["orthographic"]
    assert (cam["xmag"], cam["ymag"]) == (pytest.approx(0.32), pytest.approx(0.24))
    trimesh = pytest.importorskip("trimesh")
    scene = trimesh.load(path, process=False)
    mesh = next(iter(scene.geometry.values())) if hasattr(scene, "geometry") else scene
    assert mesh.vertices.shape == (5, 3) and mesh.faces.shape == (4, 3)


def test_static_mesh_without_targets(tmp_path):
    a = animation(n=1)
    path = write_animated_glb(tmp_path / "s.glb", VERTS, TRIS, a["times_s"], a["rotations"],
                              a["translations_mm"])
    doc, acc = read_glb(path)
    assert "targets" not in doc["meshes"][0]["primitives"][0] and "cameras" not in doc
    np.testing.assert_allclose(animated_vertices(doc, acc, 0),
                               (a["translations_mm"][0] + VERTS @ a["rotations"][0].T) / 1000, atol=2e-6)


@pytest.mark.parametrize("change, message", [
    (dict(times_s=np.r_[0.0, 0.04, 0.04, 0.1, 0.2, 0.3]), "keyframe times must increase strictly"),
    (dict(times_s=np.arange(6) / 25.0 - 0.1), "from 0 s or later"),
    (dict(weights=np.full((6, 2), np.nan)), "non-finite values"),
    (dict(rotations=np.eye(3)[None]), "need F >= 1 keyframes"),
    (dict(targets=np.zeros((2, 4, 3))), "targets must be (E, 5, 3)"),
    (dict(triangles=TRIS + 5), "triangles must be (T, 3) indices below 5"),
])
def test_bad_input_one_line_and_no_file(tmp_path, change, message):
    a = {**animation(), "vertices": VERTS, "triangles": TRIS, **change}
    with pytest.raises(InputError, match=r"^\S*a\.glb: ") as e:
        write_animated_glb(tmp_path / "a.glb", **a)
    assert message in str(e.value) and "\n" not in str(e.value)
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(InputError, match="does not exist"):
        write_animated_glb(tmp_path / "nosuch" / "a.glb", VERTS, TRIS, **animation())
