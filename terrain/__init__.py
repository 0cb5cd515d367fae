"""Terrain: lunar-like DEM tiles, craters, rocks, expansion and gap filling (the first stage).

The value type (:mod:`terrain.tile`) and its one reader and writer (:mod:`terrain.io`), keyed
randomness (:mod:`terrain.rng`), synthetic bases (:mod:`terrain.synthetic`,
:mod:`terrain.rmd`), craters (:mod:`terrain.crater`, :mod:`terrain.population`,
:mod:`terrain.erosion`, :mod:`terrain.cratering`, :mod:`terrain.catalog`), rocks and hazards
(:mod:`terrain.rocks`, :mod:`terrain.hazards`), fractal expansion and gap filling
(:mod:`terrain.expand`, :mod:`terrain.roughness`, :mod:`terrain.gapfill`), layer stacks
(:mod:`terrain.layers`), chunked runs (:mod:`terrain.chunked`, :mod:`terrain.zarrstore`) and
safe outputs (:mod:`terrain.outputs`). The ``craterscape`` root command lives in
:mod:`terrain.cli`; higher layers register their groups through entry points.
"""
