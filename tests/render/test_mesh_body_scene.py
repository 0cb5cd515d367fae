"""Bodies kept as their own mesh, from scenario files: the command line, the server, binaries.

The body is what ``craterscape asteroid build`` writes for a packing base (a contact binary
whose rays from the centre cross its surface more than once). The references are the mesh
itself: every pixel's range puts its point on the body's surface, the normal there faces the
camera, and the server's inside test agrees with the winding number computed here.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

from tests.render.server_helpers import served

SCENARIO = """
name = "mesh-body"
seed = 3
[scene]
type = "asteroid"
body = "{body}"
boulders = true
spin_axis = [0.0, 0.0, 1.0]
spin_period = 20000.0
[sun]
direction = [0.6, -0.7, 0.35]
[surface]
albedo = 0.25
reflectance = "lommel-seeliger"
[camera]
width = 64
height = 64
fov = 40.0
[sensor]
bits = 8
exposure = 3.0
gain = 0.0
read_noise = 0.0
[render]
shadow_size = 512
[output]
range = true
normals = true
[trajectory]
type = "approach"
frames = 2
duration = 600.0
start_distance = 2000.0
end_distance = 1800.0
direction = [0.2, 1.0, 0.3]
"""


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    """A contact binary built as ``asteroid build`` writes it: mesh file, .npz, catalogues."""
    from asteroid.build import build, output_paths, write_outputs
    from asteroid.recipe import Recipe

    folder = tmp_path_factory.mktemp("meshbody")
    recipe = Recipe.from_sources(base="packing:contact-binary", magnitude=16, radius=300.0,
                                 seed=1, craters={"density": 40.0, "dmin": 20.0, "dmax": 60.0},
                                 boulders={"density": 300.0, "dmin": 4.0, "dmax": 12.0,
                                           "levels": 2})
    result = build(recipe)
    write_outputs(result, output_paths(folder / "cb.ply", craters=True, boulders=True))
    scenario = folder / "cb.toml"
    scenario.write_text(SCENARIO.format(body="cb.npz"))
    return folder, result


def _world_points(truth, rng, fov=40.0):
    """World points of a range image and their unit rays (truth: the frame's ``camera``)."""
    from render.camera import Intrinsics, Pose

    k = Intrinsics.from_fov(rng.shape[1], rng.shape[0], fov)
    pose = Pose(tuple(truth["camera"]["position"]), tuple(truth["camera"]["attitude"]))
    rays = k.rays().reshape(rng.shape[0], rng.shape[1], 3) @ pose.rotation.T
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    return np.asarray(pose.position) + rays * rng[..., None], rays


def test_a_mesh_body_is_found_by_its_format(built):
    from render.mesh_scene import MeshBodyScene, is_mesh_body
    from render.scenario import load_scenario
    from render.sequence import load_scene

    folder, result = built
    assert is_mesh_body(folder / "cb.npz") and is_mesh_body(folder / "cb.ply")
    scene = load_scene(load_scenario(folder / "cb.toml"))
    assert isinstance(scene, MeshBodyScene) and scene.kind == "asteroid"
    # the boulders are drawn with the body, exactly as the build placed them
    assert len(scene.surface[1]) == len(result.body.faces)
    assert scene.reach >= np.linalg.norm(result.boulders.vertices, axis=1).max() - 1e-9


def test_render_frame_of_a_mesh_body_gives_range_and_normals_on_its_surface(built, gl):
    """Every hit pixel's range lies on the built mesh (or a boulder), its normal faces us."""
    from terrain.cli.commands import main
    from terrain.io import read_float_tiff

    folder, result = built
    out = folder / "f.png"
    r = CliRunner().invoke(main, ["render", "frame", str(folder / "cb.toml"), "-o", str(out)])
    assert r.exit_code == 0, r.output
    truth = json.loads((folder / "f_truth.json").read_text())
    rng = read_float_tiff(folder / "f_range.tif")
    normals = read_float_tiff(folder / "f_normals.tif")
    hit = np.isfinite(rng)
    assert hit.sum() > 150 and (~hit).sum() > 150  # the body and the sky around it
    pts, rays = _world_points(truth, rng)
    # body frame: the truth's body rotation R_WB at the frame's time
    from render.camera import quat_to_matrix

    rot = quat_to_matrix(truth["body_rotation"])
    local = pts[hit] @ rot
    surface = np.concatenate([result.body.vertices, result.boulders.vertices])
    gap, _ = cKDTree(surface).query(local)
    edge = np.linalg.norm(result.body.vertices[result.body.faces[:, 0]]
                          - result.body.vertices[result.body.faces[:, 1]], axis=1).max()
    assert np.all(gap < edge), gap.max()
    assert np.all(np.einsum("ij,ij->i", normals[hit], rays[hit]) < 0.05)


def test_render_sequence_of_a_mesh_body(built, tmp_path, gl):
    from render.rundir import RunReader
    from terrain.cli.commands import main

    folder, _ = built
    r = CliRunner().invoke(main, ["render", "sequence", str(folder / "cb.toml"), "-o",
                                  str(tmp_path / "run")])
    assert r.exit_code == 0, r.output
    run = RunReader(tmp_path / "run")
    assert len(run.truth) == 2
    for k in range(2):
        assert np.isfinite(run.range(k)).sum() > 150


def _probe_points(scene, n=4000, seed=5):
    """Points within the body's reach, with their winding number computed here."""
    from asteroid.shape import winding_number

    rng = np.random.default_rng(seed)
    p = rng.uniform(-1.0, 1.0, (n, 3)) * scene.reach
    p = p[np.linalg.norm(p, axis=1) < 0.9 * scene.reach]
    v, f = scene.surface
    return p, np.array([winding_number(v, f, q) for q in p[:300]])


def test_the_server_serves_a_mesh_body_and_knows_its_inside(built):
    """Over TCP: range and truth; a camera in the neck's hollow is outside, in a lobe inside."""
    from render.camera import look_at
    from render.client import Client
    from render.errors import ServerError
    from render.mesh_scene import MeshBodyScene

    folder, _ = built
    scene = MeshBodyScene(folder / "cb.npz")
    pts, wn = _probe_points(scene)
    pts = pts[:300]
    # outside the body yet within its bounding sphere, and nearer the centre than the
    # lowest point of a star-shaped body would let it be: the concavity of the neck
    hollow = pts[(wn < 0.5) & (np.linalg.norm(pts, axis=1) < 0.6 * scene.reach)]
    inside = pts[wn > 0.5]
    assert len(hollow) and len(inside)
    with served(folder / "cb.toml") as (_, port), Client(port=port) as c:
        assert c.info()["scene"] == "asteroid"
        pose = look_at((0.0, 1500.0, 300.0), (0.0, 0.0, 0.0))
        c.set_pose(pose.position, pose.attitude, time=0.0)
        rng = c.get_range()
        assert np.isfinite(rng).sum() > 150
        truth = c.get_truth()
        assert truth["camera"]["position"] == pytest.approx(list(pose.position))
        p = hollow[0]
        c.set_pose(tuple(p), look_at(p, (0.0, 0.0, 0.0)).attitude, time=0.0)
        with pytest.raises(ServerError, match="inside"):
            q = inside[0]
            c.set_pose(tuple(q), look_at(q, (0.0, 0.0, 0.0)).attitude, time=0.0)
        c.ping()  # the connection lives


def test_a_mesh_body_in_a_binary_is_labelled_and_its_inside_exact(built, renderer):
    """A mesh body's .npz as a binary's primary: its pixels are labelled 1, the inside test
    follows its shape (not its bounding sphere)."""
    from asteroid.body import Body
    from asteroid.sphere import SphereMesh
    from render.binary_scene import BinaryScene
    from render.camera import Intrinsics, look_at
    from render.mesh_scene import MeshBodyScene
    from render.orbit import MutualOrbit
    from render.renderer import Lighting, RenderOptions, View

    folder, _ = built
    binary = BinaryScene(folder / "cb.npz", Body.sphere(SphereMesh(16), 120.0),
                         orbit=MutualOrbit(semi_major_axis=1500.0, mean_anomaly=40.0))
    assert isinstance(binary.bodies[0], MeshBodyScene)
    t = 100.0
    (c1, q1), (c2, _) = binary.body_poses(t)
    pts, wn = _probe_points(binary.bodies[0])
    from render.camera import quat_to_matrix

    world = pts[:300] @ quat_to_matrix(q1).T + c1
    for p, w in zip(world[:40], wn[:40], strict=True):
        assert binary.contains(p, t) == (w > 0.5)
    pose = look_at(c1 + np.array([0.0, -2200.0, 600.0]), 0.5 * (c1 + c2))
    k = Intrinsics.from_fov(96, 96, 50.0)
    view = View(pose, k, t)
    frame = renderer.render(binary, view, Lighting((0.6, -0.7, 0.35), albedo=0.2),
                            RenderOptions(shadows=False))
    ids = binary.body_ids(view, frame)
    assert np.array_equal(ids == 0, ~np.isfinite(frame.range))
    # each labelled pixel's point is nearer its own body's centre than the other's reach
    pts_w, _ = _world_points(dict(camera=dict(position=list(pose.position),
                                              attitude=list(pose.attitude))), frame.range, 50.0)
    for label, centre in ((1, c1), (2, c2)):
        sel = ids == label
        assert sel.sum() > 20
        d = np.linalg.norm(pts_w[sel] - centre, axis=1)
        assert np.all(d <= binary.bodies[label - 1].reach + 1.0)
