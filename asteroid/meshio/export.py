"""Writing asteroid meshes as PLY, OBJ, STL or glTF binary (GLB), through trimesh.

A model is written as named parts (the body, then optionally the boulders at their finest
level of detail). PLY, OBJ and STL hold one mesh, so the parts are concatenated in order (the
body's vertices and triangles come first, with the canonical indices of
:mod:`asteroid.sphere`); GLB keeps each part as its own node and carries the provenance in the
scene's ``extras``. Coordinates are metres in the body frame (z is the mesh's polar axis).
PLY, STL and GLB store float32 coordinates (glTF allows nothing else), OBJ eight decimals; the
native ``.npz`` keeps the float64 radii. Files are written atomically and never over an input.

Example
-------
>>> import tempfile, pathlib
>>> from asteroid.sphere import SphereMesh
>>> mesh = SphereMesh(2)
>>> path = pathlib.Path(tempfile.mkdtemp()) / "ball.ply"
>>> _ = write_mesh(path, [("body", mesh.directions() * 10.0, mesh.faces())])
>>> path.read_bytes()[:3]
b'ply'
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from terrain.core import memory
from terrain.core.errors import InvalidParameterError, OutputPathError
from terrain.core.outputs import atomic_path

__all__ = ["MESH_FORMATS", "mesh_format", "write_mesh"]

log = logging.getLogger(__name__)

#: Mesh file suffixes and the trimesh exporter each selects.
MESH_FORMATS = {".ply": "ply", ".obj": "obj", ".stl": "stl", ".glb": "glb"}
#: Bytes of scratch per vertex while exporting (OBJ formats text, the worst case).
_EXPORT_BYTES_PER_VERTEX = {"ply": 120, "obj": 400, "stl": 250, "glb": 120}


def mesh_format(path) -> str:
    """Return the trimesh file type for an output path, from its suffix.

    >>> mesh_format("eros.glb")
    'glb'
    """
    suffix = Path(path).suffix.lower()
    if suffix not in MESH_FORMATS:
        raise InvalidParameterError(
            f"mesh output '{path}' must end in one of {', '.join(MESH_FORMATS)} (or .npz for "
            f"the native model only); got '{suffix}'")
    return MESH_FORMATS[suffix]


def _check_part(name, vertices, faces):
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    if v.ndim != 2 or v.shape[1] != 3:
        raise InvalidParameterError(f"{name} vertices must be (n, 3) float; got {v.shape}")
    if f.ndim != 2 or f.shape[1] != 3:
        raise InvalidParameterError(f"{name} faces must be (m, 3) int; got {f.shape}")
    if f.size and (f.min() < 0 or f.max() >= len(v)):
        raise InvalidParameterError(f"{name} faces index outside its {len(v)} vertices")
    return v, f


def write_mesh(path, parts: Sequence[tuple[str, np.ndarray, np.ndarray]], *,
               metadata: dict | None = None, inputs: Iterable = ()) -> Path:
    """Write named mesh parts to ``path`` in the format its suffix names, atomically.

    Parameters
    ----------
    path : str or Path
        ``.ply``, ``.obj``, ``.stl`` or ``.glb``.
    parts : sequence of (name, vertices (n, 3) float64 metres, faces (m, 3) int64)
    metadata : dict, optional
        Provenance: GLB scene extras, and the OBJ header line.
    inputs : iterable of paths
        Files the output must not replace.
    """
    import trimesh  # local: heavy, and only needed when a mesh file is written

    file_type = mesh_format(path)
    checked = [(name, *_check_part(name, v, f)) for name, v, f in parts if len(f)]
    if not checked:
        raise InvalidParameterError("nothing to write: every mesh part is empty")
    n_vertices = sum(len(v) for _, v, _ in checked)
    memory.require(n_vertices * _EXPORT_BYTES_PER_VERTEX[file_type],
                   f"exporting {n_vertices:,} vertices as {file_type.upper()}")
    meta = dict(metadata or {})
    if file_type == "glb":
        scene = trimesh.Scene()
        for name, v, f in checked:
            scene.add_geometry(trimesh.Trimesh(v, f, process=False), geom_name=name,
                               node_name=name)
        scene.metadata["craterscape"] = json.loads(json.dumps(meta))
        data = scene.export(file_type="glb")
    else:
        offsets = np.cumsum([0] + [len(v) for _, v, _ in checked])
        vertices = np.concatenate([v for _, v, _ in checked])
        faces = np.concatenate([f + o for (_, _, f), o in zip(checked, offsets, strict=False)])
        mesh = trimesh.Trimesh(vertices, faces, process=False)
        if file_type == "obj":
            header = "craterscape asteroid " + json.dumps(meta, sort_keys=True,
                                                          separators=(",", ":"))
            data = trimesh.exchange.obj.export_obj(mesh, include_normals=False,
                                                   include_color=False, include_texture=False,
                                                   header=header)
        else:
            data = mesh.export(file_type=file_type)
    if isinstance(data, str):
        data = data.encode("utf-8")
    with atomic_path(path, inputs) as tmp:
        try:
            Path(tmp).write_bytes(data)
        except OSError as exc:  # pragma: no cover - disk full and the like
            raise OutputPathError(f"cannot write '{path}': {exc}") from exc
    log.info("wrote %s (%s, %d vertices)", path, file_type, n_vertices)
    return Path(path)
