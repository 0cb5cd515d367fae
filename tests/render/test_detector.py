"""The detector chain on rendered flat fields: photon transfer, saturation, PRNU, old sensors."""

import math

import numpy as np
import pytest

from render.camera import Intrinsics, look_at
from render.renderer import Lighting, RenderOptions, View
from render.sensor import PLANCK, SPEED_OF_LIGHT, Sensor
from render.terrain_scene import TerrainScene
from terrain.core.errors import InvalidParameterError, MissingInputError
from terrain.core.tile import DEMTile
from terrain.craters.catalog import CraterCatalog
from terrain.stack.model import Layer, LayerStack

K = Intrinsics.from_fov(128, 128, 20.0)


@pytest.fixture(scope="module")
def flat_field(gl):
    """I/F of a flat Lambert plane seen from above: the same in every pixel."""
    from render.renderer import Renderer

    tile = DEMTile.from_array(np.zeros((129, 129)), resolution=1.0)
    cat = CraterCatalog.empty(layered=True)
    scene = TerrainScene(LayerStack((Layer(tile, None, (0, 0)),), cat, {"site": [64.5, 64.5]}),
                         curvature=False)
    light = Lighting.from_angles(90.0, 60.0, albedo=0.2, brdf="lambert")
    fr = Renderer(gl).render(scene, View(look_at((64.5, 64.5, 100.0), (64.5, 64.6, 0.0)), K),
                             light, RenderOptions(shadows=False))
    assert np.all(np.isfinite(fr.range))
    return fr.radiance, light


def camera(**kw):
    base = dict(exposure_time=0.001, aperture=0.001, transmission=0.8, qe=0.6, wavelength=643.0,
                bandwidth=50.0, gain=2.5, read_noise=12.0, full_well=40000.0, bias=64.0,
                bits=14, dark_current=50.0)
    base.update(kw)
    return Sensor.from_mapping(base, seed=11)


def test_signal_follows_the_radiometry(flat_field):
    rad, light = flat_field
    s = camera(read_noise=0.0, shot_noise=False, dark_current=0.0, bias=0.0, bits=16,
               full_well=1e5)
    img = s.expose(rad, 0, intrinsics=K, spectral_irradiance=light.spectral_irradiance)
    # by hand: L = I/F F / pi; P = L dlambda A Omega tau; electrons = P t qe lambda / (h c)
    L = 0.2 * math.sin(math.radians(60.0)) * 1.58 / math.pi
    power = L * 50.0 * (math.pi * 0.001**2 / 4) / (K.fx * K.fy) * 0.8
    electrons = power * 0.001 * 0.6 * 643e-9 / (PLANCK * SPEED_OF_LIGHT)
    assert img.astype(float).mean() == pytest.approx(electrons / 2.5, rel=2e-3)


def test_photon_transfer_recovers_gain_and_read_noise(flat_field):
    rad, light = flat_field
    s0 = camera()
    per_second = s0.electrons_per_unit_if(K, light.spectral_irradiance) / s0.exposure_time
    signal = float(rad.mean()) * per_second  # electrons per second
    means, variances = [], []
    for t in np.geomspace(0.5, 30000.0, 14) / signal:  # 0.5 e- to 3/4 of the full well
        s = camera(exposure_time=float(t))
        a = s.expose(rad, 2, intrinsics=K, spectral_irradiance=light.spectral_irradiance)
        b = s.expose(rad, 3, intrinsics=K, spectral_irradiance=light.spectral_irradiance)
        a, b = a.astype(float), b.astype(float)
        means.append(0.5 * (a.mean() + b.mean()) - 64.0)
        variances.append(np.var(a - b) / 2)  # the difference cancels the fixed pattern
    slope, intercept = np.polyfit(means, variances, 1)
    gain = 1 / slope
    read = math.sqrt(max(intercept - 1 / 12, 0.0)) * gain  # less the rounding's 1/12 DN^2
    assert gain == pytest.approx(2.5, rel=0.02)
    assert read == pytest.approx(12.0, rel=0.05)


