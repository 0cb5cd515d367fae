"""The default campaign `make demo` runs: a lunar descent and an asteroid approach, evaluated.

The campaign is ``examples/demo.toml`` (what each stage makes, and the reduced ``--quick``
form); :mod:`evaluation.campaign` runs it. Stages, each skipped when its outputs are
complete from an earlier run with the same parameters:

1. ``lunar/base/``: a synthetic polar-like base, 1025 x 1025 at 1 km per pixel, at the
   lunar south pole, and its hillshade.
2. ``lunar/stack/stack/``: the base enhanced in 15 nested layers down to 3 cm at the
   flattest spot near its centre, with craters and rocks at every scale.
3. ``lunar/run/run/``: a descent from 10 km to 20 m under a sun 7 degrees high, 120 frames
   at 1024 x 1024 with LIDAR range, normals and truth (``examples/lunar_descent.toml``).
   ``lunar/closed_loop/``: a landing from 2 km flown through ``craterscape render serve`` by
   guidance that sees only the laser altimeter and the camera (``examples/closed_loop.py``).
4. ``asteroid/body/``: an Eros-like body (``examples/eros_like.toml``).
5. ``asteroid/run/run/``: an approach while it spins (``examples/asteroid_approach.toml``).
6. ``evaluation/``: tracks, slopes, spectra, real-data comparisons (where ``../shared/data``
   holds them), hazards and ``report.html``, which links every file.

``demo.json`` holds the time of every stage; the figures the run measured go to
``docs/results.md`` (the ``--quick`` or another campaign's: ``results.md`` in the output
folder), stamped with the commit. Nothing else outside the output folder is written, and
only what a campaign wrote there is ever removed: a non-empty folder that holds no campaign
is refused. A bad campaign file or output folder is one line on stderr (exit 2; ``-v`` shows
the traceback).

Usage::

    .venv/bin/python examples/demo.py [--out demo-output] [--fresh] [--quick]
                                      [--campaign examples/demo.toml] [-v]
"""

from __future__ import annotations

import argparse
import logging
import os
import sys
import time
from pathlib import Path

from evaluation.campaign import load_campaign, run_campaign
from terrain.core.errors import CraterscapeError

HERE = Path(__file__).resolve().parent


def say(message: str) -> None:
    """Print one line of progress with the time."""
    print(f"[demo {time.strftime('%H:%M:%S')}] {message}", flush=True)


def main(argv=None) -> int:
    """Run the demo campaign; see the module docstring."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=HERE.parent / "demo-output")
    parser.add_argument("--fresh", action="store_true",
                        help="remove what an earlier campaign wrote in the output folder first")
    parser.add_argument("--quick", action="store_true", help="a reduced campaign")
    parser.add_argument("--campaign", type=Path, default=HERE / "demo.toml",
                        help="the campaign file (default: examples/demo.toml)")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="log more, and show the traceback of an error")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    shared = os.environ.get("CRATERSCAPE_SHARED_DATA")  # the real data, never copied
    try:
        campaign = load_campaign(args.campaign, quick=args.quick)
        # the full demo's figures are the README's: docs/results.md, stamped with the commit
        full = not args.quick and args.campaign.resolve() == HERE / "demo.toml"
        run_campaign(campaign, args.out, shared=shared, fresh=args.fresh, say=say,
                     summary_name="demo.json",
                     results=HERE.parent / "docs" / "results.md" if full else None)
    except (CraterscapeError, OSError) as exc:
        if args.verbose:
            logging.getLogger("demo").exception("the campaign stopped")
        print(f"demo: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
