"""Run every benchmark (``benchmarks/bench_*.py``) and print one JSON document.

``make bench`` runs this; ``make bench-quick`` and CI (``.ci/run``) run it with ``--quick``,
so that a benchmark that breaks fails the build. Each benchmark script prints its own JSON
(speed and memory against a baseline measured in the same run, interleaved with it, with
pass/fail flags against its issue's targets); this driver collects them under their names,
with each script's wall time and the CPU time of its process tree (``timing``).

Usage::

    .venv/bin/python benchmarks/run.py [--quick] [--only NAME ...] [--output FILE]

The exit status is 1 when a script fails, prints no JSON or runs past its time limit
(``--limit``: a benchmark that degenerates fails the run instead of hanging it), else 0
(targets met or not).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
#: Seconds one script may run (full, quick): several times the longest seen on 2 cores
#: (the Dask benchmark, about 4.5 minutes full).
LIMIT_S = (1800.0, 600.0)


def _children_cpu_s() -> float:
    """User + system CPU seconds of every child process waited for so far."""
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def _write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file beside it, renamed into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def _run_script(name: str, quick: bool, limit: float) -> tuple[str, int | None]:
    """Run one benchmark script; return its stdout and exit status (None: past ``limit``).

    The script gets a session of its own, so that past the limit its children (a Dask
    cluster, a render server) are ended with it.
    """
    proc = subprocess.Popen([sys.executable, str(HERE / f"bench_{name}.py")]
                            + (["--quick"] if quick else []),
                            stdout=subprocess.PIPE, text=True, start_new_session=True)
    try:
        out, _ = proc.communicate(timeout=limit)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        return "", None
    return out, proc.returncode


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke-test sizes")
    names = sorted(p.stem.removeprefix("bench_") for p in HERE.glob("bench_*.py"))
    parser.add_argument("--only", nargs="*", default=None, choices=names, metavar="NAME",
                        help=f"benchmarks to run, of: {' '.join(names)}")
    parser.add_argument("--output", type=Path, default=None, metavar="FILE",
                        help="write the JSON to FILE and print a one-line summary instead")
    parser.add_argument("--limit", type=float, default=None, metavar="SECONDS",
                        help=f"time limit per script (default {LIMIT_S[0]:.0f}, quick "
                             f"{LIMIT_S[1]:.0f}); past it the script and its children are "
                             "ended and it fails")
    args = parser.parse_args(argv)
    if args.limit is not None and not args.limit > 0:
        parser.error(f"--limit must be a positive number of seconds; got {args.limit}")
    limit = args.limit or LIMIT_S[1 if args.quick else 0]
    results, timing, failed = {}, {}, []
    t0 = time.perf_counter()
    for name in names:
        if args.only and name not in args.only:
            continue
        print(f"[bench] {name} ...", file=sys.stderr, flush=True)
        w0, c0 = time.perf_counter(), _children_cpu_s()
        out, code = _run_script(name, args.quick, limit)
        timing[name] = dict(wall_s=round(time.perf_counter() - w0, 2),
                            cpu_s=round(_children_cpu_s() - c0, 2))
        if code is None:
            results[name] = {"error": f"ran past its limit of {limit:g} s"}
            failed.append(name)
        else:
            try:
                results[name] = json.loads(out)
            except json.JSONDecodeError:
                results[name] = {"error": f"no JSON (exit status {code})"}
                failed.append(name)
            else:
                if code != 0:
                    failed.append(name)
        said = "past its limit" if code is None else f"exit {code}"
        print(f"[bench] {name}: {said}, {timing[name]['wall_s']:.0f} s wall, "
              f"{timing[name]['cpu_s']:.0f} s CPU", file=sys.stderr, flush=True)
    total = time.perf_counter() - t0
    doc = dict(benchmarks=results, quick=args.quick, failed=failed, timing=timing,
               total_s=total, total_cpu_s=round(sum(t["cpu_s"] for t in timing.values()), 2),
               load_average=list(os.getloadavg()))
    text = json.dumps(doc, indent=2) + "\n"
    if args.output is None:
        sys.stdout.write(text)
    else:
        _write(args.output, text)
        verdict = f"FAILED: {' '.join(failed)}" if failed else "all ran"
        print(f"benchmarks{' (quick)' if args.quick else ''}: {len(results)} scripts, "
              f"{verdict}, {total:.0f} s; JSON in {args.output}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
