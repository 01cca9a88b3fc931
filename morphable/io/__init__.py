"""Readers and writers: models (eos, ICT, BFM, FLAME, native npz), landmarks, meshes."""
from .atomic import atomic_path
from .landmark_files import read_ljson, read_pts, write_ljson, write_pts
from .mesh import read_mesh, write_mesh
from .native import load_model_npz, save_model_npz

__all__ = ["atomic_path", "read_pts", "write_pts", "read_ljson", "write_ljson", "read_mesh",
           "write_mesh", "save_model_npz", "load_model_npz"]
