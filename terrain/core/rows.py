"""Unique rows of an integer array, by one integer key per row.

``np.unique(a, axis=0)`` views each row as one structured element and sorts those, an order
of magnitude slower than sorting integers (0.6-0.9 s against 0.05 s for the 393,218 grid
cells of the demo body's vertices). An integer row is its own mixed-radix number: with each
column offset by its least value and ``m_j`` its span, ``(a_0 m_1 + a_1) m_2 + a_2 ...`` is
one int64 whose order is the rows' lexicographic order, the order ``np.unique`` gives them.
So :func:`unique_rows` returns what ``np.unique(a, axis=0, ...)`` returns, the same arrays,
wherever the keys fit in an int64 (and falls back to it where they do not).

>>> import numpy as np
>>> a = np.array([[2, 1], [0, 5], [2, 1], [-1, 7]])
>>> rows, first, inverse = unique_rows(a, return_index=True, return_inverse=True)
>>> rows.tolist(), first.tolist(), inverse.tolist()
([[-1, 7], [0, 5], [2, 1]], [3, 1, 0], [2, 1, 2, 0])
"""

from __future__ import annotations

import numpy as np

from terrain.core.errors import InvalidParameterError

__all__ = ["unique_rows"]

_INT64_MAX = int(np.iinfo(np.int64).max)


def _row_keys(a: np.ndarray) -> np.ndarray | None:
    """(n,) int64 keys in the rows' lexicographic order, or None where they would overflow."""
    lo = a.min(axis=0).astype(np.int64)
    spans = [int(s) + 1 for s in (a.max(axis=0).astype(np.int64) - lo)]
    total = 1
    for s in spans:
        total *= s
    if total > _INT64_MAX:
        return None
    shifted = a.astype(np.int64) - lo
    keys = shifted[:, 0].copy()
    for j in range(1, a.shape[1]):
        keys *= spans[j]
        keys += shifted[:, j]
    return keys


def unique_rows(a, *, return_index: bool = False, return_inverse: bool = False):
    """``np.unique(a, axis=0, ...)`` for a 2-D integer array, sorted as integers.

    Parameters
    ----------
    a : (n, k) integer array
    return_index : bool
        Also return the index of each unique row's first occurrence.
    return_inverse : bool
        Also return, for each row of ``a``, the index of its unique row ((n,) int64).

    Returns
    -------
    rows : (u, k) array of ``a``'s dtype
        The unique rows in lexicographic order.
    index, inverse : (u,) and (n,) int64, where asked for
    """
    a = np.asarray(a)
    if a.ndim != 2 or not np.issubdtype(a.dtype, np.integer):
        raise InvalidParameterError(f"unique rows need an (n, k) integer array; got "
                                    f"{a.shape} {a.dtype}")
    keys = _row_keys(a) if a.size else None
    if keys is None:  # no rows, or keys past int64: numpy's own (slower) way
        rows, first, inverse = np.unique(a, axis=0, return_index=True, return_inverse=True)
        keys_out = [rows]
        if return_index:
            keys_out.append(first)
        if return_inverse:
            keys_out.append(inverse.reshape(-1))
        return keys_out[0] if len(keys_out) == 1 else tuple(keys_out)
    # np.unique sorts stably, so its index is each row's first occurrence; so is this one
    _, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
    out = [a[first]]
    if return_index:
        out.append(first)
    if return_inverse:
        out.append(inverse.reshape(-1))
    return out[0] if len(out) == 1 else tuple(out)
