"""Bodies of any closed shape: sites keyed by position, craters along the normal, boulders."""

from __future__ import annotations

import math

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.spatial import cKDTree

from asteroid.packing import marching_tetrahedra, packing_body
from asteroid.shape import ShapeModel, winding_number
from asteroid.sphere import SphereMesh
from asteroid.surface import (
    MeshBody,
    Sites,
    add_mesh_craters,
    face_areas,
    load_mesh_native,
    place_mesh_boulders,
    refine,
    sample_sites,
)
from terrain.craters.crater import fresh_depth, fresh_rim_height
from terrain.craters.cratering import CraterModel
from terrain.craters.population import Population


def _surface_points(vertices, faces, n, seed):
    """Points uniform by area on a mesh (numpy's generator: an independent sampler)."""
    rng = np.random.default_rng(seed)
    a = face_areas(vertices, faces)
    f = rng.choice(len(faces), size=n, p=a / a.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    p0, p1, p2 = (vertices[faces[f, i]] for i in range(3))
    return p0 + u[:, None] * (p1 - p0) + v[:, None] * (p2 - p0)


def _closest_on_triangles(p, a, b, c):
    """Closest points of triangles (a, b, c) to points p, all (n, 3) (Ericson 2004, 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = np.einsum("ij,ij->i", ab, ap), np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3, d4 = np.einsum("ij,ij->i", ab, bp), np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5, d6 = np.einsum("ij,ij->i", ab, cp), np.einsum("ij,ij->i", ac, cp)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    denom = va + vb + vc
    v = np.where(denom != 0, vb / np.where(denom == 0, 1, denom), 0)
    w = np.where(denom != 0, vc / np.where(denom == 0, 1, denom), 0)
    out = a + v[:, None] * ab + w[:, None] * ac
    with np.errstate(divide="ignore", invalid="ignore"):
        cases = [
            ((d1 <= 0) & (d2 <= 0), a),
            ((d3 >= 0) & (d4 <= d3), b),
            ((d6 >= 0) & (d5 <= d6), c),
            ((vc <= 0) & (d1 >= 0) & (d3 <= 0), a + (d1 / (d1 - d3))[:, None] * ab),
            ((vb <= 0) & (d2 >= 0) & (d6 <= 0), a + (d2 / (d2 - d6))[:, None] * ac),
            ((va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0),
             b + ((d4 - d3) / ((d4 - d3) + (d5 - d6)))[:, None] * (c - b)),
        ]
    done = np.zeros(len(p), bool)
    for cond, q in cases:
        sel = cond & ~done
        out[sel] = q[sel]
        done |= sel
    return out


def _distance_to_surface(points, vertices, faces, k=160):
    """Distance from points to a triangle mesh (exact over the k triangles nearest by centroid;
    k is large because marching tetrahedra leave long slivers whose centroids lie far away)."""
    tri = vertices[faces]
    _, near = cKDTree(tri.mean(axis=1)).query(points, k=k)
    best = np.full(len(points), np.inf)
    for j in range(k):
        t = tri[near[:, j]]
        q = _closest_on_triangles(points, t[:, 0], t[:, 1], t[:, 2])
        best = np.minimum(best, np.linalg.norm(points - q, axis=1))
    return best


def _hausdorff(a_mesh, b_mesh, n=40_000):
    """Symmetric Hausdorff distance, over both meshes' vertices and points sampled on them."""
    pa = np.concatenate([a_mesh[0], _surface_points(*a_mesh, n, 1)])
    pb = np.concatenate([b_mesh[0], _surface_points(*b_mesh, n, 2)])
    return max(_distance_to_surface(pa, *b_mesh).max(), _distance_to_surface(pb, *a_mesh).max())


@pytest.fixture(scope="module")
def binary():
    return packing_body("contact-binary", radius=1000.0, seed=1, cells=48)


def test_packing_presets_are_closed_and_not_star_shaped():
    for name in ("contact-binary", "67p-like"):
        body = packing_body(name, radius=1000.0, seed=1, cells=48)
        body.check_closed()
        assert body.equivalent_radius == pytest.approx(1000.0, rel=1e-9)
        projection = ShapeModel.from_arrays(body.vertices, body.faces).project(SphereMesh(32))
        # rays from the centre cross the neck's surface more than once
        assert projection.non_star_fraction > 0.01, name


def test_marching_tetrahedra_sphere_volume():
    step = 0.05
    axis = np.arange(-1.3, 1.3 + step / 2, step)
    x, y, z = np.meshgrid(axis, axis, axis, indexing="ij")
    values = np.sqrt(x * x + y * y + z * z) - 1.0
    v, f = marching_tetrahedra(values, (axis[0],) * 3, step)
    body = MeshBody(v, f)
    body.check_closed()
    assert body.volume() == pytest.approx(4.0 / 3.0 * math.pi, rel=0.01)
    assert np.abs(np.linalg.norm(v, axis=1) - 1.0).max() < 0.01


def test_sites_are_uniform_by_area_and_keyed_by_position(binary):
    pop = Population(dmin=20.0, dmax=200.0, density=400.0, sfd_exponent=-2.0)
    a = sample_sites(binary.vertices, binary.faces, pop, seed=7, stream=11)
    b = sample_sites(binary.vertices, binary.faces, pop, seed=7, stream=11)
    assert np.array_equal(a.points, b.points) and np.array_equal(a.uid, b.uid)
    # a patch alone (half the triangles, in another order) draws exactly its own features
    half = np.arange(len(binary.faces))[::-2]
    patch = sample_sites(binary.vertices, binary.faces[half], pop, seed=7, stream=11)
    mine = np.isin(a.face, half)
    assert sorted(patch.uid.tolist()) == sorted(a.uid[mine].tolist())
    # count against the population's expectation (Poisson, 5 sigma)
    expected = pop.expected_count(binary.area() * 1e-6)
    assert abs(len(a) - expected) < 5 * math.sqrt(expected)
    # uniform by area: the share on each side of the neck follows the area there
    areas = face_areas(binary.vertices, binary.faces)
    left = binary.vertices[binary.faces].mean(axis=1)[:, 0] < 0
    share = float(areas[left].sum() / areas.sum())
    assert abs(np.mean(a.points[:, 0] < 0) - share) < 5 * math.sqrt(share * (1 - share) / len(a))
    # diameters follow N(>D) ~ D^k: maximum likelihood index of a truncated power law
    d = a.diameters
    k_hat = -len(d) / np.sum(np.log(d / pop.dmin))
    assert abs(k_hat - (-2.0)) < 0.15


def test_refinement_is_local_and_conforming(binary):
    centre = binary.vertices[0]
    v, f, rounds = refine(binary.vertices, binary.faces, centre[None], np.array([30.0]))
    assert rounds >= 2
    MeshBody(v, f).check_closed()
    tri = v[f]
    longest = np.max(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2), axis=1)
    near = np.linalg.norm(tri.mean(axis=1) - centre, axis=1) < 30.0
    assert longest[near].max() <= 30.0 / 4.0
    far = np.linalg.norm(tri.mean(axis=1) - centre, axis=1) > 300.0
    # far from the crater the triangles are those of the base
    base_far = np.linalg.norm(binary.vertices[binary.faces].mean(axis=1) - centre, axis=1) > 300
    assert far.sum() == base_far.sum()


