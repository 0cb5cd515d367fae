"""Purely synthetic cratered terrain: an RMD base with a crater population (the paper's Fig. 4).

Martin et al. (2014, section III.C, Fig. 4) add the crater model to a diamond-square fractal
surface (F = 2.2) with a lunar crater size distribution. :func:`synthesize_tile` does exactly
that; both the base and the craters are keyed by position, so a window computed alone equals
the same window of the full tile, bitwise.
"""

from __future__ import annotations

import json

import numpy as np
from affine import Affine

from terrain.core import metakeys as mk
from terrain.core.rng import check_seed
from terrain.core.tile import DEMTile, Window, default_transform
from terrain.craters.catalog import CraterCatalog
from terrain.craters.cratering import CraterModel, CraterResult, crater_heights, describe_craters
from terrain.fractal.rmd import check_fractal_dimension, check_tile_size, synthesize

__all__ = ["synthesize_tile"]


def synthesize_tile(size: int, *, resolution: float = 1.0, fractal_dimension: float = 2.2,
                    relief: float = 30.0, seed: int = 0, craters=None,
                    model: CraterModel | None = None, window: Window | None = None,
                    progress=None, crs: str | None = None, repose=None) -> CraterResult:
    """Return a (size x size) RMD tile with optional craters, or a window of it.

    Parameters
    ----------
    size : int
        2^n + 1 pixels per side.
    resolution : float
        Metres per pixel.
    fractal_dimension, relief : float
        RMD parameters (:func:`terrain.fractal.rmd.synthesize`); relief in metres.
    seed : int
    craters : Population or CraterTable, optional
    model : CraterModel, optional
    window : Window, optional
    progress : callable, optional
        Called as ``progress(done, total)`` after each crater size class.
    crs : str, optional
        WKT of the tile's CRS (e.g. :func:`terrain.io.synthetic_crs`); the heights and map
        coordinates do not depend on it.
    repose : terrain.surface.repose.Repose, optional
        Relax slopes above the angle of repose outside fresh craters
        (:func:`terrain.surface.repose.relax_to_repose`); a window is computed with the
        relaxation's halo, so it still equals the same window of the full tile.

    Returns
    -------
    CraterResult
        float32 tile in a map frame with its lower-left corner at (0, 0) (no CRS unless
        ``crs``) and the crater catalogue (empty without craters).

    Examples
    --------
    >>> r = synthesize_tile(33, resolution=2.0, seed=1)
    >>> r.tile.shape, r.tile.resolution, r.tile.metadata[mk.SEED]
    ((33, 33), 2.0, '1')
    """
    check_tile_size(size)
    check_fractal_dimension(fractal_dimension)
    seed = check_seed(seed)
    transform = default_transform(float(resolution), size)
    window = window or Window(0, 0, size, size)
    window.check_inside(size, size)

    def base(r0, r1, c0, c1):
        return synthesize(size, fractal_dimension=fractal_dimension, relief=relief, seed=seed,
                          window=Window(c0, r0, c1 - c0, r1 - r0))

    params = dict(size=size, resolution=float(resolution),
                  fractal_dimension=float(fractal_dimension), relief=float(relief))
    work = window
    if repose is not None:
        halo = repose.iterations + 1
        r0, c0 = max(0, window.row - halo), max(0, window.col - halo)
        r1 = min(size, window.row + window.height + halo)
        c1 = min(size, window.col + window.width + halo)
        work = Window(c0, r0, c1 - c0, r1 - r0)
    if craters is None:
        z = base(work.row, work.row + work.height, work.col, work.col + work.width)
        catalog = CraterCatalog.empty()
    else:
        model = model or CraterModel()
        z, catalog = crater_heights(base, (size, size), transform, craters, seed=seed,
                                    model=model, window=work, progress=progress)
    if repose is not None:
        from terrain.surface.repose import relax_to_repose

        work_transform = transform @ Affine.translation(work.col, work.row)
        fresh = repose.fresh_mask(z.shape, work_transform, catalog.x_m, catalog.y_m,
                                  catalog.diameter_m, catalog.age_gyr)
        z, _ = relax_to_repose(z, float(resolution), repose.angle_deg, movable=~fresh,
                               iterations=repose.iterations)
        a, b = window.row - work.row, window.col - work.col
        z = z[a:a + window.height, b:b + window.width]
        if len(catalog):
            catalog = _window_catalog(catalog, window, work, float(resolution),
                                      (model or CraterModel()).footprint_factor)
    sub_transform = transform @ Affine.translation(window.col, window.row)
    tile = DEMTile.from_array(z.astype(np.float32), transform=sub_transform, crs=crs)
    meta = {mk.SEED: str(seed), mk.RMD: json.dumps(params, sort_keys=True)}
    if window.width != size or window.height != size:
        meta[mk.WINDOW] = f"{window.col},{window.row},{window.width},{window.height}"
    if craters is not None and model is not None:  # model is set whenever craters are
        meta[mk.CRATERS] = json.dumps(describe_craters(craters), sort_keys=True)
        meta[mk.CRATER_MODEL] = json.dumps(model.as_dict(), sort_keys=True)
    if repose is not None:
        meta[mk.REPOSE] = json.dumps(repose.as_dict(), sort_keys=True)
    return CraterResult(tile.replace(metadata=meta), catalog)



def _window_catalog(catalog: CraterCatalog, window: Window, work: Window,
                    resolution: float, factor: float) -> CraterCatalog:
    """Rows of the catalogue of ``work`` whose footprint touches ``window``, in its pixels.

    The same rows, in the same order, as a run over ``window`` alone gives
    (:func:`terrain.craters.cratering.crater_heights`).
    """
    rows = catalog.row - (window.row - work.row)
    cols = catalog.col - (window.col - work.col)
    gr = (np.clip(rows, -0.5, window.height - 0.5) - rows) * resolution
    gc = (np.clip(cols, -0.5, window.width - 0.5) - cols) * resolution
    touch = np.hypot(gr, gc) <= catalog.diameter_m * factor
    idx = np.flatnonzero(touch)
    return catalog.take(idx).with_columns(row=rows[idx], col=cols[idx])
