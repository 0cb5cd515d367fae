"""The `craterscape asteroid` commands, as a user runs them (click's CliRunner)."""

import csv
import json

import numpy as np
import pytest
import trimesh
from hypothesis import example, given, settings
from hypothesis import strategies as st

from asteroid.body import load_native
from asteroid.meshio import write_mesh
from asteroid.sphere import SphereMesh
from tests.cli_helpers import one_line_error, run


@pytest.fixture
def ball(tmp_path):
    mesh = SphereMesh(10)
    path = tmp_path / "ball.obj"
    write_mesh(path, [("body", mesh.directions() * np.array([1.2, 1.0, 0.8]), mesh.faces())])
    return path


@settings(max_examples=4, deadline=None)
@given(magnitude=st.integers(2, 10), radius=st.floats(10.0, 5000.0), seed=st.integers(0, 2**31))
@example(magnitude=2, radius=10.0, seed=2258)
def test_build_command_writes_a_closed_body_of_the_asked_size(tmp_path_factory, magnitude,
                                                                radius, seed):
    """What `craterscape asteroid build` promises whatever the flags: a closed, consistently
    wound mesh of 6 M^2 + 2 vertices and 12 M^2 triangles with a positive volume, of the
    asked size, and the same bytes for the same seed.

    "Of the asked size": --radius is the reference radius R the relief is added to, so
    doubling it doubles every vertex (the same seed draws the same relief, in units of R),
    and every radius lies within R times the summed band amplitudes of R (Perlin noise lies
    in [-1, 1] per band). A body's mean radius is *not* R exactly: one realisation's lowest
    band (a quarter of R) need not average to zero over the sphere (seed 2258 at M = 2 gives
    1.053 R)."""
    from asteroid.noise import PerlinNoise

    out = tmp_path_factory.mktemp("build")
    args = ["asteroid", "build", "--magnitude", magnitude, "--base", "perlin", "--seed", seed,
            "--craters", "none"]
    r = run(*args, "--radius", radius, "-o", out / "a.ply")
    assert r.exit_code == 0, r.output
    mesh = trimesh.load(out / "a.ply", process=False)
    assert len(mesh.vertices) == 6 * magnitude**2 + 2 and len(mesh.faces) == 12 * magnitude**2
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    radii = np.linalg.norm(mesh.vertices, axis=1)
    bound = PerlinNoise().band_amplitudes().sum()
    assert np.all(np.abs(radii / radius - 1.0) <= bound)
    assert run(*args, "--radius", 2 * radius, "-o", out / "big.ply").exit_code == 0
    big = trimesh.load(out / "big.ply", process=False)
    np.testing.assert_allclose(big.vertices, 2 * mesh.vertices, rtol=1e-6,
                               atol=1e-6 * radius)
    assert run(*args, "--radius", radius, "-o", out / "b.ply").exit_code == 0
    assert (out / "a.ply").read_bytes() == (out / "b.ply").read_bytes()


def test_build_perlin_with_craters_and_boulders_is_reproducible(tmp_path):
    args = ["asteroid", "build", "--magnitude", 16, "--radius", 1000, "--base", "perlin",
            "--seed", 5, "--craters", "c=0.5,dmin=150", "--boulders", "c=0.02,dmin=40,dmax=120"]
    r = run(*args, "-o", tmp_path / "a.ply")
    assert r.exit_code == 0, r.output
    names = ["a.ply", "a.npz", "a_craters.csv", "a_boulders.csv"]
    assert all((tmp_path / n).exists() for n in names)
    assert "craters applied" in r.output and "boulders" in r.output
    r = run(*args, "-o", tmp_path / "b.ply")
    assert r.exit_code == 0, r.output
    for n in names:
        assert (tmp_path / n).read_bytes() == (tmp_path / n.replace("a", "b", 1)).read_bytes(), n
    native = load_native(tmp_path / "a.npz")
    assert native.body.magnitude == 16 and native.body.metadata["seed"] == 5
    rows = list(csv.DictReader((tmp_path / "a_craters.csv").open()))
    assert len(rows) == len(native.tables["craters"]["id"]) > 0
    assert {"lat_deg", "lon_deg", "diameter_m", "age_gyr", "depth_m", "rim_height_m",
            "slope_deg", "applied"} <= set(rows[0])
    loaded = trimesh.load(tmp_path / "a.ply", process=False)
    n_boulders = len(native.tables["boulders"]["id"])
    assert len(loaded.faces) == 12 * 16**2 + n_boulders * 1280