def test_fresh_crater_depth_along_the_normal():
    """On a large sphere a fresh crater's floor lies the fresh depth below the surface."""
    mesh = SphereMesh(64)
    radius = 20_000.0
    body = MeshBody(mesh.directions() * radius, mesh.faces())
    normal = np.array([0.3, -0.5, 0.8])
    normal /= np.linalg.norm(normal)
    d = 400.0
    sites = Sites(np.array([0]), normal[None] * radius, np.array([d]), np.array([0.0]),
                  np.array([5], np.uint64), np.zeros((1, 0)))
    out = add_mesh_craters(body, sites, seed=1,
                           settings=_fresh_settings())
    out.body.check_closed()
    r = np.linalg.norm(out.body.vertices, axis=1)
    # Melosh's fresh depth is rim crest to floor: the floor lies H0 - Hr0 below the ground,
    # the crest Hr0 above it (the sphere sags R (1 - cos(s/R)) < 1 m under the bowl here)
    assert radius - r.min() == pytest.approx(float(fresh_depth(d) - fresh_rim_height(d)),
                                             rel=0.03)
    # the crest is sampled every D / 4 (the refinement's edge) and the sphere lies
    # d^2 / (8 R) = 1 m below the tangent plane at the rim
    sag = d * d / (8.0 * radius)
    assert r.max() - radius + sag == pytest.approx(float(fresh_rim_height(d)), rel=0.1)
    deepest = out.body.vertices[np.argmin(r)]
    assert np.linalg.norm(deepest / np.linalg.norm(deepest) - normal) < 0.1 * d / radius
    # nothing moves beyond the ejecta's reach
    moved = np.linalg.norm(out.body.vertices[:body.n_vertices] - body.vertices, axis=1) > 0
    reach = np.linalg.norm(body.vertices[moved] - normal * radius, axis=1)
    assert reach.max() <= 1.05 * d * CraterModel().footprint_factor


