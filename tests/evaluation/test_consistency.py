"""Frame-to-frame consistency through the truth, on the planar run of exact truth."""

import json
import shutil

import numpy as np
import pytest

from evaluation.consistency import SPIKE_BOUND, change_marks, consistency, pair_residual
from render.rundir import RunReader
from tests.cli_helpers import one_line_error, run


def test_a_consistent_run_has_a_small_flat_residual(planar_run):
    result = consistency(planar_run)
    s = result.summary()
    assert s["pairs"] == 11
    # the plane is rendered exactly: what is left is rounding to 8 bits and resampling a
    # texture of 3-4 texels per pixel, a couple of DN against a contrast of about 100 DN
    image = RunReader(planar_run).image(0).astype(np.float64)
    assert s["rms_dn_max"] < 0.05 * image.std()
    assert s["spike_ratio"] <= SPIKE_BOUND
    assert s["spikes"] == []
    # the fixture's truth changes its drawn layers at frame 6 (and only there)
    assert [f["next"] for f in result.frames if f["layer_change"]] == [6]
    # the whole plane is seen in both frames but for the image edges that move out
    assert s["counted_fraction_median"] > 0.9


def _pop(image: np.ndarray) -> np.ndarray:
    """A coarser level of detail over the middle of the frame: 4 x 4 block means."""
    out = image.astype(np.float64)
    h, w = out.shape[:2]
    y0, y1, x0, x1 = h // 4, 3 * h // 4, w // 4, 3 * w // 4
    block = out[y0:y1, x0:x1]
    coarse = block.reshape(block.shape[0] // 4, 4, block.shape[1] // 4, 4).mean(axis=(1, 3))
    out[y0:y1, x0:x1] = np.repeat(np.repeat(coarse, 4, axis=0), 4, axis=1)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def test_a_popped_frame_is_caught(planar_run, tmp_path):
    import cv2

    popped = tmp_path / "popped"
    shutil.copytree(planar_run, popped)
    frame = popped / "frames" / "frame_000004.png"
    cv2.imwrite(str(frame), _pop(cv2.imread(str(frame), cv2.IMREAD_UNCHANGED)))
    s = consistency(popped).summary()
    assert s["spike_ratio"] > SPIKE_BOUND
    assert s["spikes"] == [3, 4]  # the pairs (3, 4) and (4, 5)


def test_falsified_truth_shows_as_residual(planar_run):
    r = RunReader(planar_run)
    t0, t1 = r.truth[3], r.truth[4]
    good = pair_residual(r.image(3), r.image(4), r.range(3), r.range(4), t0, t1)
    from render.camera import Pose

    moved = type(t1)(t1.index, t1.time, Pose(tuple(np.add(t1.pose.position, [0.05, 0, 0])),
                                             t1.pose.attitude), t1.intrinsics, t1.sun)
    bad = pair_residual(r.image(3), r.image(4), r.range(3), r.range(4), t0, moved)
    assert bad.rms_dn > 2 * good.rms_dn


def test_sensor_noise_floor_matches_a_noise_only_pair(planar_run):
    """Two frames of one view that differ by sensor noise alone: rms = the noise floor."""
    from render.sensor import Sensor

    r = RunReader(planar_run)
    t = r.truth[2]
    sensor = Sensor(bits=8, exposure=1.0, gain=20.0, read_noise=1.0, seed=7)
    radiance = r.image(2).astype(np.float64) / 255.0
    a, b = sensor.expose(radiance, frame=0), sensor.expose(radiance, frame=1)
    pr = pair_residual(a, b, r.range(2), r.range(2), t, t, sensor=sensor.as_dict())
    assert pr.rms_dn == pytest.approx(pr.noise_floor_dn, rel=0.05)


def test_change_marks_tell_layers_from_levels_of_detail():
    drawn = [{"layers": [{"level": 0, "lod": [4]}], "lod_pixels": 3.0},
             {"layers": [{"level": 0, "lod": [2, 4]}], "lod_pixels": 3.0},
             {"layers": [{"level": 0, "lod": [2, 4]}, {"level": 1, "lod": [8]}],
              "lod_pixels": 3.0},
             {"body_magnitude": 64, "imposter": False, "boulders": {"0": 3}},
             {"body_magnitude": 64, "imposter": False, "boulders": {"0": 3, "1": 1}}]
    layer, lod = change_marks(drawn)
    assert layer.tolist() == [False, False, True, True, False]
    assert lod.tolist() == [False, True, True, True, True]


def test_cli_writes_json_csv_and_plot(planar_run, tmp_path):
    out = tmp_path / "cons"
    r = run("evaluation", "consistency", planar_run, "-o", out)
    assert r.exit_code == 0, r.output
    assert "residual rms median" in r.output
    doc = json.loads((out / "consistency.json").read_text())
    assert doc["summary"]["pairs"] == 11 and len(doc["frames"]) == 11
    assert (out / "consistency.png").read_bytes()[:4] == b"\x89PNG"
    assert len((out / "consistency.csv").read_text().splitlines()) == 12


def test_cli_refuses_a_run_without_truth(run_without_truth, tmp_path):
    one_line_error(run("evaluation", "consistency", run_without_truth, "-o", tmp_path / "c"),
                   "truth.json")


def test_a_sampled_measurement_agrees_with_every_pixel(planar_run, tmp_path):
    """Every other pixel: the same figures within their sampling error, a popped frame still
    caught, and the warp (projective geometry, independent of the spacing) unchanged."""
    full = consistency(planar_run)
    half = consistency(planar_run, stride=2)
    assert half.settings["stride"] == 2
    a = np.array([f["rms_dn"] for f in full.frames])
    b = np.array([f["rms_dn"] for f in half.frames])
    # a quarter of a small frame's pixels (a few thousand counted, correlated by the
    # texture): the rms of a pair typically within a per cent or two, none off by 10 %
    assert np.median(np.abs(b / a - 1)) < 0.02
    assert np.all(np.abs(b / a - 1) < 0.1)
    assert half.summary()["counted_fraction_median"] == pytest.approx(
        full.summary()["counted_fraction_median"], abs=0.01)
    import cv2

    popped = tmp_path / "popped"
    shutil.copytree(planar_run, popped)
    frame = popped / "frames" / "frame_000004.png"
    cv2.imwrite(str(frame), _pop(cv2.imread(str(frame), cv2.IMREAD_UNCHANGED)))
    assert consistency(popped, stride=2).summary()["spikes"] == [3, 4]
    r = RunReader(planar_run)
    pr = pair_residual(r.image(3), r.image(4), r.range(3), r.range(4), r.truth[3],
                       r.truth[4], stride=2)
    h, w = r.range(3).shape
    assert pr.mask.shape == (-(-h // 2), -(-w // 2))


def test_a_stride_that_does_not_divide_the_tiles_is_refused(planar_run):
    from terrain.core.errors import InvalidParameterError

    r = RunReader(planar_run)
    with pytest.raises(InvalidParameterError, match="stride"):
        pair_residual(r.image(3), r.image(4), r.range(3), r.range(4), r.truth[3],
                      r.truth[4], stride=3)
