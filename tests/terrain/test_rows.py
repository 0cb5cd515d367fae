"""terrain.core.rows: unique rows by integer keys, against numpy's own unique(axis=0)."""

import numpy as np
import pytest

from terrain.core.errors import InvalidParameterError
from terrain.core.rows import unique_rows


@pytest.mark.parametrize("shape, low, high", [((5000, 3), -40, 40), ((3000, 2), 0, 7),
                                              ((1, 4), -3, 3), ((2000, 3), 0, 2**40)])
def test_unique_rows_are_numpys_unique_along_axis_0(shape, low, high):
    # the last case's keys overflow int64: the fallback must give the same answer too
    a = np.random.default_rng(7).integers(low, high, size=shape)
    a[len(a) // 2:] = a[:len(a) - len(a) // 2]  # plenty of repeats
    rows, first, inverse = unique_rows(a, return_index=True, return_inverse=True)
    ref_rows, ref_first, ref_inverse = np.unique(a, axis=0, return_index=True,
                                                 return_inverse=True)
    assert rows.tolist() == ref_rows.tolist()
    assert first.tolist() == ref_first.tolist()
    assert inverse.tolist() == ref_inverse.reshape(-1).tolist()
    assert np.array_equal(unique_rows(a), ref_rows)


def test_unique_rows_of_no_rows_and_refusals():
    rows, inverse = unique_rows(np.zeros((0, 3), np.int64), return_inverse=True)
    assert rows.shape == (0, 3) and inverse.size == 0
    with pytest.raises(InvalidParameterError, match="integer"):
        unique_rows(np.zeros((4, 3)))