def test_an_irregular_rim_on_the_mesh_follows_the_rim_table():
    """The rim crest of a mesh crater lies at D/2 + rho(theta) D along each azimuth, rho the
    latitude/longitude path's rim table for the crater's identity (keyed by position)."""
    from asteroid.craters import CraterSettings
    from asteroid.surface import _tangents
    from terrain.craters.overlay import RIM_SAMPLES, RimIrregularity, periodic_sample, rim_table

    mesh = SphereMesh(64)
    radius = 20_000.0
    normal = np.array([0.3, -0.5, 0.8])
    normal /= np.linalg.norm(normal)
    site = normal * radius
    d = 400.0
    v, f, _ = refine(mesh.directions() * radius, mesh.faces(), site[None], np.array([d]),
                     edges_per_diameter=80.0)
    body = MeshBody(v, f)
    uid = np.array([0x5EED], np.uint64)
    sites = Sites(np.array([0]), site[None], np.array([d]), np.array([0.0]), uid,
                  np.zeros((1, 0)))
    import dataclasses

    model = dataclasses.replace(CraterModel().smooth(),
                                rim=RimIrregularity(amplitude=0.1, hurst=0.7))
    out = add_mesh_craters(body, sites, seed=1, settings=CraterSettings(model),
                           refine_mesh=False)
    out.body.check_closed()
    table = np.zeros(RIM_SAMPLES)
    rim_table(1, uid[0], 0.1, 0.7, table)
    n = np.array([out.catalog[k][0] for k in ("nx", "ny", "nz")])
    e1, e2 = _tangents(n)
    rel = out.body.vertices - site
    x, y, h = rel @ e1, rel @ e2, rel @ n
    s, theta = np.hypot(x, y), np.arctan2(y, x)
    near = s < 1.5 * d
    bins = np.linspace(-np.pi, np.pi, 25)
    crest, expected = [], []
    for lo, hi in zip(bins[:-1], bins[1:], strict=True):
        sel = np.flatnonzero(near & (theta >= lo) & (theta < hi))
        crest.append(s[sel[np.argmax(h[sel])]])
        expected.append(0.5 * d + periodic_sample(table, 0.5 * (lo + hi)) * d)
    crest, expected = np.array(crest), np.array(expected)
    edge = d / 80.0
    assert np.abs(crest - expected).max() < 3.0 * edge + 0.02 * d  # the wedge's width
    assert np.ptp(expected) > 0.05 * d  # an irregular rim, followed
    assert np.corrcoef(crest, expected)[0, 1] > 0.9


def _fresh_settings():
    from asteroid.craters import CraterSettings

    return CraterSettings(CraterModel().smooth())


