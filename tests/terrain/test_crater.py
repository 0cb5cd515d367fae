"""The crater profile satisfies the constraints Martin et al. (2014, III.A) state in the text."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from terrain.core.tile import DEMTile
from terrain.craters.catalog import Crater, CraterTable
from terrain.craters.crater import (
    BETA_MAX,
    CraterShape,
    ejecta_amplitude,
    exterior_height,
    fresh_depth,
    fresh_rim_height,
    interior_alpha,
    profile,
)
from terrain.craters.cratering import CraterModel, add_craters
from terrain.craters.erosion import ErosionModel, SlopeDegradation

EPS = 1e-6

DEGRADED = [(0.9, 0.75), (0.8, 0.55), (0.65, 0.3), (0.45, 0.1), (0.3, 0.03)]


def slope(shape, x, side, offset=0.0, h=1e-7):
    """One-sided derivative of the profile at x from the left (-1) or right (+1)."""
    if side < 0:
        return (profile(np.array([x]), shape, offset)[0]
                - profile(np.array([x - h]), shape, offset)[0]) / h
    return (profile(np.array([x + h]), shape, offset)[0]
            - profile(np.array([x]), shape, offset)[0]) / h


def curvature(shape, x, side, h=1e-4):
    xs = x + side * np.array([h, 2 * h, 3 * h])
    v = profile(np.r_[x, xs], shape)
    # second derivative from one side (forward/backward difference, second order)
    return (2 * v[0] - 5 * v[1] + 4 * v[2] - v[3]) / h**2


# ---------------------------------------------------------------- eqs. 1-2


@pytest.mark.parametrize("d_m", [1.0, 37.0, 1000.0, 12000.0])
def test_fresh_depth_and_rim_height_follow_melosh_in_kilometres(d_m):
    d_km = d_m / 1000.0
    assert fresh_depth(d_m) == pytest.approx(0.196 * d_km**1.01 * 1000.0, rel=1e-12)
    assert fresh_rim_height(d_m) == pytest.approx(0.036 * d_km**1.01 * 1000.0, rel=1e-12)
    # depth/diameter ~ 0.2 and rim/depth = 0.036 / 0.196 at every size
    assert fresh_depth(d_m) / d_m == pytest.approx(0.196, rel=0.08)
    assert fresh_rim_height(d_m) / fresh_depth(d_m) == pytest.approx(0.036 / 0.196)


def test_ejecta_follows_mcgetchin():
    assert ejecta_amplitude(200.0) == pytest.approx(0.14 * 100.0**0.74)


# ---------------------------------------------------------------- fresh crater


@pytest.mark.parametrize("d", [4.0, 100.0, 3000.0])
def test_fresh_crater_values_and_sharp_crest(d):
    s = CraterShape.from_state(d)
    assert s.alpha == 0.0 and s.beta == 0.0
    v = profile(np.array([-1.0, 0.0, 1.0]), s)
    assert v[0] == pytest.approx(s.rim_height - s.depth)  # floor: depth H below the crest
    assert v[1] == pytest.approx(s.rim_height)  # crest: rim height above the terrain
    assert v[2] == pytest.approx(0.0, abs=1e-9)  # ejecta edge: no change
    assert s.depth == pytest.approx(fresh_depth(d))
    assert s.rim_height == pytest.approx(fresh_rim_height(d))
    # continuous value at the crest, with a kink: the bowl rises, the ejecta falls
    assert profile(np.array([-EPS]), s)[0] == pytest.approx(s.rim_height, abs=1e-4 * d)
    assert profile(np.array([EPS]), s)[0] == pytest.approx(s.rim_height, abs=1e-4 * d)
    assert slope(s, 0.0, -1) > 0.1 * s.depth
    assert slope(s, 0.0, +1) < 0.0


# ---------------------------------------------------------------- degraded crater


@pytest.mark.parametrize("q", DEGRADED)
@pytest.mark.parametrize("d", [10.0, 250.0, 8000.0])
def test_degraded_crater_constraints(d, q):
    s = CraterShape.from_state(d, *q)
    scale = s.depth
    v = profile(np.array([-1.0, 0.0, 1.0]), s)
    assert v[0] == pytest.approx(s.rim_height - s.depth, abs=1e-9 * scale)
    assert v[1] == pytest.approx(s.rim_height, abs=1e-9 * scale)
    assert v[2] == pytest.approx(0.0, abs=1e-9 * scale)
    # alpha inside, beta outside (the printed eq. 8 would make beta negative)
    assert -1.0 < s.alpha < 0.0
    assert 0.0 < s.beta <= BETA_MAX
    # zero rim gradient from both sides
    assert abs(slope(s, 0.0, -1)) < 1e-4 * scale
    assert abs(slope(s, 0.0, +1)) < 1e-4 * scale
    # value and slope continuous at alpha and beta
    for x in (s.alpha, s.beta):
        left = profile(np.array([x - EPS]), s)[0]
        right = profile(np.array([x + EPS]), s)[0]
        assert left == pytest.approx(right, abs=1e-4 * scale)
        assert slope(s, x, -1) == pytest.approx(slope(s, x, +1), abs=1e-3 * scale)
    # curvature continuous at beta (cubic rim meets ejecta + correction)
    assert curvature(s, s.beta, -1) == pytest.approx(curvature(s, s.beta, +1), rel=1e-3,
                                                    abs=1e-3 * scale)
    # the crest is the highest point and the profile falls to the ejecta edge
    x = np.linspace(0.0, 1.0, 2001)
    ext = profile(x, s)
    assert ext.max() == pytest.approx(s.rim_height)
    assert np.all(np.diff(ext) <= 1e-12 * scale)
    # the bowl falls monotonically from the crest to the floor
    x = np.linspace(-1.0, 0.0, 2001)
    assert np.all(np.diff(profile(x, s)) >= -1e-12 * scale)


def test_fully_eroded_crater_is_a_rimless_depression():
    s = CraterShape.from_state(500.0, 0.2, 0.0)
    assert s.rim_height == 0.0
    x = np.linspace(0.0, 1.0, 101)
    assert np.all(profile(x, s) == 0.0)
    assert profile(np.array([-1.0]), s)[0] == pytest.approx(-s.depth)
    assert profile(np.array([-0.5]), s)[0] < 0.0


def test_alpha_and_beta_move_monotonically_with_erosion():
    erosion = ErosionModel.default()
    ages = np.linspace(0.0, 4.0, 81)
    for d in (20.0, 300.0, 5000.0):
        qd, qr = erosion.factors(ages, np.full_like(ages, d))
        shapes = [CraterShape.from_state(d, a, b) for a, b in zip(qd, qr, strict=True)]
        alpha = np.array([s.alpha for s in shapes])
        beta = np.array([s.beta for s in shapes])
        assert alpha[0] == 0.0 and beta[0] == 0.0
        assert np.all(np.diff(alpha) <= 1e-15), "alpha moves towards the centre"
        assert np.all(np.diff(beta) >= -1e-15), "beta moves outwards"


def test_alpha_follows_eq6_with_rim_terrain():
    s = CraterShape.from_state(120.0, 0.7, 0.4)
    for offset in (-0.5, 0.0, 0.3):
        e = s.rim_height + offset
        expected = (s.rim_height + offset - s.fresh_rim_height) / s.bowl_curvature  # eq. 6
        assert interior_alpha(s.bowl_curvature, s.floor, e) == pytest.approx(expected)
        # the interior still reaches the rim at E with zero slope
        assert profile(np.array([0.0]), s, offset)[0] == pytest.approx(e)
        assert abs(slope(s, 0.0, -1, offset)) < 1e-4 * s.depth


@given(d=st.floats(1.0, 20000.0), qd=st.floats(0.05, 1.0), qr=st.floats(0.0, 1.0),
       offset=st.floats(-0.1, 0.1))
def test_profile_joins_hold_for_any_state(d, qd, qr, offset):
    qr = min(qr, qd)
    s = CraterShape.from_state(d, qd, qr)
    off = offset * s.fresh_rim_height
    scale = s.fresh_depth
    # ejecta edge and the exterior's join at beta
    assert profile(np.array([1.0]), s, off)[0] == pytest.approx(0.0, abs=1e-9 * scale)
    if s.beta > 0:
        at = s.beta
        inside = s.rim_height + (s.c2 + s.c3 * at) * at * at
        outside = exterior_height(at, s.rim_height, s.ejecta, s.beta, s.a, s.b, s.c2, s.c3)
        assert inside == pytest.approx(outside, abs=1e-7 * scale)
    # the interior rim reaches E = Hr + Tr - Pr at the crest
    assert profile(np.array([0.0]), s, off)[0] == pytest.approx(s.rim_height + off,
                                                             abs=1e-9 * scale)
    assert np.all(np.isfinite(profile(np.linspace(-1, 1.2, 50), s, off)))


# ---------------------------------------------------------------- on a DEM


def _plane(n, res, gx, gy, z0=100.0):
    rows, cols = np.mgrid[0:n, 0:n]
    x = (cols + 0.5) * res
    y = (n - rows - 0.5) * res
    return z0 + gx * x + gy * y, x, y


@pytest.mark.parametrize("age", [0.0, 0.02, 0.3])
@pytest.mark.parametrize("tilt", [(0.0, 0.0), (0.12, -0.07)])
def test_crater_on_flat_and_tilted_planes_matches_the_profile(age, tilt):
    n, res, d = 161, 0.5, 36.0
    z, x, y = _plane(n, res, *tilt)
    tile = DEMTile.from_array(z, resolution=res)
    cx, cy = 40.3, 39.7
    crater = CraterTable.from_craters([Crater(cx, cy, d, age, 9)])
    out = add_craters(tile, crater, seed=1, model=CraterModel().smooth())
    # a crater on the tilted plane ages faster (terrain.craters.erosion.SlopeDegradation)
    qd, qr = ErosionModel.default().factors(
        SlopeDegradation().effective_age(age, np.arctan(np.hypot(*tilt))), d)
    s = CraterShape.from_state(d, float(qd), float(qr))
    r = np.hypot(x - cx, y - cy)
    xn = 2 * r / d - 1
    change = out.tile.heights.astype(np.float64) - tile.heights.astype(np.float64)
    # inside the rim: plane + h1/h2 - terrain = h (the fitted plane is the terrain);
    # outside: the change h3/h4 itself
    expected = profile(xn, s)
    inside = xn <= 1
    assert np.max(np.abs(change[inside] - expected[inside])) < 2e-4 * d
    # unchanged beyond the ejecta edge, bitwise
    assert np.array_equal(out.tile.heights[~inside], tile.heights[~inside])
    # the catalogue reports what was built
    cat = out.catalog
    assert len(cat.id) == 1
    assert cat.depth_m[0] == pytest.approx(s.depth)
    assert cat.rim_height_m[0] == pytest.approx(s.rim_height)
    assert cat.reference_elevation_m[0] == pytest.approx(100 + tilt[0] * cx + tilt[1] * cy,
                                                           abs=1e-6)


def test_rim_rides_on_the_terrain_along_each_radius():
    """On a slope the rim crest sits Hr above the local terrain, uphill and downhill."""
    n, res, d = 241, 0.5, 50.0
    z, x, y = _plane(n, res, 0.3, 0.0)
    tile = DEMTile.from_array(z, resolution=res)
    cx, cy = 60.0, 60.0
    out = add_craters(tile, CraterTable.from_craters([Crater(cx, cy, d, 0.1, 3)]), seed=1,
                      model=CraterModel().smooth(slope=SlopeDegradation(enabled=False)))
    qd, qr = ErosionModel.default().factors(0.1, d)
    s = CraterShape.from_state(d, float(qd), float(qr))
    for sign in (-1, 1):
        col = int(round((cx + sign * d / 2) / res - 0.5))
        row = int(round((n * res - cy) / res - 0.5))
        gain = out.tile.heights[row, col] - tile.heights[row, col]
        assert gain == pytest.approx(s.rim_height, abs=0.02 * s.rim_height + 1e-3)


def test_craters_sit_on_other_craters():
    """A small crater on a large crater's wall follows the wall (fitted plane is tilted)."""
    n, res = 401, 1.0
    tile = DEMTile.from_array(np.zeros((n, n)), resolution=res)
    big = Crater(200.5, 200.5, 300.0, 0.0, 1)
    small = Crater(200.5 + 100.0, 200.5, 20.0, 0.0, 2)
    both = add_craters(tile, CraterTable.from_craters([big, small]), seed=3,
                       model=CraterModel().smooth())
    cat = both.catalog
    row_small = int(np.flatnonzero(cat.diameter_m == 20.0)[0])
    # the small crater's pre-impact level is the big crater's wall there, well below 0
    assert cat.reference_elevation_m[row_small] < -10.0
    heights = both.tile.heights
    big_only = add_craters(tile, CraterTable.from_craters([big]), seed=3,
                           model=CraterModel().smooth()).tile.heights
    # outside the small crater's footprint the big crater is untouched
    rows, cols = np.mgrid[0:n, 0:n]
    far = np.hypot(cols + 0.5 - 300.5, (n - rows - 0.5) - 200.5) > 20.0 + 1.0
    assert np.array_equal(heights[far], big_only[far])


