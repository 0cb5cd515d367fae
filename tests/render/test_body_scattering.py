"""Sunlight a body scatters into its own shadows (render.body_scattering).

The reference is a hemispherical bowl: every beam of sunlight entering its opening (area
pi R^2, seen from a sun at elevation e as pi R^2 sin e) lands once on its inside, and inside
a sphere an element sees every other element dA with the view factor dA / (4 pi R^2)
(cos t_i = cos t_j = r / 2R). So every point of the bowl, sunlit or in the rim's shadow,
receives E / F = A sin(e) / 4 of the solar irradiance from a Lambertian inside of albedo A.
"""

import math

import numpy as np
import pytest

ALBEDO = 0.25


def _bowl(n_theta=12, n_phi=32, radius=1.0):
    """The lower half of a sphere of ``radius``, faces wound towards its centre."""
    verts = [(0.0, 0.0, -radius)]
    for i in range(1, n_theta + 1):
        th = 0.5 * math.pi * i / n_theta
        for k in range(n_phi):
            ph = 2.0 * math.pi * k / n_phi
            verts.append((radius * math.sin(th) * math.cos(ph),
                          radius * math.sin(th) * math.sin(ph), -radius * math.cos(th)))
    v = np.array(verts)

    def ring(i, k):
        return 1 + (i - 1) * n_phi + k % n_phi

    faces = [(0, ring(1, k), ring(1, k + 1)) for k in range(n_phi)]
    for i in range(1, n_theta):
        for k in range(n_phi):
            a, b, c, d = ring(i, k), ring(i, k + 1), ring(i + 1, k), ring(i + 1, k + 1)
            faces += [(a, c, d), (a, d, b)]
    f = np.array(faces)
    cross = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    assert np.all(np.einsum("ij,ij->i", cross, -v[f].mean(axis=1)) > 0), "wound inwards"
    return v, f


def _sun(elevation_deg):
    e = math.radians(elevation_deg)
    return np.array([math.cos(e), 0.0, math.sin(e)])


@pytest.fixture(scope="module")
def bowl_light():
    from render.body_scattering import BodyLight

    v, f = _bowl()
    return v, BodyLight(v, f)


@pytest.mark.parametrize("elevation", [90.0, 30.0, 10.0])
def test_every_point_of_a_bowl_receives_a_quarter_of_what_enters_it(bowl_light, elevation):
    """E / F = A sin(e) / 4 within 10 % on the rim's shadow and below a third of the depth.

    (The sunlit strip just under the rim of a bowl under a low sun is a few faces wide: its
    own vertices, lit by their neighbours, are where the patches are too coarse.)
    """
    v, light = bowl_light
    s = _sun(elevation)
    e = light.irradiance(s, ALBEDO, snap=False)
    expected = ALBEDO * math.sin(math.radians(elevation)) / 4.0
    n = -v / np.linalg.norm(v, axis=1, keepdims=True)
    beyond = v - 2.0 * (v @ s)[:, None] * s  # where a ray to the sun meets the sphere again
    shadowed = (v[:, 2] < -0.05) & ((n @ s <= 0) | (beyond[:, 2] < -1e-9))
    deep = v[:, 2] < -0.3
    if elevation < 45:
        assert shadowed.sum() > 100
    for where in (shadowed, deep):
        assert np.all(np.abs(e[where] / expected - 1.0) < 0.10)


def test_a_convex_body_scatters_nothing_into_itself():
    """No two outward faces of a convex body see each other."""
    from asteroid.sphere import SphereMesh
    from render.body_scattering import BodyLight

    mesh = SphereMesh(8)
    d = mesh.directions()
    light = BodyLight(d * np.array([3.0, 2.0, 1.0]), mesh.faces())
    assert light.pairs == 0
    assert np.all(light.irradiance((1.0, 0.5, 0.2), 0.3) == 0)


def test_sun_lattice_is_fixed_and_near():
    """A sun snaps to the same lattice point whatever came before, within the spacing."""
    from render.body_scattering import SUN_STEP_DEG, snap_direction

    rng = np.random.default_rng(3)
    for s in rng.normal(size=(200, 3)):
        p = np.array(snap_direction(s))
        assert abs(np.linalg.norm(p) - 1.0) < 1e-12
        angle = math.degrees(math.acos(min(1.0, float(p @ (s / np.linalg.norm(s))))))
        assert angle <= SUN_STEP_DEG
        assert snap_direction(p) == tuple(p)


def test_bad_patch_meshes_are_refused():
    from render.body_scattering import BodyLight
    from terrain.core.errors import InvalidParameterError

    with pytest.raises(InvalidParameterError, match="faces"):
        BodyLight(np.zeros((3, 3)), np.array([[0, 1, 5]]))
    with pytest.raises(InvalidParameterError, match="vertices"):
        BodyLight(np.zeros((3, 2)), np.array([[0, 1, 2]]))


