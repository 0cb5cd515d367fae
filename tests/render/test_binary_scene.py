"""Binary scenes: mutual shadows, occlusion and body labels against rays cast in numpy.

The bodies are spheres, so every reference here is an exact ray-sphere intersection computed
independently of the renderer: which sphere a pixel's ray meets first, and whether the ray
from that surface point towards the Sun meets the other sphere.
"""

import numpy as np
import pytest

from render.camera import Intrinsics, look_at
from render.orbit import MutualOrbit
from render.renderer import Lighting, RenderOptions, View

R1, R2 = 390.0, 80.0        # Didymos-like sphere radii (m)
#: Pixels whose rays pass within this many metres of a sphere's limb or of the shadow's
#: edge are left out: a pixel's footprint (~4 m here) and the mesh's facets decide them.
EDGE_M = 9.0


def _sphere_hit(origin, rays, centre, radius):
    """Distance along unit rays to a sphere (inf where missed) and the closest approach."""
    oc = np.asarray(origin, dtype=np.float64) - centre
    b = rays @ oc                      # < 0 where the centre lies ahead
    cc = oc @ oc
    disc = b * b - (cc - radius**2)
    t = np.where(disc >= 0, -b - np.sqrt(np.maximum(disc, 0.0)), np.inf)
    t = np.where(t > 0, t, np.inf)
    closest = np.sqrt(np.maximum(cc - np.where(b < 0, b * b, 0.0), 0.0))
    return t, closest


@pytest.fixture(scope="module")
def binary():
    from asteroid.body import Body
    from asteroid.sphere import SphereMesh
    from render.binary_scene import BinaryScene

    return BinaryScene(Body.sphere(SphereMesh(64), R1), Body.sphere(SphereMesh(32), R2),
                       orbit=MutualOrbit(mean_anomaly=30.0, inclination=10.0, node=20.0),
                       boulders=False)


def _geometry(binary, t=0.0):
    (c1, _), (c2, _) = binary.body_poses(t)
    sun = c2 - c1
    sun /= np.linalg.norm(sun)
    sun = sun + np.array([0.0, 0.0, 0.25])  # the secondary a little off the sub-solar point
    return c1, c2, sun / np.linalg.norm(sun)


def _analytic(binary, pose, k, t):
    """Reference labels, ranges and shadows of every pixel by exact ray casting."""
    c1, c2, sun = _geometry(binary, t)
    o = np.asarray(pose.position, dtype=np.float64)
    rays = (k.rays() @ pose.rotation.T).reshape(-1, 3)
    t1, a1 = _sphere_hit(o, rays, c1, R1)
    t2, a2 = _sphere_hit(o, rays, c2, R2)
    label = np.where(np.isinf(t1) & np.isinf(t2), 0, np.where(t1 <= t2, 1, 2))
    limb = (np.abs(a1 - R1) < EDGE_M) | (np.abs(a2 - R2) < EDGE_M)
    rng = np.minimum(t1, t2)
    # from the primary's surface point towards the Sun: does the ray meet the secondary?
    p = o + rays * np.where(np.isinf(t1), 0.0, t1)[:, None]
    oc = p - c2
    b = oc @ sun
    miss = np.sqrt(np.maximum(np.einsum("ij,ij->i", oc, oc) - b * b, 0.0))
    shadow = (b < 0) & (miss < R2)
    shadow_edge = (b < 0) & (np.abs(miss - R2) < EDGE_M)
    facing = ((p - c1) / R1) @ sun
    shape = (k.height, k.width)
    return (label.reshape(shape), rng.reshape(shape), limb.reshape(shape),
            shadow.reshape(shape), shadow_edge.reshape(shape), facing.reshape(shape))


def _render(renderer, binary, pose, k, t, **options):
    _, _, sun = _geometry(binary, t)
    light = Lighting(tuple(sun), albedo=0.2, brdf="lommel-seeliger")
    view = View(pose, k, t)
    frame = renderer.render(binary, view, light, RenderOptions(**options))
    return frame, binary.body_ids(view, frame)


