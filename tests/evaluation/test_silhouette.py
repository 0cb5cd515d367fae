"""Occluding contours of range images against a pixel-by-pixel reference."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from evaluation.silhouette import SILHOUETTE_JUMP, contour_pixels, dilate, near_contours


def _reference(rng: np.ndarray, jump: float) -> np.ndarray:
    """Each pixel looked at on its own: no return, or a 4-neighbour too far in range."""
    h, w = rng.shape
    out = np.zeros((h, w), bool)
    for i in range(h):
        for j in range(w):
            if not np.isfinite(rng[i, j]):
                out[i, j] = True
                continue
            for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1)):
                a, b = i + di, j + dj
                if 0 <= a < h and 0 <= b < w and np.isfinite(rng[a, b]):
                    if abs(rng[i, j] - rng[a, b]) > jump * min(rng[i, j], rng[a, b]):
                        out[i, j] = True
    return out


ranges = arrays(np.float64, st.tuples(st.integers(1, 7), st.integers(1, 7)),
                elements=st.one_of(st.floats(1.0, 30.0), st.just(np.nan)))


@settings(max_examples=60, deadline=None)
@given(ranges, st.sampled_from([SILHOUETTE_JUMP, 0.2]))
def test_contours_match_the_pixel_by_pixel_reference(rng, jump):
    assert np.array_equal(contour_pixels(rng, jump), _reference(rng, jump))


@settings(max_examples=40, deadline=None)
@given(ranges, st.integers(0, 3))
def test_near_means_within_px_in_both_axes(rng, px):
    edge = contour_pixels(rng)
    near = near_contours(rng, px)
    rows, cols = np.nonzero(edge)
    for i in range(rng.shape[0]):
        for j in range(rng.shape[1]):
            close = np.any((np.abs(rows - i) <= px) & (np.abs(cols - j) <= px))
            assert near[i, j] == close


def test_a_smooth_surface_has_no_contour():
    rng = np.linspace(100.0, 104.0, 64).reshape(8, 8)   # 0.06 m steps on 100 m: smooth
    assert not contour_pixels(rng).any()
    mask = np.zeros((5, 5), bool)
    assert dilate(mask, 0) is mask
