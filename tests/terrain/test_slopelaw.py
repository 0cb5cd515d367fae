"""Layer stacks whose roughness follows a preset's slope law, checked against the published laws.

The laws as published, not as the code writes them: LOLA's median bidirectional slope
``atan(tan(theta_17) (L / 17 m)^(H - 1))`` (Rosenburg et al. 2011, Table 1: south-polar 7.6
deg and H 0.95; maria 2.0 deg and H 0.76), within a degree at every baseline a layer holds; the
angle of repose (Carrier et al. 1991, 35 deg) bounding the slopes of every layer; and an RMS
slope of 10-20 deg at centimetre baselines with the plane removed (Helfenstein and Shepard
1999; Shepard et al. 2001).
"""

import math

import numpy as np
import pytest

from terrain.core.presets import preset
from terrain.core.tile import DEMTile
from terrain.fractal.expand import expand_level
from terrain.fractal.rmd import noise_taps
from terrain.fractal.roughness import ExpansionParameters, RoughnessChoice
from terrain.fractal.synthetic import synthesize_tile
from terrain.stack.build import build_stack
from terrain.stack.slopelaw import (
    FILL_GAIN,
    fill_amplitude,
    fill_target,
    gradient_sample,
    local_gradient,
    map_halo,
)
from terrain.surface.repose import Repose


def published_median_slope(theta_17_deg, hurst, baseline_m):
    """Rosenburg et al. (2011): median bidirectional slope at a baseline, degrees."""
    return math.degrees(math.atan(math.tan(math.radians(theta_17_deg))
                                  * (baseline_m / 17.0) ** (hurst - 1.0)))


def median_slope(z, lag, resolution):
    """Median |z(x + L) - z(x)| / L over both map axes, as LOLA's bidirectional slopes."""
    d = np.concatenate([np.abs(z[:, lag:] - z[:, :-lag]).ravel(),
                        np.abs(z[lag:] - z[:-lag]).ravel()])
    return math.degrees(math.atan(float(np.median(d)) / (lag * resolution)))


def rms_slope_plane_removed(z, resolution):
    """RMS one-pixel slope (deg) of heights less their least-squares plane."""
    ny, nx = z.shape
    yy, xx = np.mgrid[0:ny, 0:nx]
    a = np.column_stack([xx.ravel(), yy.ravel(), np.ones(z.size)])
    coef, *_ = np.linalg.lstsq(a, z.ravel().astype(np.float64), rcond=None)
    r = z - (coef[0] * xx + coef[1] * yy + coef[2])
    d = np.concatenate([(r[:, 1:] - r[:, :-1]).ravel(), (r[1:] - r[:-1]).ravel()])
    return math.degrees(math.atan(math.sqrt(float(np.mean(d * d))) / resolution))


def horn_slope_deg(z, resolution):
    """Horn's slope of the interior cells, degrees."""
    gx = ((z[:-2, 2:] + 2 * z[1:-1, 2:] + z[2:, 2:])
          - (z[:-2, :-2] + 2 * z[1:-1, :-2] + z[2:, :-2])) / (8 * resolution)
    gy = ((z[2:, :-2] + 2 * z[2:, 1:-1] + z[2:, 2:])
          - (z[:-2, :-2] + 2 * z[:-2, 1:-1] + z[:-2, 2:])) / (8 * resolution)
    return np.degrees(np.arctan(np.hypot(gx, gy)))


@pytest.mark.parametrize("hurst", [0.7, 0.95])
@pytest.mark.parametrize("level", [1, 2])
def test_fill_gain_is_what_a_flat_parents_expansion_measures(hurst, level):
    """FILL_GAIN: median-equivalent one-pixel variance per unit displacement variance."""
    p = ExpansionParameters(3.0 - hurst, 0.1, 1.0, 1024, local_box=0)
    out = expand_level(np.zeros((257, 257), np.float32), (0, 0), (0, 512), (0, 512),
                       level=level, sigmas=(1.0, 1.0, 1.0), weights=p.weights(level),
                       taps=noise_taps(hurst), seed=11).astype(np.float64)
    d = np.concatenate([(out[:, 1:] - out[:, :-1]).ravel(), (out[1:] - out[:-1]).ravel()])
    measured = (np.median(np.abs(d)) / 0.6745) ** 2
    assert measured == pytest.approx(FILL_GAIN, rel=0.05)


def test_local_gradient_of_a_plane():
    plane = np.add.outer(np.zeros(20), 0.3 * np.arange(20.0))  # 0.3 m per 2 m pixel, in x
    g = local_gradient(plane, 2.0, box=5)
    # half the box's differences are 0 (y), half 0.3: mean |dz| 0.15 over sqrt(2 / pi) 2 m
    assert np.allclose(g[2:-2, 2:-2], 0.15 / (math.sqrt(2 / math.pi) * 2.0))


