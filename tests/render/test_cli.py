"""`craterscape render` as a user runs it: sequences, single frames, resumption, errors."""

import json

import numpy as np
import pytest

from tests.cli_helpers import run
from tests.render.scenes import cratered_stack, descent_scenario


@pytest.fixture(scope="module")
def stack_dir(tmp_path_factory, gl):
    return cratered_stack(tmp_path_factory.mktemp("stack") / "stack")


def scenario(tmp_path, stack_dir, **extra):
    path = tmp_path / "s.toml"
    path.write_text(descent_scenario(stack_dir, "cli-test", frames=extra.get("frames", 3)))
    return path


def test_sequence_writes_frames_range_normals_truth_and_manifest(tmp_path, stack_dir):
    sc = scenario(tmp_path, stack_dir)
    r = run("render", "sequence", sc, "-o", tmp_path / "run")
    assert r.exit_code == 0, r.output
    run_dir = tmp_path / "run"
    truth = json.loads((run_dir / "truth.json").read_text())
    assert [t["index"] for t in truth] == [0, 1, 2]
    assert (run_dir / "scenario.toml").read_text() == sc.read_text()
    manifest = json.loads((run_dir / "manifest.json").read_text())
    assert manifest["frames_written"] == 3 and manifest["resolution"] == [64, 48]
    from render.rundir import RunReader

    reader = RunReader(run_dir)
    assert reader.image(2).dtype == np.uint16 and reader.image(2).shape == (48, 64)
    range_m = reader.range(1)
    assert range_m.dtype == np.float32 and np.nanmin(range_m) > 0
    assert reader.normals(0).shape == (48, 64, 3)
    assert truth[0]["drawn"]["triangles"] > 0
    # the same scenario and seed give the same bytes
    r = run("render", "sequence", sc, "-o", tmp_path / "again")
    for sub in ("frames/frame_000002.png", "range/range_000001.tif", "truth.json"):
        assert (run_dir / sub).read_bytes() == (tmp_path / "again" / sub).read_bytes()


def test_resume_renders_only_what_is_missing(tmp_path, stack_dir):
    sc = scenario(tmp_path, stack_dir, frames=3)
    assert run("render", "sequence", sc, "-o", tmp_path / "r").exit_code == 0
    # what an interrupted run leaves: the last frame missing from disk and from the truth
    truth = json.loads((tmp_path / "r" / "truth.json").read_text())
    (tmp_path / "r" / "truth.json").write_text(json.dumps(truth[:2]))
    (tmp_path / "r" / "frames" / "frame_000002.png").unlink()
    first = (tmp_path / "r" / "frames" / "frame_000001.png").stat().st_mtime_ns
    r = run("render", "sequence", sc, "-o", tmp_path / "r", "--frames", 2, "--resume")
    assert r.exit_code == 2 and "frames 3, not 2" in r.output  # another trajectory: refused
    r = run("render", "sequence", sc, "-o", tmp_path / "r", "--resume")
    assert r.exit_code == 0, r.output
    assert (tmp_path / "r" / "frames" / "frame_000002.png").exists()
    assert (tmp_path / "r" / "frames" / "frame_000001.png").stat().st_mtime_ns == first
    r = run("render", "sequence", sc, "-o", tmp_path / "r")
    assert r.exit_code == 2 and "not empty" in r.output


def test_single_frame_and_resolution_override(tmp_path, stack_dir):
    sc = scenario(tmp_path, stack_dir)
    out = tmp_path / "one.png"
    r = run("render", "frame", sc, "-o", out, "--index", 1, "--resolution", "32x24")
    assert r.exit_code == 0, r.output
    truth = json.loads((tmp_path / "one_truth.json").read_text())
    assert truth["intrinsics"]["width"] == 32 and truth["index"] == 1
    assert (tmp_path / "one_range.tif").exists()


@pytest.mark.parametrize("change, message", [
    ('type = "descent"', "frames"),
    ('type = "terrain"', "'terrain' or 'asteroid'"),
    ("[sun]", "unknown scenario [sun] key"),
])
def test_bad_scenarios_are_one_line_errors(tmp_path, stack_dir, change, message):
    sc = scenario(tmp_path, stack_dir)
    text = sc.read_text()
    if change == 'type = "descent"':
        text = text.replace("frames = 3", "frames = 0")
    elif change == 'type = "terrain"':
        text = text.replace('type = "terrain"', 'type = "planet"')
    else:
        text = text.replace("[sun]", "[sun]\nbrightness = 3")
    sc.write_text(text)
    r = run("render", "sequence", sc, "-o", tmp_path / "x")
    assert r.exit_code == 2, r.output
    assert message in r.output and len(r.output.strip().splitlines()) == 1
    r = run("render", "sequence", tmp_path / "missing.toml", "-o", tmp_path / "y")
    assert r.exit_code == 2 and "does not exist" in r.output


def test_missing_egl_names_the_packages(monkeypatch):
    import moderngl

    from render import context

    def broken(*args, **kwargs):
        raise RuntimeError("libEGL.so.1: cannot open shared object file")

    monkeypatch.setattr(moderngl, "create_context", broken)
    monkeypatch.setattr(context, "_made", None)  # as in a fresh process; undone after the test
    with pytest.raises(context.RenderUnavailableError) as err:
        context.create_context()
    msg = str(err.value)
    assert "libegl1" in msg and "libgl1-mesa-dri" in msg and "\n" not in msg


def _egl_current_context():
    import ctypes

    lib = ctypes.CDLL("libEGL.so.1")
    lib.eglGetCurrentContext.restype = ctypes.c_void_p
    return lib.eglGetCurrentContext()


@pytest.mark.parametrize("command", ["frame", "sequence"])
def test_an_in_process_render_gives_the_callers_gl_context_back(tmp_path, stack_dir, gl,
                                                                command):
    # an application with its own context current renders through the CLI entry point
    import moderngl

    sc = scenario(tmp_path, stack_dir, frames=2)
    mine = moderngl.create_context(standalone=True, backend="egl")
    try:
        handle = _egl_current_context()
        assert handle
        viewport = mine.viewport
        mine.viewport = (0, 0, 3, 2)  # a state of the caller's that no render may change
        out = tmp_path / ("one.png" if command == "frame" else "run")
        r = run("render", command, sc, "-o", out, "--resolution", "32x24")
        assert r.exit_code == 0, r.output
        assert _egl_current_context() == handle    # still the caller's, not the renderer's
        assert mine.viewport == (0, 0, 3, 2)       # and the render drew with its own context
        assert mine.error == "GL_NO_ERROR"
        mine.viewport = viewport
        # and the next render in the process still draws with its own context
        again = tmp_path / "two.png"
        r = run("render", "frame", sc, "-o", again, "--resolution", "32x24", "--index", 1)
        assert r.exit_code == 0, r.output
        assert _egl_current_context() == handle
    finally:
        mine.release()
        gl.__enter__()  # this test's own context is gone: the session's is current again
    assert _egl_current_context() and gl.error == "GL_NO_ERROR"
