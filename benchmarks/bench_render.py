"""Rendering benchmark: frame time of the default lunar descent scene at 1024 x 1024.

Each lighting effect is timed off and on in the same run: shadow maps with a point sun
("shadows"), then the extended sun's soft shadows, the light the terrain scatters into
shadows, earthshine, and the defaults (all of them but earthshine, whose lighting has no
Earth); ``effect_cost_s`` is each one's median frame time less the point sun's.

Builds the descent scene the demo uses (a 1025^2 base at 1 km, 11 nested 1025^2 layers down
to about 0.5 m, a lunar crater population), renders frames along a 10 km -> 20 m descent with
and without shadows, and reports median frame time and triangles per frame. Baseline in the
same run: raw moderngl (one vertex array, one draw call, a minimal shader writing the same
three images, a standard depth buffer, no culling, no level of detail) of a grid with the same
triangle count as the median frame, without shadows (``plain_single_mesh``) and with its own
per-frame shadow pass (``plain_with_shadow_pass``: the grid drawn into a depth map from the
sun, looked up with one comparison), rendered interleaved with the scene's frames (each
frame: every configuration, the order reversed every other frame). ``ratio_to_plain`` is the
frame without shadows over the first, ``shadows_ratio_to_plain`` the frame with shadows over
the second (``defaults_ratio_to_plain``: every default effect). Targets (the rendering
issue): ratios <= 1.5 (goal 1.2); <= 0.5 s per frame with shadows on this CPU. ``--stack``
renders an existing stack (the demo's) instead of building the synthetic one.

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


RAW_VERTEX = """
#version 330 core
uniform mat4 u_clip;
uniform mat4 u_light;
in vec3 in_position;
in vec3 in_normal;
out vec3 v_position;
out vec3 v_normal;
out vec4 v_light;
void main() {
    v_position = in_position;
    v_normal = in_normal;
    v_light = u_light * vec4(in_position, 1.0);
    gl_Position = u_clip * vec4(in_position, 1.0);
}
"""
RAW_FRAGMENT = """
#version 330 core
uniform vec3 u_camera;
uniform vec3 u_sun;
uniform float u_albedo;
uniform int u_shadows;
uniform sampler2DShadow u_shadow_map;
in vec3 v_position;
in vec3 v_normal;
in vec4 v_light;
layout(location = 0) out float out_radiance;
layout(location = 1) out float out_range;
layout(location = 2) out vec4 out_normal;
void main() {
    vec3 n = normalize(v_normal);
    float lit = 1.0;
    if (u_shadows == 1)
        lit = texture(u_shadow_map, vec3(v_light.xy, v_light.z - 1e-4));
    out_radiance = u_albedo * max(dot(n, u_sun), 0.0) * lit;
    out_range = length(v_position - u_camera);
    out_normal = vec4(n, 1.0);
}
"""
RAW_DEPTH_VERTEX = """
#version 330 core
uniform mat4 u_clip;
in vec3 in_position;
void main() { gl_Position = u_clip * vec4(in_position, 1.0); }
"""
RAW_DEPTH_FRAGMENT = """
#version 330 core
void main() {}
"""


def plain_render(ctx, triangles: int, size: int, shadow_size: int):
    """Raw moderngl: one grid mesh of ``triangles`` triangles, one draw, a minimal shader.

    The least a renderer of the same images does: the three images (a Lambert radiance,
    the range and the normals) from one draw with a standard 24-bit depth buffer and a
    minimal shader, read back as the renderer reads them; ``shadows=True`` adds its own
    per-frame shadow pass (the mesh drawn into a ``shadow_size`` square depth map from the
    sun, looked up with one bilinear comparison).

    Returns
    -------
    call : callable
        ``call(shadows)`` renders one frame.
    release : callable
        Frees the GL objects.
    """
    import moderngl
    import numpy as np

    from render.camera import Intrinsics, look_at

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
    prog = ctx.program(vertex_shader=RAW_VERTEX, fragment_shader=RAW_FRAGMENT)
    depth_prog = ctx.program(vertex_shader=RAW_DEPTH_VERTEX, fragment_shader=RAW_DEPTH_FRAGMENT)
    vbo = ctx.buffer(np.hstack([pos, nor]).astype("f4").tobytes())
    ibo = ctx.buffer(faces.tobytes())
    vao = ctx.vertex_array(prog, [(vbo, "3f 3f", "in_position", "in_normal")], ibo)
    dvao = ctx.vertex_array(depth_prog, [(vbo, "3f 12x", "in_position")], ibo)
    k = Intrinsics.from_fov(size, size, 60.0)
    pose = look_at((0.0, -0.6 * n, 0.5 * n), (0.0, 0.0, 0.0))
    near, far = 0.01 * n, 3.0 * n
    view = np.eye(4)
    view[:3, :3] = pose.rotation.T
    view[:3, 3] = -pose.rotation.T @ np.asarray(pose.position)
    proj = np.zeros((4, 4))  # OpenCV camera to GL clip, finite far plane
    proj[0, 0], proj[0, 2] = 2.0 * k.fx / size, (2.0 * k.cx + 1.0) / size - 1.0
    proj[1, 1], proj[1, 2] = -2.0 * k.fy / size, 1.0 - (2.0 * k.cy + 1.0) / size
    proj[2, 2], proj[2, 3] = (far + near) / (far - near), -2.0 * far * near / (far - near)
    proj[3, 2] = 1.0
    sun = np.array([0.5, 0.5, 0.7071])
    sun /= np.linalg.norm(sun)
    # the sun's orthographic view of the grid: light axes x, y across, z along the light
    lz = -sun
    lx = np.cross([0.0, 0.0, 1.0], lz)
    lx /= np.linalg.norm(lx)
    ly = np.cross(lz, lx)
    half = 0.75 * n
    light = np.eye(4)
    light[0, :3], light[1, :3], light[2, :3] = lx / half, ly / half, lz / half
    light[2, 3] = 0.0
    to_tex = np.eye(4)
    to_tex[:3, :3] *= 0.5
    to_tex[:3, 3] = 0.5
    color = [ctx.texture((size, size), 1, dtype="f4"), ctx.texture((size, size), 1, dtype="f4"),
             ctx.texture((size, size), 4, dtype="f4")]
    depth = ctx.depth_renderbuffer((size, size))
    fbo = ctx.framebuffer(color_attachments=color, depth_attachment=depth)
    shadow_tex = ctx.depth_texture((shadow_size, shadow_size))
    shadow_tex.compare_func = "<="
    shadow_tex.filter = (moderngl.LINEAR, moderngl.LINEAR)
    shadow_fbo = ctx.framebuffer(depth_attachment=shadow_tex)
    clip = (proj @ view).T.astype("f4").tobytes()
    light_clip = light.T.astype("f4").tobytes()
    light_tex = (to_tex @ light).T.astype("f4").tobytes()

    def call(shadows: bool):
        ctx.enable(moderngl.DEPTH_TEST)
        ctx.disable(moderngl.CULL_FACE)
        ctx.depth_func = "<"
        if shadows:
            shadow_fbo.use()
            ctx.viewport = (0, 0, shadow_size, shadow_size)
            shadow_fbo.clear(depth=1.0)
            depth_prog["u_clip"].write(light_clip)
            dvao.render(moderngl.TRIANGLES)
            shadow_tex.use(location=0)
        prog["u_clip"].write(clip)
        prog["u_light"].write(light_tex)
        prog["u_camera"].value = tuple(pose.position)
        prog["u_sun"].value = tuple(sun)
        prog["u_albedo"].value = 0.12
        prog["u_shadows"].value = int(shadows)
        prog["u_shadow_map"].value = 0
        fbo.use()
        ctx.viewport = (0, 0, size, size)
        fbo.clear(depth=1.0)
        vao.render(moderngl.TRIANGLES)
        for i, comps in ((0, 1), (1, 1), (2, 4)):
            fbo.read(attachment=i, components=comps, dtype="f4")

    def release():
        for obj in (vao, dvao, vbo, ibo, prog, depth_prog, fbo, shadow_fbo, shadow_tex, depth,
                    *color):
            obj.release()

    return call, release


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small scene and image")
    parser.add_argument("--frames", type=int, default=None, help="frames along the descent")
    parser.add_argument("--stack", type=Path, default=None,
                        help="render this layer stack (e.g. the demo's) instead of building one")
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
        if args.stack is None:
            stack_dir, build_s = build_scene(Path(tmp), quick)
        else:
            stack_dir, build_s = args.stack, None
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
        shadow_size = RenderOptions().shadow_size
        plain, release = plain_render(renderer.ctx, median_tris, size, shadow_size)
        plain(False)  # warm
        plain(True)
        raw = ["plain_single_mesh", "plain_with_shadow_pass"]
        log(f"{frames} frames x (raw, raw with a shadow pass, each setting), interleaved")
        names = [*raw, *options]
        for name in names[2:]:  # warm each setting's one-off work (earthshine's grids)
            renderer.render(scene, View(samples[0].pose, k), lights[name], options[name])
        times: dict[str, list[float]] = {name: [] for name in names}
        drawn: dict[str, list] = {name: [] for name in names[2:]}
        for i, s in enumerate(samples):
            for name in order(names, i):
                t0 = time.perf_counter()
                if name in raw:
                    plain(name == "plain_with_shadow_pass")
                else:
                    frame = renderer.render(scene, View(s.pose, k), lights[name],
                                            options[name])
                times[name].append(time.perf_counter() - t0)
                if name not in raw:
                    drawn[name].append(frame.drawn["triangles"])
        release()
        result = {name: dict(summary(times[name]), triangles=drawn[name],
                             median_triangles=int(statistics.median(drawn[name])))
                  for name in names[2:]}
        for name in raw:
            result[name] = dict(summary(times[name]), triangles=median_tris,
                                shadow_size=shadow_size if "shadow" in name else None)
        for name in names:
            log(f"{name}: median {result[name]['median_s']:.3f} s")
        ratio = result["no_shadows"]["median_s"] / result["plain_single_mesh"]["median_s"]
        shadows_ratio = (result["shadows"]["median_s"]
                         / result["plain_with_shadow_pass"]["median_s"])
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
            shadows_ratio_to_plain=shadows_ratio,
            defaults_ratio_to_plain=(result["defaults"]["median_s"]
                                     / result["plain_with_shadow_pass"]["median_s"]),
            renderer=describe(), peak_rss_bytes=peak_rss_bytes(),
            targets=None if quick else dict(
                ratio_ok=ratio <= 1.5, shadows_ratio_ok=shadows_ratio <= 1.5,
                shadows_ratio_goal=shadows_ratio <= 1.2,
                shadows_frame_ok=result["shadows"]["median_s"] <= 0.5),
            machine=machine_facts(),
        )
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
