"""A frame's arrays from the read-back buffers: flipped rows, NaN where no surface was seen."""

import numpy as np

from render.readback import Staging, unpack


def _staged(h, w, seed=7):
    rng = np.random.default_rng(seed)
    s = Staging((w, h))
    s.radiance[:] = rng.random((h, w), dtype=np.float32)
    s.range[:] = rng.random((h, w), dtype=np.float32) * 1000
    s.normals[:] = rng.standard_normal((h, w, 4)).astype(np.float32)
    alpha = s.normals[:, :, 3]
    alpha[:] = rng.random((h, w)) > 0.3  # seen / not seen, as the shader writes it
    alpha[0, :3] = (np.nan, 0.5, np.nextafter(np.float32(0.5), np.float32(1)))
    return s


def test_unpack_matches_flipping_and_masking_with_numpy():
    s = _staged(150, 53)  # three bands of rows, the last one short
    rad, range_m, normals = unpack(s)
    hit = s.normals[::-1, :, 3] > 0.5  # a NaN flag is no hit
    want_range = s.range[::-1].copy()
    want_range[~hit] = np.nan
    want_normals = np.where(hit[:, :, None], s.normals[::-1, :, :3], np.float32(np.nan))
    assert rad.dtype == range_m.dtype == normals.dtype == np.float32
    assert np.array_equal(rad, s.radiance[::-1])
    assert np.array_equal(range_m, want_range, equal_nan=True)
    assert np.array_equal(normals, want_normals, equal_nan=True)
    # the three read-row-0 cases: NaN and exactly 0.5 are unseen, just above 0.5 seen
    assert np.isnan(range_m[-1, :2]).all() and not np.isnan(range_m[-1, 2])
    assert all(a.flags.c_contiguous for a in (rad, range_m, normals))


def test_outputs_are_fresh_arrays_not_views_of_the_staging_buffers():
    s = _staged(8, 5)
    first = unpack(s)
    kept = [a.copy() for a in first]
    s.radiance[:] = -1.0
    s.range[:] = -1.0
    s.normals[:] = 1.0
    for a, b in zip(first, kept, strict=True):
        assert np.array_equal(a, b, equal_nan=True)
    rad, _, _ = unpack(s, with_radiance=False)
    assert rad is None