def test_no_step_at_the_rim_on_rough_ground():
    """The bowl (built on the smoothed rim level) meets the ejecta (on the real terrain)."""
    from terrain.fractal.synthetic import synthesize_tile

    base = synthesize_tile(129, resolution=1.0, relief=40.0, seed=6).tile
    crater = Crater(64.5, 64.5, 70.0, 0.3, 4)
    out = add_craters(base, CraterTable.from_craters([crater]), seed=1,
                      model=CraterModel().smooth()).tile
    rows, cols = np.mgrid[0:129, 0:129]
    x, y = base.xy(rows, cols)
    xn = 2 * np.hypot(x - 64.5, y - 64.5) / 70.0 - 1
    band = np.abs(xn) < 0.06
    z = out.heights.astype(np.float64)
    b = base.heights.astype(np.float64)

    def max_step(h):
        dx = np.abs(np.diff(h, axis=1))[band[:, 1:] & band[:, :-1]]
        dy = np.abs(np.diff(h, axis=0))[band[1:, :] & band[:-1, :]]
        return max(dx.max(), dy.max())

    # the degraded rim has zero slope at its crest: across it, steps are the terrain's own
    assert max_step(z) < 1.3 * max_step(b) + 0.05


# ---------------------------------------------------------------- complex craters


