"""What every benchmark script shares: child processes, peak memory, timings, machine facts.

Each configuration runs in its own child process (the script re-invoked with ``--child
SPEC``) so that its peak resident set size is its own; the parent collects the children's
JSON and describes the machine it ran on.

A baseline is measured interleaved with what is compared with it, never in a block before or
after: :func:`alternate` times calls in one process A B, B A, A B ...; :func:`run_rounds` runs
one child per configuration per round, in the same alternating order. A change in the load of
a shared machine then hits both sides alike, and their ratio stays fair.
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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def logger(tag: str):
    """A ``log(message)`` that prints a timestamped progress line on stderr."""

    def log(message: str) -> None:
        print(f"[{tag} {time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)

    return log


def peak_rss_bytes() -> int:
    """Peak resident set size of this process's own memory so far, in bytes.

    On Linux this is ``VmHWM`` of ``/proc/self/status``: ``ru_maxrss`` is not, because Linux
    carries it across ``fork`` and ``exec``, so a freshly started child (a benchmark's child
    process, a Dask worker) reports its parent's peak until it exceeds it. Elsewhere,
    ``ru_maxrss``.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as status:
            for line in status:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return int(peak) if sys.platform == "darwin" else int(peak) * 1024


def worker_memory() -> dict:
    """This process's id and own peak RSS (bytes): what a Dask worker reports of itself."""
    return dict(pid=os.getpid(), peak_rss_bytes=peak_rss_bytes())


def summary(times: list[float]) -> dict:
    """Median, min, max and every run of a list of wall times (seconds)."""
    return dict(median_s=statistics.median(times), min_s=min(times), max_s=max(times),
                runs_s=times)


def order(names: list, round_: int) -> list:
    """The order of round ``round_``: as given on even rounds, reversed on odd ones."""
    return list(names) if round_ % 2 == 0 else list(reversed(names))


@dataclass
class Interleaved:
    """What :func:`alternate` measured.

    Attributes
    ----------
    timings : dict
        Per call, :func:`summary` of its wall times (seconds).
    results : dict
        Per call, what its last run returned.
    peak_after_first_bytes : int
        This process's peak RSS right after the first run of the first call, before any
        other call ran (that call's memory, uncoloured by its baseline's).
    """

    timings: dict
    results: dict
    peak_after_first_bytes: int

    def ratio(self, name: str, baseline: str) -> float:
        """Median wall time of ``name`` over that of ``baseline``."""
        return self.timings[name]["median_s"] / max(self.timings[baseline]["median_s"], 1e-12)


def alternate(calls: dict[str, Callable[[], object]], repeat: int) -> Interleaved:
    """Time every call ``repeat`` times, interleaved: A B C, then C B A, then A B C, ...

    Parameters
    ----------
    calls : dict of str to callable
        The calls to time, by name; the first is also the one whose peak memory is read
        (:attr:`Interleaved.peak_after_first_bytes`).
    repeat : int
        Timed runs of each call.
    """
    names = list(calls)
    times: dict[str, list[float]] = {name: [] for name in names}
    results: dict[str, object] = {}
    peak_first = None
    for r in range(repeat):
        for name in order(names, r):
            t0 = time.perf_counter()
            results[name] = calls[name]()
            times[name].append(time.perf_counter() - t0)
            if peak_first is None:
                peak_first = peak_rss_bytes()
    return Interleaved({name: summary(times[name]) for name in names}, results,
                       peak_first if peak_first is not None else peak_rss_bytes())


def run_rounds(script, specs: dict[str, dict], rounds: int, timeout: float,
               log) -> dict[str, list[dict]]:
    """Run one child per configuration per round, alternating configurations between rounds.

    Round ``r`` runs the configurations in the order given when ``r`` is even, reversed when
    it is odd; each child gets its spec with ``round`` set, and times what its spec's
    ``repeat`` says (one call, usually: the rounds are the repeats).

    Returns
    -------
    dict of str to list of dict
        Per configuration, its children's JSON in round order.
    """
    out: dict[str, list[dict]] = {name: [] for name in specs}
    for r in range(rounds):
        for name in order(list(specs), r):
            child = run_child(script, dict(specs[name], round=r), timeout, log)
            child.pop("_child_s", None)
            out[name].append(child)
    return out


def pool(children: list[dict]) -> dict:
    """Merge the JSON of several children of one configuration (from :func:`run_rounds`).

    Timing summaries (dicts with ``runs_s``) are pooled and summarised again; a key naming a
    peak (``peak...``) keeps the largest; booleans must hold in every child (``all``); other
    numbers keep their median; anything else is the first child's (sizes and counts, which
    do not change between rounds).
    """
    first = children[0]
    merged: dict = {}
    for key, value in first.items():
        values = [c[key] for c in children if key in c]
        if isinstance(value, dict) and "runs_s" in value:
            merged[key] = summary([t for v in values for t in v["runs_s"]])
        elif isinstance(value, bool):
            merged[key] = all(values)
        elif isinstance(value, int | float) and "peak" in key:
            merged[key] = max(values)
        elif isinstance(value, float):
            merged[key] = statistics.median(values)
        else:
            merged[key] = value
    merged["children"] = len(children)
    return merged


def run_child(script, spec: dict, timeout: float, log) -> dict:
    """Run ``script --child SPEC`` and return its JSON; raise RuntimeError if it fails."""
    where = f", round {spec['round'] + 1}" if "round" in spec else ""
    log(f"{spec['name']}: starting child ({spec.get('repeat', 1)} runs{where})")
    t0 = time.perf_counter()
    before = host_cpu_ticks()
    proc = subprocess.run([sys.executable, str(Path(script).resolve()), "--child",
                           json.dumps(spec)], stdout=subprocess.PIPE, stderr=None, text=True,
                          timeout=timeout, cwd=ROOT, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"child {spec['name']} failed with exit status {proc.returncode}")
    out = json.loads(proc.stdout)
    out["_child_s"] = time.perf_counter() - t0
    out["host_steal_share"] = steal_share(before, host_cpu_ticks())
    return out


def host_cpu_ticks() -> list[int] | None:
    """The machine's CPU time counters (``/proc/stat``'s first line, in ticks), or None.

    Fields: user, nice, system, idle, iowait, irq, softirq, steal (and guests, which user
    already counts).
    """
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
    except OSError:
        return None
    if not fields or fields[0] != "cpu" or len(fields) < 9:
        return None
    return [int(x) for x in fields[1:9]]


def steal_share(before: list[int] | None, after: list[int] | None) -> float | None:
    """Share of the machine's CPU time the hypervisor gave other guests between two readings.

    On a virtual machine that shares its host's cores, time the host runs others on our
    virtual CPUs ("steal") is neither our processes' CPU time nor idle: a parallel run looks
    as if fewer cores were busy (a run of the crater benchmark here measured 1.15 cores busy
    in one child and 1.8 in the next, the same code). None where the counters are missing.
    """
    if before is None or after is None:
        return None
    delta = [b - a for a, b in zip(before, after, strict=True)]
    total = sum(delta)
    return round(delta[7] / total, 4) if total > 0 else None


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
