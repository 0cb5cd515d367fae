"""Layer stacks as records: the layers around a landing site, their craters and provenance.

A *layer stack* turns a coarse base DEM into a model that is sharp where a lander looks (Martin
et al. 2014, IV.A): layer 0 is the base (gaps filled with fractal terrain), and every further
layer is a window of the layer above, centred on the site, expanded 2x
(:mod:`terrain.fractal.expand`). With 1025 x 1025 layers a 1 km base reaches about 0.5 m after
11 levels, as the paper's South Pole model did.

Agreement between layers: a finer layer's even pixels are copies of the coarser layer's
pixels, and after the stack is built every coarser pixel inside a finer layer is set to its
co-located fine pixel (so craters added to a fine layer appear, sampled, in the coarse ones):
a coarse pixel equals the co-located fine pixel, exactly.

The stack is planned in :mod:`terrain.stack.plan`, built in :mod:`terrain.stack.build` (chunk
by chunk in :mod:`terrain.stack.chunkedlayers`), kept on disk by :mod:`terrain.stack.store`
and edited in place by :mod:`terrain.stack.edit`.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable
from dataclasses import dataclass, field, replace

from terrain.core.errors import InvalidParameterError
from terrain.core.tile import DEMTile
from terrain.craters.catalog import CraterCatalog, RockCatalog

__all__ = ["CATALOG", "Layer", "LayerStack", "layer_records", "merge_catalogs"]

log = logging.getLogger(__name__)

#: Catalogue file in a layer-stack folder.
CATALOG = "craters.csv"


def _int_tuple(value, n: int, what: str) -> tuple[int, ...]:
    """``value`` as a tuple of ``n`` ints, or an error naming the field."""
    try:
        items = tuple(value)
        if len(items) != n or not all(float(v) == int(v) for v in items):
            raise ValueError
        return tuple(int(v) for v in items)
    except (TypeError, ValueError):
        raise InvalidParameterError(f"layer {what} must be {n} integers; got {value!r}") from None


@dataclass(frozen=True, eq=False)
class Layer:
    """One layer of a stack: its heights and where it lies in the layer above.

    Parameters
    ----------
    tile : DEMTile
        The layer's heights, ``(ny, nx) float32, metres`` (a stack built chunk by chunk
        writes its manifest from stand-ins with the tile's shape, transform and CRS).
    window : (col, row, width, height) of int, or None
        The window of the layer above (pixels) this layer expands; None for the base.
    origin : (row, col) of int
        Global index of this layer's pixel (0, 0) at its level (the expansion's key).
    file : str, optional
        Name of the layer's file in its stack folder, once written or read.
    """

    tile: DEMTile
    window: tuple[int, int, int, int] | None
    origin: tuple[int, int]
    file: str | None = None

    def __post_init__(self):
        if self.window is not None:
            object.__setattr__(self, "window", _int_tuple(self.window, 4, "window"))
        object.__setattr__(self, "origin", _int_tuple(self.origin, 2, "origin"))


@dataclass(frozen=True, eq=False)
class LayerStack:
    """Layers (coarse to fine), the crater catalogue and provenance, as one frozen record.

    Parameters
    ----------
    layers : sequence of Layer
        Layer 0 (the base, no window) first, each further layer a 2x expansion of a window
        of the one before.
    catalog : CraterCatalog
        The crater catalogue (each crater once, with the ``layer`` it was added to).
    info : mapping
        Provenance recorded in the manifest (seed, site, parameters, edits).
    rocks : dict of column arrays, optional
        The rock catalogue, when rocks were added.
    catalog_file : str
        Name of the catalogue file in the stack folder.
    """

    layers: tuple[Layer, ...]
    catalog: CraterCatalog
    info: dict = field(default_factory=dict)
    rocks: RockCatalog | None = None
    catalog_file: str = CATALOG

    def __post_init__(self):
        layers = tuple(self.layers)
        if not layers or not all(isinstance(layer, Layer) for layer in layers):
            raise InvalidParameterError("a layer stack needs one or more Layer records")
        if layers[0].window is not None:
            raise InvalidParameterError("the base layer (0) has no window in a parent")
        for k, layer in enumerate(layers[1:], 1):
            if layer.window is None:
                raise InvalidParameterError(f"layer {k} needs its window in layer {k - 1}")
        object.__setattr__(self, "layers", layers)
        if not isinstance(self.catalog, CraterCatalog) or self.catalog.layer is None:
            raise InvalidParameterError(
                "a layer stack's catalog must be a CraterCatalog with a layer column; got "
                f"{type(self.catalog).__name__}")
        object.__setattr__(self, "info", dict(self.info))

    @property
    def tiles(self) -> tuple[DEMTile, ...]:
        """Every layer's tile, coarse to fine."""
        return tuple(layer.tile for layer in self.layers)

    @property
    def windows(self) -> tuple[tuple[int, int, int, int] | None, ...]:
        """Every layer's window in the layer above; None for the base."""
        return tuple(layer.window for layer in self.layers)

    @property
    def origins(self) -> tuple[tuple[int, int], ...]:
        """Every layer's global (row, col) origin at its level."""
        return tuple(layer.origin for layer in self.layers)

    @property
    def levels(self) -> int:
        """Number of 2x expansions (layers less one)."""
        return len(self.layers) - 1

    def with_info(self, **items) -> LayerStack:
        """Return a copy with ``items`` added to the provenance.

        Parameters
        ----------
        **items
            JSON-able values recorded in the manifest.

        Returns
        -------
        LayerStack
        """
        return replace(self, info={**self.info, **items})

    def layer_of(self, x: float, y: float, reach: float) -> int:
        """Finest layer whose extent holds a disc of radius ``reach`` m at (x, y), or -1.

        Parameters
        ----------
        x, y : float
            Centre, map coordinates (m).
        reach : float
            Radius (m).

        Returns
        -------
        int
        """
        for k in range(len(self.layers) - 1, -1, -1):
            left, bottom, right, top = self.layers[k].tile.bounds
            if (x - reach >= left and x + reach <= right and y - reach >= bottom
                    and y + reach <= top):
                return k
        return -1


def layer_records(tiles, windows, origins, files=None) -> tuple[Layer, ...]:
    """Layer records of parallel lists (as the builders and editors keep them)."""
    files = files or [None] * len(tiles)
    return tuple(Layer(t, w, o, f) for t, w, o, f in zip(tiles, windows, origins, files,
                                                          strict=True))


def merge_catalogs(catalogs: Iterable[CraterCatalog]) -> CraterCatalog:
    """Return a stack's crater catalogue from the per-layer ones, in composition order.

    Parameters
    ----------
    catalogs : iterable of CraterCatalog
        The layers' catalogues, each with its ``layer`` column, coarse to fine.

    Returns
    -------
    CraterCatalog
        Their rows in order (with a ``layer`` column even when there are none).
    """
    return CraterCatalog.concatenate(catalogs, optional=("layer",))
