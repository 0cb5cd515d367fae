"""Monte Carlo campaigns: every case rendered, each byte for byte what rendering it alone
gives (in this process, on a local pool, on a `dask scheduler`/`dask worker` cluster),
resumable, with a summary a user can read."""

import csv
import json
import math
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.cli_helpers import one_line_error, run, snapshot
from tests.render.scenes import cratered_stack, descent_scenario

#: What a run directory holds that depends only on the case (the manifest has timings).
SAME_BYTES = ("frames", "range", "normals", "truth.json", "scenario.toml")


@pytest.fixture(scope="module")
def stack_dir(tmp_path_factory, gl):
    return cratered_stack(tmp_path_factory.mktemp("stack") / "stack")


@pytest.fixture
def files(tmp_path, stack_dir):
    scenario = tmp_path / "s.toml"
    scenario.write_text(descent_scenario(stack_dir, "mc", frames=2))
    table = tmp_path / "d.csv"
    table.write_text("seed,sun.elevation,position.x,attitude.z,sensor.gain\n"
                     "1,10,,0.5,\n2,20,50,,5\n3,30,-50,1,8\n")
    return scenario, table


def _run_bytes(run_dir: Path) -> dict:
    return {p.relative_to(run_dir): b for p, b in snapshot(
        *(run_dir / name for name in SAME_BYTES)).items()}


def _alone(case_file: Path, out: Path) -> dict:
    result = run("render", "sequence", case_file, "-o", out)
    assert result.exit_code == 0, result.output
    return _run_bytes(out)


def _summary(out: Path) -> list[dict]:
    with open(out / "summary.csv", newline="") as f:
        return list(csv.DictReader(f))


def test_every_case_is_rendered_as_its_own_scenario_would_be_alone(files, tmp_path):
    scenario, table = files
    out = tmp_path / "out"
    result = run("render", "campaign", scenario, table, "-o", out)
    assert result.exit_code == 0, result.output
    rows = _summary(out)
    assert [r["case"] for r in rows] == ["0", "1", "2"]
    assert [r["sun.elevation"] for r in rows] == ["10.0", "20.0", "30.0"]
    assert rows[0]["position.x"] == "" and rows[0]["sensor.gain"] == ""  # kept the scenario's
    # case 1 is shifted 50 m east of case 0 and case 2 50 m west, from the first frame on
    x0 = [float(r["start_x"]) for r in rows]
    assert x0[1] - x0[0] == pytest.approx(50.0) and x0[0] - x0[2] == pytest.approx(50.0)
    assert all(r["frames"] == "2" for r in rows)
    for k in range(3):
        case_run = out / "cases" / f"{k:06d}"
        truth = json.loads((case_run / "truth.json").read_text())
        assert truth[0]["sun"]["direction"][2] == pytest.approx(
            math.sin(math.radians(10.0 * (k + 1))))
    # the last case rendered after two others in one process equals it rendered alone
    case = out / "cases" / "000002.toml"
    assert _run_bytes(out / "cases" / "000002") == _alone(case, tmp_path / "alone")
    # the sensor's noise differs between cases (their seeds differ)
    a = (out / "cases" / "000000" / "frames" / "frame_000000.png").read_bytes()
    b = (out / "cases" / "000001" / "frames" / "frame_000000.png").read_bytes()
    assert a != b


@pytest.mark.slow
def test_a_resumed_campaign_skips_finished_cases_and_redoes_partial_ones(files, tmp_path):
    scenario, table = files
    out = tmp_path / "out"
    assert run("render", "campaign", scenario, table, "-o", out).exit_code == 0
    finished = _run_bytes(out / "cases" / "000000")
    stamp = (out / "cases" / "000000" / "manifest.json").stat().st_mtime_ns
    # an interruption: case 1 was being rendered, case 2 never started
    (out / "cases" / "000001").rename(out / "cases" / ".000001.rendering")
    (out / "cases" / ".000001.rendering" / "truth.json").write_text("[")
    shutil.rmtree(out / "cases" / "000002")
    again = run("render", "campaign", scenario, table, "-o", out)
    one_line_error(again, "--resume")
    result = run("render", "campaign", scenario, table, "-o", out, "--resume")
    assert result.exit_code == 0, result.output
    assert "rendered 2 of 3 cases" in result.output
    assert (out / "cases" / "000000" / "manifest.json").stat().st_mtime_ns == stamp
    assert _run_bytes(out / "cases" / "000000") == finished
    assert not list((out / "cases").glob(".*"))
    assert [r["case"] for r in _summary(out)] == ["0", "1", "2"]
    assert _run_bytes(out / "cases" / "000001") == _alone(out / "cases" / "000001.toml",
                                                          tmp_path / "alone")
    table.write_text("seed\n9\n")  # other dispersions are another campaign
    one_line_error(run("render", "campaign", scenario, table, "-o", out, "--resume"),
                   "another scenario or other dispersions")


@pytest.mark.parametrize("text, fragments", [
    ("seed,sun.elevaton\n1,2\n", ("sun.elevaton", "did you mean 'sun.elevation'")),
    ("seed,sensor.bits\n1,99\n", ("case 0", "bits")),
])
def test_bad_dispersions_are_one_line_and_write_nothing(files, tmp_path, text, fragments):
    scenario, table = files
    table.write_text(text)
    result = run("render", "campaign", scenario, table, "-o", tmp_path / "out")
    one_line_error(result, *fragments)
    assert not (tmp_path / "out").exists()


@pytest.mark.slow
def test_a_case_on_a_dask_cluster_equals_it_rendered_alone(files, tmp_path):
    """One `dask scheduler` and one `dask worker` on loopback, as a cluster is started."""
    scenario, table = files
    table.write_text("seed,sun.elevation,velocity.y\n4,12,3.0\n5,25,-2.0\n")
    dask = Path(sys.executable).with_name("dask")
    info = tmp_path / "scheduler.json"
    quiet = dict(stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs = [subprocess.Popen([dask, "scheduler", "--host", "127.0.0.1", "--port", "0",
                               "--no-dashboard", "--scheduler-file", info], **quiet)]
    try:
        deadline = time.monotonic() + 60
        while not info.exists() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(info.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        procs.append(subprocess.Popen([dask, "worker", address, "--nworkers", "1",
                                       "--nthreads", "1", "--no-dashboard",
                                       "--host", "127.0.0.1"], **quiet))
        out = tmp_path / "out"
        result = run("render", "campaign", scenario, table, "-o", out, "--scheduler", address)
        assert result.exit_code == 0, result.output
        assert "rendered 2 of 2 cases" in result.output
    finally:
        for p in reversed(procs):
            p.terminate()
            p.wait(timeout=30)
    rows = _summary(out)
    assert all(r["worker"].rsplit(":", 1)[1] != str(os.getpid()) for r in rows)  # not here
    assert _run_bytes(out / "cases" / "000001") == _alone(out / "cases" / "000001.toml",
                                                          tmp_path / "alone")


@pytest.mark.slow
def test_an_unreachable_scheduler_is_one_line_and_writes_nothing(files, tmp_path):
    import socket

    scenario, table = files
    with socket.socket() as s:  # a port nothing listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    result = run("render", "campaign", scenario, table, "-o", tmp_path / "out",
                 "--scheduler", f"tcp://127.0.0.1:{port}")
    one_line_error(result, "cannot reach the Dask scheduler")
    assert not (tmp_path / "out").exists()
