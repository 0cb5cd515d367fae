"""Terrain presets against published lunar statistics, on large synthetic areas.

Each test compares what the pipeline makes with a published measurement (crater depth/diameter
of counted small craters, the equilibrium density, the angle of repose, the LOLA slope law),
measured with tools independent of the generator (the evaluation's Horn slope and bidirectional
slope curve).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from evaluation.slope import horn_slope
from evaluation.validate import slope_curve
from terrain.core.presets import preset
from terrain.core.tile import DEMTile, Window
from terrain.fractal.rmd import synthesize
from terrain.fractal.synthetic import synthesize_tile
from terrain.stages.dems import crater_model, population, preset_relief, repose
from terrain.stages.specs import SynthSpec
from terrain.surface.repose import Repose, relax_to_repose

#: Stopar et al. (2017, Icarus 298, 34): fresh small simple craters have d/D 0.14-0.2 ...
FRESH_DD = (0.14, 0.20)
#: ... and crater counts stop near d/D 0.04 (degraded past visibility).
COUNT_FLOOR_DD = 0.04
#: Trask (1966): N(>=D) = 10^-1.1 D^-2 per m^2, D in metres.
TRASK = 10 ** -1.1


def _preset_tile(size, resolution, *, dmin, dmax, seed=3, relief=None, fd=None, relax=True):
    spec = SynthSpec.from_mapping(dict(terrain="south-polar", size=size,
                                       resolution=resolution, dmin=dmin, dmax=dmax))
    pop = population(spec, resolution=resolution, extent=(size - 1) * resolution)
    model = crater_model(spec).smooth()
    f, r = preset_relief(preset("south-polar"), size, resolution)
    return synthesize_tile(size, resolution=resolution, fractal_dimension=fd or f,
                           relief=r if relief is None else relief, seed=seed, craters=pop,
                           model=model, repose=repose(spec) if relax else None)


@pytest.fixture(scope="module")
def flat_craters():
    """10-100 m craters of the south-polar preset on 1 km^2 of flat ground (2 m pixels)."""
    return _preset_tile(513, 2.0, dmin=10.0, dmax=100.0, relief=0.0, relax=False)


def test_visible_small_craters_have_the_observed_depth_diameter(flat_craters):
    c = flat_craters.catalog
    dd = c.depth_m / c.diameter_m
    assert len(dd) > 300
    assert dd.min() >= COUNT_FLOOR_DD - 1e-3          # nothing degraded past visibility kept
    p90 = np.percentile(dd, 90)
    assert FRESH_DD[0] <= p90 <= FRESH_DD[1]          # the freshest are fresh, not deeper
    # a population spread between fresh and the counting floor, not piled at either end
    assert COUNT_FLOOR_DD < np.percentile(dd, 10) < 0.06
    assert 0.07 < dd.mean() < 0.14


def test_visible_small_craters_stay_near_equilibrium(flat_craters):
    c = flat_craters.catalog
    xmin, ymin, xmax, ymax = flat_craters.tile.bounds
    inside = (c.x_m >= xmin) & (c.x_m <= xmax) & (c.y_m >= ymin) & (c.y_m <= ymax)
    area = (xmax - xmin) * (ymax - ymin)
    for d in (10.0, 20.0, 40.0):
        n = np.count_nonzero(inside & (c.diameter_m >= d)) / area
        assert n == pytest.approx(TRASK * d ** -2, rel=0.25)


def _steep_share_outside_fresh(result):
    tile, c = result.tile, result.catalog
    fresh = Repose().fresh_mask(tile.shape, tile.transform, c.x_m, c.y_m, c.diameter_m,
                                c.age_gyr)
    slope = horn_slope(tile, edges="mask")
    old = ~fresh & np.isfinite(slope)
    assert old.mean() > 0.3
    return np.mean(slope[old] > 35.0)


def test_old_slopes_roll_over_at_repose():
    # rough ground (1 m pixels, F 2.6, median Horn slope ~17 deg) with equilibrium craters
    kw = dict(dmin=4.0, dmax=64.0, relief=3.0, fd=2.6)
    assert _steep_share_outside_fresh(_preset_tile(257, 1.0, relax=False, **kw)) > 0.02
    # at most 0.5 % of the ground outside craters younger than 100 Myr above 35 deg
    assert _steep_share_outside_fresh(_preset_tile(257, 1.0, **kw)) <= 0.005


def test_repose_relaxation_keeps_known_heights_and_volume():
    z = synthesize(65, fractal_dimension=2.5, relief=3.0, seed=4)
    assert np.mean(horn_slope(DEMTile.from_array(z.astype(np.float32))) > 35.0) > 0.05
    known = np.zeros(z.shape, bool)
    known[::4, ::4] = True
    out, changed = relax_to_repose(z, 1.0, 35.0, movable=~known, iterations=400)
    assert np.array_equal(out[known], z[known])
    assert not changed[known].any()
    # Horn's slope of the relaxed cells: at repose, allowing for the pinned known cells
    s = horn_slope(DEMTile.from_array(out.astype(np.float32)))
    assert np.mean(s[1:-1, 1:-1] > 36.0) < 0.005


def test_repose_window_equals_full_run():
    full = _preset_tile(129, 1.0, dmin=4.0, dmax=32.0, relief=40.0, fd=2.3)
    spec = SynthSpec.from_mapping(dict(terrain="south-polar", size=129, resolution=1.0,
                                       dmin=4.0, dmax=32.0))
    pop = population(spec, resolution=1.0, extent=128.0)
    f, _ = preset_relief(preset("south-polar"), 129, 1.0)
    win = Window(40, 20, 50, 60)
    part = synthesize_tile(129, resolution=1.0, fractal_dimension=2.3, relief=40.0, seed=3,
                           craters=pop, model=crater_model(spec).smooth(),
                           repose=repose(spec), window=win)
    assert f == pytest.approx(2.05)
    np.testing.assert_array_equal(part.tile.heights,
                                  full.tile.heights[20:80, 40:90])


def _law(baseline, p):
    return math.degrees(math.atan(math.tan(math.radians(p.slope_17m_deg))
                                  * (baseline / 17.0) ** (p.hurst - 1.0)))


def test_kilometre_base_follows_the_lola_law():
    # the demo's base: 1 km pixels, the south-polar preset, craters from 4 km
    p = preset("south-polar")
    spec = SynthSpec.from_mapping(dict(terrain="south-polar", size=257, resolution=1000.0,
                                       dmin=4000.0, dmax=60000.0, density=0.004))
    f, r = preset_relief(p, 257, 1000.0)
    tile = synthesize_tile(257, resolution=1000.0, fractal_dimension=f, relief=r, seed=2014,
                           craters=population(spec, resolution=1000.0, extent=256e3),
                           model=crater_model(spec), repose=repose(spec)).tile
    curve = slope_curve(tile, max_lag=8)
    assert curve.baseline_m[0] == 1000.0
    assert curve.median_deg[0] == pytest.approx(_law(1000.0, p), abs=1.0)
    # beyond the self-affine range the slopes fall at least as fast as the law's
    assert np.all(curve.median_deg[1:] <= [_law(b, p) + 1.0 for b in curve.baseline_m[1:]])


@pytest.mark.slow
@pytest.mark.parametrize("name", ["south-polar", "maria"])
def test_synth_preset_follows_the_lola_slope_law(name):
    # 17 m pixels over six 8.7 km tiles (a large area: one tile's median slope at H 0.95 is
    # its regional tilt, 6.6 to 10 deg between seeds), baselines 17 m - 1 km, pooled
    p = preset(name)
    spec = SynthSpec.from_mapping(dict(terrain=name, size=513, resolution=17.0))
    f, r = preset_relief(p, 513, 17.0)
    pooled: dict[float, list] = {}
    for seed in range(1, 7):
        z = synthesize_tile(513, resolution=17.0, fractal_dimension=f, relief=r, seed=seed,
                            craters=population(spec, resolution=17.0, extent=512 * 17.0),
                            model=crater_model(spec).smooth(),
                            repose=repose(spec)).tile.heights.astype(np.float64)
        lag = 1
        while lag * 17.0 <= p.self_affine_max_m * 1.1:
            d = np.concatenate([(z[:, lag:] - z[:, :-lag]).ravel(),
                                (z[lag:, :] - z[:-lag, :]).ravel()])
            pooled.setdefault(lag * 17.0, []).append(np.abs(d))
            lag *= 2
    for b, parts in pooled.items():
        m = math.degrees(math.atan(float(np.median(np.concatenate(parts))) / b))
        assert m == pytest.approx(_law(b, p), abs=1.0), (b, m)


def test_large_craters_are_as_many_as_the_surface_received():
    # Neukum et al. (2001): a 3.9 Gyr surface has received N(>=1 km) ~ 3.3e-2 per km^2, under
    # Trask's equilibrium (7.9e-2); below ~400 m the equilibrium is the smaller
    spec = SynthSpec.from_mapping(dict(terrain="south-polar", dmin=200.0, dmax=8000.0))
    pop = population(spec, resolution=50.0, extent=1e6)
    side = 400e3
    t = pop.generate(5, (0.0, 0.0, side, side))
    area_km2 = (side / 1e3) ** 2
    n1 = np.count_nonzero(t.diameter >= 1000.0) / area_km2
    assert n1 == pytest.approx(3.3e-2, rel=0.1)
    n200 = np.count_nonzero(t.diameter >= 200.0) / area_km2
    assert n200 == pytest.approx(TRASK * 200.0 ** -2 * 1e6, rel=0.15)


def test_synth_terrain_option(tmp_path):
    from terrain.io import read_dem
    from tests.cli_helpers import one_line_error, run

    out, cat = tmp_path / "t.tif", tmp_path / "c.csv"
    r = run("terrain", "synth", "-o", out, "--size", 129, "--resolution", 2.0,
            "--terrain", "maria", "--seed", 1, "--catalog", cat)
    assert r.exit_code == 0, r.output
    meta = read_dem(out).metadata
    assert '"terrain": "maria"' in meta["CRATERSCAPE_PARAMETERS"]
    assert '"angle_deg": 35.0' in meta["CRATERSCAPE_REPOSE"]
    assert cat.exists()
    # a window of the preset's tile is the same pixels of the full run
    win = tmp_path / "w.tif"
    assert run("terrain", "synth", "-o", win, "--size", 129, "--resolution", 2.0,
               "--terrain", "maria", "--seed", 1, "--window", "30,20,40,50").exit_code == 0
    np.testing.assert_array_equal(read_dem(win).heights, read_dem(out).heights[20:70, 30:70])
    bad = run("terrain", "synth", "-o", tmp_path / "b.tif", "--terrain", "mare")
    assert bad.exit_code == 2
    one_line_error(bad, "--terrain", "mare")


def test_stack_relaxation_never_moves_known_heights(tmp_path):
    from terrain.fractal.roughness import RoughnessChoice
    from terrain.stack.build import build_stack
    from terrain.stack.store import read_stack, write_stack

    # a rough real-like base with a gap: relaxation may touch only what the stack synthesizes
    base = synthesize_tile(33, resolution=8.0, fractal_dimension=2.6, relief=60.0, seed=2).tile
    heights = base.heights.copy()
    heights[10:14, 12:18] = np.nan
    base = base.replace(heights=heights, valid=np.isfinite(heights))
    stack = build_stack(base, (132.0, 132.0), levels=3, layer_size=33, seed=1,
                        params=RoughnessChoice(2.3, 0.3), repose=Repose())
    known = np.isfinite(heights)
    for k, layer in enumerate(stack.layers):
        r0, c0 = layer.origin
        step = 2 ** k
        tile = layer.tile
        rows = np.arange(tile.shape[0]) + r0
        cols = np.arange(tile.shape[1]) + c0
        on = np.ix_(np.flatnonzero(rows % step == 0), np.flatnonzero(cols % step == 0))
        base_idx = np.ix_(rows[rows % step == 0] // step, cols[cols % step == 0] // step)
        colocated = tile.heights[on]
        mask = known[base_idx]
        np.testing.assert_array_equal(colocated[mask], heights[base_idx][mask])
    plain = build_stack(base, (132.0, 132.0), levels=3, layer_size=33, seed=1,
                        params=RoughnessChoice(2.3, 0.3))
    assert any(not np.array_equal(a.tile.heights, b.tile.heights)
               for a, b in zip(stack.layers, plain.layers, strict=True))  # it did relax
    assert stack.info["repose"]["angle_deg"] == 35.0
    write_stack(stack, tmp_path / "s")
    assert read_stack(tmp_path / "s").info["repose"] == stack.info["repose"]


@pytest.mark.parametrize("win", [(0, 0, 20, 30), (17, 23, 25, 19), (40, 41, 25, 24)])
def test_relaxation_of_a_grown_window_equals_the_whole_tile(win):
    z = synthesize(65, fractal_dimension=2.6, relief=6.0, seed=9)
    movable = np.ones(z.shape, bool)
    movable[::5, ::7] = False
    full, _ = relax_to_repose(z, 1.0, 35.0, movable=movable, iterations=30)
    c, r, w, h = win
    halo = 31
    r0, c0 = max(0, r - halo), max(0, c - halo)
    r1, c1 = min(65, r + h + halo), min(65, c + w + halo)
    part, _ = relax_to_repose(z[r0:r1, c0:c1], 1.0, 35.0, movable=movable[r0:r1, c0:c1],
                              iterations=30)
    np.testing.assert_array_equal(part[r - r0:r - r0 + h, c - c0:c - c0 + w],
                                  full[r:r + h, c:c + w])


def test_chunked_stack_relaxes_as_the_in_memory_stack(tmp_path):
    import rasterio

    from terrain.craters.population import Population
    from terrain.execution.chunked import open_reader
    from terrain.fractal.roughness import ExpansionParameters
    from terrain.io import read_dem, write_dem
    from terrain.stack.build import build_stack
    from terrain.stack.chunkedlayers import build_stack_chunked
    from terrain.stack.store import read_stack

    tile = synthesize_tile(65, resolution=4.0, fractal_dimension=2.6, relief=40.0, seed=2).tile
    h = tile.heights.copy()
    h[40:44, 10:15] = np.nan
    tile = DEMTile(h, np.isfinite(h), tile.transform,
                   rasterio.crs.CRS.from_epsg(32633).to_wkt(), -9999.0, {})
    write_dem(tile, tmp_path / "base.tif")
    pop = Population(dmin=2.0, dmax=40.0, density=2e5, max_age=0.3)
    params = ExpansionParameters(2.3, 0.3, 4.0, 64)
    args = dict(levels=2, layer_size=33, seed=3, population=pop, params=params,
                repose=Repose(iterations=20))
    mem = build_stack(read_dem(tmp_path / "base.tif", exact=True), (130.0, 130.0), **args)
    plain = build_stack(read_dem(tmp_path / "base.tif", exact=True), (130.0, 130.0),
                        **{**args, "repose": None})
    assert any(not np.array_equal(a, b) for a, b in zip(
        [t.heights for t in mem.tiles], [t.heights for t in plain.tiles], strict=True))
    build_stack_chunked(open_reader(tmp_path / "base.tif"), tmp_path / "chunked",
                        (130.0, 130.0), chunk=16, **args)
    chunked = read_stack(tmp_path / "chunked")
    for a, b in zip(mem.tiles, chunked.tiles, strict=True):
        np.testing.assert_array_equal(a.heights, b.heights)


def test_chunked_synth_with_a_preset_equals_the_whole_tile(tmp_path):
    from terrain.io import read_dem
    from tests.cli_helpers import run

    args = ["terrain", "synth", "--size", 129, "--resolution", 2.0, "--terrain", "highlands",
            "--seed", 4]
    assert run(*args, "-o", tmp_path / "whole.tif").exit_code == 0
    r = run(*args, "-o", tmp_path / "chunked.zarr", "--chunk", 48)
    assert r.exit_code == 0, r.output
    np.testing.assert_array_equal(read_dem(tmp_path / "chunked.zarr").heights,
                                  read_dem(tmp_path / "whole.tif").heights)
