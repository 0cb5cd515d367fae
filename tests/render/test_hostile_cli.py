"""Hostile input to the render commands: typed scenarios, refusals before work, run folders that are
never mixed up, and no partial file after a resumed run. Refusals are exit code 2 with one
line on stderr, every input byte-identical and no output left."""

import json
import os
import subprocess
import sys

import pytest

from tests.cli_helpers import file_size_limit, refused, run, snapshot, unwritable_folder
from tests.render.test_cli import scenario


@pytest.fixture(autouse=True)
def _session_context_current_again(gl):
    """Every CLI render makes a context of its own current; moderngl does not switch back,
    so the session's context is made current again for the GL tests that follow."""
    yield
    gl.__enter__()


@pytest.fixture(scope="module")
def stack_dir(tmp_path_factory, gl):
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    base = synthesize_tile(65, resolution=100.0, relief=500.0, seed=3).tile
    stack = build_stack(base, (3250.0, 3250.0), levels=1, layer_size=33, seed=4)
    return write_stack(stack, tmp_path_factory.mktemp("stack") / "stack")


def _edit(path, old, new):
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new))
    return path


@pytest.mark.parametrize("old, new, fragment", [
    ("[render]\n", '[render]\nshadows = "false"\n', "true or false"),
    ("[render]\n", '[output]\nrange = "no"\n[render]\n', "true or false"),
    ("width = 64", 'width = "abc"', "scenario [camera] width must be an integer"),
    ("exposure = 4.0", 'exposure = "high"', "exposure must be a number"),
    ("seed = 5", "seed = -1", "seed"),
    ("[sun]", "[sun]\nazimut = 3.0", "did you mean 'azimuth'"),
    ("[render]\n", "[render]\n[extra]\nx = 1\n", "'extra'"),
    ("exposure = 4.0", "exposure = 4.0\npsf = [[1.0, 1e9]]", "psf sigma must be <="),
    ("exposure = 4.0", "exposure = 4.0\npsf_sigma = 1e300", "psf_sigma must be <="),
    ("exposure = 4.0", 'exposure = 4.0\npsf_kernel = "/dev/zero"', "not a regular file"),
    ("ground_track = [300.0, 100.0]", 'ground_track = [300.0, "x"]', "ground_track"),
    ("ground_track = [300.0, 100.0]", 'ground_track = [300.0, 100.0]\n'
     '[[trajectory.keyframe]]\ntime = "abc"\nposition = [0.0, 0.0, 100.0]\n',
     "keyframe]] #1 time must be a number"),
])
def test_scenarios_are_typed_key_by_key(tmp_path, stack_dir, old, new, fragment):
    sc = _edit(scenario(tmp_path, stack_dir), old, new)
    before = snapshot(sc, stack_dir)
    out = tmp_path / "f.png"
    refused(run("render", "frame", sc, "-o", out), before, out, fragments=[fragment],
            folder=tmp_path)
    refused(run("render", "sequence", sc, "-o", tmp_path / "run"), before, tmp_path / "run",
            fragments=[fragment], folder=tmp_path)


def test_frames_larger_than_memory_are_refused_before_rendering(tmp_path, stack_dir):
    sc = scenario(tmp_path, stack_dir)
    before = snapshot(sc, stack_dir)
    out = tmp_path / "f.png"
    refused(run("render", "frame", sc, "-o", out, "--resolution", "100000x100000"), before,
            out, fragments=["largest image side"], folder=tmp_path)
    refused(run("render", "frame", sc, "-o", out, "--resolution", "30000x30000",
                env={"CRATERSCAPE_MEMORY_LIMIT": "1G"}), before, out,
            fragments=["needs about"], folder=tmp_path)
    refused(run("render", "sequence", sc, "-o", tmp_path / "run", "--resolution",
                "30000x30000", env={"CRATERSCAPE_MEMORY_LIMIT": "1G"}), before,
            tmp_path / "run", fragments=["needs about"], folder=tmp_path)


