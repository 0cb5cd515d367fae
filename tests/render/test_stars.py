"""Stars from the Hipparcos catalogue land where the catalogue, projected through the camera's
truth attitude, puts them: centroids of the imaged stars (through the sensor's PSF and
quantisation) within 0.1 px of an independent projection (SPICE's radrec and the camera
model's own ``Pose.project``)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from render.camera import Intrinsics, Pose
from render.sensor import Sensor
from render.stars import (
    HIPPARCOS_EPOCH,
    JULIAN_YEAR_S,
    StarField,
    add_stars,
    load_catalog,
    star_irradiance,
)
from terrain.core.errors import InvalidParameterError


def _look(ra_deg: float, dec_deg: float) -> Pose:
    """A camera at the origin looking at (ra, dec) of the world (= ICRF) frame."""
    from render.camera import look_at

    ra, dec = math.radians(ra_deg), math.radians(dec_deg)
    d = np.array([math.cos(dec) * math.cos(ra), math.cos(dec) * math.sin(ra), math.sin(dec)])
    return look_at((0.0, 0.0, 0.0), tuple(1e3 * d), up=(0.0, 0.0, 1.0))


def test_imaged_stars_sit_on_the_catalogue_within_a_tenth_of_a_pixel():
    import spiceypy

    k = Intrinsics.from_fov(256, 256, 20.0)
    pose = _look(84.0, -2.0)  # Orion's belt and sword
    et = HIPPARCOS_EPOCH * JULIAN_YEAR_S  # the catalogue's epoch: no proper motion
    radiance = np.zeros((256, 256), np.float32)
    info = add_stars(radiance, np.ones((256, 256), bool), StarField(6.0), np.eye(3), et, pose,
                     k, 1.58)
    assert info["drawn"] > 20 and info["hidden"] == 0
    sensor = Sensor.from_mapping({"bits": 16, "exposure": 3e5, "psf_sigma": 1.0})
    image = sensor.expose(radiance, 0, intrinsics=k, spectral_irradiance=1.58).astype(float)
    cat = load_catalog(6.0)
    # the independent projection of every catalogue star
    dirs = np.array([spiceypy.radrec(1.0, a, d) for a, d in zip(cat.ra, cat.dec, strict=True)])
    uv = pose.project(1e9 * dirs, k)
    ok = np.isfinite(uv).all(axis=1) & (uv[:, 0] > 6) & (uv[:, 0] < 249) & (uv[:, 1] > 6) \
        & (uv[:, 1] < 249)
    checked = 0
    for i in np.flatnonzero(ok):
        others = np.delete(uv[ok], np.flatnonzero(np.flatnonzero(ok) == i), axis=0)
        if np.min(np.hypot(*(others - uv[i]).T)) < 8.0:  # blended with a neighbour
            continue
        u0, v0 = np.round(uv[i]).astype(int)
        win = image[v0 - 4:v0 + 5, u0 - 4:u0 + 5]
        if win.max() >= 65535 or win.max() < 200:  # saturated, or too faint to centroid
            continue
        yy, xx = np.mgrid[v0 - 4:v0 + 5, u0 - 4:u0 + 5]
        cu, cv = (win * xx).sum() / win.sum(), (win * yy).sum() / win.sum()
        assert math.hypot(cu - uv[i, 0], cv - uv[i, 1]) <= 0.1, cat.hip[i]
        checked += 1
    assert checked >= 5


def test_a_star_behind_a_surface_is_hidden_and_flux_follows_magnitude():
    k = Intrinsics.from_fov(128, 128, 30.0)
    pose = _look(84.0, -2.0)
    radiance = np.zeros((128, 128), np.float32)
    sky = np.ones((128, 128), bool)
    sky[:, :64] = False  # a limb covering the left half
    info = add_stars(radiance, sky, StarField(5.0), np.eye(3), 0.0, pose, k, 1.58)
    assert info["hidden"] > 0 and not radiance[:, :63].any()
    # total I/F of the drawn stars equals their irradiance over the solar one, per pixel
    cat = load_catalog(5.0)
    full = np.zeros((128, 128), np.float32)
    add_stars(full, np.ones((128, 128), bool), StarField(5.0), np.eye(3), 0.0, pose, k, 1.58)
    scale = math.pi * k.fx * k.fy / 1.58
    assert full.sum() > 0
    assert star_irradiance(cat.magnitude).max() * scale >= full.max()


def test_the_field_refuses_bad_settings():
    with pytest.raises(InvalidParameterError, match="did you mean 'magnitude_limit'"):
        StarField.from_mapping({"magnitude": 6})
    with pytest.raises(InvalidParameterError, match="magnitude_limit"):
        StarField(30.0)


@pytest.mark.slow
def test_a_dated_view_of_the_horizon_shows_stars_in_its_sky(tmp_path, gl):
    """A camera over the cratered stack looking at the horizon under a dated sun: stars are
    imaged in the sky (hiding behind surfaces is tested above on a known mask), and the
    frame's truth holds the rotation to ICRF they were placed with."""
    from render.rundir import RunReader
    from render.scenario import load_scenario
    from render.sequence import run_sequence
    from tests.render.scenes import cratered_stack

    stack = cratered_stack(tmp_path / "stack")
    (tmp_path / "s.toml").write_text(f"""
name = "stars"
seed = 1
[scene]
type = "terrain"
stack = "{stack}"
[sun]
utc = "2027-01-15T12:00:00"
longitude = 0.0
latitude = -89.5
[camera]
width = 96
height = 64
fov = 60.0
[sensor]
bits = 16
exposure = 200000.0
[render]
shadow_size = 256
[stars]
magnitude_limit = 6.0
[trajectory]
type = "keyframes"
frames = 1
[[trajectory.keyframe]]
time = 0.0
position = [0.0, 0.0, 800.0]
look_at = [3000.0, 3000.0, 900.0]
""")
    run_sequence(load_scenario(tmp_path / "s.toml"), tmp_path / "run")
    run = RunReader(tmp_path / "run")
    truth = run.truth[0]
    stars = truth.drawn["stars"]
    assert stars["drawn"] > 0
    assert np.asarray(stars["world_to_icrf"]).shape == (3, 3)
    image = run.image(0).astype(float)
    rng = run.range(0)
    ground = np.isfinite(rng)
    assert ground.any() and (~ground).any()
    sky_bright = image[~ground & (image > 1000)]
    assert sky_bright.size > 0
