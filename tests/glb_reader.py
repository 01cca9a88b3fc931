"""A glTF 2.0 binary read back by hand (struct and json), so that the tests check the bytes
against the specification rather than against the writer's own reading of them."""
import json
import struct

import numpy as np

COMPONENTS = {5126: np.float32, 5125: np.uint32}
WIDTH = {"SCALAR": 1, "VEC3": 3, "VEC4": 4}


def read_glb(path):
    """-> (document, accessor reader): the header, the JSON chunk and the BIN chunk checked for
    the layout the specification requires (magic, version, total length, 4-byte alignment,
    chunk types and order)."""
    data = open(path, "rb").read()
    magic, version, length = struct.unpack_from("<III", data, 0)
    assert (magic, version, length) == (0x46546C67, 2, len(data))
    n_json, kind = struct.unpack_from("<II", data, 12)
    assert kind == 0x4E4F534A and n_json % 4 == 0
    doc = json.loads(data[20:20 + n_json])
    n_bin, kind = struct.unpack_from("<II", data, 20 + n_json)
    assert kind == 0x004E4942 and n_bin % 4 == 0 and 28 + n_json + n_bin == len(data)
    blob = data[28 + n_json:]
    assert doc["asset"]["version"] == "2.0" and doc["buffers"] == [{"byteLength": n_bin}]

    def accessor(i):
        acc = doc["accessors"][i]
        view = doc["bufferViews"][acc["bufferView"]]
        assert view["byteOffset"] % 4 == 0 and view["byteOffset"] + view["byteLength"] <= n_bin
        dtype, width = COMPONENTS[acc["componentType"]], WIDTH[acc["type"]]
        assert view["byteLength"] == acc["count"] * width * np.dtype(dtype).itemsize
        a = np.frombuffer(blob, dtype, acc["count"] * width, view["byteOffset"]).reshape(acc["count"], width)
        if "min" in acc:    # the bounds must be those of the data
            np.testing.assert_array_equal(acc["min"], a.min(0))
            np.testing.assert_array_equal(acc["max"], a.max(0))
        return a

    return doc, accessor


def quaternion_matrix(q):
    """(..., 4) x, y, z, w -> (..., 3, 3)."""
    x, y, z, w = np.moveaxis(np.asarray(q, dtype=np.float64), -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
                     np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
                     np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def animated_vertices(doc, accessor, frame):
    """The scene's vertices (V, 3) m at keyframe ``frame``: base + weights . targets, then the
    node's translation, rotation and scale, as a viewer computes them."""
    prim = doc["meshes"][0]["primitives"][0]
    base = accessor(prim["attributes"]["POSITION"]).astype(np.float64)
    paths = {c["target"]["path"]: doc["animations"][0]["samplers"][c["sampler"]]
             for c in doc["animations"][0]["channels"]}
    out = {p: accessor(s["output"]) for p, s in paths.items()}
    v = base
    if "weights" in out:
        targets = [accessor(t["POSITION"]) for t in prim["targets"]]
        w = out["weights"].reshape(-1, len(targets))[frame]
        v = base + np.tensordot(w, np.stack(targets), 1)
    R = quaternion_matrix(out["rotation"][frame])
    return out["translation"][frame] + (out["scale"][frame] * v) @ R.T
