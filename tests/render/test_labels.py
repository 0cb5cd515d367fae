"""Image-space labels checked against what the rendered range, normals and images show."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from render.camera import Intrinsics, look_at
from render.labels import (
    ROCK,
    SHADOWED,
    Labeller,
    LabelSpec,
    ellipse_from_conic,
    shadow_mask,
    surface_points,
)
from render.renderer import Lighting, RenderOptions, View
from terrain.core.errors import InvalidParameterError
from tests.render.scenes import cratered_stack

SUN = Lighting.from_angles(90.0, 30.0)


def _flat_scene(stack_rocks=None, *, crater: float | None = None, n: int = 257,
                res: float = 0.5):
    """A level plane, with one fresh smooth crater at its centre or the rocks given."""
    from render.terrain_scene import TerrainScene
    from terrain.core.tile import DEMTile
    from terrain.craters.catalog import Crater, CraterCatalog, CraterTable
    from terrain.craters.cratering import CraterModel, add_craters
    from terrain.stack.model import Layer, LayerStack

    tile = DEMTile.from_array(np.zeros((n, n), np.float32), resolution=res)
    left, bottom, right, top = tile.bounds
    cx, cy = (left + right) / 2, (bottom + top) / 2
    catalog = CraterCatalog.empty(layered=True)
    rocks = None
    if crater is not None:
        out = add_craters(tile, CraterTable.from_craters([Crater(cx, cy, crater)]), seed=1,
                          model=CraterModel().smooth())
        tile, catalog = out.tile, out.catalog.with_layer(0)
    if stack_rocks is not None:
        from terrain.surface.rocks import add_rocks

        tile, rocks = add_rocks(tile, stack_rocks, seed=2)
    stack = LayerStack((Layer(tile, None, (0, 0)),), catalog, info={"site": [cx, cy]},
                       rocks=rocks)
    return TerrainScene(stack, curvature=False), (cx, cy)


def _crest(points, centre, diameter, bins=72):
    """Rim crest points traced in a range image, independently of any label.

    Per azimuth bin, the crest is where the inner wall's and the outer flank's height
    profiles meet: two lines fitted to z(r) either side of the highest point, iterated;
    bins where either flank is not seen (hidden behind the near rim) are left out.
    """
    cx, cy = centre
    ok = np.isfinite(points[..., 0])
    dx, dy, z = points[..., 0][ok] - cx, points[..., 1][ok] - cy, points[..., 2][ok]
    r, th = np.hypot(dx, dy), np.arctan2(dy, dx)
    width = 0.08 * diameter
    out = []
    for j in range(bins):
        a0 = -math.pi + 2 * math.pi * j / bins
        sel = (th >= a0) & (th < a0 + 2 * math.pi / bins) & (r > 0.35 * diameter) \
            & (r < 0.65 * diameter)
        rs, zs = r[sel], z[sel]
        if len(rs) < 10:
            continue
        start = rp = rs[np.argmax(zs)]
        good = True
        for _ in range(3):
            inner, outer = (rs < rp) & (rs > rp - width), (rs > rp) & (rs < rp + width)
            if inner.sum() < 5 or outer.sum() < 5:
                good = False
                break
            a1, b1 = np.polyfit(rs[inner], zs[inner], 1)
            a2, b2 = np.polyfit(rs[outer], zs[outer], 1)
            rp = (b2 - b1) / (a1 - a2)
        if not good or abs(rp - start) > width:
            continue
        tc = a0 + math.pi / bins
        out.append([cx + rp * math.cos(tc), cy + rp * math.sin(tc), a1 * rp + b1])
    return np.array(out)


def _distance_to_ellipse(uv, ell):
    u0, v0, a, b, ang = ell
    t = np.linspace(0.0, 2 * math.pi, 7200)
    ca, sa = math.cos(math.radians(ang)), math.sin(math.radians(ang))
    eu = u0 + a * np.cos(t) * ca - b * np.sin(t) * sa
    ev = v0 + a * np.cos(t) * sa + b * np.sin(t) * ca
    return np.min(np.hypot(uv[:, :1] - eu[None], uv[:, 1:] - ev[None]), axis=1)


@pytest.mark.parametrize(("off_nadir", "azimuth"), [(0, 0), (30, 30), (45, 200), (60, 30),
                                                    (60, 135)])
def test_rim_ellipse_lies_on_the_crest_seen_in_the_range_image(renderer, off_nadir, azimuth):
    diameter = 40.0
    scene, (cx, cy) = _flat_scene(crater=diameter)
    k = Intrinsics.from_fov(256, 256, 40.0)
    e, az, dist = math.radians(off_nadir), math.radians(azimuth), 120.0
    pose = look_at((cx + dist * math.sin(e) * math.cos(az),
                    cy + dist * math.sin(e) * math.sin(az), dist * math.cos(e)), (cx, cy, 0.0))
    frame = renderer.render(scene, View(pose, k), SUN, RenderOptions(lod_pixels=0.5))
    labels = Labeller(scene, LabelSpec()).label(frame, pose, k, SUN)
    assert len(labels.craters) == 1
    rim = labels.craters[0]
    assert rim["in_frame"] == 1.0 and rim["occluded"] == 0.0
    crest = _crest(surface_points(frame.range, pose, k), (cx, cy), diameter)
    assert len(crest) >= 36  # at least half the rim traced
    ell = ellipse_from_conic(np.array(rim["conic"]).reshape(3, 3))
    d = _distance_to_ellipse(pose.project(crest, k), ell)
    assert math.sqrt(np.mean(d ** 2)) < 0.5
    # the ellipse's minor axis shrinks with the view angle as cos(off-nadir), near enough
    major, minor = rim["ellipse"]["axes"]
    assert minor / major == pytest.approx(math.cos(e), abs=0.02)


def test_instance_masks_hold_every_rock_range_discontinuity(renderer):
    from terrain.surface.rocks import RockModel

    scene, (cx, cy) = _flat_scene(RockModel.from_spec("golombek-rapp-mars:k=0.15,dmin=0.3"), n=201,
                                  res=0.05)
    k = Intrinsics.from_fov(200, 200, 50.0)
    pose = look_at((cx + 4.0, cy - 5.0, 6.0), (cx, cy, 0.0))
    frame = renderer.render(scene, View(pose, k), SUN, RenderOptions(lod_pixels=0.5))
    labels = Labeller(scene, LabelSpec()).label(frame, pose, k, SUN)
    mask, rng = labels.instance_mask, frame.range.astype(np.float64)
    kinds = {r["instance"]: r["kind"] for r in labels.instances}
    # on a plane only rocks break the range image: at every jump the nearer pixel is a rock's
    jumps = 0
    for axis in (0, 1):
        a, b = rng, np.roll(rng, -1, axis=axis)
        ma, mb = mask, np.roll(mask, -1, axis=axis)
        jump = np.abs(a - b) > 0.03 * np.minimum(a, b)
        jump[(-1 if axis == 0 else slice(None)), (-1 if axis == 1 else slice(None))] = False
        near = np.where(a < b, ma, mb)[jump]
        jumps += int(jump.sum())
        assert np.all(near > 0)
        assert all(kinds[int(n)] == "rock" for n in np.unique(near))
    assert jumps > 50
    # every rock wider than 3 px in the image, its centre seen, has its own instance
    rocks = scene.stack.rocks
    ids = {r["id"] for r in labels.instances}
    base = np.stack([rocks.x_m, rocks.y_m, rocks.z_base_m + rocks.height_m], axis=1)
    uv = pose.project(base, k)
    cam = pose.to_camera(base)
    width = k.fx * rocks.diameter_m / cam[:, 2]
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < k.width) & (uv[:, 1] >= 0) & (uv[:, 1] < k.height)
    for i in np.flatnonzero(inside & (width > 3)):
        u, v = np.rint(uv[i]).astype(int)
        if rng[v, u] < np.linalg.norm(cam[i]) - 0.05:  # hidden behind a nearer rock
            continue
        assert f"{int(rocks.id[i]):016x}" in ids
    assert np.all((labels.semantic == ROCK) <= (mask > 0))


def test_flow_warps_frame_t_onto_frame_t_plus_1_to_the_noise_floor(tmp_path):
    import cv2

    from render.renderer import Renderer
    from render.scenario import load_scenario
    from render.sequence import load_scene, render_sample

    stack = cratered_stack(tmp_path / "stack")
    (tmp_path / "s.toml").write_text(f"""