def test_the_secondarys_shadow_falls_where_rays_to_the_sun_meet_it(renderer, binary):
    c1, _, sun = _geometry(binary)
    side = np.cross(sun, [0.0, 0.0, 1.0])
    u = np.cos(np.radians(25)) * sun + np.sin(np.radians(25)) * side / np.linalg.norm(side)
    pose = look_at(c1 + 2600.0 * u, c1)
    k = Intrinsics.from_fov(192, 192, 24.0)
    frame, ids = _render(renderer, binary, pose, k, 0.0)
    label, _, limb, shadow, edge, facing = _analytic(binary, pose, k, 0.0)
    # lit side of the primary, away from the shadow's edge and the limb
    judged = (label == 1) & (ids == 1) & ~limb & ~edge & (facing > 0.05)
    dark = frame.radiance < 1e-6
    assert shadow[judged].sum() > 400, "the test's geometry must put a shadow in view"
    agree = (dark[judged] == shadow[judged]).mean()
    assert agree == 1.0, f"{(dark[judged] != shadow[judged]).sum()} pixels disagree"
    # and the shadow is the secondary's: without shadows those pixels are lit
    bright, _ = _render(renderer, binary, pose, k, 0.0, shadows=False)
    assert np.all(bright.radiance[judged & shadow] > 0.01)


def test_the_body_id_image_and_mutual_occlusion_match_the_spheres(renderer, binary):
    c1, c2, _ = _geometry(binary)
    # from beyond the secondary: it stands in front of the primary
    away = (c2 - c1) / np.linalg.norm(c2 - c1)
    up = np.cross(away, [0.0, 0.0, 1.0])
    cam = c2 + 900.0 * away + 150.0 * up / np.linalg.norm(up)
    pose = look_at(cam, c1)
    k = Intrinsics.from_fov(160, 160, 40.0)
    # the finest level of detail: its flat facets lie a few cm inside the sphere, a little
    # more along the oblique rays near the limb
    frame, ids = _render(renderer, binary, pose, k, 0.0, lod_pixels=0.1)
    label, rng, limb, *_ = _analytic(binary, pose, k, 0.0)
    judged = ~limb
    assert np.array_equal(ids[judged], label[judged])
    assert (label[judged] == 1).sum() > 500 and (label[judged] == 2).sum() > 500
    # the secondary hides the primary: where both spheres lie on a ray, the nearer is seen
    rays = (k.rays() @ pose.rotation.T).reshape(-1, 3)
    t1, _ = _sphere_hit(np.asarray(cam), rays, c1, R1)
    both = (np.isfinite(t1).reshape(label.shape) & (label == 2)) & judged
    assert both.sum() > 100
    err = np.abs(frame.range[both] - rng[both])
    assert err.max() < 0.15, f"range off by up to {err.max():.3f} m where occluded"
    assert np.all(frame.range[both] < t1.reshape(label.shape)[both] - 100.0)
    # each body's normals point out of its own centre (the sphere's normal at the hit)
    hit = (np.asarray(cam) + rays * rng.reshape(-1)[:, None]).reshape(*label.shape, 3)
    for body, centre, radius in ((1, c1, R1), (2, c2, R2)):
        sel = judged & (label == body)
        expected = (hit[sel] - centre) / radius
        assert np.einsum("ij,ij->i", frame.normals[sel], expected).min() > 0.995


def test_the_secondary_moves_on_its_orbit_between_frames(renderer, binary):
    """A quarter period later the secondary is where Kepler puts it (its pixels follow)."""
    t = binary.orbit.period / 4
    (c1, _), (c2, _) = binary.body_poses(t)
    pose = look_at(c1 + np.array([0.0, 0.0, 3000.0]) + 10.0, c1)
    k = Intrinsics.from_fov(128, 128, 60.0)
    _, ids = _render(renderer, binary, pose, k, t, shadows=False)
    label, _, limb, *_ = _analytic(binary, pose, k, t)
    assert (label == 2).sum() > 20
    assert np.array_equal(ids[~limb], label[~limb])


def test_the_primary_eclipses_the_secondary(renderer, binary):
    """With the primary between the Sun and the secondary, the secondary lies in its shadow."""
    (c1, _), (c2, _) = binary.body_poses(0.0)
    sun = (c1 - c2) / np.linalg.norm(c1 - c2)
    side = np.cross(sun, [0.0, 0.0, 1.0])
    # from the sunward side and off the line of centres, so the lit face is in view
    cam = c2 + 600.0 * (0.5 * sun + side / np.linalg.norm(side))
    pose = look_at(cam, c2)
    k = Intrinsics.from_fov(96, 96, 30.0)
    light = Lighting(tuple(sun), albedo=0.2, brdf="lommel-seeliger")
    view = View(pose, k, 0.0)
    frame = renderer.render(binary, view, light, RenderOptions())
    ids = binary.body_ids(view, frame)
    facing = np.einsum("ijk,k->ij", np.nan_to_num(frame.normals), sun) > 0.1
    lit_face = (ids == 2) & facing
    assert lit_face.sum() > 200
    assert np.all(frame.radiance[lit_face] < 1e-6)  # total eclipse: 390 m hides 80 m
    bright = renderer.render(binary, view, light, RenderOptions(shadows=False))
    assert np.all(bright.radiance[lit_face] > 0.01)


