"""Craters added below a DEM's resolution meet the parent layer at the layer's ends.

A layer of a stack is a window of its parent; where it ends, the parent's own heights take
over. The part of a crater's change that the known lattice samples is taken out so the known
heights stay; between the last lattice line and the layer's end that part must fall to zero,
or the layer's whole margin is raised or lowered against its parent (a straight step along
the layer's outline in every image).
"""

import numpy as np

from terrain.craters.unresolved import keep_lattice


def _bowl(shape, centre, radius, depth):
    r, c = np.mgrid[0:shape[0], 0:shape[1]]
    d2 = (r - centre[0]) ** 2 + (c - centre[1]) ** 2
    return np.where(d2 < radius ** 2, -depth * (1.0 - d2 / radius ** 2), 0.0)


def test_a_layer_without_known_pixels_gets_its_craters_whole():
    # 65 x 65 pixels at global origin 1000; the lattice (step 4096) has no line inside it.
    before = np.random.default_rng(1).normal(0.0, 0.01, (65, 65))
    for corner in ((0, 0), (64, 64), (0, 64)):
        d = _bowl(before.shape, corner, 20, 0.3)  # a crater over one of the layer's corners
        out = keep_lattice(before, before + d, step=4096, origin=(1000, 1000),
                           layer_rows=(1000, 1064), layer_cols=(1000, 1064))
        np.testing.assert_allclose(out - before, d, atol=1e-12)


def test_the_taken_part_falls_to_zero_at_the_layer_ends_and_keeps_the_lattice():
    # one lattice line each way (global 1024), a crater over the lattice point
    before = np.random.default_rng(2).normal(0.0, 0.01, (65, 65))
    d = _bowl(before.shape, (24, 24), 12, 0.3)
    out = keep_lattice(before, before + d, step=1024, origin=(1000, 1000),
                       layer_rows=(1000, 1064), layer_cols=(1000, 1064))
    assert out[24, 24] == before[24, 24]  # the known pixel, bitwise
    # the layer's four ends: the crater does not reach them, so neither does any change
    for edge in (out[0] - before[0], out[-1] - before[-1], out[:, 0] - before[:, 0],
                 out[:, -1] - before[:, -1]):
        np.testing.assert_allclose(edge, 0.0, atol=1e-12)
