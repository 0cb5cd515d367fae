"""Layer-stack edits under kills and concurrent readers: nothing lost or stale.

Edits run in forked children that are SIGKILLed at random moments; every stack that
survives must be consistent: the manifest, the catalogue it names and the layers it names
agree (one catalogue row per recorded edit, no phantom crater), coarse pixels equal their
co-located fine pixels, and the next edit sweeps whatever the killed one left.
"""

import json
import os
import signal
import time

import numpy as np
import pytest

from terrain.craters.population import Population
from terrain.fractal.synthetic import synthesize_tile
from terrain.stack.build import build_stack
from terrain.stack.edit import replace_crater
from terrain.stack.store import LOCK, MANIFEST, READERS_LOCK, read_stack, write_stack

KILLS = 24


@pytest.fixture
def stack_folder(tmp_path):
    base = synthesize_tile(33, resolution=100.0, relief=300.0, seed=2).tile
    stack = build_stack(base, (1650.0, 1650.0), levels=2, layer_size=33, seed=4,
                        population=Population(dmin=60.0, dmax=600.0, density=40.0))
    return write_stack(stack, tmp_path / "stack")


def _edit(folder, i):
    # the smallest craters the finest layer resolves (4 of its 25 m pixels), near the site,
    # each in the finest layer; positions differ per edit
    replace_crater(folder, 1650.0 + 3.0 * (i % 7), 1650.0 - 2.0 * (i % 5), 100.0 + i % 4)


def _check_consistent(folder, base_rows):
    stack = read_stack(folder)
    manifest = json.loads((folder / MANIFEST).read_text())
    edits = manifest.get("edits", [])
    assert len(stack.catalog.id) == base_rows + len(edits)  # no phantom, none lost
    for k in range(1, len(stack.tiles)):
        col, row, size, _ = stack.windows[k]
        np.testing.assert_array_equal(
            stack.tiles[k - 1].heights[row:row + size, col:col + size],
            stack.tiles[k].heights[::2, ::2])
    return len(edits)


def _named(folder):
    manifest = json.loads((folder / MANIFEST).read_text())
    return {e["file"] for e in manifest["layers"]} | {manifest["catalog"], MANIFEST}


def _fork(target):
    pid = os.fork()
    if pid == 0:  # pragma: no cover - child
        code = 0
        try:
            target()
        except BaseException:
            code = 1
        os._exit(code)
    return pid


@pytest.mark.slow
def test_killed_edits_leave_a_consistent_stack_and_are_swept(stack_folder):
    base_rows = len(read_stack(stack_folder).catalog.id)
    t0 = time.perf_counter()
    _edit(stack_folder, 0)  # warm the kernels before forking, and time one edit
    duration = time.perf_counter() - t0
    done = _check_consistent(stack_folder, base_rows)
    assert done == 1
    rng = np.random.default_rng(17)
    finished = 0
    for i in range(1, KILLS + 1):
        pid = _fork(lambda i=i: _edit(stack_folder, i))
        time.sleep(rng.uniform(0.0, 1.3 * duration))
        os.kill(pid, signal.SIGKILL)
        _, status = os.waitpid(pid, 0)
        finished += os.WIFEXITED(status)
        edits = _check_consistent(stack_folder, base_rows)
        assert done <= edits <= done + 1
        done = edits
    assert done >= 1 + finished  # every finished edit committed (some killed ones did too)
    _edit(stack_folder, 99)  # the next edit sweeps what killed ones left
    _check_consistent(stack_folder, base_rows)
    left = {p.name for p in stack_folder.iterdir()}
    assert left == _named(stack_folder) | {LOCK, READERS_LOCK}


def test_readers_never_fail_while_a_stack_is_edited(stack_folder):
    _edit(stack_folder, 0)  # warm the kernels before forking
    pid = _fork(lambda: [_edit(stack_folder, i) for i in range(1, 7)])
    reads = failures = 0
    errors = []
    deadline = time.monotonic() + 300
    while True:
        if time.monotonic() > deadline:  # never hang the suite on a stuck child
            os.kill(pid, signal.SIGKILL)
            os.waitpid(pid, 0)
            pytest.fail("the editing child did not finish in 300 s")
        try:
            stack = read_stack(stack_folder)
            assert len(stack.tiles) == 3
            reads += 1
        except Exception as exc:  # every failure is the defect under test
            failures += 1
            errors.append(repr(exc))
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
    assert os.WEXITSTATUS(status) == 0
    assert failures == 0, errors[:3]
    assert reads >= 5
    assert json.loads((stack_folder / MANIFEST).read_text())["edits"][-1]["replace_crater"]
    assert {p.name for p in stack_folder.iterdir()} == _named(stack_folder) | {
        LOCK, READERS_LOCK}