@pytest.mark.slow
def test_shape_model_through_the_command_line(tmp_path, binary):
    """A non-star-shaped shape model keeps its volume and surface, craters and boulders on it."""
    from asteroid.cli import asteroid

    source = tmp_path / "binary.obj"
    lines = [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in binary.vertices / 1000.0]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in binary.faces]
    source.write_text("\n".join(lines) + "\n")
    out = tmp_path / "body.npz"
    args = ["build", "--base", f"shape:{source}", "--magnitude", "48", "--seed", "3",
            "--craters", "density=8,dmin=10,dmax=30",
            "--boulders", "density=20,dmin=2,dmax=10,levels=2", "-o", str(out)]
    result = CliRunner().invoke(asteroid, args)
    assert result.exit_code == 0, result.output
    assert "not star-shaped" in result.output
    body, tables = load_mesh_native(out)
    body.check_closed()
    assert len(tables["craters"]["id"]) > 50 and tables["craters"]["applied"].sum() > 50
    assert body.volume() == pytest.approx(binary.volume(), rel=0.01)
    mean_radius = float(np.mean(np.linalg.norm(binary.vertices, axis=1)))
    assert _hausdorff((binary.vertices, binary.faces), (body.vertices, body.faces)) \
        < 0.005 * mean_radius
    # same seed, same bytes
    again = tmp_path / "again.npz"
    CliRunner().invoke(asteroid, args[:-1] + [str(again)])
    assert again.read_bytes() == out.read_bytes()
    # boulders: centres outside the body, each touching its surface
    cat = tables["boulders"]
    assert len(cat["id"]) > 20
    centres = np.column_stack([cat["x_m"], cat["y_m"], cat["z_m"]])
    gap = _distance_to_surface(centres, body.vertices, body.faces)
    for c in centres[:20]:
        assert winding_number(body.vertices, body.faces, c) < 0.5
    # a centre sits at most its boulder's size above the surface (resting, not floating)
    assert np.all(gap <= cat["diameter_m"])


@pytest.mark.slow
def test_packing_base_with_craters_and_boulders():
    from asteroid.build import build
    from asteroid.recipe import Recipe

    recipe = Recipe.from_sources(base="packing:67p-like", magnitude=48, radius=1500.0, seed=2,
                                 craters={"density": 2.0, "dmin": 15.0, "dmax": 40.0},
                                 boulders={"density": 5.0, "dmin": 3.0, "dmax": 15.0,
                                           "levels": 2})
    result = build(recipe)
    body = result.body
    body.check_closed()
    base = packing_body("67p-like", radius=1500.0, seed=2, cells=96)
    assert body.volume() == pytest.approx(base.volume(), rel=0.01)
    assert result.report["craters_applied"] > 20 and result.report["boulders"] > 10
    mean_radius = float(np.mean(np.linalg.norm(base.vertices, axis=1)))
    assert _hausdorff((base.vertices, base.faces), (body.vertices, body.faces)) \
        < 0.005 * mean_radius


def test_boulders_rest_on_their_facet():
    """Each boulder's lowest point lies its burial depth below its facet, its centre above."""
    mesh = SphereMesh(16)
    body = MeshBody(mesh.directions() * 50_000.0, mesh.faces())
    pop = Population(dmin=5.0, dmax=50.0, density=0.2, sfd_exponent=-3.0, max_age=0.0)
    b = place_mesh_boulders(body, pop, seed=4)
    assert len(b) > 100
    cat = b.catalog
    a = body.vertices[body.faces[cat["face"], 0]]
    n = np.column_stack([cat["nx"], cat["ny"], cat["nz"]])
    verts = b.vertices.reshape(len(b), -1, 3)
    above = np.einsum("nvi,ni->nv", verts - a[:, None, :], n)
    assert np.allclose(above.min(axis=1), -cat["burial_depth_m"], atol=1e-6)
    centre = np.column_stack([cat["x_m"], cat["y_m"], cat["z_m"]])
    assert np.all(np.einsum("ni,ni->n", centre - a, n) > 0)
    assert np.all(cat["burial_depth_m"] < 0.5 * cat["height_m"])


