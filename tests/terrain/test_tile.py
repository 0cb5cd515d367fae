"""The DEM tile value type validates at its door and keeps NaN out of sight."""

import numpy as np
import pytest
from affine import Affine

from terrain.core.errors import InvalidDEMError, InvalidParameterError
from terrain.core.tile import DEMTile, Window


def test_nan_heights_become_invalid_and_tiles_are_immutable():
    h = np.array([[1.0, np.nan], [np.inf, 4.0]])
    t = DEMTile.from_array(h, resolution=2.0)
    assert t.valid.tolist() == [[True, False], [False, True]]
    assert np.isnan(t.heights[~t.valid]).all()
    assert t.heights.dtype == np.float32
    with pytest.raises(ValueError):
        t.heights[0, 0] = 3.0


def test_invalid_mask_wins_over_values():
    t = DEMTile.from_array(np.ones((2, 2)), valid=np.array([[True, False], [True, True]]))
    assert np.isnan(t.heights[0, 1])


def test_geometry_and_windows():
    t = DEMTile.from_array(np.arange(12.0).reshape(3, 4), resolution=0.5)
    assert t.bounds == (0.0, 0.0, 2.0, 1.5)
    x, y = t.xy(0, 0)
    assert (x, y) == (0.25, 1.25)
    r, c = t.rowcol(x, y)
    assert (r, c) == (0.0, 0.0)
    w = t.window(Window(1, 1, 2, 2))
    assert w.heights.tolist() == [[5.0, 6.0], [9.0, 10.0]]
    assert w.xy(0, 0) == t.xy(1, 1)


@pytest.mark.parametrize("kwargs, message", [
    (dict(heights=np.zeros(3)), "2-D"),
    (dict(heights=np.zeros((0, 3))), "2-D|non-empty"),
    (dict(heights=np.zeros((2, 2)), valid=np.ones((3, 3), bool)), "valid mask"),
    (dict(heights=np.zeros((2, 2)), transform=Affine(1, 0.2, 0, 0, -1, 0)), "north-up"),
    (dict(heights=np.zeros((2, 2)), transform=Affine(1, 0, 0, 0, 1, 0)), "negative y"),
    (dict(heights=np.zeros((2, 2)), transform=Affine(1, 0, 0, 0, -2, 0)), "square"),
    (dict(heights=np.array([["a"]])), "real numbers|2-D"),
])
def test_bad_tiles_are_refused(kwargs, message):
    with pytest.raises(InvalidDEMError, match=message):
        DEMTile.from_array(**kwargs)


@pytest.mark.parametrize("text", ["1,2,3", "a,b,c,d", "0,0,0,5", "0,0,-1,5", ""])
def test_bad_windows_are_refused(text):
    with pytest.raises(InvalidParameterError, match="window"):
        Window.parse(text)


def test_window_must_fit():
    with pytest.raises(InvalidParameterError, match="does not fit"):
        Window(3, 0, 2, 2).check_inside(4, 4)
