"""`render.sequence.run_sequence`: frames exposed and written behind the next frame's render."""

import json

import numpy as np
import pytest

from tests.render.scenes import cratered_stack, descent_scenario

AUTO_EXPOSURE = "[sensor]\nauto_exposure = true\nae_rate = 0.5\n"


@pytest.fixture(scope="module")
def stack_dir(tmp_path_factory, gl):
    return cratered_stack(tmp_path_factory.mktemp("stack") / "stack")


def auto_exposed(tmp_path, stack_dir, frames=4):
    from render.scenario import load_scenario

    path = tmp_path / "s.toml"
    path.write_text(descent_scenario(stack_dir, "sequence-test", frames=frames)
                    .replace("[sensor]\n", AUTO_EXPOSURE))
    return load_scenario(path)


def test_sequence_equals_frames_rendered_one_at_a_time(tmp_path, stack_dir):
    """The images and exposures written equal those of render_sample, frame after frame."""
    from render.renderer import Renderer
    from render.rundir import RunReader
    from render.sensor import ExposureControl
    from render.sequence import load_scene, render_sample, run_sequence

    sc = auto_exposed(tmp_path, stack_dir)
    run_sequence(sc, tmp_path / "run")
    reader = RunReader(tmp_path / "run")
    truth = json.loads((tmp_path / "run" / "truth.json").read_text())
    renderer, scene = Renderer(), load_scene(sc)
    samples = sc.samples(scene)
    control = ExposureControl(sc.sensor)
    exposures = []
    for i, sample in enumerate(samples):
        image, frame, t = render_sample(renderer, scene, sc, sample, i, samples,
                                        exposure=control)
        assert np.array_equal(reader.image(i), image)
        assert np.array_equal(reader.range(i), frame.range, equal_nan=True)
        assert truth[i]["exposure"] == t.exposure
        exposures.append(t.exposure["exposure"])
    assert len(set(exposures)) > 1  # the loop moved: each frame took the one before's


def test_a_failed_write_ends_the_run_with_complete_frames_listed(tmp_path, stack_dir,
                                                                 monkeypatch):
    from render.rundir import RunReader, RunWriter
    from render.sequence import run_sequence
    from terrain.core.errors import OutputPathError

    write = RunWriter.write_frame

    def fail_on_frame_2(self, truth, *args, **kwargs):
        if truth.index == 2:
            raise OutputPathError("disk full (test)")
        return write(self, truth, *args, **kwargs)

    monkeypatch.setattr(RunWriter, "write_frame", fail_on_frame_2)
    with pytest.raises(OutputPathError, match="disk full"):
        run_sequence(auto_exposed(tmp_path, stack_dir), tmp_path / "run")
    reader = RunReader(tmp_path / "run")
    assert [t.index for t in reader.truth] == [0, 1]
    assert all(reader.images[k].exists() for k in (0, 1))
    assert not (tmp_path / "run" / "frames" / "frame_000002.png").exists()
