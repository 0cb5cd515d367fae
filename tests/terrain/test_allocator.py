"""keep_freed_memory: large freed blocks reused by the process instead of mapped afresh."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest


def churn_faults() -> int:
    """Page faults of 40 rounds of 8 MB arrays made and dropped, after one such round.

    What the evaluation does with frames (and a chunk task with its arrays): the heap as a
    run finds it after one such array, then 40 made, used and dropped.
    """
    import resource

    import numpy as np

    a = np.ones((1024, 1024))
    del a
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(40):
        a = np.empty((1024, 1024))
        a[:] = 1.0
        b = a * 2.0
        del a, b
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before


_CHURN = textwrap.dedent("""
    import sys
    from terrain.core.memory import keep_freed_memory
    applied = keep_freed_memory() if sys.argv[1] == "keep" else None
    from tests.terrain.test_allocator import churn_faults
    print(applied, churn_faults())
""")
ROOT = Path(__file__).resolve().parents[2]


def _faults(mode):
    out = subprocess.run([sys.executable, "-c", _CHURN, mode], capture_output=True, text=True,
                         check=True, cwd=ROOT).stdout.split()
    return out[0], int(out[1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt only")
def test_freed_frames_are_reused_not_faulted_in_again():
    applied, kept = _faults("keep")
    _, default = _faults("default")
    if applied != "True":
        pytest.skip("this C library has no mallopt (not glibc): nothing to compare")
    # by default glibc hands freed heap back (its trim threshold follows the largest block
    # freed), so each round faults in megabytes of pages again (about 1,000 pages here)
    assert default > 40 * 250
    # kept: the same heap pages serve every round
    assert kept < default / 20
