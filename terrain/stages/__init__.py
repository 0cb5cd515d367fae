"""Terrain stages as records plus one runner.

``Spec.from_mapping(table)`` (:mod:`terrain.stages.specs`) -> ``run(spec, inputs, output,
execution)`` (:mod:`terrain.stages.runner`); the command line is options -> spec -> run.
"""