def test_an_approach_may_not_end_inside_the_body(tmp_path, gl):
    body = tmp_path / "b.npz"
    assert run("asteroid", "build", "-o", body, "--magnitude", 8, "--radius", 500,
               "--base", "perlin").exit_code == 0
    sc = tmp_path / "a.toml"
    sc.write_text(f"""
[scene]
type = "asteroid"
body = "{body}"
[camera]
width = 32
height = 32
[trajectory]
type = "approach"
frames = 2
start_distance = 5000.0
end_distance = 100.0
""")
    before = snapshot(sc, body)
    out = tmp_path / "f.png"
    refused(run("render", "frame", sc, "-o", out), before, out, fragments=["inside the body"],
            folder=tmp_path)


def test_cannot_write_here_is_exit_2_for_frames_and_runs(tmp_path, stack_dir):
    sc = scenario(tmp_path, stack_dir)
    before = snapshot(sc, stack_dir)
    ro = unwritable_folder(tmp_path)
    refused(run("render", "frame", sc, "-o", ro / "f.png"), before, fragments=["cannot write"])
    refused(run("render", "sequence", sc, "-o", ro / "run"), before,
            fragments=["cannot write"])
    with file_size_limit(3_000):  # a full disk: the range image does not fit
        r = run("render", "frame", sc, "-o", tmp_path / "f.png")
    refused(r, before, tmp_path / "f.png", tmp_path / "f_truth.json",
            fragments=["cannot write"], folder=tmp_path)
    with file_size_limit(3_000):
        r = run("render", "sequence", sc, "-o", tmp_path / "run")
    one_line = [ln for ln in r.output.splitlines() if ln.strip()]
    assert r.exit_code == 2 and len(one_line) == 1 and "cannot write" in one_line[0]
    assert snapshot(*before) == before
    assert not [p for p in tmp_path.rglob("*.partial")]


def test_resume_only_continues_a_run_of_the_same_scenario(tmp_path, stack_dir):
    sc = scenario(tmp_path, stack_dir)
    other = tmp_path / "photos"
    other.mkdir()
    (other / "holiday.png").write_bytes(b"not a run")
    before = snapshot(sc, stack_dir, other)
    refused(run("render", "sequence", sc, "-o", other, "--resume"), before,
            fragments=["not a craterscape run directory"])
    assert sorted(p.name for p in other.iterdir()) == ["holiday.png"]
    refused(run("render", "sequence", sc, "-o", stack_dir, "--resume"), before,
            fragments=["input folder"])


def test_a_resumed_run_leaves_no_partial_files(tmp_path, stack_dir):
    sc = scenario(tmp_path, stack_dir)
    out = tmp_path / "run"
    assert run("render", "sequence", sc, "-o", out).exit_code == 0
    # what a killed render leaves: a frame half written by a process that is gone
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True).stdout.strip()
    truth = json.loads((out / "truth.json").read_text())
    (out / "truth.json").write_text(json.dumps(truth[:1]))
    for name in ("frames/frame_000001.png", "range/range_000001.tif"):
        (out / name).unlink()
        (out / name).with_name(f".{(out / name).name}.{dead}-abcd1234.partial").write_bytes(b"x")
    r = run("render", "sequence", sc, "-o", out, "--resume")
    assert r.exit_code == 0, r.output
    assert not [p for p in out.rglob("*.partial")]
    assert [t["index"] for t in json.loads((out / "truth.json").read_text())] == [0, 1, 2]
    assert os.path.exists(out / "frames" / "frame_000001.png")


def test_a_kernel_that_is_a_fifo_is_refused_at_once(tmp_path, stack_dir):
    """A FIFO named as the PSF kernel would block a reader for ever; it is not a file."""
    import threading

    sc = _edit(scenario(tmp_path, stack_dir), "exposure = 4.0",
               'exposure = 4.0\npsf_kernel = "pipe.txt"')
    os.mkfifo(tmp_path / "pipe.txt")
    out = tmp_path / "f.png"
    got = {}
    th = threading.Thread(target=lambda: got.setdefault("r", run("render", "frame", sc, "-o",
                                                                 out)))
    th.start()
    th.join(timeout=60)
    if th.is_alive():  # release the blocked reader before failing
        os.close(os.open(tmp_path / "pipe.txt", os.O_WRONLY | os.O_NONBLOCK))
        th.join()
        pytest.fail("reading the PSF kernel blocked on a FIFO")
    refused(got["r"], {}, out, fragments=["not a regular file"], folder=tmp_path)
