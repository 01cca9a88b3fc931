import json
import pickle
import struct

import numpy as np
import pytest

from morphable import InputError, load_model
from morphable.io import read_ljson, read_mesh, read_pts, write_ljson, write_mesh, write_pts
from morphable.io.eos import read_eos_blendshapes, read_eos_model
from morphable.io.ict import load_ict_folder
from morphable.io.native import load_model_npz, save_model_npz
from morphable.io.registry import download, find_model, search_path
from morphable.ibug68 import from_menpo_labels


# --- eos ------------------------------------------------------------------------------
def test_eos_reader_matches_eos_py(data_dir, sfm):
    eos = pytest.importorskip("eos")
    m = eos.morphablemodel.load_model(str(data_dir / "models/sfm/sfm_shape_3448.bin"))
    shape = m.get_shape_model()
    np.testing.assert_allclose(sfm.mean.ravel(), shape.get_mean(), atol=1e-5)
    ours = sfm.identity_basis.reshape(63, -1).T
    np.testing.assert_allclose(ours, shape.get_rescaled_pca_basis(), rtol=1e-5, atol=1e-4)
    np.testing.assert_array_equal(sfm.triangles, np.array(shape.get_triangle_list()))
    eos_uv = np.array(m.get_texture_coordinates())  # v down in eos, v up here
    np.testing.assert_allclose(sfm.uv, np.column_stack([eos_uv[:, 0], 1 - eos_uv[:, 1]]), atol=1e-12)
    top, chin = np.argmax(sfm.mean[:, 1]), np.argmin(sfm.mean[:, 1])
    assert sfm.uv[top, 1] > 0.9 and sfm.uv[chin, 1] < 0.1
    coeffs = np.linspace(-1, 1, 63)
    sample = np.array(shape.draw_sample(coeffs.astype(np.float32).tolist()))
    np.testing.assert_allclose(sfm.vertices(coeffs).ravel(), sample, atol=1e-3)
    bs = eos.morphablemodel.load_blendshapes(str(data_dir / "models/sfm/expression_blendshapes_3448.bin"))
    assert [b.name for b in bs] == sfm.expression_names
    np.testing.assert_allclose(sfm.expression_basis[3].ravel(), bs[3].deformation, atol=1e-6)


@pytest.mark.parametrize("expression", ["blendshapes", "pca"])
def test_eos_v4_written_by_eos_py(tmp_path, data_dir, expression):
    eos = pytest.importorskip("eos")
    mm = eos.morphablemodel
    m = mm.load_model(str(data_dir / "models/sfm/sfm_shape_3448.bin"))
    shape = m.get_shape_model()
    expr = (mm.load_blendshapes(str(data_dir / "models/sfm/expression_blendshapes_3448.bin"))
            if expression == "blendshapes" else shape)
    model = mm.MorphableModel(shape, expr, color_model=mm.PcaModel(),
                              vertex_definitions={"30": 114, "nose": 114},
                              texture_coordinates=m.get_texture_coordinates(),
                              texture_triangle_indices=shape.get_triangle_list())
    path = tmp_path / "v4.bin"
    mm.save_model(model, str(path))
    d = read_eos_model(path)
    assert d["expression_kind"] == expression
    assert d["expression_basis"].shape == ((6 if expression == "blendshapes" else 63), 3448, 3)
    assert d["landmarks"] == {"30": 114, "nose": 114}
    np.testing.assert_array_equal(d["triangle_uv"], d["triangles"])
    # a folder with only this file: landmark "30" (iBUG 30) comes from the model itself
    loaded = load_model(path)
    assert loaded.landmark_ids[29] == 114


def test_eos_corrupt_files(tmp_path, data_dir):
    raw = (data_dir / "models/sfm/sfm_shape_3448.bin").read_bytes()
    for name, blob in [("truncated.bin", raw[:5000]), ("empty.bin", b""),
                       ("version.bin", struct.pack("<I", 9) + raw[4:]),
                       ("trailing.bin", raw + b"\0\0"), ("garbage.bin", b"\xff" * 64)]:
        p = tmp_path / name
        p.write_bytes(blob)
        with pytest.raises(InputError) as e:
            read_eos_model(p)
        assert name in str(e.value) and "\n" not in str(e.value)
    p = tmp_path / "bs.bin"
    p.write_bytes((data_dir / "models/sfm/expression_blendshapes_3448.bin").read_bytes()[:300])
    with pytest.raises(InputError, match="bs.bin"):
        read_eos_blendshapes(p)


