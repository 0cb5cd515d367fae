"""Reading triangle meshes (OBJ, PLY, STL, OFF, GLB) into plain arrays, through trimesh.

Only the geometry is kept: vertex positions in the file's units and triangle indices in the
file's order (``process=False``: no merging, no reordering, so indices match the file).
Polygons with more than three corners are triangulated by trimesh; files holding several
meshes (a scene) are concatenated.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from asteroid.errors import InvalidShapeError
from terrain.core import memory
from terrain.core.errors import MissingInputError

__all__ = ["READ_FORMATS", "read_mesh"]

log = logging.getLogger(__name__)

#: File suffixes read_mesh accepts.
READ_FORMATS = (".obj", ".ply", ".stl", ".off", ".glb", ".gltf", ".icq")


def read_mesh(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a mesh file.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    vertices : (n, 3) float64, the file's units
    faces : (m, 3) int64
    """
    import trimesh  # local: heavy, and only needed when a mesh file is read

    path = Path(path)
    if not path.exists():
        raise MissingInputError(f"shape model '{path}' does not exist")
    if path.is_dir():
        raise InvalidShapeError(f"shape model '{path}' is a folder, not a file")
    if path.suffix.lower() not in READ_FORMATS:
        raise InvalidShapeError(
            f"shape model '{path}' has suffix '{path.suffix}'; expected one of "
            f"{', '.join(READ_FORMATS)}")
    memory.require(path.stat().st_size * 12.0, f"reading shape model '{path}'")
    if path.suffix.lower() == ".icq":
        from asteroid.meshio.icq import read_icq

        return read_icq(path)
    try:
        loaded = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many types for malformed files
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InvalidShapeError(f"cannot read shape model '{path}': {first}") from exc
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=np.float64)
    faces = np.asarray(getattr(loaded, "faces", np.zeros((0, 3))), dtype=np.int64)
    if len(faces) == 0 or vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InvalidShapeError(f"shape model '{path}' holds no triangles")
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InvalidShapeError(
            f"shape model '{path}' faces must be (m, 3) int; got {faces.shape}")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise InvalidShapeError(f"shape model '{path}' has face indices outside its vertices")
    if not np.all(np.isfinite(vertices)):
        raise InvalidShapeError(f"shape model '{path}' has non-finite vertex coordinates")
    log.info("read %s: %d vertices, %d triangles", path, len(vertices), len(faces))
    return vertices, faces
