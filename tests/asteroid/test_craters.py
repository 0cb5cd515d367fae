"""Craters on the curved mesh: the flat profile in true distance, order, limits, erosion."""

import math

import numpy as np
import pytest
from scipy import stats

from asteroid.body import Body
from asteroid.catalog import CRATER_COLUMNS
from asteroid.craters import (
    CraterModel,
    CraterSettings,
    SlopeErosion,
    add_craters,
    craters_at,
    max_diameter,
    sample_craters,
)
from asteroid.sphere import SphereMesh
from terrain.core.errors import InvalidParameterError
from terrain.craters.crater import CraterShape, profile
from terrain.craters.population import Population

R = 100_000.0
MESH = SphereMesh(128)
SMOOTH = CraterModel().smooth()


def _arc(mesh, centre, radius):
    u = mesh.directions()
    c = np.asarray(centre) / np.linalg.norm(centre)
    return radius * np.arctan2(np.linalg.norm(np.cross(u, c), axis=1), u @ c)


@pytest.mark.parametrize("lat,lon", [(20.0, 33.0), (90.0, 0.0), (-1.0, 359.9), (-75.0, 200.0)])
def test_fresh_crater_on_a_large_sphere_is_the_flat_profile_in_true_distance(lat, lon):
    body = Body.sphere(MESH, R)
    spacing = MESH.mean_spacing * R
    d = 40 * spacing
    crater = craters_at([lat], [lon], [d])
    result = add_craters(body, crater, seed=1, model=SMOOTH)
    dr = result.body.radii - R
    s = _arc(MESH, crater.directions[0], R)
    x = 2 * s / d - 1
    shape = CraterShape.from_state(d)
    near = x <= 1.0
    expected = profile(x[near], shape)
    # the flat-triangle surface under the centre lies a chord below the sphere (R (a/2)^2 / 2)
    chord = R * (MESH.mean_spacing / 2) ** 2
    assert np.abs(dr[near] - expected).max() < chord + 1e-6 * d
    assert np.all(dr[~near] == 0.0)                         # nothing beyond the ejecta edge
    floor = dr.min()
    rim = dr.max()
    assert -floor == pytest.approx(shape.depth - shape.rim_height, rel=0.05)
    assert rim == pytest.approx(shape.rim_height, rel=0.05)
    row = result.catalog
    assert row.depth_m[0] == pytest.approx(shape.depth)
    assert row.rim_height_m[0] == pytest.approx(shape.rim_height)
    assert row.slope_deg[0] < 0.1 and row.applied[0] == 1


def test_crater_positions_are_uniform_over_equal_area_cells():
    from asteroid.boulders import icosahedron

    body = Body.sphere(SphereMesh(8), 5000.0)
    pop = Population(dmin=20.0, dmax=100.0, density=300.0, sfd_exponent=-2.0)
    craters = sample_craters(pop, body, seed=3)
    assert len(craters) > 50_000
    v, f = icosahedron()
    centres = v[f].mean(axis=1)
    cells = np.argmax(craters.directions @ centres.T, axis=1)
    assert stats.chisquare(np.bincount(cells, minlength=20)).pvalue > 0.01
    # counts from the SFD over the body's area
    expected = pop.expected_count(body.area() / 1e6)
    assert abs(len(craters) - expected) < 5 * math.sqrt(expected)


def test_craters_are_applied_oldest_first():
    mesh = SphereMesh(64)
    body = Body.sphere(mesh, 1000.0)
    big, small = 300.0, 60.0
    at_small = int(np.argmin(_arc(mesh, craters_at([0.0], [3.0], [1.0]).directions[0], 1.0)))

    def depression(big_age, small_age):
        """How much lower the surface is at the small crater than with the big one alone."""
        alone = add_craters(body, craters_at([0.0], [0.0], [big], [big_age]), seed=1,
                            model=SMOOTH).body.radii
        both = craters_at([0.0, 0.0], [0.0, 3.0], [big, small], [big_age, small_age])
        r = add_craters(body, both, seed=1, model=SMOOTH).body.radii
        return alone[at_small] - r[at_small]

    small_depth = CraterShape.from_state(small).depth
    assert depression(0.02, 0.01) > 0.5 * small_depth      # the young small crater survives
    assert abs(depression(0.01, 0.02)) < 0.15 * small_depth  # the young big one erased it


def test_slope_erosion_reduces_craters_on_steep_slopes():
    mesh = SphereMesh(64)
    u = mesh.directions()
    d = 100.0

    def on_ramp(slope_deg):
        # radial heights rising along -x near the crater at (0, 90): a plane of this slope
        t = math.tan(math.radians(slope_deg))
        body = Body(mesh, 1000.0, 1000.0 - t * 1000.0 * np.clip(u[:, 0], -0.4, 0.4))
        return body, add_craters(body, craters_at([0.0], [90.0], [d]), seed=2, model=SMOOTH)

    _, gentle = on_ramp(10.0)
    assert gentle.catalog.slope_factor[0] == 1.0
    body, steep = on_ramp(40.0)
    assert steep.catalog.slope_deg[0] == pytest.approx(40.0, abs=1.0)
    assert steep.catalog.slope_factor[0] == pytest.approx(0.5, abs=0.05)
    fresh = CraterShape.from_state(d)
    assert steep.catalog.depth_m[0] == pytest.approx(0.5 * fresh.depth, rel=0.1)
    body, cliff = on_ramp(55.0)
    assert cliff.catalog.applied[0] == 0 and cliff.catalog.slope_factor[0] == 0.0
    assert np.array_equal(cliff.body.radii, body.radii)
    # switched off, the crater keeps its full depth on the same slope
    off = CraterSettings(SMOOTH, slope=SlopeErosion(enabled=False))
    body, kept = on_ramp(40.0)
    kept = add_craters(body, craters_at([0.0], [90.0], [d]), seed=2, settings=off)
    assert kept.catalog.depth_fraction[0] == 1.0