# --- ICT ------------------------------------------------------------------------------
def test_ict_obj_folder_matches_npz(data_dir, ict):
    folder = load_ict_folder(data_dir / "models/ict-facekit/obj_sample")
    np.testing.assert_allclose(folder.mean, ict.mean, atol=1e-3)
    np.testing.assert_array_equal(folder.triangles, ict.triangles)
    np.testing.assert_array_equal(folder.triangle_uv, ict.triangle_uv)
    np.testing.assert_array_equal(folder.landmark_ids, ict.landmark_ids)
    assert folder.expression_names == ["jawOpen", "mouthSmile_L"]
    j = ict.expression_index("jawOpen")
    np.testing.assert_allclose(folder.expression_basis[0], ict.expression_basis[j], atol=1e-3)
    np.testing.assert_allclose(folder.identity_basis[:2], ict.identity_basis[:2], atol=1e-3)


def test_ict_folder_vertex_mismatch(tmp_path, data_dir):
    src = data_dir / "models/ict-facekit/obj_sample/generic_neutral_mesh.obj"
    (tmp_path / "generic_neutral_mesh.obj").write_bytes(src.read_bytes())
    (tmp_path / "identity000.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    with pytest.raises(InputError, match="identity000.obj: 3 vertices"):
        load_ict_folder(tmp_path)


# --- native, BFM, FLAME ---------------------------------------------------------------
def test_native_round_trip(tmp_path, sfm):
    path = save_model_npz(sfm, tmp_path / "sfm.npz")
    back = load_model(path)
    for key in ("mean", "triangles", "identity_basis", "expression_basis", "landmark_ids",
                "contour_right", "contour_left", "uv", "symmetry"):
        np.testing.assert_array_equal(getattr(back, key), getattr(sfm, key))
    assert back.expression_names == sfm.expression_names
    assert not list(tmp_path.glob(".*"))  # no temporary left behind


def test_native_rejects_other_npz(tmp_path):
    p = tmp_path / "x.npz"
    np.savez(p, format=np.array("something-else"), mean=np.zeros((3, 3)))
    with pytest.raises(InputError, match="x.npz: not a morphable model npz"):
        load_model_npz(p)
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 not really")
    with pytest.raises(InputError, match="bad.npz"):
        load_model(tmp_path / "bad.npz")


def _tiny_mesh():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
    f = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    return v, f


def test_bfm_h5(tmp_path):
    h5py = pytest.importorskip("h5py")
    v, f = _tiny_mesh()
    rng = np.random.default_rng(1)
    U, _ = np.linalg.qr(rng.standard_normal((12, 2)))
    p = tmp_path / "bfm.h5"
    with h5py.File(p, "w") as h:
        h["shape/representer/points"] = v.T
        h["shape/representer/cells"] = f.T
        h["shape/model/mean"] = v.ravel()
        h["shape/model/pcaBasis"] = U
        h["shape/model/pcaVariance"] = np.array([4.0, 1.0])
        h["expression/model/mean"] = np.zeros(12)
        h["expression/model/pcaBasis"] = U[:, :1]
        h["expression/model/pcaVariance"] = np.array([9.0])
    m = load_model(p)
    assert (m.n_identity, m.n_expression, m.expression_kind) == (2, 1, "pca")
    np.testing.assert_allclose(m.identity_std, [2.0, 1.0], rtol=1e-6)
    np.testing.assert_allclose(m.vertices([1.0]).ravel(), v.ravel() + 2 * U[:, 0], atol=1e-6)
    with h5py.File(tmp_path / "other.h5", "w") as h:
        h["x"] = 1
    with pytest.raises(InputError, match="other.h5: not a BFM 2017 file"):
        load_model(tmp_path / "other.h5")


def test_flame_pkl_with_and_without_chumpy(tmp_path):
    v, f = _tiny_mesh()
    dirs = np.random.default_rng(2).standard_normal((4, 3, 5)) * 1e-3
    p = tmp_path / "flame.pkl"
    with open(p, "wb") as fh:
        pickle.dump({"v_template": v * 1e-3, "shapedirs": dirs, "f": f}, fh)
    from morphable.io.flame import load_flame_pkl

    m = load_flame_pkl(p, n_shape=3)
    assert (m.n_identity, m.n_expression) == (3, 2)
    np.testing.assert_allclose(m.mean, v)  # metres -> mm
    np.testing.assert_allclose(m.identity_basis[1], dirs[:, :, 1] * 1000)
    # a pickle that names another module is refused, not executed
    (tmp_path / "evil.pkl").write_bytes(pickle.dumps({"v_template": print}))
    with pytest.raises(InputError, match="evil.pkl: cannot read FLAME pkl"):
        load_flame_pkl(tmp_path / "evil.pkl")


# --- landmarks --------------------------------------------------------------------------
def test_pts_one_based_round_trip(tmp_path, data_dir):
    pts = read_pts(data_dir / "images/image_0010.pts")
    assert pts.shape == (68, 2)
    first = (data_dir / "images/image_0010.pts").read_text().split("{")[1].split()[:2]
    np.testing.assert_allclose(pts[0], np.array(first, dtype=float) - 1)
    write_pts(tmp_path / "a.pts", pts)
    np.testing.assert_allclose(read_pts(tmp_path / "a.pts"), pts, atol=1e-6)


@pytest.mark.parametrize("text,problem", [
    ("version: 1\nn_points: 2\n{\n1 2\n}", "header says 2 points"),
    ("1 2\n3 4\n", "no { ... } block"),
    ("n_points: 1\n{\n1 x\n}", "non-numeric"),
    ("n_points: 1\n{\n1 2 3\n}", "expected 'x y'"),
    ("n_points: 1\n{\nnan 2\n}", "NaN"),
])
def test_pts_bad_files(tmp_path, text, problem):
    p = tmp_path / "bad.pts"
    p.write_text(text)
    with pytest.raises(InputError, match=problem) as e:
        read_pts(p)
    assert str(e.value).startswith(str(p))


def test_ljson_james_in_ibug_order(data_dir):
    pts, labels = read_ljson(data_dir / "scans/james/james.ljson")
    assert pts.shape == (68, 3) and set(labels) >= {"chin", "leye", "mouth"}
    ibug = from_menpo_labels(pts, labels)
    # subject's right (jaw start, right eye, right brow) is at negative x, as in the models
    assert ibug[0, 0] < 0 and ibug[36, 0] < 0 and ibug[17, 0] < 0
    assert ibug[16, 0] > 0 and ibug[45, 0] > 0 and ibug[26, 0] > 0
    assert ibug[30, 2] > ibug[36, 2]  # nose tip in front of the eyes


def test_ljson_round_trip_2d(tmp_path):
    pts = np.array([[10.5, 20.0], [np.nan, np.nan], [3, 4]])
    write_ljson(tmp_path / "a.ljson", pts, {"all": [0, 1, 2]})
    back, labels = read_ljson(tmp_path / "a.ljson")
    np.testing.assert_array_equal(back, pts)
    assert list(labels["all"]) == [0, 1, 2]
    (tmp_path / "b.ljson").write_text(json.dumps({"landmarks": {"points": [[1, 2]]},
                                                  "labels": [{"label": "x", "mask": [3]}]}))
    with pytest.raises(InputError, match="b.ljson: label 'x' refers to a missing point"):
        read_ljson(tmp_path / "b.ljson")


# --- meshes -----------------------------------------------------------------------------
def test_obj_export_with_uvs(tmp_path, sfm, ict):
    write_mesh(tmp_path / "sfm.obj", sfm.mean, sfm.triangles, sfm.uv)
    back = read_mesh(tmp_path / "sfm.obj")
    np.testing.assert_allclose(back.vertices, sfm.mean, atol=1e-5)
    np.testing.assert_allclose(back.visual.uv, sfm.uv, atol=1e-6)
    # per-triangle UVs: seam vertices are split, positions stay exact
    write_mesh(tmp_path / "ict.obj", ict.mean, ict.triangles, ict.uv, ict.triangle_uv)
    back = read_mesh(tmp_path / "ict.obj")
    assert len(back.vertices) == len(ict.uv)
    corners = back.vertices[back.faces]
    np.testing.assert_allclose(corners, ict.mean[ict.triangles], atol=1e-5)
    write_mesh(tmp_path / "ict.ply", ict.mean, ict.triangles)
    assert read_mesh(tmp_path / "ict.ply").vertices.shape == (26719, 3)


def test_mesh_bad_input(tmp_path):
    with pytest.raises(InputError, match="NaN"):
        write_mesh(tmp_path / "a.obj", np.full((3, 3), np.nan), [[0, 1, 2]])
    assert not list(tmp_path.iterdir())
    with pytest.raises(InputError, match="does not exist"):
        write_mesh(tmp_path / "no/such/dir/a.obj", np.eye(3), [[0, 1, 2]])
    (tmp_path / "empty.obj").write_text("# nothing\n")
    with pytest.raises(InputError, match="empty.obj"):
        read_mesh(tmp_path / "empty.obj")


# --- registry ---------------------------------------------------------------------------
def test_search_order(tmp_path, monkeypatch, data_dir):
    monkeypatch.setenv("MORPHABLE_DATA", str(tmp_path))
    assert search_path()[0] == tmp_path
    assert find_model("sfm") == data_dir / "models/sfm"  # falls through to ../shared
    (tmp_path / "sfm").mkdir()
    (tmp_path / "sfm/sfm_shape_3448.bin").write_bytes(b"")
    assert find_model("sfm") == tmp_path / "sfm"
    with pytest.raises(InputError, match="nope: unknown model"):
        find_model("nope")


def _serve_sfm(src, folder, corrupt=None):
    folder.mkdir()
    for p in src.iterdir():
        blob = p.read_bytes()
        if p.name == corrupt:
            blob = blob[:-1] + b"x"
        (folder / p.name).write_bytes(blob)
    return folder.as_uri() + "/"


def test_download_verifies_checksums(tmp_path, data_dir):
    url = _serve_sfm(data_dir / "models/sfm", tmp_path / "mirror")
    target = download("sfm", tmp_path / "cache", url=url)
    assert (target / "sfm_shape_3448.bin").is_file()
    assert load_model(target).n_vertices == 3448
    bad = _serve_sfm(data_dir / "models/sfm", tmp_path / "bad", corrupt="ibug_to_sfm.txt")
    with pytest.raises(InputError, match="ibug_to_sfm.txt has the wrong sha256"):
        download("sfm", tmp_path / "cache2", url=bad)
    assert not (tmp_path / "cache2").exists()  # a failed download leaves nothing, not even its folder


def test_download_ict_archive(tmp_path, data_dir):
    import zipfile

    zpath = tmp_path / "ict.zip"
    with zipfile.ZipFile(zpath, "w") as z:
        for p in (data_dir / "models/ict-facekit/obj_sample").iterdir():
            z.write(p, f"ICT-FaceKit-master/FaceXModel/{p.name}")
        z.write(data_dir / "models/ict-facekit/vertex_indices.json",
                "ICT-FaceKit-master/FaceXModel/vertex_indices.json")
    target = download("ict", tmp_path / "cache", url=zpath.as_uri())
    assert load_model(target).n_identity == 2
    (tmp_path / "junk.zip").write_bytes(b"junk")
    with pytest.raises(InputError, match="not a zip archive"):
        download("ict", tmp_path / "cache3", url=(tmp_path / "junk.zip").as_uri())


def test_atomic_outputs_get_the_usual_mode(tmp_path):
    import os

    from morphable.io import atomic_path

    with atomic_path(tmp_path / "a.txt") as tmp:
        tmp.write_text("x")
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "a.txt").stat().st_mode & 0o777 == 0o666 & ~umask


