"""Terrain: lunar-like DEM tiles, craters, rocks, expansion and gap filling (the first stage).

The value type (:mod:`terrain.core.tile`) and its one reader and writer (:mod:`terrain.io`), keyed
randomness (:mod:`terrain.core.rng`), synthetic bases (:mod:`terrain.fractal.synthetic`,
:mod:`terrain.fractal.rmd`), craters (:mod:`terrain.craters.crater`,
:mod:`terrain.craters.population`,
:mod:`terrain.craters.erosion`, :mod:`terrain.craters.cratering`, :mod:`terrain.craters.catalog`),
rocks and hazards
(:mod:`terrain.surface.rocks`, :mod:`terrain.surface.hazards`), fractal expansion and gap filling
(:mod:`terrain.fractal.expand`, :mod:`terrain.fractal.roughness`, :mod:`terrain.fractal.gapfill`),
layer stacks
(:mod:`terrain.stack.model`), chunked runs (:mod:`terrain.execution.chunked`,
:mod:`terrain.core.zarrstore`) and
safe outputs (:mod:`terrain.core.outputs`). The ``craterscape`` root command lives in
:mod:`terrain.cli.commands`; higher layers register their groups through entry points.
"""
