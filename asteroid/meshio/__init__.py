"""Mesh files in and out: the only place craterscape imports trimesh."""

from asteroid.meshio.export import MESH_FORMATS, mesh_format, write_mesh
from asteroid.meshio.read import read_mesh

__all__ = ["MESH_FORMATS", "mesh_format", "read_mesh", "write_mesh"]