@pytest.mark.slow
def test_build_faulting_preset_and_native_only(tmp_path):
    r = run("asteroid", "build", "-o", tmp_path / "f.npz", "--preset", "fig9-faulting",
            "--magnitude", 10, "--craters", "none", "--seed", 2)
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.npz"]
    body = load_native(tmp_path / "f.npz").body
    assert body.metadata["recipe"]["faulting"]["fine_faults"] == 20000
    assert body.metadata["recipe"]["stretch"] == [2.0, 1.0, 1.0]


def test_build_from_a_shape_model_and_export(tmp_path, ball):
    r = run("asteroid", "build", "-o", tmp_path / "s.glb", "--magnitude", 12, "--base",
            f"shape:{ball}", "--shape-units", "m", "--seed", 1)
    assert r.exit_code == 0, r.output
    assert "not star-shaped" in r.output
    body = load_native(tmp_path / "s.npz").body
    assert body.radius == pytest.approx((1.2 * 1.0 * 0.8) ** (1 / 3), rel=0.02)
    assert body.metadata["shape"]["non_star_fraction"] == 0.0
    r = run("asteroid", "export", tmp_path / "s.npz", "-o", tmp_path / "s.obj")
    assert r.exit_code == 0, r.output
    assert trimesh.load(tmp_path / "s.obj", process=False).is_watertight
    r = run("asteroid", "info", tmp_path / "s.npz")
    assert r.exit_code == 0, r.output
    report = json.loads(r.output)
    assert report["vertices"] == 6 * 144 + 2 and report["metadata"]["seed"] == 1
    r = run("asteroid", "presets")
    assert r.exit_code == 0 and "fig9-faulting" in json.loads(r.output)


def test_scaled_shape_with_config(tmp_path, ball):
    config = tmp_path / "r.toml"
    config.write_text(f'magnitude = 8\nbase = "shape:{ball.name}"\nradius = 500.0\n'
                      '[shape]\nunits = "m"\ncentre = "origin"\n')
    r = run("asteroid", "build", "-o", tmp_path / "s.stl", "--config", config)
    assert r.exit_code == 0, r.output
    assert load_native(tmp_path / "s.npz").body.radius == pytest.approx(500.0)


