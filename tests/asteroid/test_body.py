"""The body value type, the native .npz and the stretch."""

import numpy as np
import pytest

from asteroid.body import Body, Stretch, load_native, save_native
from asteroid.sphere import SphereMesh
from terrain.core.errors import InvalidParameterError, MissingInputError, OutputPathError


def test_native_round_trip_and_identical_bytes(tmp_path, rng):
    mesh = SphereMesh(7)
    body = Body(mesh, 500.0, 500.0 + rng.normal(0, 3, mesh.n_vertices), {"seed": 4, "a": [1, 2]})
    tables = {"craters": {"id": np.array([1, 2], np.uint64), "diameter_m": np.array([3.0, 4.0])}}
    a, b = tmp_path / "a.npz", tmp_path / "b.npz"
    save_native(a, body, tables)
    save_native(b, body, tables)
    assert a.read_bytes() == b.read_bytes()
    native = load_native(a)
    assert native.body.magnitude == 7 and native.body.radius == 500.0
    assert np.array_equal(native.body.radii, body.radii)
    assert dict(native.body.metadata) == {"seed": 4, "a": [1, 2]}
    assert np.array_equal(native.tables["craters"]["id"], tables["craters"]["id"])
    assert native.tables["craters"]["id"].dtype == np.uint64


def test_volume_and_area_converge_to_the_sphere():
    for m, tol in ((16, 0.01), (64, 0.001)):
        body = Body.sphere(SphereMesh(m), 2.0)
        assert body.volume() == pytest.approx(4 / 3 * np.pi * 8, rel=tol)
        assert body.area() == pytest.approx(4 * np.pi * 4, rel=tol)
        assert body.volume() < 4 / 3 * np.pi * 8          # inscribed polyhedron


def test_body_validation():
    mesh = SphereMesh(2)
    with pytest.raises(InvalidParameterError, match="radii must be"):
        Body(mesh, 1.0, np.ones(5))
    radii = np.ones(mesh.n_vertices)
    radii[3] = -1.0
    with pytest.raises(InvalidParameterError, match="positive and finite; 1 of 26"):
        Body(mesh, 1.0, radii)
    with pytest.raises(InvalidParameterError, match="radius must be positive"):
        Body(mesh, 0.0, np.ones(mesh.n_vertices))
    with pytest.raises(InvalidParameterError, match="JSON"):
        Body(mesh, 1.0, np.ones(mesh.n_vertices), {"x": object()})
    body = Body.sphere(mesh, 1.0)
    with pytest.raises(ValueError):
        body.radii[0] = 3.0                                  # immutable


def test_native_errors(tmp_path):
    with pytest.raises(MissingInputError):
        load_native(tmp_path / "none.npz")
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(InvalidParameterError, match="cannot read native model"):
        load_native(bad)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    with pytest.raises(InvalidParameterError, match="not a craterscape asteroid model"):
        load_native(tmp_path / "other.npz")
    body = Body.sphere(SphereMesh(1), 1.0)
    src = tmp_path / "in.npz"
    save_native(src, body)
    with pytest.raises(OutputPathError):
        save_native(src, body, inputs=[src])


def test_stretch_is_the_affine_image():
    s = Stretch(2.0, 1.0, 0.5)
    rng = np.random.default_rng(1)
    u = rng.normal(size=(500, 3))
    u /= np.linalg.norm(u, axis=1)[:, None]
    u0, factor = s.source(u)
    # the unit-sphere point u0 maps onto the ray through u at distance factor
    assert np.allclose(u0 * s.factors, u * factor[:, None])
    assert np.allclose(np.linalg.norm(u0, axis=1), 1.0)
    assert Stretch.parse("2,1,1") == Stretch(2, 1, 1) and Stretch.parse(None).is_identity
    with pytest.raises(InvalidParameterError, match="three numbers"):
        Stretch.parse("2,1")
    with pytest.raises(InvalidParameterError, match="stretch x must be > 0"):
        Stretch(0, 1, 1)