def test_saturation_clips_at_the_full_well(flat_field):
    rad, light = flat_field
    s = camera(read_noise=0.0, full_well=20000.0)
    e_per_if = s.electrons_per_unit_if(K, light.spectral_irradiance)
    over = camera(read_noise=0.0, full_well=20000.0,
                  exposure_time=0.001 * 5 * 20000.0 / (float(rad.mean()) * e_per_if))
    img = over.expose(rad, 0, intrinsics=K, spectral_irradiance=light.spectral_irradiance)
    assert np.all(img == round(20000.0 / 2.5 + 64.0))
    under = camera(read_noise=0.0, full_well=20000.0,
                   exposure_time=0.001 * 0.5 * 20000.0 / (float(rad.mean()) * e_per_if))
    img = under.expose(rad, 0, intrinsics=K, spectral_irradiance=light.spectral_irradiance)
    assert img.max() < 20000.0 / 2.5 + 64.0 and img.std() > 5
    # a full well beyond the converter's range clips at the top DN instead
    top = camera(read_noise=0.0, full_well=1e6, bits=12,
                 exposure_time=0.001 * 5 * 20000.0 / (float(rad.mean()) * e_per_if))
    assert np.all(top.expose(rad, 0, intrinsics=K,
                             spectral_irradiance=light.spectral_irradiance) == 4095)


def test_prnu_has_its_spread_and_is_fixed_across_frames(flat_field):
    rad, light = flat_field
    s = camera(prnu=0.015, read_noise=5.0)
    e_per_if = s.electrons_per_unit_if(K, light.spectral_irradiance)
    s = camera(prnu=0.015, read_noise=5.0,
               exposure_time=0.001 * 30000.0 / (float(rad.mean()) * e_per_if))
    a, b, c = (s.expose(rad, f, intrinsics=K, spectral_irradiance=light.spectral_irradiance)
               .astype(float) - 64.0 for f in (0, 1, 7))
    # noise is independent between frames, the fixed pattern is not: the covariance of two
    # frames is the pattern's variance alone
    for x, y in ((a, b), (a, c)):
        cov = np.mean((x - x.mean()) * (y - y.mean()))
        assert math.sqrt(cov) / x.mean() == pytest.approx(0.015, rel=0.05)
    pattern = s.prnu_map(rad.shape)
    assert pattern.std() == pytest.approx(0.015, rel=0.02)
    assert np.corrcoef(pattern.ravel(), (a + b + c).ravel())[0, 1] > 0.9
    # another sensor seed, another pattern
    other = Sensor.from_mapping(dict(exposure_time=0.01, aperture=0.01, gain=2.5, prnu=0.015),
                                seed=12)
    assert abs(np.corrcoef(pattern.ravel(), other.prnu_map(rad.shape).ravel())[0, 1]) < 0.05
    # a camera's own pattern, whatever the scenario's seed
    mine = dict(exposure_time=0.01, aperture=0.01, gain=2.5, prnu=0.015, prnu_seed=99)
    assert np.array_equal(Sensor.from_mapping(mine, seed=1).prnu_map(rad.shape),
                          Sensor.from_mapping(mine, seed=2).prnu_map(rad.shape))


def test_same_seed_same_bytes_and_frames_differ(flat_field):
    rad, light = flat_field
    s = camera(prnu=0.01)
    a = s.expose(rad, 4, intrinsics=K, spectral_irradiance=light.spectral_irradiance)
    b = s.expose(rad, 4, intrinsics=K, spectral_irradiance=light.spectral_irradiance)
    c = s.expose(rad, 5, intrinsics=K, spectral_irradiance=light.spectral_irradiance)
    assert a.tobytes() == b.tobytes() and not np.array_equal(a, c)


def test_low_signal_shot_noise_is_poisson():
    s = Sensor.from_mapping(dict(exposure_time=1.0, aperture=0.01, gain=1.0, bits=12))
    e = np.full((200, 200), 3.0)
    counts = s.digitise(e, 0)
    assert counts.mean() == pytest.approx(3.0, abs=0.03)
    assert counts.var() == pytest.approx(3.0, rel=0.05)
    assert np.mean(counts == 0) == pytest.approx(math.exp(-3.0), abs=0.005)


def test_psf_as_a_sum_of_gaussians_and_as_a_kernel_file(tmp_path):
    img = np.zeros((41, 41))
    img[20, 20] = 1.0
    s = Sensor.from_mapping(dict(exposure=1.0, bits=16, psf=[[0.7, 1.0], [0.3, 4.0]]))
    out = s.blur(img)
    assert out.sum() == pytest.approx(1.0, rel=1e-6)
    r2 = ((np.mgrid[0:41, 0:41] - 20.0) ** 2).sum(0)
    # second moment per axis of the mixture: 0.7 * 1^2 + 0.3 * 4^2
    assert (out * r2).sum() / 2 == pytest.approx(0.7 + 0.3 * 16, rel=0.02)
    kernel = np.zeros((5, 5))
    kernel[2, 2], kernel[2, 4] = 3.0, 1.0  # 1/4 of the light two pixels to the right
    np.save(tmp_path / "k.npy", kernel)
    s = Sensor.from_mapping(dict(exposure=1.0, psf_kernel="k.npy"), base=tmp_path)
    out = s.blur(img)
    assert out[20, 20] == pytest.approx(0.75) and out[20, 22] == pytest.approx(0.25)


