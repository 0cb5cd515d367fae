"""Craters per second on an arbitrary closed mesh against the lat/lon mesh: JSON on stdout.

The arbitrary mesh is the contact-binary packing base (:mod:`asteroid.packing`) split
uniformly to about 1M triangles (``--quick``: about 110k); the baseline is the
6M^2 + 2 latitude/longitude body (:mod:`asteroid.craters`) with the same number of vertices
and the same equivalent radius. Both take the same number of craters, sized so that neither
mesh needs refining (D >= 4 vertex spacings), so the figure compares the crater kernels and
their neighbourhood searches. The two run interleaved in one process (A B, B A, ...), after
a warm-up that compiles the numba kernels.

Usage::

    .venv/bin/python benchmarks/bench_meshbody.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from _common import alternate, logger, machine_facts  # noqa: E402

log = logger("bench-meshbody")
SEED = 27
RADIUS = 1000.0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--repeat", type=int, default=None)
    args = parser.parse_args(argv)
    from asteroid.body import Body
    from asteroid.craters import CraterSettings, add_craters, craters_at
    from asteroid.packing import packing_body
    from asteroid.sphere import SphereMesh
    from asteroid.surface import MeshBody, Sites, add_mesh_craters, split
    from terrain.craters.cratering import CraterModel

    splits = 1 if args.quick else 2
    cells = 64 if args.quick else 96
    count = 200 if args.quick else 2000
    repeat = args.repeat or (2 if args.quick else 2)
    base = packing_body("contact-binary", radius=RADIUS, seed=SEED, cells=cells)
    v, f = base.vertices, base.faces
    for _ in range(splits):
        v, f = split(v, f, np.ones(len(f), bool))
    body = MeshBody(v, f)
    m = max(8, int(round(math.sqrt((body.n_vertices - 2) / 6.0))))
    sphere = Body.sphere(SphereMesh(m), RADIUS)
    log(f"arbitrary mesh {body.n_vertices:,} vertices / {len(f):,} triangles; "
        f"lat/lon M = {m}: {sphere.mesh.n_vertices:,} vertices")
    spacing = max(body.mean_edge(), sphere.mesh.mean_spacing * RADIUS)
    dmin = 4.0 * spacing * 1.5
    rng = np.random.default_rng(SEED)           # benchmark inputs only
    d = dmin * (1.0 + 3.0 * rng.random(count))
    ages = 3.5 * rng.random(count)
    faces = rng.choice(len(f), count, replace=False)
    pts = v[f[faces]].mean(axis=1)
    sites = Sites(faces.astype(np.int64), pts, d, ages, np.arange(count, dtype=np.uint64),
                  np.zeros((count, 0)))
    lat = np.degrees(np.arcsin(2 * rng.random(count) - 1))
    lon = 360.0 * rng.random(count)
    placement = craters_at(lat, lon, d, ages, seed=SEED)
    settings = CraterSettings(CraterModel().smooth())

    def on_mesh():
        return add_mesh_craters(body, sites, seed=SEED, settings=settings, refine_mesh=False)

    def on_latlon():
        return add_craters(sphere, placement, seed=SEED, settings=settings)

    # warm-up: compile every kernel on a few craters
    add_mesh_craters(body, Sites(sites.face[:3], sites.points[:3], d[:3], ages[:3],
                                 sites.uid[:3], np.zeros((3, 0))), seed=SEED,
                     settings=settings, refine_mesh=False)
    add_craters(Body.sphere(SphereMesh(16), RADIUS), craters_at([0.0], [0.0], [300.0]),
                seed=SEED, settings=settings)
    timed = alternate({"mesh": on_mesh, "latlon": on_latlon}, repeat)
    mesh_s = timed.timings["mesh"]["median_s"]
    latlon_s = timed.timings["latlon"]["median_s"]
    out = dict(
        benchmark="meshbody", quick=args.quick,
        mesh=dict(vertices=body.n_vertices, triangles=int(len(f)), craters=count,
                  craters_per_s=count / mesh_s, **timed.timings["mesh"]),
        latlon=dict(magnitude=m, vertices=sphere.mesh.n_vertices, craters=count,
                    craters_per_s=count / latlon_s, **timed.timings["latlon"]),
        ratio_mesh_over_latlon_time=timed.ratio("mesh", "latlon"),
        crater_diameters_m=[float(d.min()), float(d.max())],
        machine=machine_facts())
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
