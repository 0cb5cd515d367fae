"""The compiled kernels of the truth warps: what a range sampler, a noise model and a thread
pool must each get right, checked against independent expectations."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation.warpkernels import noisy_rows, sample_range_points
from terrain.core.parallel import limited
from terrain.core.rng import normal, stream_id


def test_range_on_a_plane_is_interpolated_exactly():
    """A planar range image: bilinear sampling between agreeing returns is the plane itself."""
    v, u = np.mgrid[0:32, 0:48].astype(np.float64)
    plane = 100.0 + 0.01 * u + 0.02 * v
    rng = np.random.default_rng(3)
    pts = rng.uniform([0, 0], [47, 31], size=(500, 2))
    got = sample_range_points(plane, pts[:, 0], pts[:, 1], 0.02)
    assert np.allclose(got, 100.0 + 0.01 * pts[:, 0] + 0.02 * pts[:, 1], rtol=0, atol=1e-9)


def test_range_across_a_step_takes_the_nearest_return_and_outside_is_nan():
    """Returns that disagree (an occluding step) are not blended; off the image is no return."""
    r = np.full((8, 8), 10.0, dtype=np.float32)
    r[:, 4:] = 20.0  # a step far beyond any tolerance
    r[0, 0] = np.nan
    got = sample_range_points(r, np.array([3.4, 3.6, 0.2, -0.6, 7.6, 2.0]),
                              np.array([2.0, 2.0, 0.2, 3.0, 3.0, 2.0]), 0.02)
    assert got[0] == 10.0 and got[1] == 20.0  # nearest of the two sides, never 15
    assert got[2] != got[2]  # a missing return among the four: nearest is the missing one
    assert np.isnan(got[3]) and np.isnan(got[4])  # more than half a pixel outside
    assert got[5] == 10.0


def test_fresh_noise_has_the_sensor_variance_and_is_keyed():
    """Shot plus read noise: the residual's variance is DN / gain + read^2 at each level."""
    gain, read = 2.0, 3.0
    img = np.zeros((256, 256), dtype=np.uint16)
    img[:, :128] = 400  # shot noise 400 / 2 = 200 DN^2, plus 9
    img[:, 128:] = 2000  # 1000 + 9
    noisy = noisy_rows(img, 11, stream_id("test-noise"), 3, gain, read).astype(np.float64)
    for sl, level in ((np.s_[:, :128], 400.0), (np.s_[:, 128:], 2000.0)):
        d = noisy[sl] - level
        expected = level / gain + read * read
        n = d.size
        # the sample variance of n normal deviates scatters by sqrt(2 / n) of it; 5 sigma
        assert abs(d.var() / expected - 1.0) < 5.0 * np.sqrt(2.0 / n)
        assert abs(d.mean()) < 5.0 * np.sqrt(expected / n)
    again = noisy_rows(img, 11, stream_id("test-noise"), 3, gain, read)
    assert np.array_equal(again, noisy.astype(np.uint16))  # same key, same bytes
    other = noisy_rows(img, 11, stream_id("test-noise"), 4, gain, read)
    assert not np.array_equal(other, again)  # another frame, other noise


def test_fresh_noise_is_the_position_keyed_normal_of_each_pixel():
    """Pixel (x, y) carries the stream's Gaussian of (x, y): a window equals the full frame's."""
    img = np.full((40, 30), 100, dtype=np.uint8)
    full = noisy_rows(img, 5, stream_id("w"), 0, 0.0, 2.0).astype(np.float64)
    z = normal(5, stream_id("w"), 0, np.arange(30)[None, :], np.arange(40)[:, None])
    assert np.array_equal(full, np.clip(np.rint(100.0 + 2.0 * z), 0, 255))


@pytest.mark.parametrize("n", [1, 2, 3])
def test_kernels_give_the_same_bytes_on_any_number_of_threads(n):
    """Blocks, not threads, decide the work: one thread and several give the same bytes."""
    rng = np.random.default_rng(8)
    r = rng.uniform(50, 60, (300, 200)).astype(np.float32)
    r[rng.random(r.shape) < 0.05] = np.nan
    pts = rng.uniform(-2, 302, (200_000, 2))
    img = rng.integers(0, 4000, (300, 200)).astype(np.uint16)
    with limited(1):
        a = sample_range_points(r, pts[:, 0], pts[:, 1], 0.002)
        na = noisy_rows(img, 1, 2, 3, 1.5, 2.0)
    with limited(n):
        b = sample_range_points(r, pts[:, 0], pts[:, 1], 0.002)
        nb = noisy_rows(img, 1, 2, 3, 1.5, 2.0)
    assert np.array_equal(a, b, equal_nan=True) and np.array_equal(na, nb)


def test_truth_warp_maps_are_the_carry_then_the_sample_bit_for_bit():
    """The fused warp kernel gives exactly what camera_map_rows, then sample_range_points and
    the visibility test on their results give (the maps truth_warped_frame used to build)."""
    from evaluation.warpkernels import camera_map_rows, truth_warp_rows

    rng = np.random.default_rng(11)
    h, w = 60, 80
    r1 = rng.uniform(90, 110, (h, w)).astype(np.float32)
    r1[rng.random(r1.shape) < 0.05] = np.nan
    r0 = rng.uniform(95, 105, (h, w)).astype(np.float32)
    r0[rng.random(r0.shape) < 0.05] = np.nan
    x = (np.arange(w) - 40.0) / 70.0
    y = (np.arange(h) - 30.0) / 70.0
    c, s = np.cos(0.05), np.sin(0.05)
    a = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    t = np.array([0.3, -0.2, -1.5])
    u, v, dist, lifted = camera_map_rows(r1, x, y, a, t, 70.0, 70.0, 40.0, 30.0)
    idx = np.flatnonzero(lifted)
    seen = sample_range_points(r0, u.ravel()[idx], v.ravel()[idx], 0.002)
    q0, q1 = u.ravel()[idx], v.ravel()[idx]
    with np.errstate(invalid="ignore"):
        good = ((q0 >= -0.5) & (q0 <= w - 0.5) & (q1 >= -0.5) & (q1 <= h - 0.5)
                & np.isfinite(seen) & (seen >= dist.ravel()[idx] * (1.0 - 0.002)))
    want_ok = np.zeros(h * w, dtype=bool)
    want_ok[idx[good]] = True
    want_u = np.full(h * w, -10.0, dtype=np.float32)
    want_u[idx[good]] = q0[good]
    want_v = np.full(h * w, -10.0, dtype=np.float32)
    want_v[idx[good]] = q1[good]
    mu, mv, ok = truth_warp_rows(r1, x, y, a, t, 70.0, 70.0, 40.0, 30.0, r0, 0.002)
    assert 0 < ok.sum() < ok.size  # some pixels kept, some not: both branches checked
    assert ok.tobytes() == want_ok.tobytes()
    assert mu.tobytes() == want_u.tobytes() and mv.tobytes() == want_v.tobytes()
