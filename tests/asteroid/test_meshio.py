"""Mesh files out (PLY, OBJ, STL, GLB) and in, through trimesh."""

import numpy as np
import pytest
import trimesh

from asteroid.meshio import read_mesh, write_mesh
from asteroid.sphere import SphereMesh
from terrain.core.errors import InvalidParameterError, OutputPathError


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".stl", ".glb"])
def test_formats_round_trip_and_are_reproducible(tmp_path, suffix):
    mesh = SphereMesh(6)
    v = mesh.directions() * 1234.5
    f = mesh.faces()
    a, b = tmp_path / f"a{suffix}", tmp_path / f"b{suffix}"
    write_mesh(a, [("body", v, f)], metadata={"seed": 3})
    write_mesh(b, [("body", v, f)], metadata={"seed": 3})
    assert a.read_bytes() == b.read_bytes()
    loaded = trimesh.load(a, force="mesh", process=False)
    if suffix != ".stl":                          # STL stores triangle soup
        assert len(loaded.vertices) == len(v)
        assert np.allclose(loaded.vertices, v, rtol=1e-6)
    assert len(loaded.faces) == len(f)
    assert trimesh.Trimesh(loaded.vertices, loaded.faces).is_watertight
    vv, ff = read_mesh(a)
    assert len(ff) == len(f)


def test_parts_are_concatenated_or_kept_as_nodes(tmp_path):
    m1, m2 = SphereMesh(2), SphereMesh(1)
    parts = [("body", m1.directions() * 10, m1.faces()),
             ("boulders", m2.directions() + 20, m2.faces())]
    write_mesh(tmp_path / "x.ply", parts)
    loaded = trimesh.load(tmp_path / "x.ply", process=False)
    assert len(loaded.faces) == 48 + 12
    assert loaded.faces[48:].min() == 26                 # boulder indices follow the body
    write_mesh(tmp_path / "x.glb", parts, metadata={"seed": 1})
    scene = trimesh.load(tmp_path / "x.glb", force="scene")
    assert sorted(scene.geometry) == ["body", "boulders"]
    assert scene.metadata.get("craterscape", {}).get("seed") == 1 or b'"seed":1' in \
        (tmp_path / "x.glb").read_bytes()


def test_bad_outputs(tmp_path):
    mesh = SphereMesh(1)
    with pytest.raises(InvalidParameterError, match="must end in one of"):
        write_mesh(tmp_path / "x.vtk", [("body", mesh.directions(), mesh.faces())])
    with pytest.raises(InvalidParameterError, match="faces must be"):
        write_mesh(tmp_path / "x.ply", [("body", mesh.directions(), np.zeros((3, 4), int))])
    src = tmp_path / "in.ply"
    write_mesh(src, [("body", mesh.directions(), mesh.faces())])
    with pytest.raises(OutputPathError, match="same file as input"):
        write_mesh(src, [("body", mesh.directions(), mesh.faces())], inputs=[src])
    with pytest.raises(OutputPathError, match="does not exist"):
        write_mesh(tmp_path / "no" / "x.ply", [("body", mesh.directions(), mesh.faces())])
