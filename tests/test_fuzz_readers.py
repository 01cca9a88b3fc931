"""Readers of untrusted files either return well-formed data or raise InputError naming the
file — never another exception (hypothesis fuzzing)."""
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from morphable import InputError
from morphable.io import read_ljson, read_pts
from morphable.io.eos import read_eos_blendshapes, read_eos_model

FUZZ = settings(max_examples=150, deadline=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture])


def _check(reader, path):
    try:
        return reader(path)
    except InputError as e:
        assert str(path) in str(e) and "\n" not in str(e)
        return None


@FUZZ
@given(st.binary(max_size=400))
def test_pts_random_bytes(tmp_path, blob):
    p = tmp_path / "f.pts"
    p.write_bytes(blob)
    pts = _check(read_pts, p)
    if pts is not None:
        assert pts.ndim == 2 and pts.shape[1] == 2 and np.isfinite(pts).all()


@FUZZ
@given(st.lists(st.tuples(st.floats(allow_nan=True, allow_infinity=True), st.floats()), max_size=70),
       st.integers(-2, 80), st.booleans())
def test_pts_structured(tmp_path, rows, n, header):
    body = "\n".join(f"{x} {y}" for x, y in rows)
    text = (f"version: 1\nn_points: {n}\n" if header else "") + "{\n" + body + "\n}\n"
    p = tmp_path / "g.pts"
    p.write_text(text)
    pts = _check(read_pts, p)
    if pts is not None:
        assert len(pts) == len(rows) and np.isfinite(pts).all()


json_values = st.recursive(
    st.none() | st.booleans() | st.floats() | st.integers() | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=20)


@FUZZ
@given(st.dictionaries(st.sampled_from(["version", "landmarks", "labels", "groups", "points"]),
                       json_values, max_size=4))
def test_ljson_random_documents(tmp_path, doc):
    import json

    p = tmp_path / "f.ljson"
    p.write_text(json.dumps(doc))
    out = _check(read_ljson, p)
    if out is not None:
        pts, labels = out
        assert pts.ndim == 2 and pts.shape[1] in (2, 3)


@pytest.fixture(scope="module")
def sfm_bytes(data_dir):
    return ((data_dir / "models/sfm/sfm_shape_3448.bin").read_bytes(),
            (data_dir / "models/sfm/expression_blendshapes_3448.bin").read_bytes())


@FUZZ
@given(data=st.data())
def test_eos_mutations(tmp_path, sfm_bytes, data):
    model, shapes = sfm_bytes
    which = data.draw(st.sampled_from(["model", "shapes"]))
    blob = bytearray(model if which == "model" else shapes)
    # flip bytes in the headers (where sizes live) or cut the file anywhere
    for _ in range(data.draw(st.integers(0, 4))):
        i = data.draw(st.integers(0, min(len(blob) - 1, 64)))
        blob[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.integers(0, len(blob)))
    p = tmp_path / "m.bin"
    p.write_bytes(bytes(blob[:cut]))
    reader = read_eos_model if which == "model" else read_eos_blendshapes
    out = _check(reader, p)
    if out is not None and which == "model":
        V = out["mean"].shape[0]
        assert out["mean"].shape == (V, 3) and out["identity_basis"].shape[1:] == (V, 3)
