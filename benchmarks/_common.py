"""What every benchmark script shares: child processes, peak memory, timings, machine facts.

Each configuration runs in its own child process (the script re-invoked with ``--child
SPEC``) so that its peak resident set size is its own; the parent collects the children's
JSON and describes the machine it ran on.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def logger(tag: str):
    """A ``log(message)`` that prints a timestamped progress line on stderr."""

    def log(message: str) -> None:
        print(f"[{tag} {time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)

    return log


def peak_rss_bytes() -> int:
    """Peak resident set size of this process so far (ru_maxrss, in bytes)."""
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak) if sys.platform == "darwin" else int(peak) * 1024


def summary(times: list[float]) -> dict:
    """Median, min, max and every run of a list of wall times (seconds)."""
    return dict(median_s=statistics.median(times), min_s=min(times), max_s=max(times),
                runs_s=times)


def run_child(script, spec: dict, timeout: float, log) -> dict:
    """Run ``script --child SPEC`` and return its JSON; raise RuntimeError if it fails."""
    log(f"{spec['name']}: starting child ({spec['repeat']} runs)")
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, str(Path(script).resolve()), "--child",
                           json.dumps(spec)], stdout=subprocess.PIPE, stderr=None, text=True,
                          timeout=timeout, cwd=ROOT, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"child {spec['name']} failed with exit status {proc.returncode}")
    out = json.loads(proc.stdout)
    out["_child_s"] = time.perf_counter() - t0
    return out


def machine_facts(**extra) -> dict:
    """Python, NumPy, numba, CPU and platform facts, the git commit, and ``extra``."""
    import numba
    import numpy

    try:
        affinity = len(os.sched_getaffinity(0))
    except AttributeError:
        affinity = None
    facts = dict(python=platform.python_version(), implementation=platform.python_implementation(),
                 numpy=numpy.__version__, numba=numba.__version__, cpu_count=os.cpu_count(),
                 cpu_affinity=affinity, numba_num_threads=numba.config.NUMBA_NUM_THREADS,
                 platform=platform.platform(), machine=platform.machine(),
                 processor=platform.processor() or None,
                 timestamp=_dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"), **extra)
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"],
                               cwd=ROOT, capture_output=True, text=True, check=True).stdout
        facts["git"] = dict(commit=head, dirty=bool(dirty.strip()))
    except (OSError, subprocess.CalledProcessError):
        facts["git"] = None
    return facts
