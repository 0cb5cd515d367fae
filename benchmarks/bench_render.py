"""Rendering benchmark: frame time of the default lunar descent scene at 1024 x 1024.

Each lighting effect is timed off and on in the same run: shadow maps with a point sun
("shadows"), then the extended sun's soft shadows, the light the terrain scatters into
shadows, earthshine, and the defaults (all of them but earthshine, whose lighting has no
Earth); ``effect_cost_s`` is each one's median frame time less the point sun's.

Builds the descent scene the demo uses (a 1025^2 base at 1 km, 11 nested 1025^2 layers down
to about 0.5 m, a lunar crater population), renders frames along a 10 km -> 20 m descent with
and without shadows, and reports median frame time and triangles per frame. Baseline in the
same run: a plain single-mesh moderngl render (one vertex array, one draw call, the same
fragment shader, no culling, no level of detail, no shadows) of a grid with the same triangle
count as the median frame, rendered interleaved with the scene's frames (each frame: plain,
without shadows, with shadows, the order reversed every other frame). Targets (the rendering
issue): ratio <= 1.5; <= 0.5 s per frame with shadows on this CPU.

Usage::

    .venv/bin/python benchmarks/bench_render.py [--quick]
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import logger, machine_facts, order, peak_rss_bytes, summary  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SEED = 2014
log = logger("bench-render")


def build_scene(tmp: Path, quick: bool):
    from terrain.craters.population import Population
    from terrain.fractal.synthetic import synthesize_tile
    from terrain.stack.build import build_stack
    from terrain.stack.store import write_stack

    size, levels = (257, 6) if quick else (1025, 11)
    base = synthesize_tile(size, resolution=1000.0, relief=2500.0, seed=SEED).tile
    site = (size * 500.0, size * 500.0)
    t0 = time.perf_counter()
    stack = build_stack(base, site, levels=levels, layer_size=size, seed=SEED,
                        population=Population(dmin=1.0, dmax=20000.0, density=1e5))
    build_s = time.perf_counter() - t0
    write_stack(stack, tmp / "stack")
    return tmp / "stack", build_s


def plain_render(ctx, renderer, triangles: int, size: int):
    """A call rendering one grid mesh of ``triangles`` triangles: one draw, the scene shader.

    Every uniform the draw reads is set in the call (a scene's frame sets them differently),
    and the three images are read back as the renderer reads them.
    """
    import moderngl
    import numpy as np

    from render.camera import Intrinsics, look_at
    from render.renderer import LOG_NEAR, clip_from_camera

    n = int(math.sqrt(triangles / 2)) + 1
    yy, xx = np.mgrid[0:n, 0:n].astype(np.float64)
    z = 20.0 * np.sin(xx / 17.0) * np.cos(yy / 23.0)
    pos = np.stack([xx - n / 2, yy - n / 2, z], -1).reshape(-1, 3)
    nor = np.zeros_like(pos)
    nor[:, 2] = 1.0
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), \
        idx[1:, 1:].ravel()
    faces = np.stack([a, c, b, b, c, d], 1).astype(np.uint32).ravel()
    prog = renderer.scene_program
    vbo = ctx.buffer(np.hstack([pos, nor]).astype("f4").tobytes())
    ibo = ctx.buffer(faces.tobytes())
    vao = ctx.vertex_array(prog, [(vbo, "3f 3f", "in_position", "in_normal")], ibo)
    k = Intrinsics.from_fov(size, size, 60.0)
    pose = look_at((0.0, -0.6 * n, 0.5 * n), (0.0, 0.0, 0.0))
    far = 3.0 * n
    clip = clip_from_camera(k, LOG_NEAR, far)
    rot = np.eye(4)
    rot[:3, :3] = pose.rotation.T
    clip_rel = (clip @ rot).T.astype("f4").tobytes()
    eye3 = np.eye(3, dtype="f4").tobytes()
    ints = dict(u_use_discard=0, u_shadows=0, u_vertex_albedo=0, u_morph=0, u_normal_map=0,
                u_normal_cube=0, u_use_albedo_map=0, u_brdf=0)
    fbo = renderer._target((size, size))

    def call():
        prog["u_clip_from_camera_rel"].write(clip_rel)
        prog["u_world_from_model"].write(eye3)
        prog["u_model_offset"].value = tuple((-np.asarray(pose.position)).tolist())
        prog["u_camera"].value = tuple(pose.position)
        prog["u_axis"].value = tuple(pose.rotation[:, 2].tolist())
        prog["u_sun"].value = (0.5, 0.5, 0.7071)
        prog["u_albedo"].value = 0.12
        prog["u_log_near"].value = math.log(LOG_NEAR)
        prog["u_log_scale"].value = 1.0 / math.log(far / LOG_NEAR)
        for name, value in ints.items():
            prog[name].value = value
        fbo.use()
        ctx.viewport = (0, 0, size, size)
        ctx.enable(moderngl.DEPTH_TEST)
        fbo.clear(depth=1.0)
        vao.render(moderngl.TRIANGLES)
        for i, comps in ((0, 1), (1, 1), (2, 4)):
            fbo.read(attachment=i, components=comps, dtype="f4")

    def release():
        vao.release()
        vbo.release()
        ibo.release()

    return call, release


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small scene and image")
    parser.add_argument("--frames", type=int, default=None, help="frames along the descent")
    args = parser.parse_args(argv)
    from render.camera import Intrinsics
    from render.context import describe
    from render.renderer import Lighting, Renderer, RenderOptions, View
    from render.terrain_scene import TerrainScene
    from render.trajectory import descent

    quick = args.quick
    size = 256 if quick else 1024
    frames = args.frames or (4 if quick else 12)
    with tempfile.TemporaryDirectory() as tmp:
        log("building the descent scene")
        stack_dir, build_s = build_scene(Path(tmp), quick)
        renderer = Renderer()
        t0 = time.perf_counter()
        scene = TerrainScene(stack_dir)
        scene.upload(renderer.gpu)  # what the renderer's first frame would do
        upload_s = time.perf_counter() - t0
        k = Intrinsics.from_fov(size, size, 60.0)
        site = scene.site
        ground = scene.height_at(*site)
        samples = descent(frames, (site[0], site[1], ground), start_altitude=10000.0,
                          end_altitude=20.0, duration=100.0, ground_track=(4000.0, -3000.0),
                          height_at=scene.height_at)
        light = Lighting.from_angles(60.0, 6.0)
        # the Earth low in the north-west at full phase: ~1e-4 of the sun's irradiance
        earthlit = Lighting.from_angles(60.0, 6.0, earth=(-0.6, 0.78, 0.17), earthshine=1e-4)
        point = dict(soft_shadows=False, scattering=False, earthshine=False)
        options = {"no_shadows": RenderOptions(shadows=False, **point),
                   "shadows": RenderOptions(shadows=True, **point),
                   "soft_shadows": RenderOptions(shadows=True, scattering=False),
                   "scattering": RenderOptions(shadows=True, soft_shadows=False),
                   "earthshine": RenderOptions(shadows=True, soft_shadows=False,
                                               scattering=False),
                   "defaults": RenderOptions()}
        lights = {name: earthlit if name == "earthshine" else light for name in options}
        first_s = {}
        for name in ("shadows", "scattering"):  # the maps, then the scattered light, once
            t0 = time.perf_counter()
            renderer.render(scene, View(samples[0].pose, k), lights[name], options[name])
            first_s[name] = time.perf_counter() - t0
        first_shadow_s = first_s["shadows"]
        # one untimed pass: warms every view's vertex arrays and gives the triangle counts
        # the plain baseline is sized by
        tris = [renderer.render(scene, View(s.pose, k), light, options["no_shadows"])
                .drawn["triangles"] for s in samples]
        median_tris = int(statistics.median(tris))
        plain, release = plain_render(renderer.ctx, renderer, median_tris, size)
        plain()  # warm
        log(f"{frames} frames x (plain, no shadows, shadows), interleaved")
        names = ["plain_single_mesh", *options]
        for name in names[1:]:  # warm each setting's one-off work (earthshine's grids)
            renderer.render(scene, View(samples[0].pose, k), lights[name], options[name])
        times = {name: [] for name in names}
        drawn = {name: [] for name in names[1:]}
        for i, s in enumerate(samples):
            for name in order(names, i):
                t0 = time.perf_counter()
                if name == "plain_single_mesh":
                    plain()
                else:
                    frame = renderer.render(scene, View(s.pose, k), lights[name],
                                            options[name])
                times[name].append(time.perf_counter() - t0)
                if name != "plain_single_mesh":
                    drawn[name].append(frame.drawn["triangles"])
        release()
        result = {name: dict(summary(times[name]), triangles=drawn[name],
                             median_triangles=int(statistics.median(drawn[name])))
                  for name in names[1:]}
        result["plain_single_mesh"] = dict(summary(times["plain_single_mesh"]),
                                           triangles=median_tris)
        for name in names:
            log(f"{name}: median {result[name]['median_s']:.3f} s")
        ratio = result["no_shadows"]["median_s"] / result["plain_single_mesh"]["median_s"]
        out = dict(
            benchmark="render", quick=quick, image=[size, size], frames=frames,
            scene=dict(layers=len(scene.stack.tiles), full_triangles=scene.triangles_full,
                       stack_build_s=build_s, load_and_upload_s=upload_s),
            first_frame_with_shadow_maps_s=first_shadow_s,
            scattered_light_grids_s=first_s["scattering"], **result,
            effect_cost_s={name: result[name]["median_s"] - result["shadows"]["median_s"]
                           for name in ("soft_shadows", "scattering", "earthshine",
                                        "defaults")},
            ratio_to_plain=ratio,
            shadows_ratio_to_plain=(result["shadows"]["median_s"]
                                    / result["plain_single_mesh"]["median_s"]),
            renderer=describe(), peak_rss_bytes=peak_rss_bytes(),
            targets=None if quick else dict(
                ratio_ok=ratio <= 1.5, shadows_frame_ok=result["shadows"]["median_s"] <= 0.5),
            machine=machine_facts(),
        )
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