def test_bad_input_gives_one_line_errors(tmp_path, ball):
    out = ["-o", tmp_path / "x.ply"]
    perlin = ["--radius", 1000, "--base", "perlin"]
    one_line_error(run("asteroid", "build", *out, "--magnitude", 0, *perlin),
                   "magnitude M must be an integer >= 1")
    one_line_error(run("asteroid", "build", *out, "--magnitude", 8, *perlin, "--craters",
                       "c=0.5,dmax=2000"), "maximum extent")
    one_line_error(run("asteroid", "build", *out, "--magnitude", 300_000, *perlin),
                   "needs about", "of memory")
    one_line_error(run("asteroid", "build", *out, "--magnitude", 64, *perlin,
                       env={"CRATERSCAPE_MEMORY_LIMIT": "1M"}), "of memory")
    open_mesh = tmp_path / "open.obj"
    mesh = SphereMesh(4)
    write_mesh(open_mesh, [("body", mesh.directions(), mesh.faces()[2:])])
    one_line_error(run("asteroid", "build", *out, "--magnitude", 8, "--base",
                       f"shape:{open_mesh}"), "not a closed surface")
    one_line_error(run("asteroid", "build", *out, "--magnitude", 8, "--base", f"shape:{ball}",
                       "--shape-units", "m", "--shape-centre", "5,0,0"),
                   "lies outside its surface")
    one_line_error(run("asteroid", "build", *out, "--magnitude", 8, "--base",
                       f"shape:{tmp_path / 'none.obj'}"), "does not exist")
    one_line_error(run("asteroid", "build", "-o", ball, "--magnitude", 8, "--base",
                       f"shape:{ball}"), "same file as input")
    one_line_error(run("asteroid", "build", "-o", tmp_path / "x.vtk", "--magnitude", 8,
                       *perlin), "must end in one of")
    one_line_error(run("asteroid", "build", *out, "--magnitude", 8, *perlin, "--stretch", "2,1"),
                   "three numbers")
    one_line_error(run("asteroid", "build", *out, "--magnitude", 8, "--base", "perlin"),
                   "needs --radius")
    one_line_error(run("asteroid", "build", *out, "--preset", "fig42"), "unknown preset")
    one_line_error(run("asteroid", "build", *out, "--magnitude", 8, *perlin, "--craters",
                       "density=3,c=1"), "exactly one of c")
    one_line_error(run("asteroid", "info", tmp_path / "none.npz"), "does not exist")
    assert not (tmp_path / "x.ply").exists()


def test_traceback_only_with_verbose(tmp_path):
    r = run("-v", "asteroid", "build", "-o", tmp_path / "x.ply", "--magnitude", 0, "--radius",
            1, "--base", "perlin")
    assert r.exit_code == 2 and "Traceback" in r.output


def test_info_and_export_read_a_mesh_body(tmp_path):
    """A packing body (kept as its own mesh): info describes it, export writes the mesh the
    build wrote (same bytes), its boulders at any level, or the body alone, watertight."""
    from asteroid.surface import load_mesh_native

    r = run("asteroid", "build", "-o", tmp_path / "cb.ply", "--base", "packing:contact-binary",
            "--radius", 300, "--magnitude", 16, "--seed", 1, "--craters",
            "density=40,dmin=20,dmax=60", "--boulders", "density=300,dmin=4,dmax=12,levels=2")
    assert r.exit_code == 0, r.output
    body, tables = load_mesh_native(tmp_path / "cb.npz")
    r = run("asteroid", "info", tmp_path / "cb.npz")
    assert r.exit_code == 0, r.output
    report = json.loads(r.output)
    assert report["kind"] == "mesh" and report["closed"] is True
    assert report["triangles"] == len(body.faces)
    assert report["volume_m3"] == pytest.approx(4 / 3 * np.pi * 300.0**3, rel=0.01)
    assert report["tables"] == {"craters": len(tables["craters"]["id"]),
                                "boulders": len(tables["boulders"]["id"])}
    r = run("asteroid", "export", tmp_path / "cb.npz", "-o", tmp_path / "again.ply")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "again.ply").read_bytes() == (tmp_path / "cb.ply").read_bytes()
    r = run("asteroid", "export", tmp_path / "cb.npz", "-o", tmp_path / "coarse.obj",
            "--level", 0)
    assert r.exit_code == 0, r.output
    coarse = trimesh.load(tmp_path / "coarse.obj", process=False)
    n_boulders = len(tables["boulders"]["id"])
    assert len(coarse.faces) == len(body.faces) + 20 * n_boulders  # icosahedra
    r = run("asteroid", "export", tmp_path / "cb.npz", "-o", tmp_path / "bare.stl",
            "--no-boulders")
    assert r.exit_code == 0, r.output
    bare = trimesh.load(tmp_path / "bare.stl")
    assert bare.is_watertight and len(bare.faces) == len(body.faces)
    one_line_error(run("asteroid", "export", tmp_path / "cb.npz", "-o", tmp_path / "x.ply",
                       "--level", 5), "boulder level")
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    one_line_error(run("asteroid", "info", tmp_path / "junk.npz"), "junk.npz")