def test_rendered_bowl_shadow_holds_the_scattered_light(renderer):
    """A Lambertian bowl's shadowed floor renders as I/F = A E/F (= A^2 sin e / 4); off, 0."""
    from render.camera import Intrinsics, look_at
    from render.mesh_scene import MeshScene
    from render.renderer import Lighting, RenderOptions, View

    v, f = _bowl(16, 48, radius=100.0)
    scene = MeshScene(v, f)
    elevation = 25.0
    light = Lighting(tuple(_sun(elevation)), albedo=ALBEDO, brdf="lambert")
    view = View(look_at((0.0, 0.0, 400.0), (0.0, 0.0, -50.0), up=(0.0, 1.0, 0.0)),
                Intrinsics.from_fov(96, 96, 40.0))
    on = renderer.render(scene, view, light, RenderOptions(soft_shadows=False))
    off = renderer.render(scene, view, light, RenderOptions(soft_shadows=False,
                                                             scattering=False))
    expected = ALBEDO * ALBEDO * math.sin(math.radians(elevation)) / 4.0
    shadow = np.isfinite(off.range) & (off.radiance == 0)
    assert shadow.sum() > 50, "the rim shades part of the floor"
    ratio = on.radiance[shadow] / expected
    assert np.all(np.abs(ratio - 1.0) < 0.10), (ratio.min(), ratio.max())
    # where sunlit, the scattered light adds the same to the direct light
    lit = np.isfinite(off.range) & (off.radiance > 0.02)
    assert np.allclose(on.radiance[lit] - off.radiance[lit], expected, rtol=0.15)


@pytest.mark.parametrize("phase", [0.0, 60.0, 90.0])
def test_a_far_lambert_sphere_lights_a_second_body_as_its_phase_law_says(phase):
    """A Lambertian sphere of radius a and albedo A at distance d and phase angle g sends
    E / F = (2/3) A (a/d)^2 (sin g + (pi - g) cos g) / pi onto a surface facing it (its
    geometric albedo 2A/3 and the Lambert sphere's phase law; Russell 1916, ApJ 43, 173):
    within 5 % at 30 radii."""
    from asteroid.sphere import SphereMesh
    from render.body_scattering import BodyLight, mutual_irradiance

    mesh = SphereMesh(16)
    d = mesh.directions()
    source, receiver = BodyLight(d * 1.0, mesh.faces()), BodyLight(d * 0.2, mesh.faces())
    g = math.radians(phase)
    distance = 30.0  # the source's centre at -x from the receiver's
    e = mutual_irradiance(receiver, source, np.eye(3), (-distance, 0.0, 0.0),
                          (math.cos(g), math.sin(g), 0.0), ALBEDO)
    facing = int(np.argmin(d[:, 0]))
    r = distance - 0.2
    expected = 2.0 / 3.0 * ALBEDO / r**2 * (math.sin(g) + (math.pi - g) * math.cos(g)) / math.pi
    assert e[facing] == pytest.approx(expected, rel=0.05)
    assert np.all(e[d[:, 0] > 0.2] == 0), "the far side sees nothing of it"


def test_a_fine_mesh_is_clustered_and_keeps_the_bowls_light():
    """A 19,000-face bowl clustered to at most 1,500 faces still receives A sin(e) / 4
    within 10 % on the rim's shadow and below a third of the depth (a 30 degree sun)."""
    from render.body_scattering import BodyLight, cluster_mesh

    v, f = _bowl(60, 160)
    cv, cf = cluster_mesh(v, f, 1500)
    assert len(cf) <= 1500 and len(f) > 10 * len(cf)
    light = BodyLight(cv, cf)
    s = _sun(30.0)
    e = light.irradiance(s, ALBEDO, snap=False)
    expected = ALBEDO * 0.5 / 4.0
    n = -cv / np.linalg.norm(cv, axis=1, keepdims=True)
    beyond = cv - 2.0 * (cv @ s)[:, None] * s
    shadowed = (cv[:, 2] < -0.05) & ((n @ s <= 0) | (beyond[:, 2] < -1e-9))
    for where in (shadowed, cv[:, 2] < -0.3):
        assert where.sum() > 50
        assert np.all(np.abs(e[where] / expected - 1.0) < 0.10)


def test_a_fine_mesh_scene_renders_the_clustered_light(renderer):
    """A mesh scene above PATCH_FACES faces gets its light from the clustered patch mesh:
    its shadowed floor renders I/F = A^2 sin(e) / 4 within 15 %."""
    from render.body_scattering import PATCH_FACES
    from render.camera import Intrinsics, look_at
    from render.mesh_scene import MeshScene
    from render.renderer import Lighting, RenderOptions, View

    v, f = _bowl(60, 160, radius=100.0)
    assert len(f) > PATCH_FACES
    scene = MeshScene(v, f)
    light = Lighting(tuple(_sun(30.0)), albedo=ALBEDO, brdf="lambert")
    view = View(look_at((0.0, 0.0, 400.0), (0.0, 0.0, -50.0), up=(0.0, 1.0, 0.0)),
                Intrinsics.from_fov(96, 96, 40.0))
    on = renderer.render(scene, view, light, RenderOptions(soft_shadows=False))
    off = renderer.render(scene, view, light, RenderOptions(soft_shadows=False,
                                                             scattering=False))
    expected = ALBEDO * ALBEDO * 0.5 / 4.0
    shadow = np.isfinite(off.range) & (off.radiance == 0)
    assert shadow.sum() > 50
    ratio = on.radiance[shadow] / expected
    assert np.all(np.abs(ratio - 1.0) < 0.15), (ratio.min(), ratio.max())