def _flat_crater(d, res, age=0.0, model=None):
    """A crater of diameter d centred on a flat DEM 2.5 d wide: (change, radius) arrays."""
    n = int(round(2.5 * d / res)) | 1
    tile = DEMTile.from_array(np.full((n, n), 500.0), resolution=res)
    c = n * res / 2
    out = add_craters(tile, CraterTable.from_craters([Crater(c, c, d, age, 1)]), seed=1,
                      model=model or CraterModel().smooth())
    rows, cols = np.mgrid[0:n, 0:n]
    r = np.hypot((cols + 0.5) * res - c, (n - rows - 0.5) * res - c)
    return out.tile.heights.astype(np.float64) - 500.0, r, out.catalog


def test_a_40_km_crater_on_a_flat_dem_has_pikes_complex_shape():
    """Depth, rim height, flat floor and central peak of a fresh 40 km lunar crater."""
    d = 40_000.0
    change, r, cat = _flat_crater(d, 200.0)
    d_km = d / 1000
    depth_pike = 1.044 * d_km**0.301 * 1000      # Pike (1977), rim crest to floor
    rim_pike = 0.236 * d_km**0.399 * 1000        # rim crest above the surroundings
    floor_fraction = 0.187 * d_km**1.249 / d_km  # Df / D
    peak = 0.0049 * d_km**1.297 * 1000           # peak height above the floor
    crest = change[np.abs(r - d / 2) < 300].max()
    floor_ring = (r > 0.12 * d) & (r < 0.45 * floor_fraction * d)
    floor = np.median(change[floor_ring])
    assert crest == pytest.approx(rim_pike, rel=0.10)
    assert crest - floor == pytest.approx(depth_pike, rel=0.10)
    # flat floor: between the peak's foot and the documented floor edge the floor is level
    # (to the mm), and just beyond the edge the wall has begun to rise
    assert np.ptp(change[floor_ring]) < 1e-3
    assert np.ptp(change[(r > 0.1 * d) & (r < 0.5 * floor_fraction * d - 100)]) < 1e-3
    wall = change[(r > 0.5 * floor_fraction * d + 1500) & (r < 0.5 * floor_fraction * d + 2000)]
    assert wall.min() > floor + 10.0
    # central peak of the documented height at the centre
    assert change[r < 150].max() - floor == pytest.approx(peak, rel=0.10)
    # the catalogue reports Pike's values
    assert cat.depth_m[0] == pytest.approx(depth_pike, rel=1e-3)
    assert cat.rim_height_m[0] == pytest.approx(rim_pike, rel=1e-3)


