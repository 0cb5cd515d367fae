"""Benchmark of Monte Carlo campaigns (``craterscape render campaign``): one JSON document.

A descent scenario over a synthetic cratered layer stack, dispersed by sampling rules
(position, velocity, attitude, sun elevation, sensor seed), rendered as a campaign of
``CASES`` cases in four configurations, each in its own child process per round, the
configurations alternating between rounds (:func:`_common.run_rounds`):

* ``alone`` (the baseline): every case's scenario rendered on its own, one after another,
  as ``craterscape render sequence CASE.toml`` does (the scene loaded for every case);
* ``inprocess``: the campaign in one process (the scene loaded once);
* ``workers1`` and ``workers2``: the campaign on a local pool of 1 and 2 worker processes
  (``--workers N``; the pool's start, paid once per campaign, is reported apart).

Reported: cases per second of each (the pool's start excluded and included), the speed-up
of 2 workers over 1, and of the campaign over the baseline; for the campaigns, the median
and largest seconds one case took on its worker (the largest is a worker's first case,
which loads the scene and makes its GL context). Usage::

    .venv/bin/python benchmarks/bench_campaign.py            # 256^2 frames, 12 cases, 3 rounds
    .venv/bin/python benchmarks/bench_campaign.py --quick    # 64x48, 4 cases, 1 round

Progress goes to stderr. Timings taken on a shared machine vary; compare ratios.
"""

from __future__ import annotations

import argparse
import csv
import json
import shutil
import sys
import tempfile
import time
from pathlib import Path

from _common import logger, machine_facts, peak_rss_bytes, pool, run_rounds, summary

log = logger("bench-campaign")

SCENARIO = """
name = "bench"
seed = 5
[scene]
type = "terrain"
stack = "{stack}"
[sun]
azimuth = 100.0
elevation = 15.0
[camera]
width = {width}
height = {height}
fov = 50.0
[sensor]
bits = 12
exposure = 4.0
gain = 10.0
read_noise = 2.0
[render]
shadow_size = 1024
[trajectory]
type = "descent"
frames = {frames}
duration = 10.0
start_altitude = 1500.0
end_altitude = 100.0
ground_track = [300.0, 100.0]
"""

RULES = """
cases = {cases}
seed = 3
[sample]
"position.x" = {{normal = [0.0, 30.0]}}
"position.y" = {{normal = [0.0, 30.0]}}
"velocity.z" = {{normal = [0.0, 1.0]}}
"attitude.x" = {{normal = [0.0, 0.3]}}
"sun.elevation" = {{uniform = [10.0, 20.0]}}
seed = "per-case"
"""


def _inputs(work: Path, quick: bool) -> dict:
    """Write the stack, the scenario and the rules; return the sizes."""
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    size = dict(width=64, height=48, frames=2, cases=4) if quick else \
        dict(width=256, height=256, frames=4, cases=12)
    base = synthesize_tile(129, resolution=50.0, relief=500.0, seed=3).tile
    stack = build_stack(base, (3200.0, 3200.0), levels=2, layer_size=65, seed=4,
                        population=Population(dmin=1.0, dmax=3000.0, density=5e4))
    write_stack(stack, work / "stack")
    (work / "s.toml").write_text(SCENARIO.format(stack=work / "stack", **size))
    (work / "d.toml").write_text(RULES.format(**size))
    return size


def child(spec: dict) -> dict:
    """Render the campaign (or its cases alone) once; return its timings."""
    from render.context import keep_current
    from render.dispersions import read_dispersions
    from render.montecarlo import case_scenarios, run_campaign
    from render.scenario import load_scenario
    from render.sequence import run_sequence

    work = Path(spec["dir"])
    out = work / f"{spec['name']}-{spec['round']}"
    if spec["mode"] == "alone":
        scenario = load_scenario(work / "s.toml")
        texts = case_scenarios(scenario, read_dispersions(work / "d.toml"))
        out.mkdir()
        t0 = time.perf_counter()
        for k, text in enumerate(texts):
            case = out / f"{k:06d}.toml"
            case.write_text(text)
            with keep_current():
                run_sequence(load_scenario(case), out / f"{k:06d}")
        seconds = time.perf_counter() - t0
        result = dict(cases=len(texts), seconds=seconds, start_seconds=0.0)
    else:
        workers = None if spec["mode"] == "inprocess" else spec["workers"]
        record = run_campaign(work / "s.toml", work / "d.toml", out, workers=workers)
        with open(out / "summary.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        per_case = sorted(float(r["render_seconds"]) for r in rows)
        result = dict(cases=record["cases_rendered"], seconds=record["seconds"],
                      start_seconds=record["start_seconds"],
                      case_seconds_median=per_case[len(per_case) // 2],
                      case_seconds_max=per_case[-1], workers_used=record["workers"])
    shutil.rmtree(out)
    steady = result["seconds"] - result["start_seconds"]
    return dict(result, wall=summary([result["seconds"]]),
                cases_per_second=result["cases"] / result["seconds"],
                cases_per_second_started=result["cases"] / steady,
                peak_rss_bytes=peak_rss_bytes())


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="64x48 frames, 4 cases, 1 round")
    parser.add_argument("--rounds", type=int, default=None, help="rounds (default 3; quick 1)")
    parser.add_argument("--child", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        print(json.dumps(child(json.loads(args.child))))
        return 0
    work = Path(tempfile.mkdtemp(prefix="bench-campaign-"))
    results: dict = dict(machine=machine_facts(note="shared machine: other jobs ran "
                                                    "concurrently"))
    try:
        size = _inputs(work, args.quick)
        rounds = args.rounds or (1 if args.quick else 3)
        specs = {mode: dict(name=mode, mode=mode, workers=workers, dir=str(work))
                 for mode, workers in (("alone", None), ("inprocess", None),
                                       ("workers1", 1), ("workers2", 2))}
        runs = {mode: pool(children) for mode, children in
                run_rounds(__file__, specs, rounds, 3600, log).items()}
        rate = {mode: r["cases_per_second"] for mode, r in runs.items()}
        started = {mode: r["cases_per_second_started"] for mode, r in runs.items()}
        results["campaign"] = dict(
            size, runs=runs, baseline="alone", cases_per_second=rate,
            cases_per_second_after_start=started,
            two_vs_one_worker=started["workers2"] / started["workers1"],
            two_vs_one_worker_with_start=rate["workers2"] / rate["workers1"],
            inprocess_vs_alone=rate["inprocess"] / rate["alone"])
    finally:
        shutil.rmtree(work, ignore_errors=True)
    print(json.dumps(results, indent=2, default=float))
    return 0


if __name__ == "__main__":
    sys.exit(main())
