"""Zarr DEM stores: what a window read returns, through the decoded-chunk cache and without it."""

import numpy as np
from affine import Affine
from hypothesis import given, settings
from hypothesis import strategies as st

from terrain.core import zarrstore
from terrain.core.tile import Window
from terrain.core.zarrstore import ZarrDEM

SHAPE, CHUNK = (45, 37), 16


def _store(path, heights, complete=True):
    store = ZarrDEM.create(path, heights.shape, CHUNK, transform=Affine(1, 0, 0, 0, -1, 0),
                           crs=None, nodata=float("nan"), metadata={}, plan={})
    ny, nx = store.grid
    for i in range(ny):
        for j in range(nx):
            w = store.chunk_window(i, j)
            store.write_chunk(i, j, heights[w.row:w.row + w.height, w.col:w.col + w.width])
    if complete:
        store.mark_complete()
    return ZarrDEM(path)


def _heights(seed):
    h = np.random.default_rng(seed).normal(size=SHAPE).astype(np.float32)
    h[3:20, 30:] = np.nan  # chunk (0, 2) is all nodata
    return h


@settings(max_examples=25, deadline=None)
@given(row=st.integers(0, SHAPE[0] - 1), col=st.integers(0, SHAPE[1] - 1),
       height=st.integers(1, SHAPE[0]), width=st.integers(1, SHAPE[1]))
def test_a_window_of_a_complete_store_is_the_window_of_what_was_written(tmp_path_factory, row,
                                                                        col, height, width):
    height, width = min(height, SHAPE[0] - row), min(width, SHAPE[1] - col)
    h = _heights(1)
    path = tmp_path_factory.mktemp("s") / "s.zarr"
    window = Window(col, row, width, height)
    got, valid = _store(path, h).read(window)
    want = h[row:row + height, col:col + width]
    assert got.dtype == np.float32 and got.tobytes() == want.tobytes()
    assert np.array_equal(valid, np.isfinite(want))
    direct, _ = _store(path.with_name("t.zarr"), h, complete=False).read(window)  # no cache
    assert direct.tobytes() == got.tobytes()


def test_a_store_written_again_at_the_same_path_is_read_anew(tmp_path):
    """The cache is keyed by each chunk's CRC-32 and its file's inode, size and time."""
    import shutil

    path = tmp_path / "s.zarr"
    # constant chunks compress to files of one size, and the new files may reuse the
    # inodes of the removed ones within the file system's clock tick
    for heights in (_heights(1), _heights(2), np.zeros(SHAPE, np.float32),
                    np.ones(SHAPE, np.float32), np.zeros(SHAPE, np.float32)):
        shutil.rmtree(path, ignore_errors=True)
        assert _store(path, heights).read()[0].tobytes() == heights.tobytes()
        assert zarrstore._DECODED  # the chunks were kept


def test_the_cache_holds_at_most_its_budget(tmp_path, monkeypatch):
    monkeypatch.setattr(zarrstore, "DECODED_CACHE_BYTES", 3 * CHUNK * CHUNK * 4)
    zarrstore._DECODED.clear()
    h = _heights(3)
    store = _store(tmp_path / "s.zarr", h)
    assert store.read()[0].tobytes() == h.tobytes()
    assert sum(b.nbytes for b in zarrstore._DECODED.values()) <= 3 * CHUNK * CHUNK * 4
