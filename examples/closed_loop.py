"""A closed-loop landing: guidance that sees the Moon only through the render server.

A lander starts 2 km above a terrain scenario's landing site, a few hundred metres off it and
drifting. Every guidance step (``--dt`` seconds) it asks the server (``craterscape render
serve``) for exactly what its sensors would give:

- a laser altimeter: the range along the body's -z axis (``RAY``), its altitude above the
  ground below;
- a nadir camera image (``SET_POSE`` + ``GET_IMAGE``).

Navigation uses nothing else. Lateral velocity comes from optical flow: the previous image is
scaled about the principal point by the altitude ratio (the altimeter's), so only the
translation is left, which phase correlation measures to a fraction of a pixel; pixels become
metres through the altitude and the focal length (the camera's intrinsics, from ``INFO``).
The position estimate starts from an orbit-determination guess (``--initial-error`` metres
off) and integrates that velocity. Above ``--trn-above`` metres it is also fixed by
terrain-relative navigation: the server renders what the camera should see from the
estimated position (standing in for the onboard map a real lander carries) and phase
correlation against the real image gives the position error. Below that, and whenever the
correlation peak is weak, navigation runs on optical flow and dead reckoning alone.
Guidance brings the estimated position over the site with a proportional-derivative law
(acceleration limited to 1 m/s^2) while descending at the altitude over a time constant
(``--tau``), slowing to 1 m/s for the last metres, and stops at touchdown (altimeter below
``--touchdown`` metres).

The truth (the vehicle's real motion, with keyed thruster noise) is simulated here and used
only to score the navigation. Written to ``--out``: ``trajectory.csv`` (truth, estimate,
altimeter and errors per step), ``frames/`` (every image the camera returned),
``closed_loop.png`` (track and navigation error against truth) and ``summary.json``.

Usage::

    .venv/bin/python examples/closed_loop.py SCENARIO.toml --out OUT [--size 256] [--dt 1.0]
    .venv/bin/python examples/closed_loop.py --port 10363 --out OUT   # a server already running

Without ``--port`` the script starts ``craterscape render serve SCENARIO.toml`` on a free
loopback port and stops it at the end.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import re
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

#: Nadir camera, image up = north: R_WC = diag(1, -1, -1), 180 degrees about x.
NADIR = (0.0, 1.0, 0.0, 0.0)
#: Guidance gains (1/s^2 and 1/s): a critically damped lateral loop, natural period ~60 s.
KP, KD = 0.01, 0.2
MAX_ACCEL = 1.0      # m/s^2, lateral
MIN_DESCENT = 1.0    # m/s, final descent rate
MAX_DESCENT = 60.0   # m/s
THRUST_NOISE = 0.05  # m/s^2 rms per axis, the truth's unmodelled acceleration
SEED = 2024
#: Phase-correlation peaks below this are not trusted (too little texture, or too much
#: change between frames); navigation then dead-reckons on the commanded acceleration.
MIN_PEAK = 0.2
#: Phase-correlation passes per measurement (each removes the previous estimate first).
FLOW_ITERATIONS = 3


def start_server(scenario: Path):
    """``craterscape render serve SCENARIO --port 0``; returns (process, port)."""
    proc = subprocess.Popen([sys.executable, "-c",
                             "import sys; from terrain.cli.commands import main; sys.exit(main())",
                             "render", "serve", str(scenario), "--port", "0"],
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 900
    seen = []
    while time.monotonic() < deadline and proc.poll() is None:
        ready, _, _ = select.select([proc.stderr], [], [], 1.0)
        if ready:
            line = proc.stderr.readline()
            seen.append(line)
            m = re.search(r"serving .* on [\d.]+:(\d+)\s*$", line)
            if m:
                return proc, int(m.group(1))
    proc.kill()
    raise RuntimeError("the render server did not start: " + "".join(seen))


def optical_flow(previous: np.ndarray, current: np.ndarray, zoom: float, centre) -> tuple:
    """Image translation (du, dv) pixels from ``previous`` to ``current`` once ``previous`` is
    scaled by ``zoom`` about ``centre``; and the phase-correlation peak (0..1, confidence)."""
    import cv2

    prev = previous.astype(np.float32)
    b = current.astype(np.float32)
    h, w = b.shape
    cx, cy = centre
    window = cv2.createHanningWindow((w, h), cv2.CV_32F)
    du = dv = 0.0
    # OpenCV's sub-pixel peak (a centroid) is pulled towards whole pixels; shifting by the
    # estimate and measuring again leaves a residual near zero, where it is not
    for _ in range(FLOW_ITERATIONS):
        m = np.array([[zoom, 0.0, (1 - zoom) * cx + du], [0.0, zoom, (1 - zoom) * cy + dv]])
        a = cv2.warpAffine(prev, m, (w, h), flags=cv2.INTER_CUBIC,
                           borderMode=cv2.BORDER_REFLECT)
        (ru, rv), peak = cv2.phaseCorrelate(a, b, window)
        du, dv = du + ru, dv + rv
    return float(du), float(dv), float(peak)


def fly(client, out: Path, *, size: int, dt: float, tau: float, touchdown: float,
        start_altitude: float, offset, drift, initial_error, trn_above: float = 500.0,
        max_steps: int = 2000) -> dict:
    """Fly one landing against a connected :class:`render.client.Client`; see the module
    docstring. Returns the summary."""
    from render.errors import ServerError
    from render.protocol import ErrorCode
    from terrain.core.rng import normal_scalar, stream_id
    from terrain.io import write_png

    info = client.info()
    if info["scene"] != "terrain":
        raise SystemExit("closed_loop.py needs a terrain scenario (a landing site)")
    sensor = client.set_sensor(width=size, height=size)
    f, cx, cy = sensor["fx"], sensor["cx"], sensor["cy"]
    site = np.array(info["site"], dtype=np.float64)
    ground, _ = client.height_at(*site)
    (out / "frames").mkdir(parents=True, exist_ok=True)
    stream = stream_id("closed-loop-thrust")

    # truth: position and velocity of the camera (world frame)
    p = np.array([site[0] + offset[0], site[1] + offset[1], ground + start_altitude])
    v = np.array([drift[0], drift[1], 0.0])
    # navigation: an orbit-determination guess of the horizontal position, nothing else
    est_xy = p[:2] + np.asarray(initial_error, dtype=np.float64)
    est_vxy = np.zeros(2)
    rows, previous, prev_alt = [], None, None
    accel = np.zeros(2)
    t, crashed = 0.0, False
    for step in range(max_steps):
        # -- sensors: the only inputs of navigation
        try:
            client.set_pose(p, NADIR, time=t, frame=step)
        except ServerError as exc:
            if exc.code != ErrorCode.INSIDE_SURFACE:
                raise
            crashed = True  # the vehicle met the ground between two steps
            break
        alt = client.ray(p, (0.0, 0.0, -1.0)).range
        image = client.get_image(bits=8)
        write_png(image, out / "frames" / f"frame_{step:04d}.png")
        # -- navigation: predict with the commanded acceleration, correct with optical flow
        predicted = est_vxy + accel * dt
        flow = (math.nan, math.nan, math.nan)
        if previous is not None and math.isfinite(alt) and math.isfinite(prev_alt):
            flow = optical_flow(previous, image, prev_alt / alt, (cx, cy))
        if math.isfinite(flow[2]) and flow[2] >= MIN_PEAK:
            # a camera moving east by dx shifts the ground left by f dx / alt (u falls); north
            # (image up) by dy shifts it down by f dy / alt (v grows)
            dxy = np.array([-flow[0] * alt / f, flow[1] * alt / f])
            est_vxy = dxy / dt
        else:  # no texture to trust (or the first frame): dead reckoning
            dxy = 0.5 * (est_vxy + predicted) * dt if previous is not None else np.zeros(2)
            est_vxy = predicted
        est_xy = est_xy + dxy
        trn = (math.nan, math.nan, math.nan)
        if trn_above > 0 and math.isfinite(alt) and alt >= trn_above:
            # terrain-relative navigation: the onboard map (the server rendering the scene from
            # the estimated pose) against the real image; their shift is the position error
            try:
                client.set_pose((est_xy[0], est_xy[1], ground + alt), NADIR, time=t, frame=step)
                trn = optical_flow(client.get_image(bits=8), image, 1.0, (cx, cy))
            except ServerError as exc:
                if exc.code != ErrorCode.INSIDE_SURFACE:
                    raise
            if math.isfinite(trn[2]) and trn[2] >= MIN_PEAK:
                est_xy = est_xy + np.array([-trn[0] * alt / f, trn[1] * alt / f])
        est_z = ground + alt
        true_alt = p[2] - client.height_at(p[0], p[1])[0]
        rows.append(dict(step=step, time=t, x=p[0], y=p[1], z=p[2], vx=v[0], vy=v[1], vz=v[2],
                         est_x=est_xy[0], est_y=est_xy[1], est_z=est_z, est_vx=est_vxy[0],
                         est_vy=est_vxy[1], altimeter=alt, true_altitude=true_alt,
                         flow_du=flow[0], flow_dv=flow[1], flow_peak=flow[2],
                         trn_du=trn[0], trn_dv=trn[1], trn_peak=trn[2],
                         err_x=est_xy[0] - p[0], err_y=est_xy[1] - p[1], err_z=est_z - p[2],
                         err_vx=est_vxy[0] - v[0], err_vy=est_vxy[1] - v[1]))
        if not math.isfinite(alt) or alt <= touchdown:
            break
        # -- guidance (estimates only)
        accel = -KP * (est_xy - site) - KD * est_vxy
        norm = float(np.linalg.norm(accel))
        if norm > MAX_ACCEL:
            accel *= MAX_ACCEL / norm
        descent = min(max(alt / tau, MIN_DESCENT), MAX_DESCENT)
        descent = min(descent, max((alt - touchdown) / dt, 0.1))
        # -- truth: the vehicle moves, with thruster noise keyed by (seed, step, axis)
        noise = np.array([normal_scalar(SEED, stream, 0, step, axis, 0) for axis in (0, 1)])
        v[:2] = v[:2] + (accel + THRUST_NOISE * noise) * dt
        v[2] = -descent
        p = p + v * dt
        previous, prev_alt = image, alt
        t += dt
    summary = write_outputs(out, rows, site, ground, dict(
        size=size, dt=dt, tau=tau, touchdown=touchdown, start_altitude=start_altitude,
        offset=list(offset), drift=list(drift), initial_error=list(initial_error),
        trn_above=trn_above,
        scenario=info["scenario"], seed=SEED), crashed)
    return summary


def write_outputs(out: Path, rows: list[dict], site, ground, params: dict,
                  crashed: bool = False) -> dict:
    with open(out / "trajectory.csv", "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
        writer.writeheader()
        for r in rows:
            writer.writerow({k: (f"{v:.6f}" if isinstance(v, float) else v)
                             for k, v in r.items()})
    last = rows[-1]
    lateral = np.array([math.hypot(r["err_x"], r["err_y"]) for r in rows])
    vel = np.array([math.hypot(r["err_vx"], r["err_vy"]) for r in rows[1:]] or [math.nan])
    summary = dict(
        params, steps=len(rows), touchdown_time_s=last["time"], crashed=crashed,
        touchdown_altimeter_m=last["altimeter"],
        landing_error_m=math.hypot(last["x"] - site[0], last["y"] - site[1]),
        landing_error_estimated_m=math.hypot(last["est_x"] - site[0], last["est_y"] - site[1]),
        nav_error_lateral_m=dict(initial=float(lateral[0]), final=float(lateral[-1]),
                                 median=float(np.median(lateral)), max=float(lateral.max())),
        nav_error_velocity_mps=dict(median=float(np.nanmedian(vel)),
                                    max=float(np.nanmax(vel))),
        nav_error_altitude_m=dict(max_abs=float(max(abs(r["altimeter"] - r["true_altitude"])
                                                    for r in rows))),
        nav_error_height_above_site_m=dict(final=float(last["err_z"]),
                                           max_abs=float(max(abs(r["err_z"]) for r in rows))),
        touchdown_speed_mps=math.hypot(last["vx"], last["vy"], last["vz"]),
        site=[float(site[0]), float(site[1]), float(ground)])
    (out / "summary.json").write_text(json.dumps(summary, indent=2), encoding="utf-8")
    plot(out / "closed_loop.png", rows, site, ground)
    return summary


def plot(path: Path, rows: list[dict], site, ground: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = np.array([r["time"] for r in rows])
    fig, ax = plt.subplots(1, 3, figsize=(13, 4))
    ax[0].plot([r["x"] - site[0] for r in rows], [r["y"] - site[1] for r in rows], label="truth")
    ax[0].plot([r["est_x"] - site[0] for r in rows], [r["est_y"] - site[1] for r in rows],
               "--", label="navigation estimate")
    ax[0].plot([0], [0], "k+", ms=12, label="site")
    ax[0].set(xlabel="east of site (m)", ylabel="north of site (m)", title="ground track")
    ax[0].set_aspect("equal", "datalim")
    ax[0].legend(fontsize=8)
    ax[1].plot(t, [r["z"] - ground for r in rows], label="height above the site (truth)")
    ax[1].plot(t, [r["altimeter"] for r in rows], ".", ms=3,
               label="laser altimeter (to the ground below)")
    ax[1].set(xlabel="time (s)", ylabel="m", title="descent", yscale="log")
    ax[1].legend(fontsize=8)
    ax[2].plot(t, [math.hypot(r["err_x"], r["err_y"]) for r in rows], label="lateral (m)")
    ax[2].plot(t, [abs(r["altimeter"] - r["true_altitude"]) + 1e-6 for r in rows],
               label="altitude (m)")
    ax[2].plot(t, [math.hypot(r["err_vx"], r["err_vy"]) for r in rows],
               label="lateral velocity (m/s)")
    ax[2].set(xlabel="time (s)", title="navigation error against truth", yscale="log")
    ax[2].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenario", nargs="?", type=Path,
                        help="terrain scenario to serve (omit with --port)")
    parser.add_argument("--out", type=Path, required=True, help="output folder")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=None, help="use a running server")
    parser.add_argument("--token", default=None)
    parser.add_argument("--size", type=int, default=256, help="image side (pixels)")
    parser.add_argument("--dt", type=float, default=1.0, help="guidance step (s)")
    parser.add_argument("--tau", type=float, default=15.0, help="descent time constant (s)")
    parser.add_argument("--touchdown", type=float, default=2.0,
                        help="altimeter range at touchdown (m): the camera's height")
    parser.add_argument("--start-altitude", type=float, default=2000.0)
    parser.add_argument("--offset", type=float, nargs=2, default=(250.0, -180.0),
                        help="start east, north of the site (m)")
    parser.add_argument("--drift", type=float, nargs=2, default=(-3.0, 2.0),
                        help="start velocity east, north (m/s)")
    parser.add_argument("--initial-error", type=float, nargs=2, default=(30.0, -20.0),
                        help="error of the initial position estimate (m)")
    parser.add_argument("--trn-above", type=float, default=500.0,
                        help="terrain-relative position fixes above this altitude (m; 0: none)")
    args = parser.parse_args(argv)
    if args.port is None and args.scenario is None:
        parser.error("give a SCENARIO to serve, or --port of a running server")
    from render.client import Client

    args.out.mkdir(parents=True, exist_ok=True)
    proc = None
    port = args.port
    if port is None:
        proc, port = start_server(args.scenario)
    try:
        with Client(args.host, port, token=args.token) as client:
            summary = fly(client, args.out, size=args.size, dt=args.dt, tau=args.tau,
                          touchdown=args.touchdown, start_altitude=args.start_altitude,
                          offset=args.offset, drift=args.drift,
                          initial_error=args.initial_error, trn_above=args.trn_above)
    finally:
        if proc is not None:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=60)
            proc.stderr.close()
    print(f"touchdown after {summary['steps']} steps ({summary['touchdown_time_s']:.0f} s), "
          f"{summary['landing_error_m']:.1f} m from the site; navigation error "
          f"{summary['nav_error_lateral_m']['final']:.1f} m lateral at touchdown "
          f"(median {summary['nav_error_lateral_m']['median']:.1f} m); wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