def test_maximum_extent_is_enforced():
    body = Body.sphere(SphereMesh(8), 1000.0)
    assert max_diameter(1000.0) == pytest.approx(1000.0 * math.pi / 6)
    with pytest.raises(InvalidParameterError, match="beyond the maximum extent of 60 degrees"):
        add_craters(body, craters_at([0.0], [0.0], [600.0]), seed=1)
    with pytest.raises(InvalidParameterError, match="largest allowed is 523.599 m"):
        sample_craters(Population(dmin=10.0, dmax=600.0, density=1.0), body, seed=1)
    wide = CraterSettings(max_extent_deg=90.0)
    add_craters(body, craters_at([0.0], [0.0], [600.0]), seed=1, settings=wide)


def test_same_seed_same_surface_and_a_full_catalogue():
    mesh = SphereMesh(48)
    body = Body.sphere(mesh, 2000.0)
    pop = Population(dmin=60.0, dmax=500.0, density=20.0, sfd_exponent=-2.0)
    craters = sample_craters(pop, body, seed=5)
    a = add_craters(body, craters, seed=5)
    b = add_craters(body, craters, seed=5)
    c = add_craters(body, craters, seed=6)
    assert np.array_equal(a.body.radii, b.body.radii)
    assert not np.array_equal(a.body.radii, c.body.radii)   # roughness keyed by the seed
    assert a.catalog.columns == CRATER_COLUMNS
    assert len(a.catalog) == len(craters)
    assert np.all(np.diff(a.catalog.age_gyr) <= 0)        # age order, oldest first
    assert a.catalog.applied.sum() == len(craters)
    assert a.body.radii.min() < 2000.0 and a.body.metadata["craters"]["count"] == len(craters)


def test_bad_explicit_craters():
    with pytest.raises(InvalidParameterError, match="latitudes"):
        craters_at([95.0], [0.0], [1.0])
    with pytest.raises(InvalidParameterError, match="diameters"):
        craters_at([0.0], [0.0], [-1.0])
    with pytest.raises(InvalidParameterError, match="slope erosion"):
        SlopeErosion(50.0, 30.0)


def test_rim_joins_rough_terrain_without_a_step():
    from asteroid.noise import PerlinNoise

    mesh = SphereMesh(96)
    radius = 1000.0
    rough = PerlinNoise(octaves=6, frequency=12.0, persistence=0.6, amplitude=0.01)
    body = Body(mesh, radius, rough.radii(mesh, radius, seed=3))
    d = 20 * mesh.mean_spacing * radius
    crater = craters_at([5.0], [40.0], [d])
    out = add_craters(body, crater, seed=1, model=SMOOTH).body.radii
    rc = body.surface_radius(crater.directions)[0]     # distances are arcs at this radius
    x = 2 * _arc(mesh, crater.directions[0], rc) / d - 1
    shape = CraterShape.from_state(d)
    # just outside, the ejecta rides on the terrain: old height plus the profile, exactly
    outside = (x > 0) & (x < 0.03)
    assert np.allclose(out[outside], body.radii[outside] + profile(x[outside], shape))
    # just inside, the bowl meets it at the same height: no step of the terrain's relief
    # (metres here) between the inner wall and the ejecta
    inside = (x > -0.03) & (x <= 0)
    relief = body.radii[np.abs(x) < 0.05].std()
    step = np.abs(out[inside] - body.radii[inside] - profile(x[inside], shape))
    assert relief > 2.0
    assert np.percentile(step, 95) < 0.25 * shape.rim_height


def test_complex_crater_on_a_large_sphere_is_the_flat_complex_profile():
    """A 40 km crater on a 100 km body: flat floor, peak and Pike's depth, in true distance."""
    body = Body.sphere(MESH, R)
    d = 40_000.0
    crater = craters_at([30.0], [40.0], [d])
    result = add_craters(body, crater, seed=1, model=SMOOTH)
    dr = result.body.radii - R
    s = _arc(MESH, crater.directions[0], R)
    x = 2 * s / d - 1
    shape = CraterShape.from_state(d)
    assert shape.is_complex
    near = x <= 1.0
    chord = R * (MESH.mean_spacing / 2) ** 2
    assert np.abs(dr[near] - profile(x[near], shape)).max() < chord + 1e-6 * d
    floor = (x > shape.peak_x + shape.peak_halfwidth + 0.02) & (x < shape.floor_x - 0.02)
    assert np.ptp(dr[floor]) < 2 * chord
    top = np.argmin(x)  # the vertex nearest the centre, on the peak
    rho = (x[top] + 1.0) / shape.peak_halfwidth
    assert dr[top] - np.median(dr[floor]) == pytest.approx(
        shape.peak_height * (1 - rho**2) ** 2, rel=0.05)
    assert dr[top] - np.median(dr[floor]) > 0.8 * shape.peak_height
    assert result.catalog.depth_m[0] == pytest.approx(1.044 * 40**0.301 * 1000, rel=1e-3)