seed = 5
[scene]
type = "terrain"
stack = "{stack}"
[sun]
azimuth = 100.0
elevation = 25.0
[camera]
width = 128
height = 128
fov = 40.0
[sensor]
bits = 16
exposure = 4.0
gain = 10.0
read_noise = 2.0
[trajectory]
type = "descent"
frames = 20
duration = 20.0
start_altitude = 900.0
end_altitude = 700.0
ground_track = [100.0, 50.0]
[labels]
""")
    sc = load_scenario(tmp_path / "s.toml")
    scene = load_scene(sc)
    samples = sc.samples(scene)
    ren = Renderer()
    i0, f0, t0 = render_sample(ren, scene, sc, samples[5], 5, samples)
    i1, f1, t1 = render_sample(ren, scene, sc, samples[6], 6, samples)
    i1b, _, _ = render_sample(ren, scene, sc, samples[6], 106, samples)  # other noise
    lab = Labeller(scene, sc.labels)
    labels = lab.label(f0, t0.pose, t0.intrinsics, sc.lighting)
    lab.add_flow(labels, f0.range, t0.pose, t0.body_rotation, f1.range, t1.pose,
                 t1.body_rotation, t0.intrinsics)
    flow, occluded = labels.flow, labels.occluded
    v, u = np.mgrid[0:128, 0:128].astype(np.float32)
    mx, my = np.nan_to_num(u + flow[..., 0], nan=-10), np.nan_to_num(v + flow[..., 1], nan=-10)
    warped = cv2.remap(i1.astype(np.float32), mx, my, cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    shadow1 = cv2.remap(shadow_mask(f1.radiance, f1.normals, sc.lighting).astype(np.float32),
                        mx, my, cv2.INTER_LINEAR, borderValue=1.0)
    ok = np.isfinite(flow[..., 0]) & ~occluded & ~(labels.semantic == SHADOWED) \
        & (shadow1 == 0) & np.isfinite(warped)
    ok = cv2.erode(ok.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    assert ok.sum() > 0.5 * ok.size
    residual = (warped - i0.astype(np.float32))[ok].std()
    floor = (i1.astype(np.float32) - i1b.astype(np.float32))[ok].std()  # sqrt(2) x noise
    still = (i1.astype(np.float32) - i0.astype(np.float32))[ok].std()
    assert residual < 1.2 * floor
    assert still > 3 * floor  # the frames did move: the flow is what aligns them


def test_a_labelled_sequence_reads_back_in_pycocotools_and_its_camera_table(tmp_path):
    from click.testing import CliRunner
    from pycocotools.coco import COCO

    from terrain.cli.root import main
    from tests.render.scenes import descent_scenario

    stack = cratered_stack(tmp_path / "stack")
    (tmp_path / "s.toml").write_text(descent_scenario(stack, "lab", frames=3)
                                     + "[labels]\nmin_crater_pixels = 3.0\n")
    res = CliRunner().invoke(main, ["render", "sequence", str(tmp_path / "s.toml"), "-o",
                                    str(tmp_path / "run")])
    assert res.exit_code == 0, res.output
    run = tmp_path / "run"
    truth = json.loads((run / "truth.json").read_text())
    assert "flow" in truth[0]["labels"] and "flow" not in truth[-1]["labels"]
    coco = COCO(str(run / "labels/coco.json"))
    assert len(coco.getImgIds()) == 3
    import cv2

    from terrain.stack.store import read_stack

    catalog_ids = {f"{int(i):016x}" for i in read_stack(stack).catalog.id}
    n_craters = 0
    for entry in truth:
        img = coco.imgs[entry["index"] + 1]
        mask = cv2.imread(str(run / entry["labels"]["instances"]), cv2.IMREAD_UNCHANGED)
        rims = json.loads((run / entry["labels"]["rims"]).read_text())
        by_id = {r["id"]: r for r in rims["craters"]}
        for ann in coco.loadAnns(coco.getAnnIds(imgIds=img["id"])):
            assert ann["catalog_id"] in (catalog_ids if ann["category_id"] == 1
                                          else {r["id"] for r in rims["instances"]})
            if ann["category_id"] == 1:
                n_craters += 1
                assert ann["ellipse"] == by_id[ann["catalog_id"]]["ellipse"]
                n = by_id[ann["catalog_id"]]["instance"]
                if n:
                    assert np.array_equal(coco.annToMask(ann).astype(bool), mask == n)
    assert n_craters > 0
    with open(run / "labels/cameras.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [int(r["index"]) for r in rows] == [0, 1, 2]
    for r, entry in zip(rows, truth, strict=True):
        assert [float(r[c]) for c in ("x", "y", "z")] == entry["camera"]["position"]
        assert float(r["fx"]) == entry["intrinsics"]["fx"]


def test_labels_are_off_unless_asked_and_their_table_is_checked(tmp_path):
    from render.scenario import parse_scenario

    base = {"scene": {"type": "terrain", "stack": "s"},
            "trajectory": {"type": "descent", "start_altitude": 10.0, "end_altitude": 5.0}}
    assert parse_scenario(base).labels is None
    with pytest.raises(InvalidParameterError, match="min_crater_pixel.*min_crater_pixels"):
        parse_scenario(dict(base, labels={"min_crater_pixel": 3}))
    with pytest.raises(InvalidParameterError, match="lander_diameter"):
        parse_scenario(dict(base, labels={"hazards": True}))
    spec = parse_scenario(dict(base, labels={"lander_diameter": 4.0})).labels
    assert spec is not None and spec.hazards


def test_a_rim_seen_from_straight_above_is_its_circle():
    # a circle of radius R at distance Z below a nadir camera images as a circle of f R / Z
    from render.labels import rim_conic

    k = Intrinsics(501, 401, 800.0, 800.0, 250.0, 200.0)
    pose = look_at((10.0, 20.0, 500.0), (10.0, 20.0, 0.0))
    u, v, a, b, _ = ellipse_from_conic(rim_conic((30.0, 20.0, 0.0), 25.0, (0, 0), pose, k))
    assert (u, v) == pytest.approx((250.0 + 800.0 * 20.0 / 500.0, 200.0))
    assert (a, b) == pytest.approx((40.0, 40.0))


@pytest.mark.slow
def test_labels_over_the_server_equal_render_frame_labels(tmp_path):
    import subprocess

    import cv2

    from render.client import Client
    from tests.render.scenes import descent_scenario
    from tests.render.server_helpers import CRATERSCAPE, served

    stack = cratered_stack(tmp_path / "stack")
    scenario = tmp_path / "s.toml"
    scenario.write_text(descent_scenario(stack, "lab", frames=3)
                        + "[labels]\nmin_crater_pixels = 3.0\n")
    out = tmp_path / "one.png"
    done = subprocess.run([*CRATERSCAPE, "render", "frame", str(scenario), "-o", str(out),
                           "--index", "1"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    truth = json.loads((tmp_path / "one_truth.json").read_text())
    names = truth["labels"]
    assert {"rims", "instances", "semantic", "flow", "occlusion"} <= set(names)
    rims = json.loads((tmp_path / names["rims"]).read_text())
    with served(scenario) as (_proc, port), Client("127.0.0.1", port) as c:
        assert c.info()["protocol_minor"] >= 1
        c.set_pose(truth["camera"]["position"], truth["camera"]["attitude"],
                   time=truth["time"], frame=truth["index"])
        wire = c.get_labels()
        inst, sem, haz = c.get_masks()
    assert wire == json.loads(json.dumps(rims))
    assert np.array_equal(inst, cv2.imread(str(tmp_path / names["instances"]),
                                           cv2.IMREAD_UNCHANGED))
    assert np.array_equal(sem, cv2.imread(str(tmp_path / names["semantic"]),
                                          cv2.IMREAD_UNCHANGED))
    assert np.all(haz == 255)  # no lander in the scenario: hazards unknown everywhere


def test_labels_flag_and_a_bad_labels_table_on_the_command_line(tmp_path):
    from tests.cli_helpers import one_line_error, run
    from tests.render.scenes import descent_scenario

    stack = cratered_stack(tmp_path / "stack")
    plain = tmp_path / "plain.toml"
    plain.write_text(descent_scenario(stack, "plain", frames=2))
    r = run("render", "sequence", plain, "-o", tmp_path / "off", "--resolution", "32x24")
    assert r.exit_code == 0, r.output
    assert not (tmp_path / "off/labels").exists()  # off unless asked
    assert "labels" not in json.loads((tmp_path / "off/truth.json").read_text())[0]
    r = run("render", "frame", plain, "-o", tmp_path / "one.png", "--labels", "--index", "0")
    assert r.exit_code == 0, r.output
    names = json.loads((tmp_path / "one_truth.json").read_text())["labels"]
    assert all((tmp_path / p).is_file() for p in names.values())
    assert names["flow"].startswith("one_labels/")
    bad = tmp_path / "bad.toml"
    bad.write_text(descent_scenario(stack, "bad") + "[labels]\nmasks = true\nflows = false\n")
    one_line_error(run("render", "sequence", bad, "-o", tmp_path / "bad"), "flows", "flow")


def test_an_asteroid_frame_gets_sky_surface_shadow_and_flow_but_no_catalogue_labels(renderer):
    from asteroid.body import Body
    from asteroid.sphere import SphereMesh
    from render.asteroid_scene import AsteroidScene
    from render.camera import quat_from_matrix
    from render.labels import SKY, TERRAIN

    scene = AsteroidScene(Body.sphere(SphereMesh(64), 1000.0), boulders=False)
    k = Intrinsics.from_fov(96, 96, 40.0)
    pose = look_at((0.0, -5000.0, 0.0), (0.0, 0.0, 0.0))
    sun = Lighting((1.0, -0.3, 0.0))
    frame = renderer.render(scene, View(pose, k), sun, RenderOptions(shadow_size=256))
    lab = Labeller(scene, LabelSpec())
    labels = lab.label(frame, pose, k, sun)
    assert labels.craters == [] and labels.instances == []
    assert {SKY, TERRAIN, SHADOWED} <= set(np.unique(labels.semantic).tolist())
    # the body turns 5 degrees about z between frames: the flow follows the surface
    a = math.radians(5.0)
    turn = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])
    lab.add_flow(labels, frame.range, pose, (1, 0, 0, 0), frame.range, pose,
                 tuple(quat_from_matrix(turn)), k)
    centre = labels.flow[48, 48]
    # the sub-camera point moves 5 degrees of the 1000 m sphere across the image
    expected = k.fx * 1000.0 * math.sin(a) / (5000.0 - 1000.0 * math.cos(a))
    assert abs(centre[0]) == pytest.approx(expected, rel=0.02) and abs(centre[1]) < 0.05
