"""Render: images, range and normals with exact ground truth (the third stage).

Headless OpenGL (:mod:`render.context`, the one module that creates contexts), cameras,
trajectories and motion (:mod:`render.camera`, :mod:`render.trajectory`,
:mod:`render.motion`), photometry (:mod:`render.reflectance`), the detector chain
(:mod:`render.sensor`), scenes of DEM stacks and asteroid models (:mod:`render.scene`,
:mod:`render.terrain_scene`, :mod:`render.asteroid_scene`, :mod:`render.mesh_scene`), the
renderer and its imposters (:mod:`render.renderer`, :mod:`render.imposter`), scenarios and
sequences (:mod:`render.scenario`, :mod:`render.sequence`) and run folders
(:mod:`render.rundir`).
"""
