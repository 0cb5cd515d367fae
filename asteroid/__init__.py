"""Asteroid models on the 6M^2 + 2 latitude/longitude mesh (Martin et al. 2014, sections III-V).

The mesh (:mod:`asteroid.sphere`, :mod:`asteroid.patches`), the value type and native file
(:mod:`asteroid.body`), the bases (:mod:`asteroid.noise`, :mod:`asteroid.faulting`,
:mod:`asteroid.shape`), craters (:mod:`asteroid.craters`) and boulders
(:mod:`asteroid.boulders`), mesh files (:mod:`asteroid.meshio`) and the build pipeline
(:mod:`asteroid.recipe`, :mod:`asteroid.build`, :mod:`asteroid.cli`).
"""

from asteroid.body import Body, Stretch, load_native, save_native
from asteroid.boulders import Boulders, BoulderSettings, place_boulders
from asteroid.build import BuildResult, build
from asteroid.craters import CraterSettings, SlopeErosion, add_craters, craters_at
from asteroid.faulting import Faulting
from asteroid.noise import Band, PerlinNoise
from asteroid.patches import PatchTree
from asteroid.recipe import PRESETS, Recipe
from asteroid.shape import ShapeModel
from asteroid.sphere import SphereMesh

__all__ = [
    "PRESETS",
    "Band",
    "Body",
    "BoulderSettings",
    "Boulders",
    "BuildResult",
    "CraterSettings",
    "Faulting",
    "PatchTree",
    "PerlinNoise",
    "Recipe",
    "ShapeModel",
    "SlopeErosion",
    "SphereMesh",
    "Stretch",
    "add_craters",
    "build",
    "craters_at",
    "load_native",
    "place_boulders",
    "save_native",
]
