"""Render server benchmark: frames per second and latency over TCP against in-process rendering.

Builds a lunar layer stack, starts ``craterscape render serve`` on a free loopback port, and
flies the same descent poses (1024 x 1024, shadows on, sensor noise on) two ways:

- in process: :func:`render.sequence.render_sample` in this process (the baseline, what
  ``craterscape render sequence`` does per frame);
- through the server: ``SET_POSE`` then ``GET_IMAGE`` ("image") or ``SET_POSE``, ``GET_IMAGE``
  and ``GET_RANGE`` ("image+range"), measured by the client from the first byte sent to the
  last byte received.

Each pose is rendered the three ways back to back (in process, image, image+range; the order
reversed every other pose), over ``--rounds`` passes, so a change in machine load hits all
three alike. Reported per mode:
median and 99th-percentile latency, frames per second and requests per second, and the
overhead: the median over poses of (server time / in-process time of the same pose) - 1.
Target (issue 13): server latency at most 10 % above in-process rendering; PANGU's 10 Hz is
the reference rate.

Usage::

    .venv/bin/python benchmarks/bench_server.py [--quick] [--size 1024] [--frames 12]
"""

from __future__ import annotations

import argparse
import json
import re
import select
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import ROOT, logger, machine_facts, order  # noqa: E402

SEED = 1013
log = logger("bench-server")
#: Server overhead target (fraction of the in-process frame time).
TARGET_OVERHEAD = 0.10


def build(tmp: Path, quick: bool, size: int, frames: int) -> Path:
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    n, levels = (129, 3) if quick else (513, 6)
    base = synthesize_tile(n, resolution=200.0, relief=2000.0, seed=SEED).tile
    site = (n * 100.0, n * 100.0)
    stack = build_stack(base, site, levels=levels, layer_size=n, seed=SEED,
                        population=Population(dmin=2.0, dmax=10000.0, density=1e5))
    write_stack(stack, tmp / "stack")
    scenario = tmp / "bench.toml"
    scenario.write_text(f"""
name = "bench-server"
seed = {SEED}
[scene]
type = "terrain"
stack = "{tmp / 'stack'}"
[sun]
azimuth = 120.0
elevation = 12.0
[camera]
width = {size}
height = {size}
fov = 50.0
[sensor]
bits = 8
exposure = 4.0
psf_sigma = 0.5
gain = 20.0
read_noise = 1.0
[render]
shadow_size = 2048
lod_pixels = 1.5
[trajectory]
type = "descent"
frames = {frames}
duration = 60.0
start_altitude = 2000.0
end_altitude = 30.0
ground_track = [800.0, -500.0]
""")
    return scenario


def start_server(scenario: Path):
    proc = subprocess.Popen([sys.executable, "-c",
                             "import sys; from terrain.cli.commands import main; sys.exit(main())",
                             "render", "serve", str(scenario), "--port", "0"],
                            stderr=subprocess.PIPE, text=True, cwd=ROOT)
    deadline = time.monotonic() + 600
    said = []
    while time.monotonic() < deadline and proc.poll() is None:
        ready, _, _ = select.select([proc.stderr], [], [], 1.0)
        if ready:
            line = proc.stderr.readline()
            said.append(line.rstrip())
            m = re.search(r"serving .* on [\d.]+:(\d+)\s*$", line)
            if m:
                return proc, int(m.group(1))
    proc.kill()
    said += proc.stderr.read().splitlines()
    raise RuntimeError("the server did not start; it said: " + " | ".join(said[-5:]))


def stats(times: list[float], requests_per_frame: int) -> dict:
    t = np.asarray(times)
    return dict(median_s=float(np.median(t)), p99_s=float(np.percentile(t, 99)),
                mean_s=float(t.mean()), frames_per_s=float(len(t) / t.sum()),
                requests_per_s=float(requests_per_frame * len(t) / t.sum()), frames=len(t))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke-test sizes")
    parser.add_argument("--size", type=int, default=None, help="image side (default 1024)")
    parser.add_argument("--frames", type=int, default=None, help="poses per pass")
    parser.add_argument("--rounds", type=int, default=None, help="passes per mode")
    args = parser.parse_args(argv)
    size = args.size or (256 if args.quick else 1024)
    frames = args.frames or (4 if args.quick else 12)
    rounds = args.rounds or (1 if args.quick else 3)

    from render.client import Client
    from render.context import describe
    from render.renderer import Renderer
    from render.scenario import load_scenario
    from render.sequence import load_scene, render_sample

    with tempfile.TemporaryDirectory(prefix="bench-server-") as tmpdir:
        tmp = Path(tmpdir)
        log(f"building the scene ({'quick' if args.quick else 'full'})")
        scenario_path = build(tmp, args.quick, size, frames)
        scenario = load_scenario(scenario_path)
        renderer = Renderer()
        scene = load_scene(scenario)
        samples = scenario.samples(scene)
        render_sample(renderer, scene, scenario, samples[0], 0)  # warm: shadows, programs
        proc, port = start_server(scenario_path)
        times = {"in_process": [], "image": [], "image+range": []}
        same = True
        try:
            with Client("127.0.0.1", port) as client:
                client.set_pose(samples[0].pose.position, samples[0].pose.attitude)
                client.get_image()  # warm
                for r in range(rounds):
                    log(f"round {r + 1}/{rounds}: {frames} poses x 3 modes at {size}^2")
                    for i, s in enumerate(samples):
                        images = {}
                        for mode in order(list(times), r * frames + i):
                            t0 = time.perf_counter()
                            if mode == "in_process":
                                images[mode], frame, _ = render_sample(renderer, scene,
                                                                       scenario, s, i)
                                _ = frame.range  # image+range in process: the same render
                            else:
                                client.set_pose(s.pose.position, s.pose.attitude, s.time, i)
                                images[mode] = client.get_image()
                                if mode == "image+range":
                                    client.get_range()
                            times[mode].append(time.perf_counter() - t0)
                        same &= all(bool(np.array_equal(images[mode], images["in_process"]))
                                    for mode in ("image", "image+range"))
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=60)
    base = stats(times["in_process"], 1)
    out = dict(benchmark="server", size=[size, size], poses=frames, rounds=rounds,
               quick=args.quick, renderer=describe(), in_process=base,
               server={"image": stats(times["image"], 2),
                       "image+range": stats(times["image+range"], 3)},
               images_equal_in_process=same, target_overhead=TARGET_OVERHEAD,
               machine=machine_facts())
    base_t = np.asarray(times["in_process"])
    for mode, s in out["server"].items():
        s["overhead_median"] = float(np.median(np.asarray(times[mode]) / base_t)) - 1.0
        s["overhead_of_medians"] = s["median_s"] / base["median_s"] - 1.0
        s["meets_overhead_target"] = s["overhead_median"] <= TARGET_OVERHEAD
        s["meets_10_hz"] = s["frames_per_s"] >= 10.0
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