def test_obj_is_written_without_trimesh_as_trimesh_writes_it(tmp_path):
    """An OBJ (with and without UVs, with a texture's material) holds the v, vt and f lines that
    trimesh's export_obj writes for the same mesh, and reads back as the mesh written."""
    import trimesh

    from morphable.io.mesh import uv_unwelded

    m = load_model("sfm")
    v = m.mean.reshape(-1, 3)
    seams = (np.vstack([m.uv, m.uv]), m.triangles + len(v) * (np.arange(len(m.triangles)) % 2)[:, None])
    for uv, tuv in ((None, None), (m.uv, None), seams):
        mine = write_mesh(tmp_path / "m.obj", v, m.triangles, uv, tuv).read_text()
        vv, ff, uu = (v, m.triangles, uv) if tuv is None else uv_unwelded(v, m.triangles, uv, tuv)
        ref = trimesh.Trimesh(vv, ff, process=False, visual=None if uu is None else trimesh.visual.TextureVisuals(uv=uu))
        theirs = trimesh.exchange.obj.export_obj(ref, include_texture=True, include_normals=False)
        assert mine.splitlines() == [ln for ln in theirs.splitlines()
                                     if ln and not ln.startswith(("#", "mtllib", "usemtl"))]
        back = read_mesh(tmp_path / "m.obj")
        np.testing.assert_allclose(back.vertices, vv, atol=1e-8)
        np.testing.assert_array_equal(back.faces, ff)
    (tmp_path / "t.png").write_bytes(b"")
    text = write_mesh(tmp_path / "t.obj", v, m.triangles, m.uv, m.triangle_uv, texture=tmp_path / "t.png").read_text()
    assert text.startswith("mtllib t.mtl\nv ") and text.count("usemtl face\nf ") == 1
