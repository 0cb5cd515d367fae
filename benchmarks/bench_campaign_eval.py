"""The campaign's evaluation stage alone, on the outputs of a finished campaign.

``make demo`` times its evaluation stage once, in wall seconds, on whatever load the machine
had. This runs :func:`evaluation.campaign_report.evaluate` again on a finished demo's stages
1-5 (read in place, never written: the new evaluation folder and the stage markers go to
``--dest``, which links the other stages' folders) and prints the wall and CPU seconds
(every thread's) of each of its steps, as announced by its progress lines, with the load
average before and after. The report's numbers (``report.json``) go to ``--dest`` too, so
two runs can be compared figure by figure.

Usage::

    .venv/bin/python benchmarks/bench_campaign_eval.py DEMO_OUTPUT --dest FOLDER
                                                       [--campaign examples/demo.toml]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import sys
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


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outputs", type=Path, help="a finished campaign's output folder")
    parser.add_argument("--dest", type=Path, required=True,
                        help="where the evaluation goes (replaced)")
    parser.add_argument("--campaign", type=Path, default=ROOT / "examples" / "demo.toml")
    args = parser.parse_args(argv)
    from evaluation.campaign import load_campaign
    from evaluation.campaign_report import evaluate

    c = load_campaign(args.campaign)
    outputs = args.outputs.resolve()
    mirror(outputs, args.dest)
    shared = os.environ.get("CRATERSCAPE_SHARED_DATA")
    real = c.real_data(None if shared is None else Path(shared))
    lunar = {"stack": str(outputs / "lunar" / "stack" / "stack"),
             "run": str(outputs / "lunar" / "run" / "run")}
    asteroid = {"body": str(outputs / "asteroid" / "body" / "body.npz"),
                "run": str(outputs / "asteroid" / "run" / "run")}
    steps: list[dict] = []

    def say(message: str) -> None:
        now, cpu = time.perf_counter(), time.process_time()
        if steps:
            steps[-1].update(wall_s=now - steps[-1].pop("_t"), cpu_s=cpu - steps[-1].pop("_c"))
        steps.append(dict(step=message, _t=now, _c=cpu))
        log(message)

    load0 = os.getloadavg()
    t0, c0 = time.perf_counter(), time.process_time()
    say("start")
    report = evaluate(c, args.dest, lunar, asteroid, real, say)
    say("end")
    steps.pop()
    out = dict(benchmark="campaign evaluation stage", outputs=str(outputs),
               report=str(report), wall_s=time.perf_counter() - t0,
               cpu_s=time.process_time() - c0,
               # what the stage's worker processes used (counted once they have ended)
               children_cpu_s=sum(getattr(resource.getrusage(resource.RUSAGE_CHILDREN), f)
                                  for f in ("ru_utime", "ru_stime")),
               steps=steps,
               loadavg_before=load0, loadavg_after=os.getloadavg(),
               peak_rss_bytes=peak_rss_bytes(), machine=machine_facts())
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
