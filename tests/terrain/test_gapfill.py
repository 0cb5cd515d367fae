"""Gap filling (Martin et al. 2014, IV.B-C): known pixels sacred, realistic roughness, speed."""

import numpy as np
import pytest
from scipy import ndimage, stats

from terrain.core.errors import InvalidDEMError
from terrain.core.tile import DEMTile
from terrain.craters.catalog import Crater, CraterTable
from terrain.fractal.gapfill import (
    denoise,
    despike,
    estimate_roughness,
    fill_crater_gaps,
    fill_gaps,
)
from terrain.fractal.synthetic import synthesize_tile
from terrain.surface.hillshade import horn_gradient


def holes(shape):
    ny, nx = shape
    rr, cc = np.mgrid[0:ny, 0:nx]
    disc = (rr - ny // 2) ** 2 + (cc - nx // 3) ** 2 <= 20**2  # a 40 px disc
    rng = np.random.default_rng(3)
    noise = ndimage.gaussian_filter(rng.normal(size=shape), 6)
    blob = (noise > np.quantile(noise, 0.985)) & (cc > nx // 2)
    lab, n = ndimage.label(blob)
    blob = lab == (np.argmax(ndimage.sum(blob, lab, range(1, n + 1))) + 1)  # irregular blob
    border = (rr**2 + (cc - nx // 2) ** 2) <= 25**2  # touches the top border
    return {"disc": disc, "blob": blob, "border": border}


def slope_deg(heights, res):
    gx, gy = horn_gradient(DEMTile.from_array(heights, resolution=res))
    return np.degrees(np.arctan(np.hypot(gx, gy)))


def roughness_ratio(fill_heights, truth_heights, hole, s=2):
    """Small-scale roughness inside the hole, filled over truth.

    Roughness: RMS of a pixel minus the mean of its diagonal neighbours at distance s (the
    square residual of :mod:`terrain.fractal.roughness`; s = 2 steps over the pixel-scale
    checkerboard noise of the shape-from-shading DEM).
    """
    inner = ndimage.binary_erosion(hole, iterations=s + 1)

    def rough(z):
        z = z.astype(np.float64)
        r = np.full(z.shape, np.nan)
        r[s:-s, s:-s] = z[s:-s, s:-s] - 0.25 * (z[:-2 * s, :-2 * s] + z[:-2 * s, 2 * s:]
                                                + z[2 * s:, :-2 * s] + z[2 * s:, 2 * s:])
        return np.sqrt(np.nanmean(r[inner] ** 2))

    return rough(fill_heights) / rough(truth_heights)


def test_filling_never_changes_a_known_pixel_and_fills_every_gap():
    tile = synthesize_tile(129, resolution=2.0, relief=20.0, seed=1).tile
    for name, hole in holes(tile.shape).items():
        h = tile.heights.copy()
        h[hole] = np.nan
        cut = DEMTile.from_array(h, resolution=2.0)
        out = fill_gaps(cut, seed=4)
        assert np.array_equal(out.tile.heights[~hole], tile.heights[~hole]), name
        assert out.tile.valid.all() and np.array_equal(out.filled, hole)
        again = fill_gaps(cut, seed=4)
        assert out.tile.heights.tobytes() == again.tile.heights.tobytes()


def _compare_fills(truth, transform, res):
    """KS distance of Horn slopes and small-scale roughness, ours and IDW, per hole."""
    from rasterio.fill import fillnodata

    truth = truth.astype(np.float32)
    truth_slope = slope_deg(truth, res)
    rows = {}
    for name, hole in holes(truth.shape).items():
        h = truth.copy()
        h[hole] = np.nan
        ours = fill_gaps(DEMTile.from_array(h, transform=transform), seed=1).tile
        assert np.array_equal(ours.heights[~hole], truth[~hole])
        idw = fillnodata(h.copy(), mask=(~hole).astype("uint8"), max_search_distance=400)
        inner = ndimage.binary_erosion(hole, iterations=1)
        ks_ours = stats.ks_2samp(truth_slope[inner], slope_deg(ours.heights, res)[inner])
        ks_idw = stats.ks_2samp(truth_slope[inner], slope_deg(idw, res)[inner])
        rows[name] = (int(hole.sum()), ks_ours.statistic, ks_idw.statistic,
                      roughness_ratio(ours.heights, truth, hole),
                      roughness_ratio(idw, truth, hole))
    print("\nhole    pixels | KS(Horn slope) ours   IDW | roughness/truth ours   IDW")
    for name, (n, ko, ki, ro, ri) in rows.items():
        print(f"{name:7s} {n:6d} | {ko:19.3f} {ki:5.3f} | {ro:20.2f} {ri:5.2f}")
    return rows


def test_fill_matches_a_known_fbm_surface_where_idw_is_too_smooth():
    from terrain.core.tile import default_transform

    from .test_expand import fbm_surface

    z = fbm_surface(400, 0.7, seed=4) * 20.0
    rows = _compare_fills(z, default_transform(1.0, 400), 1.0)
    for name, (_, ks_ours, ks_idw, r_ours, r_idw) in rows.items():
        assert ks_ours < 0.1 and ks_ours < 0.5 * ks_idw, name
        assert 0.7 < r_ours < 1.6, name
        assert r_idw < 0.8, name


def test_fill_on_the_real_south_pole_dem(shared_file):
    """LRO shape-from-shading DEM with three holes cut; rasterio's fillnodata alongside.

    This DEM carries pixel-scale striping from its processing, which IDW copies along its
    search rays; the table reports both methods. Ours keeps the slope distribution close
    (KS < 0.35) everywhere; where the truth inside a hole is smoother than the terrain
    around it (the border hole), no fill that looks only at the surroundings can know it.
    """
    from terrain.io import read_dem

    tile = read_dem(shared_file("lunar", "southpole_85S_nac_asp_sfs_dem_1p08m.tif"))
    rows = _compare_fills(tile.heights, tile.transform, tile.resolution)
    for name, (_, ks_ours, _, r_ours, _) in rows.items():
        assert ks_ours < 0.35, name
        assert 0.3 < r_ours < 2.5, name
    assert rows["disc"][1] <= rows["disc"][2]


def test_roughness_estimate_follows_the_terrain():
    smooth = synthesize_tile(129, resolution=2.0, relief=2.0, seed=1).tile
    rough = synthesize_tile(129, resolution=2.0, relief=40.0, seed=1).tile
    gap = np.zeros(smooth.shape, bool)
    gap[50:70, 50:70] = True
    _, r_smooth = estimate_roughness(smooth, gap)
    _, r_rough = estimate_roughness(rough, gap)
    assert r_rough[1] == pytest.approx(20 * r_smooth[1], rel=1e-6)


def test_crater_gaps_are_filled_with_a_crater_that_meets_the_terrain():
    """A real crater whose shadowed interior is missing (the paper's Fig. 7 situation)."""
    from terrain.craters.cratering import CraterModel, add_craters

    terrain = synthesize_tile(129, resolution=1.0, relief=4.0, seed=2).tile
    x, y = terrain.xy(64, 64)
    crater = CraterTable.from_craters([Crater(float(x), float(y), 40.0, 0.0, 1)])
    real = add_craters(terrain, crater, seed=11, model=CraterModel().smooth()).tile
    ny, nx = real.shape
    rr, cc = np.mgrid[0:ny, 0:nx]
    hole = (rr - 64) ** 2 + (cc - 64) ** 2 <= 15**2  # the interior, inside the rim
    h = real.heights.copy()
    h[hole] = np.nan
    cut = DEMTile.from_array(h, resolution=1.0)
    out = fill_crater_gaps(cut, crater, seed=3)
    tile = real
    assert np.array_equal(out.tile.heights[~hole], real.heights[~hole])
    assert out.tile.valid.all()
    filled = out.tile.heights.astype(np.float64)
    # a bowl: the centre is well below the rim
    assert filled[64, 64] < np.median(real.heights[~hole]) - 0.3 * 0.196 * 40
    # no step where the filled crater meets known terrain
    edge = hole & ~ndimage.binary_erosion(hole)
    ring = ndimage.binary_dilation(hole) & ~hole
    jumps = [abs(filled[i, j] - filled[i + di, j + dj]) for i, j in zip(*np.nonzero(edge),
             strict=True) for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1))
             if ring[i + di, j + dj]]
    gx, gy = horn_gradient(tile)
    typical = np.percentile(np.hypot(gx, gy), 99) * 1.0 + 0.2
    assert np.max(jumps) < 2 * typical


def test_despike_and_denoise():
    tile = synthesize_tile(65, resolution=1.0, relief=2.0, seed=5).tile
    h = tile.heights.copy()
    h[20, 20] += 50.0
    h[40, 10] -= 30.0
    spiky = DEMTile.from_array(h)
    clean, removed = despike(spiky, 6.0)
    assert removed[20, 20] and removed[40, 10]
    assert removed.sum() <= 6
    assert np.array_equal(clean.heights[clean.valid], h[clean.valid])
    smooth = denoise(tile, 2.0)
    assert smooth.valid.all()
    assert np.std(np.diff(smooth.heights, axis=1)) < np.std(np.diff(tile.heights, axis=1))


def test_a_dem_without_known_pixels_is_refused():
    with pytest.raises(InvalidDEMError, match="no known pixels"):
        fill_gaps(DEMTile.from_array(np.full((4, 4), np.nan)))