def _complex_joins(s):
    """x positions where the complex profile's pieces meet."""
    tiny = 1e-9
    xs = [s.floor_x + tiny, s.peak_x + s.peak_halfwidth]
    for k in range(1, int(s.terraces)):
        xs.append(s.floor_x + k / s.terraces * (-s.floor_x))
    if s.cap_t < 1:
        xs.append(s.floor_x + s.cap_t * (-s.floor_x))
    return xs


@pytest.mark.parametrize("state", [(1.0, 1.0), (0.8, 0.5), (0.5, 0.1)])
@pytest.mark.parametrize("d", [16_000.0, 40_000.0, 120_000.0, 250_000.0])
def test_complex_profile_is_continuous_with_continuous_slope_at_its_joins(d, state):
    s = CraterShape.from_state(d, *state)
    assert s.is_complex
    for x in _complex_joins(s):
        left = profile(np.array([x - 1e-7]), s)[0]
        right = profile(np.array([x + 1e-7]), s)[0]
        assert left == pytest.approx(right, abs=1e-6 * d)
        assert slope(s, x, -1, h=1e-6) == pytest.approx(slope(s, x, +1, h=1e-6),
                                                        abs=1e-3 * s.depth)
    # the floor leaves the wall with zero slope, the peak's foot meets the floor flat
    assert abs(slope(s, s.floor_x, +1, h=1e-6)) < 1e-3 * s.depth
    # the rim stands at Hr on both sides; eroded craters meet it with zero slope (C1)
    assert profile(np.array([-1e-9]), s)[0] == pytest.approx(s.rim_height, abs=1e-6 * d)
    assert profile(np.array([1e-9]), s)[0] == pytest.approx(s.rim_height, abs=1e-6 * d)
    if s.beta > 0:
        assert abs(slope(s, 0.0, -1, h=1e-6)) < 1e-2 * s.depth
        assert abs(slope(s, 0.0, +1, h=1e-6)) < 1e-2 * s.depth
    # the wall rises monotonically from the floor to the rim
    x = np.linspace(s.floor_x, 0.0, 2001)
    assert np.all(np.diff(profile(x, s)) >= -1e-9 * d)
    assert profile(np.array([1.0]), s)[0] == pytest.approx(0.0, abs=1e-9)


