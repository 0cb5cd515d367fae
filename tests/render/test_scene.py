"""Every scene class offers what the renderer and the frame loop ask of a scene; the one
shadow-map setup every scene draws its maps through."""

import inspect

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from render.asteroid_scene import AsteroidScene
from render.mesh_scene import MeshScene
from render.scene import Scene, light_basis
from render.terrain_scene import TerrainScene

#: Methods of the Scene protocol (its own members, not Protocol machinery).
METHODS = [name for name, value in vars(Scene).items()
           if inspect.isfunction(value) and not name.startswith("_")]


@pytest.mark.parametrize("cls", [TerrainScene, AsteroidScene, MeshScene])
def test_scene_classes_implement_the_protocol(cls):
    assert METHODS  # the protocol names what it needs
    for name in METHODS:
        want = inspect.signature(getattr(Scene, name))
        have = inspect.signature(getattr(cls, name))
        assert list(have.parameters) == list(want.parameters), (cls.__name__, name)
    assert cls.kind in ("terrain", "asteroid", "mesh")


def test_every_scene_has_a_reach_that_encloses_what_turns(tmp_path):
    """``reach`` (the Scene protocol's lever arm and keep-out sphere) encloses every vertex
    of a body about its centre; a terrain map does not turn and reaches nothing."""
    from asteroid.body import Body
    from asteroid.sphere import SphereMesh
    from terrain.core.tile import DEMTile
    from terrain.craters.catalog import CraterCatalog
    from terrain.stack.model import Layer, LayerStack

    mesh = SphereMesh(8)
    radii = 100.0 + 20.0 * mesh.directions()[:, 0] ** 2
    body = AsteroidScene(Body(mesh, 100.0, radii), boulders=False)
    assert body.reach == pytest.approx(radii.max())
    verts = mesh.directions() * radii[:, None]
    shape = MeshScene(verts, mesh.faces(), centre=(5.0, 0.0, 0.0))
    assert shape.reach >= np.linalg.norm(verts, axis=1).max() * (1 - 1e-12)
    lo, hi = shape.bounds()
    assert np.all(verts + shape.origin >= lo) and np.all(verts + shape.origin <= hi)
    tile = DEMTile.from_array(np.zeros((65, 65)), resolution=1.0)
    terrain = TerrainScene(LayerStack((Layer(tile, None, (0, 0)),),
                                      CraterCatalog.empty(layered=True), {}))
    assert terrain.reach == 0.0


class _FakeTarget:
    def __init__(self):
        self.released = False

    def release(self):
        self.released = True


class _RecordingGpu:
    """A Gpu handle without a GPU: records allocations and depth draws."""

    context = None
    token = 0

    def __init__(self):
        self.targets = []
        self.draws = []

    def buffer(self, data):
        raise AssertionError("the shadow-map setup uploads nothing")

    def texture(self, size, components, data, dtype):
        raise AssertionError("the shadow-map setup uploads nothing")

    def texture_cube(self, size, components, data, dtype):
        raise AssertionError("the shadow-map setup uploads nothing")

    def vertex_arrays(self, vbo, ibo, albedo=None, morph=None, scatter=None):
        raise AssertionError("the shadow-map setup binds no meshes")

    def shadow_target(self, size):
        pair = (_FakeTarget(), _FakeTarget())
        self.targets.append((size, pair))
        return pair

    def draw_depth(self, framebuffer, size, light_clip, batches):
        self.draws.append((framebuffer, size, light_clip, list(batches)))


def _light_coords(matrix, points):
    p = np.c_[points, np.ones(len(points))] @ matrix.T
    return p[:, :3] / p[:, 3:]


@settings(max_examples=40, deadline=None)
@given(sun=st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda s: np.linalg.norm(s) > 0.1),
       spread=st.floats(1.0, 5000.0), margin=st.floats(0.0, 10.0))