def test_a_window_grown_by_the_halo_gives_the_whole_layers_fill_map():
    z = synthesize_tile(129, resolution=2.0, fractal_dimension=2.3, relief=5.0,
                        seed=4).tile.heights
    whole = fill_amplitude(z, 2.0, 0.1, 0.05)
    h = map_halo()
    r0, r1, c0, c1 = 30, 70, 0, 50
    part = fill_amplitude(z[r0 - h:r1 + h + 1, c0:c1 + h + 1], 2.0, 0.1, 0.05,
                          rows=(h, h + r1 - r0), cols=(0, c1 - c0))
    assert np.array_equal(part, whole[r0:r1 + 1, c0:c1 + 1])
    assert 0 < np.count_nonzero(whole) < whole.size  # some of it filled, some not
    # the fill target's sample, gathered window by window, is the whole layer's
    law = preset("south-polar")
    parts = []
    for a in range(0, 129, 50):
        for b in range(0, 129, 50):
            e, f = min(129, a + 50), min(129, b + 50)
            w0, v0 = max(0, a - h), max(0, b - h)
            parts.append(gradient_sample(z[w0:e + h, v0:f + h], 2.0, (a, b),
                                         rows=(a - w0, e - 1 - w0), cols=(b - v0, f - 1 - v0)))
    assert fill_target(np.concatenate(parts), 2.0, law) == fill_target(
        gradient_sample(z, 2.0), 2.0, law)


def _law_stack(name, base, levels, **kw):
    return build_stack(base, (0.5 * base.bounds[0] + 0.5 * base.bounds[2],
                              0.5 * base.bounds[1] + 0.5 * base.bounds[3]),
                       levels=levels, layer_size=257, seed=7, slope_law=preset(name),
                       params=RoughnessChoice(), **kw)


def _law_base(name, size=129, resolution=256.0, seed=3):
    """A fractal base whose one-pixel median slope is the preset's (its relief, no craters)."""
    from terrain.stages.dems import preset_relief

    f, relief = preset_relief(preset(name), size, resolution)
    return synthesize_tile(size, resolution=resolution, fractal_dimension=f, relief=relief,
                           seed=seed).tile


@pytest.mark.parametrize("name, theta, hurst, top", [("maria", 2.0, 0.76, 500.0)])
def test_layers_follow_the_published_slope_law_at_every_baseline(name, theta, hurst, top):
    """A 33 km base on the law expanded to 2 m: every layer's median slope within 1 deg."""
    stack = _law_stack(name, _law_base(name), 7)
    checked = 0
    for tile in stack.tiles[1:]:
        for lag in (1, 4):
            baseline = lag * tile.resolution
            if baseline > top:
                continue
            got = median_slope(tile.heights.astype(np.float64), lag, tile.resolution)
            want = published_median_slope(theta, hurst, baseline)
            assert abs(got - want) <= 1.0, (tile.resolution, lag, got, want)
            checked += 1
    assert checked >= 10


def test_a_base_flatter_than_the_law_is_brought_to_it():
    """A flat 33 km base: the south-polar law's slope at each layer's pixel (128 m - 8 m), and
    at four pixels once four levels have filled in below them (16 m and 8 m layers)."""
    base = DEMTile.from_array(np.zeros((129, 129), np.float32), resolution=256.0)
    stack = _law_stack("south-polar", base, 5)
    for k, tile in enumerate(stack.tiles[1:], 1):
        for lag in (1, 4) if k >= 4 else (1,):
            got = median_slope(tile.heights.astype(np.float64), lag, tile.resolution)
            want = published_median_slope(7.6, 0.95, lag * tile.resolution)
            assert abs(got - want) <= 1.0, (k, lag, got, want)


def test_a_base_steeper_than_the_law_keeps_its_slopes_and_gets_no_fill():
    base = synthesize_tile(129, resolution=256.0, fractal_dimension=2.5, relief=3000.0,
                           seed=3).tile
    stack = _law_stack("south-polar", base, 3)
    own = median_slope(base.heights.astype(np.float64), 1, 256.0)
    assert own > 10.0
    for tile in stack.tiles[1:]:
        # no smoother than the law, and not rougher than the base it interpolates
        got = median_slope(tile.heights.astype(np.float64), 1, tile.resolution)
        assert published_median_slope(7.6, 0.95, tile.resolution) - 1.0 <= got <= own + 1.0


def _cm_stack(relax):
    from terrain.fractal.regolith import RegolithLaw

    return build_stack(_law_base("south-polar", 65, 4.0), (130.0, 130.0), levels=7,
                       layer_size=257, seed=9, slope_law=preset("south-polar"),
                       params=RoughnessChoice(regolith=RegolithLaw()),
                       repose=Repose(35.0) if relax else None)


def _steep_share(tile):
    return float(np.mean(horn_slope_deg(tile.heights.astype(np.float64), tile.resolution)
                         > 35.0))


def test_centimetre_rms_slope_is_that_of_lunar_regolith_and_slopes_roll_over_at_repose():
    """Expanded to 3 cm: RMS slope 10-20 deg with the plane removed (Helfenstein and Shepard
    1999), and at most 0.5 % of every layer steeper than the 35 deg angle of repose."""
    stack = _cm_stack(relax=True)
    fine = stack.tiles[-1]
    assert fine.resolution == pytest.approx(0.03125)
    rms = rms_slope_plane_removed(fine.heights.astype(np.float64), fine.resolution)
    assert 10.0 <= rms <= 20.0
    assert max(_steep_share(t) for t in stack.tiles) <= 0.005