def test_todays_simple_sensors_keep_their_meaning():
    legacy = Sensor.from_mapping({"bits": 8, "exposure": 5.0, "psf_sigma": 0.5, "gain": 20.0,
                                  "read_noise": 1.0})
    assert not legacy.physical
    flat = np.full((300, 300), 0.1)
    img = legacy.expose(flat, 0).astype(float)
    dn = 0.1 * 5.0 * 255
    assert img.mean() == pytest.approx(dn, abs=0.1)
    assert img.std() == pytest.approx(math.sqrt(dn / 20.0 + 1.0 + 1 / 12), rel=0.05)


def test_bad_sensor_tables_name_the_key():
    with pytest.raises(InvalidParameterError, match="'read_noise'"):
        Sensor.from_mapping({"exposure_time": 0.01, "aperture": 0.01, "gain": 1.0,
                             "readnoise": 3.0})
    with pytest.raises(InvalidParameterError, match="not both"):
        Sensor.from_mapping({"exposure": 5.0, "exposure_time": 0.01})
    with pytest.raises(InvalidParameterError, match="aperture"):
        Sensor.from_mapping({"exposure_time": 0.01, "gain": 1.0})
    with pytest.raises(InvalidParameterError, match="qe"):
        Sensor.from_mapping({"exposure_time": 0.01, "aperture": 0.01, "gain": 1.0, "qe": 1.5})


def test_frame_transfer_smear_and_natural_vignetting():
    k = Intrinsics.from_fov(64, 48, 50.0)
    s = Sensor.from_mapping(dict(exposure_time=0.01, aperture=0.002, gain=1.0, bits=16,
                                 shot_noise=False, transfer_time=0.0048))
    spot = 20000.0  # electrons
    img = np.zeros((48, 64))
    img[10, 20] = spot / s.electrons_per_unit_if(k)
    dn = s.expose(img, 0, intrinsics=k).astype(float)
    streak = 0.0048 / (48 * 0.01) * spot  # 1/100 of the spot's charge in every row of its column
    assert np.allclose(np.delete(dn[:, 20], 10), streak, atol=0.5)
    assert dn[10, 20] == pytest.approx(spot + streak, abs=0.5)
    assert np.all(np.delete(dn, 20, axis=1) == 0)
    v = Sensor.from_mapping(dict(exposure_time=0.01, aperture=0.002, gain=1.0, bits=16,
                                 shot_noise=False, natural_vignetting=True))
    level = 30000.0
    out = v.expose(np.full((48, 64), level / v.electrons_per_unit_if(k)), 0,
                   intrinsics=k).astype(float)
    corner = math.atan(math.hypot(k.cx / k.fx, k.cy / k.fy))  # field angle of pixel (0, 0)
    assert out[0, 0] / level == pytest.approx(math.cos(corner) ** 4, abs=1e-4)
    centre = math.atan(math.hypot((32 - k.cx) / k.fx, (24 - k.cy) / k.fy))
    assert out[24, 32] / level == pytest.approx(math.cos(centre) ** 4, abs=1e-4)


def test_dark_current_doubles_with_temperature():
    base = dict(exposure_time=2.0, f_number=2.0, pixel_pitch=5.0, gain=1.0, bits=16,
                shot_noise=False, dark_current=100.0, dark_temperature=20.0, dark_doubling=6.0)
    black = np.zeros((8, 8))
    for temperature, want in ((20.0, 200.0), (32.0, 800.0), (8.0, 50.0)):
        s = Sensor.from_mapping(dict(base, temperature=temperature))
        assert np.all(s.expose(black, 0) == want)
    assert np.all(Sensor.from_mapping(base).expose(black, 0) == 200)  # no temperature: as given


def test_physical_keys_on_an_if_calibrated_sensor_are_refused(tmp_path):
    with pytest.raises(InvalidParameterError, match="transfer_time"):
        Sensor.from_mapping({"exposure": 5.0, "transfer_time": 0.001})
    with pytest.raises(InvalidParameterError, match="psf"):
        Sensor.from_mapping({"exposure": 5.0, "psf": 3})
    with pytest.raises(MissingInputError, match="does not exist"):
        Sensor.from_mapping({"exposure": 5.0, "psf_kernel": "nope.npy"}, base=tmp_path)
