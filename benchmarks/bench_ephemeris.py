"""Dated-sun and auto-exposure benchmark: what they add to a frame, one JSON document.

No rendering: each figure is a median over repeated calls, interleaved with its baseline
(:func:`_common.alternate`, each round in the reverse order of the last).

* ``sky_per_frame``: the Sun and Earth at a lunar site for one new frame time
  (``render.ephemeris.lunar_sky``: three SPICE look-ups with light time and aberration, the
  site's frame, earthshine) and the frame's lighting from it; every frame pays it once for a
  dated sun. Baseline ``hand_set_lighting``: building the lighting from an azimuth and
  elevation (``Lighting.from_angles``), what a hand-set sun pays.
* ``auto_exposure``: exposing a 1024 x 1024 I/F frame through an auto-exposing sensor
  (metering: the mean signal, the lit pixels' percentile; then the chain). Baseline
  ``fixed_exposure``: the same sensor with a fixed exposure.

Ratios are each figure over its baseline; no target (the issue asks for the cost measured).

Usage::

    .venv/bin/python benchmarks/bench_ephemeris.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from _common import alternate, logger, machine_facts, peak_rss_bytes

ROOT = Path(__file__).resolve().parent.parent
log = logger("bench-ephemeris")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="256 x 256 frames, fewer repeats")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    import numpy as np

    from render import ephemeris as eph
    from render.renderer import Lighting
    from render.sensor import ExposureControl, Sensor

    size = 256 if args.quick else 1024
    repeat = 20 if args.quick else 200
    site = eph.Site(20.0, -89.5)
    et0 = eph.et_from_utc("2027-01-15T12:00:00")
    base = Lighting((0.0, 0.0, 1.0))
    eph.lunar_sky(et0, site)  # kernels loaded outside the timing
    step = iter(range(10**9))

    def sky_per_frame():
        return eph.lunar_sky(et0 + next(step), site).lighting(base)

    def hand_set_lighting():
        return Lighting.from_angles(45.0, 1.5)

    rng = np.random.default_rng(0)
    rad = rng.lognormal(np.log(0.01), 0.6, (size, size))
    rad[rng.random((size, size)) < 0.3] = 0.0
    fixed = Sensor(bits=8, exposure=6.0, psf_sigma=0.5, gain=20.0, read_noise=1.0, seed=1)
    auto = Sensor(bits=8, exposure=6.0, psf_sigma=0.5, gain=20.0, read_noise=1.0, seed=1,
                  auto_exposure=True, ae_percentile=99.0, ae_fraction=0.85)
    control = ExposureControl(auto)
    log(f"timing {repeat} dated skies and {max(3, repeat // 20)} exposures of {size}^2")
    sky = alternate(dict(sky_per_frame=sky_per_frame, hand_set_lighting=hand_set_lighting),
                    repeat)
    exposure = alternate(dict(auto_exposure=lambda: control.expose(rad)[0],
                              fixed_exposure=lambda: fixed.expose(rad)), max(3, repeat // 20))
    out = dict(
        benchmark="ephemeris", quick=args.quick, frame=[size, size],
        sky_per_frame=dict(sky.timings["sky_per_frame"],
                           ratio_to_hand_set=sky.ratio("sky_per_frame", "hand_set_lighting")),
        hand_set_lighting=sky.timings["hand_set_lighting"],
        auto_exposure=dict(exposure.timings["auto_exposure"],
                           ratio_to_fixed=exposure.ratio("auto_exposure", "fixed_exposure")),
        fixed_exposure=exposure.timings["fixed_exposure"],
        peak_rss_bytes=peak_rss_bytes(), machine=machine_facts())
    for key in ("sky_per_frame", "hand_set_lighting", "auto_exposure", "fixed_exposure"):
        out[key].pop("runs_s", None)  # hundreds of runs: the summary says enough
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
