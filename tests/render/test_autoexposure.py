"""Auto-exposure (render.sensor.ExposureControl): where it puts the lit pixels, how it settles."""

import math

import numpy as np
import pytest

from render.camera import Intrinsics
from render.sensor import ExposureControl, Sensor
from terrain.core.errors import InvalidParameterError


def _scene(seed=0, shape=(96, 128)):
    """An I/F image like a polar frame: lit ground 0.002-0.05 and 30 % shadow (0)."""
    rng = np.random.default_rng(seed)
    x = rng.lognormal(math.log(0.01), 0.6, shape)
    x[rng.random(shape) < 0.3] = 0.0
    return x


def _lit_percentile(image, radiance, q):
    """The q-th percentile of the image's DN over the lit pixels, as a user measures it."""
    return float(np.percentile(image[radiance > 0].astype(np.float64), q))


@pytest.mark.parametrize("sensor", [
    Sensor(bits=8, exposure=6.0, auto_exposure=True, ae_percentile=95.0, ae_fraction=0.7),
    Sensor(bits=12, exposure=1.0, psf_sigma=0.8, auto_exposure=True, ae_percentile=50.0,
           ae_fraction=0.5, bias=40.0),
    Sensor(bits=12, exposure=0.0, exposure_time=0.01, aperture=0.02, gain=4.0, bias=30.0,
           dark_current=200.0, natural_vignetting=True, shot_noise=False, auto_exposure=True,
           ae_percentile=99.0, ae_fraction=0.8),
], ids=["if-8bit", "if-12bit-psf-bias", "physical-dark-vignetting"])
def test_the_chosen_percentile_lands_at_the_chosen_fraction_within_a_dn(sensor):
    radiance = _scene()
    k = Intrinsics.from_fov(128, 96, 40.0)
    image, record = ExposureControl(sensor).expose(radiance, intrinsics=k,
                                                   spectral_irradiance=1.5)
    got = _lit_percentile(image, radiance, sensor.ae_percentile)
    assert abs(got - sensor.ae_fraction * sensor.full_scale) <= 1.0, got
    key = "exposure_time" if sensor.physical else "exposure"
    assert record[key] == record["settled"]  # the first frame settles at once


def test_it_settles_at_the_stated_rate():
    """Starting 8x overexposed on a steady scene, the exposure's log error shrinks by
    (1 - rate) a frame, and the percentile walks down to the target."""
    rate = 0.3
    sensor = Sensor(bits=10, exposure=1.0, auto_exposure=True, ae_percentile=90.0,
                    ae_fraction=0.6, ae_rate=rate)
    radiance = _scene(1)
    settled = sensor.metered(radiance)
    ctl = ExposureControl(sensor, value=8.0 * settled)
    errors, dn = [], []
    for frame in range(12):
        image, record = ctl.expose(radiance, frame)
        errors.append(math.log(record["exposure"] / settled))
        dn.append(_lit_percentile(image, radiance, 90.0))
    ratios = np.array(errors[1:]) / np.array(errors[:-1])
    assert np.allclose(ratios, 1.0 - rate, atol=1e-9)
    assert errors[0] == pytest.approx((1 - rate) * math.log(8.0))
    assert abs(dn[-1] - 0.6 * sensor.full_scale) <= 0.02 * sensor.full_scale
    assert all(a >= b for a, b in zip(dn, dn[1:], strict=False))  # it never overshoots


def test_it_follows_a_darkening_scene():
    """A scene dimming 20 % a frame: with rate 1 every frame is placed, whatever the light."""
    sensor = Sensor(bits=8, exposure=1.0, auto_exposure=True, ae_rate=1.0, ae_fraction=0.5,
                    ae_percentile=95.0)
    ctl = ExposureControl(sensor)
    base = _scene(2)
    for frame in range(5):
        radiance = base * 0.8**frame
        image, _ = ctl.expose(radiance, frame)
        assert abs(_lit_percentile(image, radiance, 95.0) - 0.5 * 255) <= 1.0


def test_fixed_exposure_stays():
    sensor = Sensor(bits=8, exposure=6.0)
    radiance = _scene(3)
    image, record = ExposureControl(sensor).expose(radiance)
    assert record is None and np.array_equal(image, sensor.expose(radiance))


def test_a_black_frame_keeps_the_exposure_and_the_cap_holds():
    sensor = Sensor(bits=8, exposure=3.0, auto_exposure=True, ae_max=10.0)
    assert sensor.metered(np.zeros((4, 4))) == 3.0
    assert sensor.metered(np.full((4, 4), 1e-6)) == 10.0


@pytest.mark.parametrize("table, message", [
    ({"exposure": 1.0, "ae_percentil": 90.0}, "did you mean 'ae_percentile'"),
    ({"exposure": 1.0, "ae_fraction": 1.5}, "ae_fraction"),
    ({"exposure": 1.0, "ae_rate": 0.0}, "ae_rate"),
    ({"exposure": 1.0, "auto_exposure": "yes"}, "auto_exposure"),
])
def test_bad_auto_exposure_keys_are_refused(table, message):
    with pytest.raises(InvalidParameterError, match=message):
        Sensor.from_mapping(table)
