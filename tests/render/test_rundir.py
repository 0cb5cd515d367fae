"""Run directories read back: the machine-written truth file and manifest refuse any key the
writer does not write, by name and with the nearest valid one, as every input file does."""

import json

import numpy as np
import pytest

from render.camera import Intrinsics, Pose
from render.rundir import FrameTruth, RunReader, RunWriter
from terrain.core.errors import InvalidParameterError


@pytest.fixture
def run_dir(tmp_path):
    out = tmp_path / "run"
    writer = RunWriter(out, dict(scenario="s", scene="terrain", frames=2, resolution=[4, 3],
                                 seed=1, sensor={"bits": 8}, lighting={"sun": [0, 0, 1]},
                                 renderer={"GL_RENDERER": "any"}))
    for i in range(2):
        truth = FrameTruth(i, 0.5 * i, Pose((0.0, 0.0, 100.0), (0.0, 1.0, 0.0, 0.0)),
                           Intrinsics.from_fov(4, 3, 50.0), (0.0, 0.0, 1.0),
                           motion={"velocity": [1.0, 0, 0], "angular_velocity": [0, 0, 0],
                                   "body_angular_velocity": [0, 0, 0], "exposure_time": 0.1,
                                   "line_time": 0.0, "samples": 3})
        writer.write_frame(truth, np.zeros((3, 4), np.uint8), np.ones((3, 4), np.float32),
                           None)
    writer.finish(render_seconds=1.0, frames_rendered_this_run=2)
    return out


def _edit(path, change):
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def test_a_run_as_written_reads_back(run_dir):
    run = RunReader(run_dir)
    assert len(run) == 2 and run.truth[1].time == 0.5
    assert run.truth[0].motion["samples"] == 3


def test_the_range_at_one_pixel_is_the_range_image_s_value_there(run_dir):
    run = RunReader(run_dir)
    assert run.range_at(1, 2, 3) == float(run.range(1)[2, 3]) == 1.0
    assert RunReader(run_dir).range_at(0, 0, 0) == 1.0  # read from the file, not a cache


def test_frames_read_again_are_the_file_s_pixels_and_the_caller_s_own(run_dir, monkeypatch):
    import cv2

    import render.rundir as rundir

    monkeypatch.setattr(rundir, "IMAGE_KEEP_BYTES", 12)  # one 4x3 8-bit frame
    run = RunReader(run_dir)
    stored = [cv2.imread(str(p), cv2.IMREAD_UNCHANGED) for p in run.images]
    for _ in range(2):  # the first pass decodes, the second reads the kept frame 0
        for k in range(len(run)):
            img = run.image(k)
            assert img.dtype == stored[k].dtype and np.array_equal(img, stored[k])
            img[...] = 7  # the caller's copy: the reader's kept frame is unchanged
    assert list(run._images) == [0]  # the budget held frame 0 only, none dropped


@pytest.mark.parametrize("change, key, near", [
    (lambda t: t[1].update(tme=0.5), "tme", "time"),
    (lambda t: t[0]["camera"].update(positon=[0, 0, 1]), "positon", "position"),
    (lambda t: t[0]["intrinsics"].update(fz=1.0), "fz", "fx"),
    (lambda t: t[0]["sun"].update(directon=[0, 0, 1]), "directon", "direction"),
    (lambda t: t[0]["motion"].update(line_tme=0.0), "line_tme", "line_time"),
])
def test_an_unknown_key_in_the_truth_file_is_refused_by_name(run_dir, change, key, near):
    _edit(run_dir / "truth.json", change)
    for read in (lambda: RunReader(run_dir), lambda: RunWriter(run_dir, {}, resume=True)):
        with pytest.raises(InvalidParameterError, match=f"key '{key}' .*'{near}'"):
            read()


@pytest.mark.parametrize("change, key, near", [
    (lambda m: m.update(seeed=1), "seeed", "seed"),
    (lambda m: m["lighting"].update(albdo=0.1), "albdo", "albedo"),
    (lambda m: m["sensor"].update(gian=2.0), "gian", "gain"),
])
def test_an_unknown_key_in_the_manifest_is_refused_by_name(run_dir, change, key, near):
    _edit(run_dir / "manifest.json", change)
    for read in (lambda: RunReader(run_dir), lambda: RunWriter(run_dir, {}, resume=True)):
        with pytest.raises(InvalidParameterError, match=f"key '{key}' .*'{near}'"):
            read()
