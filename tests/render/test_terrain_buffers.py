"""The compiled layer buffers: a plane's normals, the skirts, the same bytes on any threads."""

from __future__ import annotations

import numpy as np

from render.terrain_buffers import block_indices, half_floats, layer_buffers
from render.terrain_scene import BLOCK, _cell_tables, _samples
from terrain.core.parallel import limited


def _plane(h=70, w=131, res=2.0):
    xs = np.arange(w) * res - 50.0
    ys = 40.0 - np.arange(h) * res
    z = 0.3 * xs[None, :] - 0.2 * ys[:, None] + 7.0  # dz/dx = 0.3, dz/dy = -0.2
    return z, xs, ys, res


def _build(z, xs, ys, res):
    h, w = z.shape
    return layer_buffers(z, xs, ys, res, _samples(0, h - 1, BLOCK), _samples(0, w - 1, BLOCK),
                         8.0 * res, _cell_tables(h, w), vertices=True, morph=True)


def test_a_planes_normals_are_its_analytic_normal_and_its_morph_targets_lie_on_it():
    z, xs, ys, res = _plane()
    n, vert, morph = _build(z, xs, ys, res)
    expect = np.array([-0.3, 0.2, 1.0]) / np.sqrt(0.3 ** 2 + 0.2 ** 2 + 1.0)
    np.testing.assert_allclose(n, np.broadcast_to(expect, n.shape), atol=1e-12)
    h, w = z.shape
    main = morph[:h * w].reshape(h, w, 7)
    # a plane is its own coarser triangulation: every target is the vertex's own height
    np.testing.assert_allclose(main[..., 2], z.astype(np.float32), rtol=1e-6, atol=1e-5)
    np.testing.assert_allclose(vert[:h * w].reshape(h, w, 6)[..., 3:], n.astype(np.float32))


def test_skirts_hang_their_depth_below_the_block_edges():
    z, xs, ys, res = _plane()
    h, w = z.shape
    _, vert, _ = _build(z, xs, ys, res)
    brows, bcols = _samples(0, h - 1, BLOCK), _samples(0, w - 1, BLOCK)
    rows = vert[h * w:h * w + len(brows) * w].reshape(len(brows), w, 6)
    cols = vert[h * w + len(brows) * w:].reshape(len(bcols), h, 6)
    np.testing.assert_allclose(rows[..., 2], (z[brows] - 8.0 * res).astype(np.float32))
    np.testing.assert_allclose(cols[..., 2], (z[:, bcols].T - 8.0 * res).astype(np.float32))


def test_one_thread_and_many_give_the_same_bytes():
    rng = np.random.default_rng(7)
    z = rng.normal(size=(150, 97)).cumsum(axis=0)
    xs, ys = np.arange(97) * 1.5, -np.arange(150) * 1.5
    many = _build(z, xs, ys, 1.5) + block_indices(150, 97, 2, _samples(0, 149, BLOCK),
                                                  _samples(0, 96, BLOCK))
    with limited(1):
        one = _build(z, xs, ys, 1.5) + block_indices(150, 97, 2, _samples(0, 149, BLOCK),
                                                     _samples(0, 96, BLOCK))
    for a, b in zip(many, one, strict=True):
        assert a.tobytes() == b.tobytes()


def test_every_index_names_a_vertex_and_every_block_is_its_cells_and_skirts():
    h, w, s = 150, 97, 4
    brows, bcols = _samples(0, h - 1, BLOCK), _samples(0, w - 1, BLOCK)
    idx, offsets, counts = block_indices(h, w, s, brows, bcols)
    n_vertices = h * w + len(brows) * w + len(bcols) * h
    assert idx.dtype == np.uint32 and int(idx.max()) < n_vertices
    assert offsets[0] == 0 and np.array_equal(offsets[1:], np.cumsum(counts)[:-1])
    assert int(counts.sum()) == idx.size and idx.size % 3 == 0


def test_half_floats_round_as_numpy_does_ties_subnormals_and_overflow_included():
    rng = np.random.default_rng(11)
    # halves and the doubles exactly between neighbouring halves (ties go to even), a hair
    # either side of the ties, subnormal and underflowing magnitudes, overflow, inf and NaN
    halves = rng.integers(0, 0x7BFF, 20_000).astype(np.uint16).view(np.float16)
    up = np.nextafter(halves, np.float16(np.inf)).astype(np.float64)
    ties = (halves.astype(np.float64) + up) / 2
    values = np.concatenate([
        rng.normal(size=20_000), rng.uniform(-1, 1, 20_000), ties, -ties,
        np.nextafter(ties, 0.0), np.nextafter(ties, 1e9), rng.normal(size=5_000) * 1e-5,
        rng.normal(size=5_000) * 1e-8, rng.normal(size=5_000) * 1e5,
        [0.0, -0.0, 65504.0, 65519.99, 65520.0, 1e300, np.inf, -np.inf, np.nan, 2.0 ** -25,
         2.0 ** -24, 3 * 2.0 ** -26, 2.0 ** -14, 2.0 ** -14 * (1 - 2.0 ** -11)]])
    with np.errstate(all="ignore"):
        expect = values.astype(np.float16)
    got = half_floats(values.reshape(-1, 1, 1))
    assert got.shape == (values.size, 1, 1) and got.dtype == np.float16
    assert got.reshape(-1).view(np.uint16).tobytes() == expect.view(np.uint16).tobytes()
    z = rng.normal(size=(150, 97)).cumsum(axis=0)
    n = _build(z, np.arange(97) * 1.5, -np.arange(150) * 1.5, 1.5)[0]
    assert half_floats(n).tobytes() == n.astype(np.float16).tobytes()
