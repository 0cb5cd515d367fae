"""Gaskell's implicitly connected quadrilateral (ICQ) shape models as triangle meshes.

An ICQ file (the PDS format of Gaskell's Eros, Itokawa and other shape models) holds the
resolution Q on its first line, then six blocks of (Q + 1)^2 vertices ``x y z`` (one cube face
each, rows of Q + 1), the cube's edges repeated in the blocks that share them. Each block's
quadrilaterals ``(i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1)`` split into two triangles;
repeated vertices are merged by their exact coordinates, and each block is wound outwards
(the sign of its share of the enclosed volume), so the result is one closed surface.
ICQ models are star-shaped by construction; they take the latitude/longitude path.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from asteroid.errors import InvalidShapeError

__all__ = ["read_icq"]


def read_icq(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (n, 3) float64 (the file's units) and triangles (m, 3) int64 of an ICQ file."""
    path = Path(path)
    try:
        with open(path, encoding="ascii") as fh:
            q = int(fh.readline().split()[0])
            data = np.loadtxt(fh, dtype=np.float64, ndmin=2)
    except (ValueError, IndexError, UnicodeDecodeError) as exc:
        raise InvalidShapeError(f"cannot read ICQ shape model '{path}': {exc}") from None
    n = q + 1
    if q < 1 or data.shape != (6 * n * n, 3):
        raise InvalidShapeError(
            f"ICQ shape model '{path}' must hold 6 (Q + 1)^2 = {6 * n * n} vertices of 3 "
            f"coordinates for Q = {q}; got {data.shape}")
    keys, inverse = np.unique(data, axis=0, return_inverse=True)
    index = inverse.reshape(6, n, n)
    faces = []
    for block in index:
        a, b = block[:-1, :-1].ravel(), block[1:, :-1].ravel()
        c, d = block[1:, 1:].ravel(), block[:-1, 1:].ravel()
        tri = np.concatenate([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
        p = keys[tri]
        if np.einsum("ij,ij->i", p[:, 0], np.cross(p[:, 1], p[:, 2])).sum() < 0:
            tri = tri[:, ::-1]
        faces.append(tri)
    return keys, np.concatenate(faces).astype(np.int64)