def test_gravitational_slopes_on_a_contact_binary(binary):
    from evaluation.meshslope import mesh_slopes

    s = mesh_slopes(binary.vertices, binary.faces, radius_deg=0.0, coarse_faces=2000)
    assert np.all(np.isfinite(s.gravitational_deg))
    # a rubble-pile shape at rest: most of the surface below the angle of repose (Eros's
    # slopes at ~300 m scale are nearly all below 35 degrees, Thomas et al. 2002)
    order = np.argsort(s.gravitational_deg)
    cum = np.cumsum(s.vertex_area[order]) / s.vertex_area.sum()
    assert s.gravitational_deg[order][np.searchsorted(cum, 0.5)] < 35.0


def test_icq_shape_model_is_read_closed(tmp_path):
    """An ICQ file (cube faces of (Q + 1)^2 vertices) reads as one closed, outward surface."""
    from asteroid.meshio.read import read_mesh

    q, radius = 8, 2.0
    t = -1.0 + 2.0 * np.arange(q + 1) / q
    u, v = np.meshgrid(t, t, indexing="ij")
    one = np.ones_like(u)
    blocks = [(one, u, v), (-one, v, u), (u, one, v), (v, -one, u), (u, v, one),
              (v, u, -one)]
    lines = [str(q)]
    for x, y, z in blocks:
        p = np.stack([x, y, z], axis=-1).reshape(-1, 3)
        p = radius * p / np.linalg.norm(p, axis=1, keepdims=True)
        lines += [f"{a:.9f} {b:.9f} {c:.9f}" for a, b, c in p]
    path = tmp_path / "ball.icq"
    path.write_text("\n".join(lines) + "\n")
    vertices, faces = read_mesh(path)
    assert len(vertices) == 6 * q * q + 2
    model = ShapeModel.from_arrays(vertices, faces)
    # a cube-sphere of Q = 8 holds within 2 % of the ball's volume, from below
    assert 0.97 < model.volume / (4.0 / 3.0 * math.pi * radius**3) < 1.0


@pytest.mark.slow
def test_a_real_non_star_shaped_shape_through_the_command_line(tmp_path, shared_file):
    """Itokawa's Gaskell model (its folded neck crosses some rays from the centre twice),
    kept as its own mesh: volume within 1 %, surface within 0.5 % of the mean radius
    (Hausdorff), watertight, with craters and boulders. The mean radius is 168 m, so the
    craters are those whose depth stays below 0.8 m (D <= 3.5 m)."""
    from asteroid.cli import asteroid
    from asteroid.meshio.read import read_mesh
    from asteroid.shape import ShapeModel

    source = shared_file("asteroids", "itokawa_gaskell_q32.obj")
    shape = ShapeModel.read(source, units="km")
    projection = shape.project(SphereMesh(64))
    assert projection.non_star_fraction > 0  # not star-shaped: some directions fold
    config = tmp_path / "itokawa.toml"
    config.write_text(f'base = "shape:{source}"\nmagnitude = 48\nseed = 4\n'
                      '[shape]\nkeep = "always"\n')
    out = tmp_path / "itokawa.ply"
    args = ["build", "--config", str(config), "--craters", "density=300,dmin=2,dmax=3.5",
            "--boulders", "density=2000,dmin=2,dmax=8,levels=2", "-o", str(out)]
    result = CliRunner().invoke(asteroid, args)
    assert result.exit_code == 0, result.output
    body, tables = load_mesh_native(out.with_suffix(".npz"))
    body.check_closed()
    assert tables["craters"]["applied"].sum() > 20 and len(tables["boulders"]["id"]) > 20
    v0, f0 = np.asarray(shape.vertices), np.asarray(shape.faces)
    assert body.volume() == pytest.approx(MeshBody(v0, f0).volume(), rel=0.01)
    mean_radius = float(np.mean(np.linalg.norm(v0, axis=1)))
    assert _hausdorff((v0, f0), (body.vertices, body.faces)) < 0.005 * mean_radius
    written, _ = read_mesh(out)  # the mesh file holds the body and its boulders
    assert len(written) > body.n_vertices
