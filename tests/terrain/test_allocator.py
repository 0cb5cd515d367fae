"""keep_freed_memory: large freed blocks reused by the process instead of mapped afresh."""

from __future__ import annotations

import subprocess
import sys
import textwrap

import pytest

_CHURN = textwrap.dedent("""
    import resource, sys
    import numpy as np
    from terrain.core.memory import keep_freed_memory
    applied = keep_freed_memory() if sys.argv[1] == "keep" else None
    a = np.ones((1024, 1024)); del a  # the heap as the run found it after one such array
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(40):  # what the evaluation does with frames: 8 MB made, used, dropped
        a = np.empty((1024, 1024)); a[:] = 1.0; b = a * 2.0; del a, b
    print(applied, resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
""")


def _faults(mode):
    out = subprocess.run([sys.executable, "-c", _CHURN, mode], capture_output=True, text=True,
                         check=True).stdout.split()
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
