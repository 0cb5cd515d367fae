"""Scene-load benchmark: a layer stack read, uploaded and drawn once, against a raw mesh.

Builds a stack like the demo's (``examples/demo.toml``: a 1025^2 base at 1 km enhanced in 15
nested 1025^2 layers, craters and rocks at every scale; ``--quick``: the reduced demo's,
257^2 and 13 layers) and
times, interleaved round by round (A B, B A, ...):

* ``scene``: ``TerrainScene(stack folder)`` (the layers, the crater and rock catalogues),
  its upload (index buffers; the layers it draws build their vertex, geomorphing and normal
  buffers in the frame) and its first 1024^2
  frame (256^2 with ``--quick``) of the descent's first pose, without shadows (their maps
  are the shadow code's and timed by bench_render) and, separately, that first frame alone;
  then the same view again with the descent's shadows (4096-texel maps, built on this first
  shadowed frame: ``shadow_frame_s``) and once more (the maps cached: ``again_s``), so the
  load with the first shadowed frame is ``seconds + shadow_frame_s``; each also in CPU
  seconds of the process, every thread (``cpu_s``, ``shadow_frame_cpu_s``, ``again_cpu_s``:
  llvmpipe's and the compiled kernels' threads included), the fairer figure on a shared
  machine;
* ``raw``: the baseline, the least any loader must do: the layers' GeoTIFFs read, and one
  plain grid mesh with as many triangles as the scene's first frame draws (positions and
  normals, one draw call, the scene's shader) uploaded, drawn and read back.

Target (the load issue): ``scene`` under 2 s for the demo's stack. The JSON gives both
medians, their ratio, the stack's size and the renderer.

Usage::

    .venv/bin/python benchmarks/bench_load.py [--quick]
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _common import logger, machine_facts, order, peak_rss_bytes, summary  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SEED = 2014
#: The descent's shadow-map cap (``examples/lunar_descent.toml``), texels.
SHADOW_SIZE = 4096
log = logger("bench-load")


def build_stack(tmp: Path, quick: bool) -> Path:
    """Build the demo's base and stack (its ``[lunar]`` tables) under ``tmp``."""
    from evaluation.campaign import load_campaign
    from evaluation.slope import horn_slope
    from render.scene_build import enhance_base, synth_base
    from terrain.io import read_dem
    from terrain.stages.specs import EnhanceSpec
    from terrain.surface.site import landing_site

    c = load_campaign(ROOT / "examples" / "demo.toml", quick=quick)
    fields = c.enhance.as_dict()
    synth_base(c.synth, tmp / "base.tif", tmp / "base_craters.csv")
    tile = read_dem(tmp / "base.tif")
    site = landing_site(tile, horn_slope(tile))
    enhance_base(EnhanceSpec.from_mapping({**fields, "site": site}), tmp / "base.tif",
                 tmp / "stack")
    return tmp / "stack"


def first_view(scene, size: int):
    """The descent's first pose over the scene (10 km above the site, looking at it)."""
    from render.camera import Intrinsics
    from render.renderer import View
    from render.trajectory import descent

    site = scene.site
    samples = descent(2, (site[0], site[1], scene.height_at(*site)), start_altitude=10000.0,
                      end_altitude=20.0, duration=100.0, ground_track=(4000.0, -3000.0),
                      height_at=scene.height_at)
    return View(samples[0].pose, Intrinsics.from_fov(size, size, 60.0))


