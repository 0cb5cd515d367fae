"""Real shape models as bases: ray casting, closed-surface and centre checks, volumes."""

import logging

import numpy as np
import pytest

from asteroid.body import Body, Stretch
from asteroid.errors import InvalidShapeError
from asteroid.meshio import write_mesh
from asteroid.shape import ShapeModel, winding_number
from asteroid.sphere import SphereMesh
from terrain.core.errors import MissingInputError

# Figures stated in asteroid/shape.py: projected volume relative to the source mesh at M = 256.
SHAPES = [("eros_gaskell_q64.obj", 2506.39e9), ("itokawa_gaskell_q32.obj", 0.017702e9),
          ("bennu-osiris2019.ply", 0.061556e9)]


def _ball(radius=1.0, m=12, centre=(0.0, 0.0, 0.0)):
    mesh = SphereMesh(m)
    return mesh.directions() * radius + np.asarray(centre), mesh.faces()


@pytest.mark.parametrize("name,volume", SHAPES)
def test_real_shape_volume_within_two_percent_at_m256(shared_file, name, volume):
    shape = ShapeModel.read(shared_file("asteroids", name), units="km")
    assert shape.volume == pytest.approx(volume, rel=1e-4)
    mesh = SphereMesh(256)
    projection = shape.project(mesh)
    body = Body(mesh, shape.equivalent_radius, projection.radii)
    error = body.volume() / shape.volume - 1.0
    assert abs(error) < 0.02, f"{name}: projected volume off by {100 * error:.3f} %"
    assert abs(error) < 0.002                  # the figures the module docstring states
    assert projection.non_star_fraction < 0.01


def test_ellipsoid_radius_function(tmp_path):
    v, f = _ball(1.0, m=48)
    axes = np.array([3000.0, 2000.0, 1000.0])
    path = tmp_path / "ellipsoid.ply"
    write_mesh(path, [("body", v * axes, f)])
    shape = ShapeModel.read(path, units="m")
    mesh = SphereMesh(16)
    p = shape.project(mesh)
    u = mesh.directions()
    exact = 1.0 / np.sqrt(((u / axes) ** 2).sum(axis=1))
    assert np.allclose(p.radii, exact, rtol=2e-3)
    assert p.non_star_fraction == 0.0
    assert np.all(p.star_shaped) and np.allclose(p.radii, p.inner, rtol=1e-9)
    # stretching the shape model stretches the radius function
    p2 = shape.stretched(Stretch(1.0, 1.0, 2.0)).project(mesh)
    exact2 = 1.0 / np.sqrt(((u / (axes * [1, 1, 2])) ** 2).sum(axis=1))
    assert np.allclose(p2.radii, exact2, rtol=2e-3)


def test_not_star_shaped_directions_are_reported_and_the_outermost_hit_kept():
    big_v, big_f = _ball(1.0, m=16)
    small_v, small_f = _ball(0.2, m=8, centre=(2.0, 0.0, 0.0))
    v = np.concatenate([big_v, small_v])
    f = np.concatenate([big_f, small_f + len(big_v)])
    shape = ShapeModel.from_arrays(v, f, centre="origin")
    mesh = SphereMesh(40)
    p = shape.project(mesh)
    u = mesh.directions()
    shadowed = u[:, 0] > np.cos(np.arcsin(0.2 / 2.0)) + 1e-3
    assert not np.any(p.star_shaped[shadowed])
    assert np.all(p.radii[shadowed] > 2.0)              # the far side of the small ball
    assert np.allclose(p.inner[shadowed], 1.0, atol=0.01)   # the big ball
    expected = (1 - np.cos(np.arcsin(0.1))) / 2         # solid angle of the shadow cone
    assert p.non_star_fraction == pytest.approx(expected, rel=0.35)


def test_centre_choices_and_inward_winding(caplog):
    v, f = _ball(5.0, centre=(10.0, 0.0, 0.0))
    shape = ShapeModel.from_arrays(v, f)
    assert np.allclose(shape.centre, [10.0, 0.0, 0.0], atol=1e-9)
    with caplog.at_level(logging.WARNING):
        flipped = ShapeModel.from_arrays(v, f[:, ::-1])
    assert "wound inwards" in caplog.text
    assert flipped.volume == pytest.approx(shape.volume)
    given = ShapeModel.from_arrays(v, f, centre=(11.0, 1.0, 0.0))
    assert np.allclose(given.centre, [11.0, 1.0, 0.0])


def test_winding_number_inside_and_outside():
    v, f = _ball(2.0)
    assert winding_number(v, f, [0.5, 0.5, 0.5]) == pytest.approx(1.0)
    assert winding_number(v, f, [3.0, 0.0, 0.0]) == pytest.approx(0.0, abs=1e-12)


def test_open_surface_is_refused(tmp_path):
    v, f = _ball()
    path = tmp_path / "open.obj"
    write_mesh(path, [("body", v, f[1:])])
    with pytest.raises(InvalidShapeError, match="not a closed surface"):
        ShapeModel.read(path, units="m")


def test_centre_outside_is_refused():
    v, f = _ball(1.0)
    with pytest.raises(InvalidShapeError, match="lies outside its surface"):
        ShapeModel.from_arrays(v, f, centre=(5.0, 0.0, 0.0))
    # a centroid outside the surface: a thin shell (ball with a ball-shaped cavity)
    outer_v, outer_f = _ball(1.0)
    inner_v, inner_f = _ball(0.9)
    shell_v = np.concatenate([outer_v, inner_v])
    shell_f = np.concatenate([outer_f, inner_f[:, ::-1] + len(outer_v)])
    with pytest.raises(InvalidShapeError, match="outside its surface"):
        ShapeModel.from_arrays(shell_v, shell_f)


def test_bad_mesh_files(tmp_path):
    with pytest.raises(MissingInputError):
        ShapeModel.read(tmp_path / "missing.obj")
    garbage = tmp_path / "garbage.ply"
    garbage.write_bytes(b"ply\nthis is not a mesh\n")
    with pytest.raises(InvalidShapeError, match="cannot read shape model|holds no triangles"):
        ShapeModel.read(garbage)
    text = tmp_path / "x.txt"
    text.write_text("v 0 0 0\n")
    with pytest.raises(InvalidShapeError, match="suffix"):
        ShapeModel.read(text)
    v, f = _ball()
    f2 = f.copy()
    f2[0, 1] = f2[0, 0]
    with pytest.raises(InvalidShapeError, match="degenerate"):
        ShapeModel.from_arrays(v, f2)
