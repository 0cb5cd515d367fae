"""Sensor model: exposure, quantisation, keyed noise with the right statistics, PSF."""

import numpy as np
import pytest

from render.sensor import Sensor
from terrain.core.errors import InvalidParameterError


def test_exposure_and_bit_depth():
    rad = np.array([[0.0, 0.05, 0.1, 0.5]])
    assert Sensor(bits=8, exposure=10.0).expose(rad).tolist() == [[0, 128, 255, 255]]
    img16 = Sensor(bits=16, exposure=10.0).expose(rad)
    assert img16.dtype == np.uint16 and img16[0, 1] == 32768
    assert Sensor().expose(np.array([[np.nan]])).tolist() == [[0]]


def test_noise_is_keyed_and_has_the_stated_statistics():
    flat = np.full((200, 200), 0.08)
    s = Sensor(bits=16, exposure=10.0, gain=2.0, read_noise=5.0, seed=3)
    a, b = s.expose(flat, frame=4), s.expose(flat, frame=4)
    assert a.tobytes() == b.tobytes()
    assert not np.array_equal(a, s.expose(flat, frame=5))
    dn = 0.08 * 10.0 * 65535
    expected = np.sqrt(dn / 2.0 + 5.0**2)  # shot (sqrt(e)/gain) and read noise in DN
    assert a.astype(float).std() == pytest.approx(expected, rel=0.03)
    assert a.astype(float).mean() == pytest.approx(dn, abs=4 * expected / 200)


def test_psf_blurs_a_point():
    img = np.zeros((21, 21))
    img[10, 10] = 1.0
    out = Sensor(bits=16, exposure=1.0, psf_sigma=1.5).expose(img).astype(float)
    assert out[10, 10] < 65535 * 0.2 and out[10, 12] > 0


def test_bad_sensors():
    with pytest.raises(InvalidParameterError):
        Sensor(bits=17)
    with pytest.raises(InvalidParameterError):
        Sensor(exposure=0.0)
