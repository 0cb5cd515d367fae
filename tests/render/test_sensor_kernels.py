"""The compiled sensor chain gives the bytes of the numpy expressions it replaced."""

import numpy as np
from scipy.special import ndtri

from render.sensor_kernels import quantise, shot_gaussian
from terrain.core.parallel import limited
from terrain.core.rng import normal, uniform

SEED, STREAM, FRAME = 4242, 17, 3


def _electrons(h=70, w=90):
    rng = np.random.default_rng(11)
    return np.where(rng.random((h, w)) < 0.3, rng.random((h, w)) * 30.0,
                    rng.random((h, w)) * 5000.0)


def test_gaussian_shot_noise_is_scipys_ndtri_of_the_keyed_uniforms():
    e = _electrons()
    cols, rows = np.arange(e.shape[1])[None, :], np.arange(e.shape[0])[:, None]
    want = np.maximum(e + np.sqrt(e) * ndtri(uniform(SEED, STREAM, FRAME, cols, rows)), 0.0)
    got = shot_gaussian(e, SEED, STREAM, FRAME, 30.0)
    high = e >= 30.0
    assert np.array_equal(got[high], want[high])
    assert np.all(got[~high] == 0.0)  # left for the exact Poisson draw
    with limited(1):
        assert np.array_equal(shot_gaussian(e, SEED, STREAM, FRAME, 30.0), got)


def test_quantisation_is_clip_of_rint_after_the_well_and_read_noise():
    e = _electrons() * 3.0
    cols, rows = np.arange(e.shape[1])[None, :], np.arange(e.shape[0])[:, None]
    read = normal(SEED, STREAM, FRAME, cols, rows)
    for well, read_e, gain, bias, bits in ((None, 1.5, 20.0, 0.0, 8), (9000.0, 12.0, 4.0, 30.0, 12),
                                           (None, 0.0, 1.0, 0.0, 16)):
        full = 2**bits - 1
        dtype = np.uint8 if bits <= 8 else np.uint16
        x = e if well is None else np.minimum(e, well)
        if read_e > 0:
            x = x + read_e * read
        want = np.clip(np.rint(x / gain + bias), 0, full).astype(dtype)
        got = quantise(e, well, read_e, SEED, STREAM, FRAME, gain, bias, full, dtype)
        assert got.dtype == dtype
        assert np.array_equal(got, want)
