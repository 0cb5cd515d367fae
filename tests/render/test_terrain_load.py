"""Loading a terrain scene: what reaches the GPU, and the frame drawn from it, never change.

The golden hashes below were computed with the loader that built every layer's geomorphing
targets vertex by vertex and its index buffers block by block (before they were vectorised
and shared between layers of one shape). The loader is an optimisation target; its output is
not, so the buffers it uploads and a frame drawn from them must stay the same bytes. The stack
is built here from closed-form heights (no crater or fractal code, whose own changes must not
move these hashes), with sides that are not 2^k + 1 so that the irregular last cells of the
levels of detail are covered, an invalid pixel (filled from its neighbour), and a finer layer
that fades into its parent.

The frame hash also depends on the shaders and on Mesa's llvmpipe: after a deliberate change
of either, recompute it with the loader of the commit before and the shaders of the new one.
"""

from __future__ import annotations

import hashlib

import numpy as np
from affine import Affine

#: sha256 of every layer's uploaded buffers, with the loader before vectorisation.
GOLDEN_BUFFERS = "f55e2f2dc651e7eccaf2297bb6bfa37a94397362414b37621060f2eca3d48b9b"
#: sha256 of the image, range and normals of one frame. First computed with the loader before
#: vectorisation; recomputed once when the shading changed on purpose (the extended sun's
#: penumbrae and light scattered into shadows), the buffers' hash above unchanged by it; and
#: again when the soft shadows' blocker search and filter changed (gathered search, 16-tap
#: spiral filter skipped where the search decides), computed with the eager loader of 420ce8e.
GOLDEN_FRAME = "21685326783c69179f449c86f859e09c51705cf6df344f463290b586ecfc9b70"


def _stack():
    """Three layers of 150, 90 and 70 px (10, 5, 2.5 m) of closed-form heights."""
    from terrain.core.tile import DEMTile
    from terrain.craters.catalog import CraterCatalog
    from terrain.stack.model import Layer, LayerStack

    def tile(n, res, x0, y0, *, hole=False):
        x = x0 + (np.arange(n) + 0.5) * res
        y = y0 - (np.arange(n) + 0.5) * res
        h = (40.0 * np.sin(x[None, :] / 97.0) * np.cos(y[:, None] / 61.0)
             + 0.002 * (x[None, :] - 700.0) ** 2 / 10.0
             + 3.0 * np.sin(x[None, :] * y[:, None] / 5e3))
        h = h.astype(np.float32)
        valid = np.ones(h.shape, bool)
        if hole:
            valid[17, 23] = False
            h[17, 23] = np.nan
        return DEMTile(h, valid, Affine(res, 0.0, x0, 0.0, -res, y0), None, float("nan"), {})

    base = tile(150, 10.0, 0.0, 1500.0, hole=True)
    mid = tile(90, 5.0, 525.0, 975.0)
    fine = tile(70, 2.5, 662.5, 837.5)
    catalog = CraterCatalog.empty(optional=("layer",))
    layers = (Layer(base, None, (0, 0)), Layer(mid, (52, 52, 45, 45), (104, 104)),
              Layer(fine, (27, 27, 35, 35), (262, 262)))
    return LayerStack(layers, catalog, {"site": [750.0, 750.0]})


def _buffers_hash(scene) -> str:
    digest = hashlib.sha256()
    for layer in scene._layers:
        digest.update(layer.vbo.read())
        digest.update(layer.morph_vbo.read())
        for s in sorted(layer.ibos):
            digest.update(layer.ibos[s].read())
            digest.update(np.asarray(layer.offsets[s], np.int64).tobytes())
            digest.update(np.asarray(layer.counts[s], np.int64).tobytes())
        digest.update(np.ascontiguousarray(layer.lo, np.float64).tobytes())
        digest.update(np.ascontiguousarray(layer.hi, np.float64).tobytes())
        digest.update(np.asarray(layer.covered, bool).tobytes())
    return digest.hexdigest()


def _frame(renderer, scene):
    from render.camera import Intrinsics, look_at
    from render.renderer import Lighting, RenderOptions, View

    pose = look_at((600.0, 400.0, 420.0), (760.0, 760.0, 0.0))
    k = Intrinsics.from_fov(96, 64, 55.0)
    return renderer.render(scene, View(pose, k), Lighting.from_angles(120.0, 20.0),
                           RenderOptions(shadows=True, shadow_size=256, lod_pixels=6.0))


def test_uploaded_buffers_are_the_golden_bytes(renderer):
    from render.terrain_scene import TerrainScene

    scene = TerrainScene(_stack())
    scene.upload(renderer.gpu, eager=True)
    assert _buffers_hash(scene) == GOLDEN_BUFFERS


