"""Run every benchmark (``benchmarks/bench_*.py``) and print one JSON document.

``make bench`` runs this. Each benchmark script prints its own JSON (speed and memory
against a baseline measured in the same run, with pass/fail flags against its issue's
targets); this driver collects them under their names.

Usage::

    .venv/bin/python benchmarks/run.py [--quick] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke-test sizes")
    parser.add_argument("--only", nargs="*", default=None,
                        help="benchmark names to run (e.g. craters enhance asteroid)")
    args = parser.parse_args(argv)
    scripts = sorted(HERE.glob("bench_*.py"))
    results, status = {}, 0
    t0 = time.perf_counter()
    for script in scripts:
        name = script.stem.removeprefix("bench_")
        if args.only and name not in args.only:
            continue
        print(f"[bench] {name} ...", file=sys.stderr, flush=True)
        proc = subprocess.run([sys.executable, str(script)] + (["--quick"] if args.quick else []),
                              stdout=subprocess.PIPE, text=True, check=False)
        try:
            results[name] = json.loads(proc.stdout)
        except json.JSONDecodeError:
            results[name] = {"error": f"no JSON (exit status {proc.returncode})"}
        if proc.returncode != 0:
            status = 1
    print(json.dumps(dict(benchmarks=results, total_s=time.perf_counter() - t0), indent=2))
    return status


if __name__ == "__main__":
    sys.exit(main())