def test_one_shadow_map_setup_covers_receivers_and_holds_casters(sun, spread, margin):
    """The one setup terrain layers and bodies share: every receiver lands inside the map,
    no caster in front of its near plane, and the scene's draw callback is told the map's
    extent and light-space window, which contain the receivers."""
    from render.scene import BODY_SHADOW_BIAS, render_shadow_map

    rng = np.random.default_rng(7)
    receivers = rng.uniform(-spread, spread, (20, 3))
    casters = np.vstack([receivers, rng.uniform(-2 * spread, 2 * spread, (20, 3))])
    gpu = _RecordingGpu()
    seen = {}

    def draw(extent, window):
        seen.update(extent=extent, window=window)
        return ["batch"]

    m = render_shadow_map(gpu, None, 256, np.asarray(sun), receivers, casters, margin=margin,
                          bias=BODY_SHADOW_BIAS, draw=draw)
    tex = _light_coords(m.light_from_world, receivers)
    eps = 1e-9
    assert np.all((tex[:, :2] >= -eps) & (tex[:, :2] <= 1 + eps)), "receivers in the footprint"
    assert np.all((tex[:, 2] > 0) & (tex[:, 2] < 1)), "receivers inside the depth range"
    # no caster lies nearer the sun than the map's near plane: every occluder that can
    # shade a receiver is in the map (casters behind all receivers need not be)
    assert np.all(_light_coords(m.light_from_world, casters)[:, 2] > 0)
    assert len(gpu.draws) == 1 and gpu.draws[0][3] == ["batch"]
    assert gpu.draws[0][0] is m.framebuffer and gpu.draws[0][1] == (256, 256)
    assert seen["extent"] == pytest.approx(m.texel_m * 256)
    x0, y0, x1, y1 = seen["window"]
    light_xy = receivers @ light_basis(sun)[:2].T
    assert np.all((light_xy[:, 0] >= x0) & (light_xy[:, 0] <= x1)
                  & (light_xy[:, 1] >= y0) & (light_xy[:, 1] <= y1))
    assert x1 - x0 <= seen["extent"] + 1e-9 and y1 - y0 <= seen["extent"] + 1e-9


def test_a_shadow_map_is_drawn_again_in_place_until_its_size_changes():
    from render.scene import TERRAIN_SHADOW_BIAS, render_shadow_map

    gpu = _RecordingGpu()
    pts = np.array([[0.0, 0.0, 0.0], [10.0, 5.0, 1.0]])

    def make(current, size):
        return render_shadow_map(gpu, current, size, (0.3, 0.2, 0.9), pts, pts, margin=1.0,
                                 bias=TERRAIN_SHADOW_BIAS, draw=lambda extent, window: [])

    first = make(None, 128)
    again = make(first, 128)
    assert again is first and len(gpu.targets) == 1
    bigger = make(first, 256)
    assert bigger is not first and len(gpu.targets) == 2
    assert first.texture.released and first.framebuffer.released
    assert not bigger.texture.released
    # the lookup's biases grow with the texel: a map twice as fine has half the offsets
    assert bigger.normal_offset == pytest.approx(first.normal_offset / 2)
    assert bigger.bias == pytest.approx(first.bias / 2)


def test_the_gpu_handle_a_scene_gets_can_run_no_camera_pass():
    """Scenes reach the GPU only through the handle's few methods (uploads, vertex arrays,
    shadow maps): the renderer's handle offers exactly the Gpu protocol's, no render and no
    context."""
    from render.renderer import SceneGpu
    from render.scene import Gpu

    def public_methods(cls):
        return {n for n, v in vars(cls).items() if inspect.isfunction(v) and n[0] != "_"}

    assert public_methods(SceneGpu) == public_methods(Gpu)
    assert not {"render", "ctx"} & {n for n in vars(SceneGpu) if n[0] != "_"}
    for name in public_methods(Gpu):
        want = inspect.signature(getattr(Gpu, name))
        assert list(inspect.signature(getattr(SceneGpu, name)).parameters) == list(
            want.parameters)
