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
    """(V, 3) mm: the mesh a fit report's mesh file holds, rebuilt from the report's numbers
    alone: one frame, its identity and expression; several, the identity without expression
    (:meth:`morphable.pipeline.ImageFit.mesh_vertices`)."""
    identity = np.asarray(report["identity"], dtype=np.float64)
    if report["n_frames"] > 1:
        return model.vertices(identity)
    expression = report["frames"][0]["expression"]
    return model.vertices(identity, np.array([expression[n] for n in model.expression_names]))
