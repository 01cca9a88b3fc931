"""A written mesh read back and compared with the vertices it should hold (tests import it as
``mesh_check``, as ``glb_reader``)."""
import numpy as np


def assert_mesh_holds(path, vertices, triangles, atol: float = 1e-4) -> None:
    """The mesh file ``path`` holds ``vertices`` (V, 3) mm on ``triangles`` (F, 3): each
    triangle's three corners, in order, within ``atol`` mm. Corners rather than vertex rows: an
    OBJ with UVs (and an STL) repeats vertices along seams, so its vertex order is not the
    model's; its triangle order is."""
    from morphable.io import read_mesh

    mesh = read_mesh(path)
    triangles = np.asarray(triangles)
    assert mesh.faces.shape == triangles.shape, (path, mesh.faces.shape, triangles.shape)
    got = np.asarray(mesh.vertices)[mesh.faces]
    want = np.asarray(vertices, dtype=np.float64)[triangles]
    err = np.abs(got - want).max()
    assert err <= atol, f"{path}: a corner lies {err:.3g} mm from the fitted face's"


def report_vertices(report: dict, model) -> np.ndarray:
    """(V, 3) mm: the mesh a fit report's mesh file holds by default, rebuilt from the report's
    numbers alone: the identity without expression, for one frame and for several
    (:meth:`morphable.pipeline.ImageFit.mesh_vertices`)."""
    return model.vertices(np.asarray(report["identity"], dtype=np.float64))


def report_expressive_vertices(report: dict, model, frame: int = 0) -> np.ndarray:
    """(V, 3) mm: frame ``frame``'s face with its expression (``--mesh expressive``), rebuilt
    from the report's numbers alone."""
    f = report["frames"][frame]
    identity = f.get("identity", report["identity"])
    expression = f["expression"]
    return model.vertices(np.asarray(identity, dtype=np.float64),
                          np.array([expression[n] for n in model.expression_names]))