def test_a_frame_is_the_golden_bytes(renderer):
    from render.terrain_scene import TerrainScene

    scene = TerrainScene(_stack())
    frame = _frame(renderer, scene)
    levels = {s for d in frame.drawn["layers"] for s in d["lod"]}
    assert len(levels) > 1, "the frame should draw several levels of detail (morphing)"
    digest = hashlib.sha256()
    for a in (frame.radiance, frame.range, frame.normals):
        digest.update(np.ascontiguousarray(a).tobytes())
    assert digest.hexdigest() == GOLDEN_FRAME


def test_shadow_maps_skip_the_discard_test_only_where_it_would_discard_nothing(
        renderer, monkeypatch):
    """Coarser blocks clear of the finer layer are drawn without the discard test: same bytes.

    The shadow pass draws a coarser layer's blocks that keep a pixel clear of the finer
    layer's extent with a depth program that has no fragment shader, and only the others
    with the discard test. A frame drawn so must equal, byte for byte, one whose shadow maps
    sent every coarser block through the discard test (as every block went before).
    """
    import render.terrain_scene as terrain_scene
    from render.renderer import SceneGpu
    from render.terrain_scene import TerrainScene

    seen, maps = [], []
    draw_depth = SceneGpu.draw_depth

    def recording(self, framebuffer, size, light_clip, batches):
        maps.append(size)
        seen.extend(batch.discard is not None for batch in batches)
        return draw_depth(self, framebuffer, size, light_clip, batches)

    monkeypatch.setattr(SceneGpu, "draw_depth", recording)
    split = _frame(renderer, TerrainScene(_stack()))
    # the maps had both kinds of batch, and more plain ones than one per map (the layer's
    # own, which never discards)
    assert any(seen) and seen.count(False) > len(maps)
    monkeypatch.setattr(terrain_scene, "_near_rectangle",
                        lambda lo, hi, rect, margin: np.ones(lo.shape[0], bool))
    every = _frame(renderer, TerrainScene(_stack()))
    for a, b in ((split.radiance, every.radiance), (split.range, every.range),
                 (split.normals, every.normals)):
        assert np.array_equal(a, b, equal_nan=True)


def test_a_layer_first_seen_coarse_gets_sparse_buffers_and_draws_the_same_frames(renderer):
    """Buffers of only the vertices a coarse level draws: the frames of the full buffers.

    A scene loaded lazily and seen from afar gives its finer layers buffers of every s-th
    vertex line (their first frame's finest level s); coming closer, a finer level replaces
    them with the full buffers, once. Every frame of the approach, with and without shadows,
    is byte for byte the frame of a scene uploaded whole.
    """
    from render.camera import Intrinsics, look_at
    from render.renderer import Lighting, RenderOptions, View
    from render.terrain_scene import TerrainScene
    from terrain.core.tile import DEMTile
    from terrain.craters.catalog import CraterCatalog
    from terrain.stack.model import Layer, LayerStack

    def tile(n, res, x0, y0):
        x = x0 + (np.arange(n) + 0.5) * res
        y = y0 - (np.arange(n) + 0.5) * res
        h = (30.0 * np.sin(x[None, :] / 53.0) * np.cos(y[:, None] / 37.0)
             + 2.0 * np.sin(x[None, :] * y[:, None] / 3e3)).astype(np.float32)
        return DEMTile(h, np.ones(h.shape, bool), Affine(res, 0.0, x0, 0.0, -res, y0), None,
                       float("nan"), {})

    # 129 px layers (2^7 + 1: every level's lines fall on the blocks' boundaries)
    layers = (Layer(tile(129, 8.0, 0.0, 1032.0), None, (0, 0)),
              Layer(tile(129, 2.0, 387.0, 645.0), (48, 48, 33, 33), (384, 384)),
              Layer(tile(129, 0.5, 483.75, 548.25), (48, 48, 33, 33), (1536, 1536)))
    stack = LayerStack(layers, CraterCatalog.empty(optional=("layer",)), {"site": [516.0, 516.0]})
    k = Intrinsics.from_fov(64, 48, 50.0)
    light = Lighting.from_angles(120.0, 20.0)
    poses = [look_at((516.0 + 0.3 * d, 516.0 - 0.4 * d, d), (516.0, 516.0, 0.0))
             for d in (3000.0, 800.0, 150.0, 25.0)]
    for shadows in (False, True):
        lazy, whole = TerrainScene(stack), TerrainScene(stack)
        whole.upload(renderer.gpu, eager=True)
        steps = []
        for pose in poses:
            options = RenderOptions(shadows=shadows, shadow_size=256, lod_pixels=6.0)
            a = renderer.render(lazy, View(pose, k), light, options)
            b = renderer.render(whole, View(pose, k), light, options)
            steps.append([layer.step for layer in lazy._layers])
            for x, y in ((a.radiance, b.radiance), (a.range, b.range), (a.normals, b.normals)):
                assert np.array_equal(x, y, equal_nan=True)
        if not shadows:
            assert max(steps[0]) > 1, steps  # the far view drew the fine layers sparse
        assert steps[-1] == [1, 1, 1], steps  # and close by, every vertex
