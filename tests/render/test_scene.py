"""Every scene class offers what the renderer and the frame loop ask of a scene."""

import inspect

import pytest

from render.asteroid_scene import AsteroidScene
from render.mesh_scene import MeshScene
from render.scene import Scene
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
