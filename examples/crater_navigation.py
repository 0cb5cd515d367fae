"""Crater-based terrain-relative navigation on a rendered descent, scored against truth.

The reference pipeline a navigation team would build on craterscape's labels
(``docs/labels.md``), frame by frame:

1. **Detect.** The detector is the truth rims perturbed by a stated noise, standing in for a
   classical ellipse detector: a crater is detected when its whole rim is in the frame, at
   most a quarter of it hidden, at least half of it lit and its semi-minor axis at least
   ``--min-axis`` pixels (a detector needs the lit crescent and the shadowed wall); each
   detected ellipse centre is moved by Gaussian noise of ``--sigma-px`` pixels plus
   ``--sigma-rel`` of its semi-major axis (a fit's error grows with the rim it fits), and a
   fraction ``--miss`` of detections is dropped. Every draw is keyed by (seed, frame).
2. **Match.** The catalogue (the scene's crater catalogue, as a lander's onboard map holds
   it) is projected with the *prior* pose: the true pose perturbed by ``--prior-error`` of
   the range in position and ``--prior-attitude`` degrees (what an inertial propagation
   gives between fixes). Each detection takes the nearest predicted crater whose size agrees
   within 30 %, gated at 5 % of the image; a predicted crater claimed twice keeps neither.
   A frame with fewer than six matches (or RANSAC inliers) gets no fix.
3. **Solve.** The 3-D rim centres of the matches and their detected ellipse centres go to
   OpenCV's ``solvePnPRansac`` (EPnP inside RANSAC, then Levenberg-Marquardt), started
   from the prior. An ellipse's centre is not the image of the rim's centre (perspective
   moves it towards the far side of the rim); the offset is predicted with the prior pose,
   removed from each detection, and predicted again with the solved pose for a second solve.
4. **Score.** The position error against the truth pose, as a percentage of the
   line-of-sight range (the rendered range at the principal point).

Written to ``--out``: ``frames.csv`` (per frame: detections, matches, inliers, range, position
error in metres and in per cent of range, the prior's error) and ``summary.json``, which
``evaluation/campaign_report.py`` puts into the campaign report when it lies in the
campaign's ``lunar/crater_navigation/`` folder.

Usage::

    craterscape render sequence examples/lunar_descent.toml -o RUN --labels
    .venv/bin/python examples/crater_navigation.py RUN --out OUT

    .venv/bin/python examples/crater_navigation.py SCENARIO.toml --out OUT [--frames 20]
        # renders the labelled descent into OUT/run first
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

#: The field-tested reference: feature-based TRN reaches about 1-3 % of line-of-sight range
#: (DLR's TRON laboratory, Krueger et al. and Theil et al.'s lunar-landing navigation tests).
TRON_PERCENT = (1.0, 3.0)
#: A detection matches a predicted crater within this fraction of the image's width ...
GATE = 0.05
#: ... whose semi-major axis agrees within this factor.
SIZE_TOLERANCE = 1.3
#: Fewest matches a pose is solved from (four fix it exactly, leaving RANSAC nothing to test).
MIN_MATCHES = 6


def _rotvec(rng, degrees: float) -> np.ndarray:
    import cv2

    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return cv2.Rodrigues(axis * math.radians(degrees) * abs(rng.normal()))[0]


def detect(rims: list[dict], rng, args) -> list[dict]:
    """Give the detector's ellipses: truth rims that pass the detector's tests, perturbed."""
    out = []
    for r in rims:
        major, minor = r["ellipse"]["axes"]
        if (r["in_frame"] < 1.0 or r["occluded"] > 0.25 or (r["lit"] or 0.0) < 0.5
                or minor < args.min_axis):
            continue
        if rng.random() < args.miss:
            continue
        sigma = args.sigma_px + args.sigma_rel * major
        u, v = np.asarray(r["ellipse"]["centre"]) + rng.normal(0.0, sigma, 2)
        out.append({"centre": np.array([u, v]), "major": major, "truth_id": r["id"]})
    return out


def predict(catalog_xyz, radii, gradient_fn, pose, k):
    """Predicted ellipses (centre, semi-major) and rim-centre projections of the catalogue."""
    from render.labels import ellipse_from_conic, rim_conic

    cam = pose.to_camera(catalog_xyz)
    dist = np.linalg.norm(cam, axis=1)
    span = 2 * radii * k.fx / np.maximum(dist, 1e-9)
    keep = np.flatnonzero((cam[:, 2] > radii) & (span > 2.0))
    centres = pose.project(catalog_xyz[keep], k)
    ok = (centres[:, 0] > -0.1 * k.width) & (centres[:, 0] < 1.1 * k.width) \
        & (centres[:, 1] > -0.1 * k.height) & (centres[:, 1] < 1.1 * k.height)
    keep, centres = keep[ok], centres[ok]
    ell, major = np.full((len(keep), 2), np.nan), np.full(len(keep), np.nan)
    for j, i in enumerate(keep):
        e = ellipse_from_conic(rim_conic(catalog_xyz[i], radii[i], gradient_fn(i), pose, k))
        if e is not None:
            ell[j], major[j] = e[:2], e[2]
    good = np.isfinite(major)
    return keep[good], ell[good], major[good], centres[good]


def solve_frame(detections, catalog_xyz, radii, gradient_fn, prior, truth_pose, k):
    """Match detections to the catalogue with the prior pose and solve the camera pose."""
    import cv2

    from render.camera import Pose, quat_from_matrix

    idx, ell, major, proj = predict(catalog_xyz, radii, gradient_fn, prior, k)
    if not len(idx) or not detections:
        return None, 0, 0
    claims: dict[int, list[int]] = {}
    for d_i, d in enumerate(detections):
        dist = np.hypot(*(ell - d["centre"]).T)
        size_ok = (major / d["major"] < SIZE_TOLERANCE) & (d["major"] / major < SIZE_TOLERANCE)
        dist[~size_ok] = np.inf
        j = int(np.argmin(dist))
        if dist[j] < GATE * k.width:
            claims.setdefault(j, []).append(d_i)
    pairs = [(j, ds[0]) for j, ds in claims.items() if len(ds) == 1]
    if len(pairs) < MIN_MATCHES:
        return None, len(pairs), 0
    world = catalog_xyz[idx[[j for j, _ in pairs]]]
    seen = np.array([detections[d]["centre"] for _, d in pairs])
    offset = ell[[j for j, _ in pairs]] - proj[[j for j, _ in pairs]]  # perspective shift
    r_cw = prior.rotation.T
    rvec, tvec = cv2.Rodrigues(r_cw)[0], (-r_cw @ np.asarray(prior.position)).reshape(3, 1)
    inliers = None
    for _ in range(2):
        ok, rvec, tvec, inliers = cv2.solvePnPRansac(
            world, seen - offset, k.matrix, None, rvec=rvec.copy(), tvec=tvec.copy(),
            useExtrinsicGuess=True, reprojectionError=3.0, iterationsCount=200,
            flags=cv2.SOLVEPNP_ITERATIVE)
        if not ok or inliers is None or len(inliers) < MIN_MATCHES:
            return None, len(pairs), 0
        r = cv2.Rodrigues(rvec)[0]
        est = Pose(tuple((-r.T @ tvec).ravel()), tuple(quat_from_matrix(r.T)))
        _, ell2, _, proj2 = predict(world, radii[idx[[j for j, _ in pairs]]],
                                    lambda i, p=pairs: gradient_fn(idx[p[i][0]]), est, k)
        if len(ell2) == len(pairs):
            offset = ell2 - proj2
    return est, len(pairs), int(len(inliers))


def main(argv=None) -> int:
    from render.labels import Labeller, LabelSpec
    from render.rundir import RunReader
    from render.scenario import load_scenario
    from render.sequence import load_scene, run_sequence
    from terrain.io import read_float_tiff

    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("source", type=Path, help="a labelled run directory, or a scenario to render")
    p.add_argument("--out", type=Path, required=True)
    p.add_argument("--scenario", type=Path, default=None,
                   help="the run's scenario file (default: the source, or RUN/scenario.toml)")
    p.add_argument("--frames", type=int, default=None, help="frames to render (scenario only)")
    p.add_argument("--resolution", type=int, default=512, help="image side (scenario only)")
    p.add_argument("--seed", type=int, default=7)
    p.add_argument("--sigma-px", type=float, default=0.5)
    p.add_argument("--sigma-rel", type=float, default=0.02)
    p.add_argument("--miss", type=float, default=0.1)
    p.add_argument("--min-axis", type=float, default=5.0)
    p.add_argument("--prior-error", type=float, default=0.05,
                   help="prior position error, fraction of range")
    p.add_argument("--prior-attitude", type=float, default=0.5, help="degrees")
    args = p.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    run_dir = args.source
    if args.source.suffix == ".toml":
        sc = load_scenario(args.source).with_overrides(args.frames,
                                                       (args.resolution, args.resolution))
        from dataclasses import replace

        sc = replace(sc, labels=LabelSpec(min_crater_pixels=6.0, flow=False, masks=False))
        run_dir = args.out / "run"
        run_sequence(sc, run_dir, resume=run_dir.exists())
    run = RunReader(run_dir)
    # the scenario as given: a run's copy of it names its stack relative to its old folder
    sc = load_scenario(args.scenario or (args.source if args.source.suffix == ".toml"
                                         else run_dir / "scenario.toml"))
    scene = load_scene(sc)
    lab = Labeller(scene, LabelSpec())
    xyz, radii, grad = lab.crater_geometry()  # the onboard map: the scene's catalogue
    rows = []
    for t in run.truth:
        if not t.labels or "rims" not in t.labels:
            continue
        rng = np.random.default_rng([args.seed, 0xC7A7E5, t.index])
        rims = json.loads((run_dir / t.labels["rims"]).read_text())["craters"]
        k = t.intrinsics
        rng_img = read_float_tiff(run_dir / t.range) if t.range else None
        los = float(rng_img[int(round(k.cy)), int(round(k.cx))]) if rng_img is not None \
            else float(np.linalg.norm(np.asarray(t.pose.position) - np.asarray(
                [*scene.site, scene.height_at(*scene.site)])))
        from render.camera import Pose, quat_from_matrix

        shift = rng.normal(size=3)
        shift *= args.prior_error * los / np.linalg.norm(shift)
        prior = Pose(tuple(np.asarray(t.pose.position) + shift),
                     tuple(quat_from_matrix(t.pose.rotation @ _rotvec(rng, args.prior_attitude))))
        dets = detect(rims, rng, args)
        est, matched, inl = solve_frame(dets, xyz, radii, lambda i: grad[i], prior, t.pose, k)
        err = float(np.linalg.norm(np.asarray(est.position) - np.asarray(t.pose.position))) \
            if est is not None else float("nan")
        rows.append(dict(frame=t.index, range_m=los, rims=len(rims), detected=len(dets),
                         matched=matched, inliers=inl, error_m=err,
                         error_percent=100 * err / los,
                         prior_error_percent=100 * float(np.linalg.norm(shift)) / los))
        print(f"frame {t.index}: range {los:.0f} m, {len(dets)} detected, {matched} matched, "
              f"{inl} inliers, error {err:.2f} m ({100 * err / los:.2f} %)", file=sys.stderr)
    with open(args.out / "frames.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) if rows else ["frame"])
        w.writeheader()
        w.writerows(rows)
    solved = [r["error_percent"] for r in rows if math.isfinite(r["error_percent"])]
    summary = dict(
        run=str(run_dir), frames=len(rows), solved=len(solved),
        median_error_percent=float(np.median(solved)) if solved else None,
        p90_error_percent=float(np.percentile(solved, 90)) if solved else None,
        tron_percent=list(TRON_PERCENT),
        detector=dict(kind="truth rims perturbed", sigma_px=args.sigma_px,
                      sigma_rel=args.sigma_rel, miss=args.miss, min_axis_px=args.min_axis),
        prior=dict(position_fraction_of_range=args.prior_error,
                   attitude_deg=args.prior_attitude),
        seed=args.seed, per_frame=rows)
    (args.out / "summary.json").write_text(json.dumps(summary, indent=2))
    print(json.dumps({k: v for k, v in summary.items() if k != "per_frame"}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
