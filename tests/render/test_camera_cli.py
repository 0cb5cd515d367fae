"""A data-sheet camera over Hapke terrain through `craterscape render`: radiance, DN, truth."""

import json
import math

import numpy as np
import pytest

from tests.cli_helpers import one_line_error, run
from tests.render.test_cli import scenario, stack_dir  # noqa: F401  (fixture)

CAMERA = """
[sensor]
bits = 12
exposure_time = 0.004
aperture = 0.004
transmission = 0.85
qe = 0.55
wavelength = 643.0
bandwidth = 40.0
gain = 3.0
bias = 32.0
full_well = 12000.0
shot_noise = false
line_time = 0.0005
"""


def datasheet_scenario(tmp_path, stack_dir, extra=""):  # noqa: F811
    sc = scenario(tmp_path, stack_dir, frames=2)
    text = sc.read_text()
    text = text[:text.index("[sensor]")] + CAMERA + text[text.index("[render]"):]
    text = text.replace("[sun]\n", "[sun]\ndistance = DIST\n").replace("DIST", extra or "1.0")
    text += '\n[surface]\nreflectance = "hapke"\n[output]\nradiance = true\n[motion]\nblur = true\n'
    sc.write_text(text)
    return sc


def test_datasheet_camera_radiance_and_rolling_shutter_truth(tmp_path, stack_dir):  # noqa: F811
    from render.rundir import RunReader
    from render.scenario import load_scenario
    from terrain.io import read_float_tiff

    sc = datasheet_scenario(tmp_path, stack_dir)
    r = run("render", "sequence", sc, "-o", tmp_path / "run")
    assert r.exit_code == 0, r.output
    reader = RunReader(tmp_path / "run")
    truth = json.loads((tmp_path / "run" / "truth.json").read_text())
    assert truth[1]["motion"]["line_time"] == 0.0005 and truth[1]["motion"]["samples"] >= 2
    assert np.linalg.norm(truth[1]["motion"]["velocity"]) > 100  # the descent's own speed
    t = reader.truth[1]
    assert t.row_time(47) == pytest.approx(t.time + 47 * 0.0005 + 0.002)
    manifest = json.loads((tmp_path / "run" / "manifest.json").read_text())
    assert manifest["lighting"]["hapke"]["w"] == 0.222
    assert manifest["sensor"]["exposure_time"] == 0.004
    rad = read_float_tiff(tmp_path / "run" / truth[1]["radiance"])
    img = reader.image(1).astype(float)
    # DN from the radiance by hand: electrons = L dlambda A Omega tau qe t lambda / (h c)
    s = load_scenario(sc)
    k = s.intrinsics
    photons = (rad * 40.0 * math.pi * 0.004**2 / 4 / (k.fx * k.fy) * 0.85 * 0.004
               * 643e-9 / (6.62607015e-34 * 299792458.0))
    want = np.minimum(photons * 0.55, 12000.0) / 3.0 + 32.0
    assert np.abs(img - want).max() <= 0.51
    assert 0.005 < float(np.median(rad)) * math.pi / 1.58 < 0.1  # lunar I/F, sun 15 deg high
    # twice as far from the Sun: a quarter of the radiance
    (tmp_path / "far").mkdir()
    far = datasheet_scenario(tmp_path / "far", stack_dir, "2.0")
    assert run("render", "sequence", far, "-o", tmp_path / "far" / "run").exit_code == 0
    rad2 = read_float_tiff(tmp_path / "far" / "run" / "radiance" / "radiance_000001.tif")
    assert np.allclose(rad2, rad / 4, rtol=1e-6)


@pytest.mark.parametrize("change, fragments", [
    ("read_noise_e = 3.0", ("read_noise_e", "did you mean 'read_noise'")),
    ("qe = 1.4", ("qe", "<= 1.0")),
    ("exposure = 5.0", ("not both",)),
])
def test_bad_sensor_keys_are_one_line_errors(tmp_path, stack_dir, change, fragments):  # noqa: F811
    sc = datasheet_scenario(tmp_path, stack_dir)
    text = sc.read_text().replace("qe = 0.55\n", "") if change.startswith("qe") else sc.read_text()
    sc.write_text(text.replace("[sensor]\n", f"[sensor]\n{change}\n"))
    one_line_error(run("render", "frame", sc, "-o", tmp_path / "x.png"), *fragments)


def test_bad_hapke_key_is_a_one_line_error(tmp_path, stack_dir):  # noqa: F811
    sc = datasheet_scenario(tmp_path, stack_dir)
    text = sc.read_text()
    sc.write_text(text.replace('reflectance = "hapke"', 'reflectance = "hapke"\nw0 = 0.3'))
    one_line_error(run("render", "frame", sc, "-o", tmp_path / "x.png"), "w0")


def test_the_camera_example_parses():
    from pathlib import Path

    from render.scenario import load_scenario

    s = load_scenario(Path(__file__).parents[2] / "examples" / "lunar_descent_camera.toml")
    assert s.sensor.physical and s.lighting.brdf == "hapke" and s.motion["blur"]
    assert s.outputs["radiance"] and s.sensor.psf == ((0.85, 0.6), (0.15, 2.5))


def test_hapke_keys_without_hapke_are_a_one_line_error(tmp_path, stack_dir):  # noqa: F811
    sc = datasheet_scenario(tmp_path, stack_dir)
    sc.write_text(sc.read_text().replace('reflectance = "hapke"',
                                         'reflectance = "lunar-lambert"\nw = 0.3'))
    one_line_error(run("render", "frame", sc, "-o", tmp_path / "x.png"), "Hapke", "w")


def test_blur_without_an_exposure_time_is_a_one_line_error(tmp_path, stack_dir):  # noqa: F811
    sc = scenario(tmp_path, stack_dir)  # today's I/F-calibrated sensor
    sc.write_text(sc.read_text() + "\n[motion]\nblur = true\n")
    one_line_error(run("render", "frame", sc, "-o", tmp_path / "x.png"), "exposure_time")
