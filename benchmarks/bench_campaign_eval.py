"""The campaign's evaluation stage: its share of the demo, and where its time goes.

Without an output folder, this runs the demo campaign (``examples/demo.toml``; ``--quick``: its
reduced form) from nothing into a temporary folder, the way ``make demo`` does, and reports
every stage's seconds and the evaluation's share of the whole (the issue's goal: under 15 % of
the full demo). Given ``DEMO_OUTPUT``, a finished campaign, it runs
:func:`evaluation.campaign_report.evaluate` again on that campaign's stages 1-5 (read in place,
never written: the new evaluation folder and the stage markers go to ``--dest``, which links the
other stages' folders), and the share is taken against that campaign's own stages 1-5.

Either way it prints the wall and CPU seconds (every thread's) of each of the evaluation's
steps, as announced by its progress lines, with the load average before and after. The
report's numbers (``report.json``) stay in ``--dest`` when one is given, so two runs can be
compared figure by figure.

Usage::

    .venv/bin/python benchmarks/bench_campaign_eval.py [--quick] [DEMO_OUTPUT]
                                                       [--dest FOLDER]
                                                       [--campaign examples/demo.toml]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import logger, machine_facts, peak_rss_bytes  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
log = logger("bench-campaign-eval")


def mirror(outputs: Path, dest: Path) -> None:
    """Make ``dest`` a campaign folder whose stages 1-5 are ``outputs``'s (linked)."""
    if dest.exists():
        shutil.rmtree(dest)
    dest.mkdir(parents=True)
    for name in (".craterscape-campaign",):
        if (outputs / name).exists():
            shutil.copy2(outputs / name, dest / name)
    for marker in outputs.glob(".*.done.json"):
        if "evaluation" not in marker.name:
            shutil.copy2(marker, dest / marker.name)
    for part in ("lunar", "asteroid"):
        (dest / part).symlink_to((outputs / part).resolve(), target_is_directory=True)


class _Steps:
    """The progress lines of a run, each with the wall and CPU seconds until the next."""

    def __init__(self) -> None:
        self.steps: list[dict] = []

    def __call__(self, message: str) -> None:
        now, cpu = time.perf_counter(), time.process_time()
        if self.steps:
            last = self.steps[-1]
            last.update(wall_s=now - last.pop("_t"), cpu_s=cpu - last.pop("_c"))
        self.steps.append(dict(step=message, _t=now, _c=cpu))
        log(message)

    def close(self) -> list[dict]:
        self("end")
        self.steps.pop()
        return self.steps


def _stage_seconds(folder: Path) -> dict[str, float]:
    """Each finished stage's seconds, from its marker in a campaign folder."""
    from evaluation.campaign import STAGES

    seconds = {}
    for name in STAGES:
        marker = folder / f".{name.replace('/', '_')}.done.json"
        if marker.is_file():
            seconds[name] = float(json.loads(marker.read_text())["seconds"])
    return seconds


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outputs", type=Path, nargs="?", default=None,
                        help="a finished campaign's output folder (default: run the campaign)")
    parser.add_argument("--dest", type=Path, default=None,
                        help="where the evaluation (or the whole campaign) goes, replaced "
                             "(default: a temporary folder, removed)")
    parser.add_argument("--quick", action="store_true", help="the campaign's reduced form")
    parser.add_argument("--campaign", type=Path, default=ROOT / "examples" / "demo.toml")
    args = parser.parse_args(argv)
    from evaluation.campaign import load_campaign

    c = load_campaign(args.campaign, quick=args.quick)
    shared = os.environ.get("CRATERSCAPE_SHARED_DATA")
    say = _Steps()
    load0 = os.getloadavg()
    # the campaign's stages print progress (and start processes that do) on stdout: point
    # file descriptor 1 at stderr until the JSON, which alone goes to the real stdout
    sys.stdout.flush()
    real_stdout = os.dup(1)
    os.dup2(2, 1)
    try:
        out = _measure(args, c, shared, say, load0)
    finally:
        sys.stdout.flush()
        os.dup2(real_stdout, 1)
        os.close(real_stdout)
    print(json.dumps(out, indent=2))
    return 0


def _measure(args, c, shared, say: _Steps, load0) -> dict:
    """Run what ``main`` asked for; return the benchmark's JSON document."""
    from evaluation.campaign import run_campaign
    from evaluation.campaign_report import evaluate

    with tempfile.TemporaryDirectory(prefix="bench-campaign-eval.") as tmp:
        dest = (Path(tmp) / "campaign" if args.dest is None else args.dest).resolve()
        t0, c0 = time.perf_counter(), time.process_time()
        if args.outputs is None:  # the whole campaign, from nothing
            if dest.exists():
                shutil.rmtree(dest)
            say("start")
            report = run_campaign(c, dest, shared=shared, say=say,
                                  summary_name="bench.json", results=dest / "results.md")
            stages = _stage_seconds(dest)
            evaluation_s = stages.pop("evaluation")
        else:  # the evaluation again, on a finished campaign's stages 1-5
            outputs = args.outputs.resolve()
            mirror(outputs, dest)
            real = c.real_data(None if shared is None else Path(shared))
            lunar = {"stack": str(outputs / "lunar" / "stack" / "stack"),
                     "run": str(outputs / "lunar" / "run" / "run")}
            asteroid = {"body": str(outputs / "asteroid" / "body" / "body.npz"),
                        "run": str(outputs / "asteroid" / "run" / "run")}
            say("start")
            report = evaluate(c, dest, lunar, asteroid, real, say)
            evaluation_s = time.perf_counter() - t0
            stages = _stage_seconds(outputs)
            stages.pop("evaluation", None)
        wall_s, cpu_s = time.perf_counter() - t0, time.process_time() - c0
        steps = say.close()
    others_s = sum(stages.values())
    share = evaluation_s / (evaluation_s + others_s) if others_s else None
    return dict(benchmark="campaign evaluation stage", quick=args.quick,
                campaign=str(args.campaign), outputs=None if args.outputs is None
                else str(args.outputs.resolve()),
                report=None if args.dest is None else str(report),
                evaluation_s=evaluation_s,
                # the baseline: the campaign's other stages, measured in the same run (or in the
                # run that made DEMO_OUTPUT)
                other_stages_s=stages, share_of_campaign=share,
                wall_s=wall_s, cpu_s=cpu_s,
                # what the stage's worker processes used (counted once they have ended)
                children_cpu_s=sum(getattr(resource.getrusage(resource.RUSAGE_CHILDREN), f)
                                   for f in ("ru_utime", "ru_stime")),
                steps=steps,
                loadavg_before=load0, loadavg_after=os.getloadavg(),
                peak_rss_bytes=peak_rss_bytes(),
                targets=None if args.quick or share is None
                else dict(evaluation_share_ok=share <= 0.15),
                machine=machine_facts())


if __name__ == "__main__":
    sys.exit(main())