def test_peak_ring_replaces_the_central_peak_at_basin_sizes():
    central = CraterShape.from_state(150_000.0)
    ring = CraterShape.from_state(250_000.0)
    xs = np.linspace(-1.0, -0.3, 701)
    pc, pr = profile(xs, central), profile(xs, ring)
    assert xs[np.argmax(pc)] == pytest.approx(-1.0)
    assert xs[np.argmax(pr)] == pytest.approx(-0.5, abs=2e-3)   # ring diameter 0.5 D
    assert pr[np.argmax(pr)] - ring.floor == pytest.approx(ring.peak_height, rel=1e-6)
    assert pr[0] == pytest.approx(ring.floor)                  # no peak at the centre


def test_transition_diameter_decides_the_morphology():
    from terrain.craters.crater import Morphology

    assert not CraterShape.from_state(14_000.0).is_complex
    assert CraterShape.from_state(16_000.0).is_complex
    lower = Morphology(transition_diameter=5_000.0)
    assert CraterShape.from_state(8_000.0, morphology=lower).is_complex
    off = Morphology(enabled=False)
    s = CraterShape.from_state(40_000.0, morphology=off)
    assert not s.is_complex and s.depth == pytest.approx(fresh_depth(40_000.0))
    with pytest.raises(ValueError, match="did you mean 'peak_ring_diameter'"):
        Morphology.from_mapping({"peak_ring_diamter": 1e5})
    with pytest.raises(ValueError, match="must exceed"):
        Morphology(transition_diameter=2e5, peak_ring_diameter=1e5)


def test_complex_crater_erodes_in_the_ross_framework():
    """Older complex craters are shallower, with lower rims and peaks, and softer terraces."""
    fresh = CraterShape.from_state(40_000.0)
    old = CraterShape.from_state(40_000.0, 0.6, 0.3)
    assert old.depth == pytest.approx(0.6 * fresh.depth)
    assert old.rim_height == pytest.approx(0.3 * fresh.rim_height)
    assert old.peak_height == pytest.approx(0.6 * fresh.peak_height)
    assert old.terrace_strength < fresh.terrace_strength


def test_steep_ground_degrades_craters_faster():
    """The same crater on a 20 degree slope is shallower than on flat ground, unless off."""
    d, res = 40.0, 0.5
    model = CraterModel().smooth()
    flat, r, cat_flat = _flat_crater(d, res, age=0.05, model=model)
    n = flat.shape[0]
    z, x, y = _plane(n, res, np.tan(np.radians(20.0)), 0.0)
    tile = DEMTile.from_array(z, resolution=res)
    c = n * res / 2
    crater = CraterTable.from_craters([Crater(c, c, d, 0.05, 1)])
    steep = add_craters(tile, crater, seed=1, model=model).catalog
    off = add_craters(tile, crater, seed=1,
                      model=model.smooth(slope=SlopeDegradation(enabled=False))).catalog
    assert steep.depth_m[0] < 0.9 * cat_flat.depth_m[0]
    assert off.depth_m[0] == pytest.approx(cat_flat.depth_m[0])
    assert steep.rim_height_m[0] <= off.rim_height_m[0]