def test_a_shape_file_can_be_the_secondary(renderer, binary, tmp_path):
    """A closed mesh file stands for a body: drawn, labelled and shadowed like a native one."""
    from asteroid.meshio.export import write_mesh
    from asteroid.sphere import SphereMesh
    from render.binary_scene import BinaryScene

    mesh = SphereMesh(32)
    write_mesh(tmp_path / "moon.ply", [("body", mesh.directions() * R2, mesh.faces())])
    mixed = BinaryScene(binary.bodies[0], tmp_path / "moon.ply", orbit=binary.orbit)
    assert mixed.bodies[1].kind == "mesh"
    c1, c2, _ = _geometry(mixed)
    away = (c2 - c1) / np.linalg.norm(c2 - c1)
    up = np.cross(away, [0.0, 0.0, 1.0])
    pose = look_at(c2 + 900.0 * away + 150.0 * up / np.linalg.norm(up), c1)
    k = Intrinsics.from_fov(96, 96, 40.0)
    _, ids = _render(renderer, mixed, pose, k, 0.0, lod_pixels=0.1)
    label, _, limb, *_ = _analytic(mixed, pose, k, 0.0)
    assert (label[~limb] == 2).sum() > 100
    assert np.array_equal(ids[~limb], label[~limb])


def test_a_binarys_body_is_shaded_with_its_finest_normals_as_alone(renderer):
    """A rough primary drawn at a coarse level: its shading normals are the single body's
    (its cube map of the finest normals, looked up about its own centre), not the level's."""
    from asteroid.body import Body
    from asteroid.sphere import SphereMesh
    from render.asteroid_scene import AsteroidScene
    from render.binary_scene import BinaryScene

    mesh = SphereMesh(128)
    d = mesh.directions()
    lon, lat = np.arctan2(d[:, 1], d[:, 0]), np.arcsin(d[:, 2])
    radii = R1 * (1.0 + 0.01 * np.sin(40 * lon) * np.cos(40 * lat))  # ~60 m bumps, 4 m high
    rough = Body(mesh, R1, radii)
    binary = BinaryScene(AsteroidScene(rough, boulders=False, imposter_pixels=0.0),
                         Body.sphere(SphereMesh(16), R2), orbit=binary_orbit(), boulders=False)
    t = 0.0
    (c1, q1), (c2, _) = binary.body_poses(t)
    away = np.array([0.3, -1.0, 0.4])
    pose = look_at(c1 + 2500.0 * away / np.linalg.norm(away), c1)
    k = Intrinsics.from_fov(96, 96, 30.0)
    light = Lighting((0.6, -0.7, 0.35), albedo=0.2, brdf="lommel-seeliger")
    options = RenderOptions(shadows=False, lod_pixels=12.0)
    pair = renderer.render(binary, View(pose, k, t), light, options)
    ids = binary.body_ids(View(pose, k, t), pair)
    alone = AsteroidScene(rough, boulders=False, imposter_pixels=0.0)
    alone.set_body_rotation(q1)
    moved = look_at(np.asarray(pose.position) - c1, (0.0, 0.0, 0.0))
    single = renderer.render(alone, View(moved, k, t), light, options)
    assert pair.drawn["primary"]["body_magnitude"] < 128  # a coarse level is drawn
    both = (ids == 1) & np.isfinite(single.range)
    assert both.sum() > 1000
    cos = np.einsum("ij,ij->i", pair.normals[both], single.normals[both])
    assert np.degrees(np.arccos(np.clip(cos, -1, 1))).max() < 1.0
    # and the bumps show: the shading normals stray from the sphere's radial direction
    rays = (k.rays() @ pose.rotation.T).reshape(96, 96, 3)
    rays /= np.linalg.norm(rays, axis=2, keepdims=True)
    pts = np.asarray(pose.position) + rays * pair.range[..., None]
    radial = (pts[both] - c1) / np.linalg.norm(pts[both] - c1, axis=1, keepdims=True)
    stray = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", pair.normals[both], radial),
                                         -1, 1)))
    assert np.median(stray) > 3.0


def binary_orbit():
    return MutualOrbit(mean_anomaly=30.0, inclination=10.0, node=20.0)
