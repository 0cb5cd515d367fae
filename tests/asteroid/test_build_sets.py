"""A build's files belong together: the mesh, the native model and the catalogues
appear together or not at all, whatever moment the build is killed at, and a rebuild
without craters or boulders removes the old catalogues."""

import csv
import os
import signal
import time

import numpy as np
import pytest
import trimesh

from asteroid.body import load_native
from asteroid.sphere import SphereMesh
from tests.cli_helpers import run

KILLS = 24
MAGNITUDE = 12


def _args(out, seed, *, features):
    args = ["asteroid", "build", "-o", out, "--magnitude", MAGNITUDE, "--radius", 1000,
            "--base", "perlin", "--seed", seed]
    if features:
        return args + ["--craters", "c=0.5,dmin=150", "--boulders", "c=0.02,dmin=40,dmax=120"]
    return args + ["--craters", "none", "--boulders", "none"]


def _check_set(folder):
    """The files in ``folder`` are one build's: same body, same catalogues, nothing stale."""
    native = load_native(folder / "a.npz")  # finishes a commit a kill interrupted
    for name in ("craters", "boulders"):
        path = folder / f"a_{name}.csv"
        assert path.exists() == (name in native.tables), name
        if path.exists():
            rows = list(csv.DictReader(path.open()))
            assert len(rows) == len(native.tables[name]["id"])
            ids = {int(r["id"], 16) if not r["id"].isdigit() else int(r["id"]) for r in rows}
            assert len(ids) == len(rows)
    mesh = trimesh.load(folder / "a.ply", process=False)
    n_boulders = len(native.tables["boulders"]["id"]) if "boulders" in native.tables else 0
    assert len(mesh.faces) == 12 * MAGNITUDE**2 + n_boulders * 1280
    n_body = SphereMesh(MAGNITUDE).n_vertices
    np.testing.assert_allclose(mesh.vertices[:n_body], native.body.vertices(), rtol=1e-6)
    return native.body.metadata["seed"]


@pytest.mark.slow
def test_rebuild_without_features_removes_the_old_catalogues(tmp_path):
    out = tmp_path / "a.ply"
    assert run(*_args(out, 1, features=True)).exit_code == 0
    assert (tmp_path / "a_craters.csv").exists() and (tmp_path / "a_boulders.csv").exists()
    r = run(*_args(out, 2, features=False))
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz", "a.ply"]
    assert _check_set(tmp_path) == 2


@pytest.mark.slow
def test_killed_builds_leave_one_consistent_set(tmp_path):
    out = tmp_path / "a.ply"
    t0 = time.perf_counter()
    r = run(*_args(out, 0, features=True))  # warms every kernel before forking
    duration = time.perf_counter() - t0
    assert r.exit_code == 0, r.output
    seeds = {0}
    rng = np.random.default_rng(3)
    for i in range(1, KILLS + 1):
        pid = os.fork()
        if pid == 0:  # pragma: no cover - child
            os._exit(run(*_args(out, i, features=i % 2 == 0)).exit_code)
        time.sleep(rng.uniform(0.0, 1.3 * duration))
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        seed = _check_set(tmp_path)
        assert seed in seeds | {i}  # the previous set or the new one, never a mixture
        seeds.add(seed)
    r = run(*_args(out, 99, features=False))  # the next build cleans what kills left
    assert r.exit_code == 0, r.output
    assert _check_set(tmp_path) == 99
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz", "a.ply"]


@pytest.mark.parametrize("first, second", [("a.ply", "a.npz"), ("a.ply", "a.obj"),
                                           ("a.glb", "a.ply")])
def test_rebuild_removes_a_mesh_of_the_old_body(tmp_path, first, second):
    # an earlier build's mesh beside the new native model would be read as the new body
    small = ["--magnitude", 6, "--radius", 1000, "--base", "perlin", "--craters", "none",
             "--boulders", "none"]
    assert run("asteroid", "build", "-o", tmp_path / first, "--seed", 1, *small).exit_code == 0
    r = run("asteroid", "build", "-o", tmp_path / second, "--seed", 2, *small)
    assert r.exit_code == 0, r.output
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted({"a.npz", second})
    if second != "a.npz":
        native = load_native(tmp_path / "a.npz").body
        mesh = trimesh.load(tmp_path / second, force="mesh", process=False)
        from scipy.spatial import cKDTree

        # the mesh is the new body (OBJ may order and round its vertices its own way)
        assert len(mesh.vertices) == len(native.vertices())
        assert cKDTree(native.vertices()).query(mesh.vertices)[0].max() < 1e-3


def test_rebuild_from_a_shape_model_keeps_the_shape_model(tmp_path):
    # a.obj is the input here, never a stale mesh of a.npz
    shape = tmp_path / "a.obj"
    trimesh.creation.icosphere(subdivisions=2, radius=1.0).export(shape)
    before = shape.read_bytes()
    r = run("asteroid", "build", "-o", tmp_path / "a.npz", "--magnitude", 6, "--base",
            f"shape:{shape}", "--shape-units", "m", "--craters", "none", "--boulders", "none")
    assert r.exit_code == 0, r.output
    assert shape.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz", "a.obj"]