def raw_load(renderer, stack_dir: Path, view, size: int, triangles: int) -> dict:
    """The baseline: read the layers, then one grid mesh of the frame's triangles, drawn.

    What any loader must do at least: decode the layers' GeoTIFFs, and upload and draw as
    many triangles as the scene's first frame draws (one plain grid mesh, one draw call, the
    scene's shader, no level of detail, no catalogue, no normals texture, no morphing).
    """
    import moderngl
    import numpy as np

    from render.renderer import NEAR_M, clip_from_camera
    from terrain.io import read_dem

    ctx = renderer.ctx
    prog = renderer.scene_program
    manifest = json.loads((stack_dir / "manifest.json").read_text())
    c0 = time.process_time()
    t0 = time.perf_counter()
    tiles = [read_dem(stack_dir / layer["file"]) for layer in manifest["layers"]]
    read_s = time.perf_counter() - t0
    # a grid of the frame's triangle count over the finest layer's heights (tiled)
    n = int(math.sqrt(triangles / 2)) + 1
    z = np.resize(np.nan_to_num(tiles[-1].heights.astype(np.float64)), (n, n))
    res = tiles[-1].resolution
    gy, gx = np.gradient(z, res)
    vert = np.empty((n, n, 6), dtype=np.float32)
    vert[..., 0] = (np.arange(n) - n / 2)[None, :] * res
    vert[..., 1] = (n / 2 - np.arange(n))[:, None] * res
    vert[..., 2] = z
    nor = np.stack([-gx, gy, np.ones_like(z)], -1)
    vert[..., 3:] = nor / np.linalg.norm(nor, axis=-1, keepdims=True)
    idx = np.arange(n * n, dtype=np.uint32).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    faces = np.stack([a, c, b, b, c, d], -1).reshape(-1)
    vbo, ibo = ctx.buffer(vert), ctx.buffer(faces)
    vao = ctx.vertex_array(prog, [(vbo, "3f 3f", "in_position", "in_normal")], ibo)
    upload_s = time.perf_counter() - t0 - read_s
    from render.camera import look_at

    pose = look_at((0.0, -0.6 * n * res, 0.5 * n * res), (0.0, 0.0, 0.0))
    k = view.intrinsics
    far = 3.0 * n * res
    rot = np.eye(4)
    rot[:3, :3] = pose.rotation.T
    clip_rel = (clip_from_camera(k, NEAR_M, far) @ rot).T.astype("f4").tobytes()
    prog["u_clip_from_camera_rel"].write(clip_rel)
    prog["u_world_from_model"].write(np.eye(3, dtype="f4").tobytes())
    prog["u_model_offset"].value = tuple((-np.asarray(pose.position)).tolist())
    prog["u_camera"].value = tuple(pose.position)
    for name in ("u_use_discard", "u_vertex_albedo", "u_vertex_scatter", "u_morph",
                 "u_normal_map", "u_normal_cube", "u_use_albedo_map", "u_scatter_map"):
        if name in prog:
            prog[name].value = 0
    # each sampler on its own unit, as the renderer sets them (a 2-D sampler and a cube
    # sampler left together on unit 0 make the draw an invalid operation)
    for name, unit in (("u_albedo_map", 1), ("u_normals", 2), ("u_normal_cube_map", 3),
                       ("u_scatter", 5)):
        if name in prog:
            prog[name].value = unit
    fbo = renderer._target((size, size)).surface  # the surface pass's images
    fbo.use()
    ctx.viewport = (0, 0, size, size)
    ctx.enable(moderngl.DEPTH_TEST)
    ctx.depth_func = ">"  # the renderer's reversed Z (near / z in [0.5, 1]: clip z [-1, 1])
    fbo.clear(depth=0.0)
    vao.render(moderngl.TRIANGLES)
    ctx.depth_func = "<"
    for i in range(len(fbo.color_attachments)):  # the surface pass's images: normal, rel
        fbo.read(attachment=i, components=4, dtype="f4")
    error = ctx.error  # (checked after the reads too: a bad read would fail the next round)
    if error != "GL_NO_ERROR":
        raise RuntimeError(f"OpenGL error in the raw draw: {error}")
    total = time.perf_counter() - t0
    for obj in (vao, vbo, ibo):
        obj.release()
    return dict(seconds=total, cpu_s=time.process_time() - c0, read_s=read_s,
                upload_s=upload_s, triangles=faces.size // 3)


def scene_load(renderer, stack_dir: Path, size: int) -> dict:
    """What a user waits for: the scene read, uploaded and its first frame drawn."""
    from render.renderer import Lighting, RenderOptions
    from render.terrain_scene import TerrainScene

    c0 = time.process_time()
    t0 = time.perf_counter()
    scene = TerrainScene(stack_dir)
    read_s = time.perf_counter() - t0
    scene.upload(renderer.gpu)
    upload_s = time.perf_counter() - t0 - read_s
    view = first_view(scene, size)
    t1 = time.perf_counter()
    frame = renderer.render(scene, view, Lighting.from_angles(60.0, 7.0),
                            RenderOptions(shadows=False))
    now = time.perf_counter()
    out = dict(seconds=now - t0, cpu_s=time.process_time() - c0, read_s=read_s,
               upload_s=upload_s, first_frame_s=now - t1,
               triangles_drawn=frame.drawn["triangles"], triangles_full=scene.triangles_full)
    lighting = Lighting.from_angles(60.0, 7.0)
    for name in ("shadow_frame_s", "again_s"):
        c2 = time.process_time()
        t2 = time.perf_counter()
        renderer.render(scene, view, lighting, RenderOptions(shadow_size=SHADOW_SIZE))
        out[name] = time.perf_counter() - t2
        out[name.replace("_s", "_cpu_s")] = time.process_time() - c2
    out["with_shadows_s"] = out["seconds"] + out["shadow_frame_s"]
    del scene, frame
    gc.collect()  # the context's gc_mode "auto" releases the layers' buffers now
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small stack and image")
    parser.add_argument("--rounds", type=int, default=None, help="rounds of (scene, raw)")
    args = parser.parse_args(argv)
    from render.context import describe
    from render.renderer import Renderer
    from render.terrain_scene import TerrainScene

    quick = args.quick
    size = 256 if quick else 1024
    rounds = args.rounds or (2 if quick else 3)
    with tempfile.TemporaryDirectory() as tmp:
        log("building the demo's stack" + (" (quick: 257^2, 13 layers)" if quick else ""))
        t0 = time.perf_counter()
        stack_dir = build_stack(Path(tmp), quick)
        build_s = time.perf_counter() - t0
        renderer = Renderer()
        renderer.ctx.gc_mode = "auto"
        view = first_view(TerrainScene(stack_dir), size)
        results: dict = {"scene": [], "raw": []}
        for i in range(rounds):
            for name in order(["scene", "raw"], i):
                if name == "scene":
                    results[name].append(scene_load(renderer, stack_dir, size))
                else:  # round 1 runs the scene first: its triangle count sizes the mesh
                    drawn = results["scene"][0]["triangles_drawn"]
                    results[name].append(raw_load(renderer, stack_dir, view, size, drawn))
                log(f"round {i + 1}: {name} {results[name][-1]['seconds']:.2f} s")
        med = {name: summary([r["seconds"] for r in runs]) for name, runs in results.items()}
        cpu = {name: summary([r["cpu_s"] for r in runs]) for name, runs in results.items()}
        shadowed = {key: summary([r[key] for r in results["scene"]])
                    for key in ("with_shadows_s", "shadow_frame_s", "again_s")}
        out = dict(
            benchmark="load", quick=quick, image=[size, size], rounds=rounds,
            stack=dict(layers=len(json.loads((stack_dir / "manifest.json").read_text())
                                  ["layers"]), build_s=build_s),
            scene=dict(med["scene"], runs=results["scene"]),
            raw=dict(med["raw"], runs=results["raw"]),
            ratio_to_raw=med["scene"]["median_s"] / med["raw"]["median_s"],
            cpu=dict(scene=cpu["scene"], raw=cpu["raw"],
                     ratio_to_raw=cpu["scene"]["median_s"] / cpu["raw"]["median_s"]),
            with_shadows=dict(shadowed, ratio_to_raw=(shadowed["with_shadows_s"]["median_s"]
                                                      / med["raw"]["median_s"])),
            renderer=describe(), peak_rss_bytes=peak_rss_bytes(),
            targets=None if quick else dict(
                load_and_first_frame_ok=med["scene"]["median_s"] <= 2.0,
                with_shadows_ok=shadowed["with_shadows_s"]["median_s"] <= 2.0),
            machine=machine_facts())
    print(json.dumps(out, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
