"""Flash and scanning LIDAR against ray-traced analytic scenes and the documented link budget."""

from __future__ import annotations

import math

import numpy as np
import pytest

from render.camera import look_at
from render.lidar import Lidar, flash, footprint, scan, scan_order
from render.motion import Motion
from terrain.core.errors import InvalidParameterError
from tests.render.analytic import plane_look, step_look

DOWN = look_at((0.0, 0.0, 100.0), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))


def unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def footprint_mean(pose, k, col, row, half_angle, m, d, n=400):
    """Power-weighted mean range over the disk of radius tan(half_angle) in the image plane.

    Dense quadrature of the continuous footprint on the plane {x : m . x = -d} (independent
    of the sub-ray grid): weights cos(i) / R^2 over equal image-plane areas.
    """
    rt = math.tan(half_angle)
    g = (np.arange(n) + 0.5) / n * 2 - 1
    gx, gy = np.meshgrid(g * rt, g * rt)
    inside = gx ** 2 + gy ** 2 <= rt * rt
    tx = (col - k.cx) / k.fx + gx[inside]
    ty = (row - k.cy) / k.fy + gy[inside]
    u = unit(np.stack([tx, ty, np.ones_like(tx)], -1)) @ pose.rotation.T
    o = np.asarray(pose.position)
    r = -(m @ o + d) / (u @ m)
    w = (-(u @ m)) / r ** 2
    return float(np.sum(w * r) / np.sum(w))


@pytest.mark.parametrize("tilt", [0.0, 40.0, 70.0])
def test_footprint_averaged_range_on_a_tilted_plane_matches_the_analytic_value(tilt):
    lid = Lidar(width=6, height=5, fov=3.0, divergence=1.5, supersample=8, threshold=0.0,
                range_resolution=1.0)
    t = math.radians(tilt)
    m = np.array([math.sin(t), 0.0, math.cos(t)])        # plane through the origin
    img = flash(lid, plane_look((0.0, 0.0, 0.0), m), DOWN)
    k = lid.intrinsics()
    for row, col in [(0, 0), (2, 3), (4, 5)]:
        want = footprint_mean(DOWN, k, col, row, math.radians(0.75), m, 0.0)
        # the footprint spans a range spread of R tan(tilt) x divergence: a metre at 70 degrees
        assert img.range[row, col] == pytest.approx(want, abs=2e-3)
        assert img.returns[row, col] == 1
        lo, hi = img.first[row, col], img.last[row, col]
        assert lo == pytest.approx(hi) and lo == pytest.approx(want, abs=2e-3)


def test_a_footprint_across_a_step_returns_both_levels_first_and_last():
    lid = Lidar(width=9, height=1, fov=4.5, divergence=1.0, supersample=8, threshold=0.0,
                range_resolution=0.2)
    img = flash(lid, step_look(0.0, 5.0), DOWN)
    mid = 4                                   # its footprint straddles the step at x = 0
    assert img.returns[0, mid] == 2
    assert img.first[0, mid] == pytest.approx(95.0, abs=0.02)
    assert img.last[0, mid] == pytest.approx(100.0, abs=0.02)
    assert 95.0 < img.range[0, mid] < 100.0
    assert img.strongest[0, mid] in (img.first[0, mid], img.last[0, mid])
    assert img.returns[0, 0] == 1 and img.returns[0, -1] == 1


def by_hand_detection_range(p_t, n_pixels, eff, albedo, cos_i, aperture, threshold):
    """Where P_t/N eff albedo cos(i) (pi D^2/4) / (pi R^2) equals the threshold."""
    return math.sqrt(p_t / n_pixels * eff * albedo * cos_i * aperture ** 2 / 4 / threshold)


@pytest.mark.parametrize("albedo,tilt", [(0.12, 0.0), (0.03, 0.0), (0.12, 75.5)])
def test_dropouts_follow_the_link_budget_for_dark_steep_and_distant_surfaces(albedo, tilt):
    lid = Lidar(width=4, height=4, fov=0.4, power=2.0, aperture=0.1, efficiency=0.6,
                albedo=albedo, threshold=1e-9, supersample=2)
    t = math.radians(tilt)
    m = np.array([math.sin(t), 0.0, math.cos(t)])
    r_star = by_hand_detection_range(2.0, 16, 0.6, albedo, math.cos(t), 0.1, 1e-9)
    for factor, seen in ((0.97, True), (1.03, False)):
        # looking straight down at the plane through the origin: the boresight meets it at
        # range factor x r_star, at incidence `tilt`
        pose = look_at((0.0, 0.0, factor * r_star), (0.0, 0.0, 0.0), up=(0.0, 1.0, 0.0))
        img = flash(lid, plane_look((0.0, 0.0, 0.0), m), pose)
        central = img.range[1:3, 1:3]
        assert np.all(np.isfinite(central)) == seen, (factor, central)


def test_range_noise_has_its_rms_and_repeats():
    lid = Lidar(width=64, height=64, fov=5.0, range_noise=0.05, threshold=0.0, supersample=1)
    a = flash(lid, plane_look(), DOWN, seed=3, frame=1)
    b = flash(lid, plane_look(), DOWN, seed=3, frame=1)
    c = flash(lid, plane_look(), DOWN, seed=3, frame=2)
    clean = flash(Lidar(width=64, height=64, fov=5.0, threshold=0.0, supersample=1),
                  plane_look(), DOWN)
    err = (a.range - clean.range).ravel()
    assert np.array_equal(a.range, b.range) and not np.array_equal(a.range, c.range)
    assert np.std(err) == pytest.approx(0.05, rel=0.05)
    assert abs(np.mean(err)) < 0.005


def test_a_scan_during_motion_measures_each_point_from_its_own_time():
    # descending at 20 m/s over a flat plane from 100 m: a point measured at time t sees
    # 100 - 20 t along its ray
    lid = Lidar(mode="scan", width=16, height=16, fov=4.0, point_rate=256.0, threshold=0.0,
                supersample=1, tolerance=0.05)
    motion = Motion(velocity=(0.0, 0.0, -20.0))
    sc = scan(lid, plane_look(), DOWN, 10.0, motion)
    assert len(sc.time) == 256 and sc.time[0] == 10.0
    assert sc.time[-1] == pytest.approx(10.0 + 255 / 256.0)
    height = sc.position[:, 2]
    assert height == pytest.approx(100.0 - 20.0 * (sc.time - 10.0))
    cos_z = -sc.direction[:, 2]
    want = height / cos_z
    # slices keep the image within 0.05 px: a descent of ~0.1 m at most between a point's
    # time and its slice's middle
    assert np.max(np.abs(sc.range - want)) < 0.2
    assert sc.range[0] > sc.range[-1] + 15.0
    assert sc.slices > 1


def test_patterns_visit_every_pixel_once_and_keys_are_checked():
    for pattern in ("raster", "spiral"):
        rows, cols = scan_order(Lidar(width=7, height=5, pattern=pattern))
        assert len(set(zip(rows.tolist(), cols.tolist(), strict=True))) == 35
    rows, cols = scan_order(Lidar(width=7, height=5, pattern="spiral"))
    assert (rows[0], cols[0]) == (2, 3)
    dy, dx, pad = footprint(Lidar(supersample=4))
    assert len(dy) == 16 and pad == 0
    with pytest.raises(InvalidParameterError, match="unknown lidar key 'divergance'"):
        Lidar.from_mapping({"divergance": 1.0})
    with pytest.raises(InvalidParameterError, match="mode"):
        Lidar(mode="sweep")
