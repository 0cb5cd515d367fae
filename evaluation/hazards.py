"""The landing site at lander scale.

The hazard map, the rock size-frequency against the model, and which layer a descent's
frames were drawn from.

:func:`rock_sfd` measures, from a rock catalogue, what the model promises: the cumulative
fractional area F(>=D) (Golombek and Rapp 1997) and the cumulative number N(>=D) per m^2,
over an area where every rock down to a diameter is resolved. :func:`descent_layers` finds,
for every frame of a terrain run, the ground point under the image centre (from the LIDAR
range of the centre pixel), its ground sample distance (range / focal length in pixels, the
footprint of the pixel across the ray) and the finest layer drawn there (the finest layer
whose extent, less the one-pixel overlap band the renderer keeps, holds the point).
:func:`site_section` turns both and a :class:`terrain.surface.hazards.HazardMap` into a report
section.
"""

from __future__ import annotations

import math

import numpy as np

from evaluation.report import Check, Section, figure_record, fmt, image_figure, jsonable
from terrain.core import metakeys as mk
from terrain.craters.catalog import RockCatalog

__all__ = ["descent_layers", "hazards_file_section", "rock_sfd", "rock_sfd_figure",
           "site_section"]


#: Relative tolerance of the SFD grid's diameters against the catalogue's (a few ulps).
GRID_SLACK = 1e-12


def rock_sfd(catalog: RockCatalog, extent, min_diameter: float, *, points: int = 24) -> dict:
    """Cumulative fractional area and number of the rocks centred in ``extent``.

    Parameters
    ----------
    catalog : RockCatalog
    extent : (xmin, ymin, xmax, ymax), map metres
    min_diameter : float
        Smallest diameter complete in the catalogue over the extent (metres).

    Returns
    -------
    dict with ``diameter_m`` (points,), ``fractional_area`` (points,), ``number_per_m2``
    (points,), ``rocks`` and ``area_m2``.
    """
    xmin, ymin, xmax, ymax = extent
    d, x, y = catalog.diameter_m, catalog.x_m, catalog.y_m
    sel = (x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax) & (d >= min_diameter)
    d = np.sort(d[sel])[::-1]
    area = (xmax - xmin) * (ymax - ymin)
    top = d[0] if d.size else min_diameter * 2
    grid = np.geomspace(min_diameter, max(top, min_diameter * 1.01), points)
    cum_area = np.cumsum(np.pi * d**2 / 4)
    # rocks with diameter >= grid; the relative slack keeps a rock whose diameter equals a grid
    # point counted when geomspace rounds that point up by an ulp
    idx = np.searchsorted(-d, -grid * (1.0 - GRID_SLACK), side="right")
    if d.size:
        frac = np.where(idx > 0, cum_area[np.maximum(idx - 1, 0)], 0.0) / area
    else:  # no rock of min_diameter or more: nothing to index
        frac = np.zeros(grid.size)
    return dict(diameter_m=grid, fractional_area=frac, number_per_m2=idx / area,
                rocks=int(d.size), area_m2=float(area))


def rock_sfd_figure(measured: dict, model):
    """Measured F(>=D) and N(>=D) (points) against the model drawn from (lines)."""
    from evaluation.figures import new_figure

    fig = new_figure()
    ax1, ax2 = fig.subplots(1, 2)
    d = measured["diameter_m"]
    dd = np.geomspace(d[0], d[-1], 200)
    ax1.loglog(d, np.maximum(measured["fractional_area"], 1e-12), "o", ms=4,
               label="measured (catalogue)")
    ax1.loglog(dd, model.fractional_area(dd) - model.fractional_area(model.dmax), "-",
               label=f"model ({model.model})")
    ax1.set_xlabel("diameter D (m)")
    ax1.set_ylabel("fractional area of rocks >= D")
    ax2.loglog(d, np.maximum(measured["number_per_m2"], 1e-12), "o", ms=4, label="measured")
    ax2.loglog(dd, model.cumulative(dd) - model.cumulative(model.dmax), "-", label="model")
    ax2.set_xlabel("diameter D (m)")
    ax2.set_ylabel("rocks >= D per m^2")
    for ax in (ax1, ax2):
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    return fig


def descent_layers(run, stack) -> list[dict]:
    """Per frame: centre ground sample distance and the finest layer drawn under the centre.

    Parameters
    ----------
    run : render.rundir.RunReader
        A terrain run with LIDAR range images and truth.
    stack : terrain.stack.model.LayerStack
        The stack it was rendered from.

    Returns
    -------
    list of dict: ``frame``, ``altitude_m`` (camera height above the centre point),
    ``range_m``, ``gsd_m``, ``layer``, ``layer_resolution_m``, ``ratio`` (layer pixel / GSD).
    """
    rows = []
    for k, truth in enumerate(run.truth):
        intr = truth.intrinsics
        i, j = int(round(intr.cy)), int(round(intr.cx))  # pixel centres at integers
        r = run.range_at(k, i, j)  # the centre's range alone: one tile of the image read
        if r is None:
            continue
        if not (math.isfinite(r) and r > 0):
            continue
        point = truth.pose.unproject([[j, i]], [r], intr)[0]
        drawn = {d["level"] for d in truth.drawn.get("layers", [])}
        layer = -1
        for level in range(len(stack.tiles) - 1, -1, -1):
            left, bottom, right, top = stack.tiles[level].bounds
            band = stack.tiles[level - 1].resolution if level else 0.0
            if (left + band <= point[0] <= right - band and bottom + band <= point[1]
                    <= top - band and (level in drawn or not drawn)):
                layer = level
                break
        res = stack.tiles[layer].resolution if layer >= 0 else float("nan")
        focal = max(intr.fx, intr.fy)
        gsd = r / focal
        # the level of detail there: the renderer's rule (render.terrain_scene) with the
        # frame's target cell size on screen, at the range (its block is no further away,
        # so this step is an upper bound)
        target = float(truth.drawn.get("lod_pixels", 1.0))
        step = int(min(64, 2 ** max(0, math.floor(math.log2(max(target * r / (res * focal),
                                                                 1.0)))))) if layer >= 0 else 1
        rows.append(dict(frame=k, altitude_m=float(truth.pose.position[2] - point[2]),
                         range_m=r, gsd_m=gsd, layer=layer, layer_resolution_m=res,
                         ratio=res / gsd, lod_step=step, cell_m=step * res))
    return rows


def site_section(hazards, hazard_png, *, layer: int | None, resolution: float, rocks=None,
                 rock_model=None, rock_extent=None, descent=None, frames=()) -> Section:
    """Return the report section on the landing site at lander scale.

    It holds the hazard truth, the rocks and the descent's layers.

    Parameters
    ----------
    hazards : terrain.surface.hazards.HazardMap
    hazard_png : path of the hazard picture
    layer, resolution : the layer the hazards were computed on (None: a single DEM) and its
        pixel size (m)
    rocks : RockCatalog, optional
        The stack's rock catalogue; with ``rock_model`` and ``rock_extent`` (a layer's extent
        and the smallest diameter complete there) its size-frequency is drawn against the model.
    descent : list of dict, optional
        :func:`descent_layers` rows; ``frames`` picks the ones tabulated.
    """
    sec = Section("site", "The landing site at lander scale")
    where = "the DEM" if layer is None else f"layer {layer}"
    sec.paragraphs.append(
        f"Hazard truth for a lander {hazards.lander_diameter:g} m across: at every pixel of "
        f"{where} ({resolution:.3g} m pixels) a plane is fitted by least squares to the "
        "heights under the footprint; the slope is its tilt and the step the largest height "
        f"above it (rocks, crater rims). Safe: slope <= {hazards.max_slope:g} degrees and "
        f"step <= {hazards.max_step:g} m. Green is safe, red unsafe, grey unknown (footprint "
        "beyond the layer).")
    if hazard_png is not None:
        sec.figures.append(image_figure("hazards", "Hazard map of the landing site",
                                        hazard_png))
    known = np.isfinite(hazards.safe)
    sec.tables.append(("Hazard truth", ["measure", "value"], [
        ["safe fraction (of known pixels)", fmt(hazards.safe_fraction)],
        ["known fraction", fmt(hazards.known_fraction)],
        ["median slope (deg)", fmt(float(np.nanmedian(hazards.slope)) if known.any()
                                    else None)],
        ["pixels unsafe by slope", fmt(int(np.sum(hazards.slope[known]
                                                   > hazards.max_slope)))],
        ["pixels unsafe by step", fmt(int(np.sum(hazards.step[known] > hazards.max_step)))],
    ]))
    data = dict(safe_fraction=hazards.safe_fraction, known_fraction=hazards.known_fraction,
                layer=layer, resolution_m=resolution)
    if rocks is not None and rock_model is not None and rock_extent is not None:
        extent, dmin = rock_extent
        measured = rock_sfd(rocks, extent, dmin)
        sec.figures.append(figure_record(
            "rock_sfd", "Rock size-frequency: catalogue against the model",
            rock_sfd_figure(measured, rock_model),
            dict(measured=measured, model=rock_model.as_dict())))
        sec.paragraphs.append(
            f"Rocks: {rock_model.model} model {rock_model.as_dict()}; {measured['rocks']} "
            f"rocks of D >= {dmin:.3g} m centred in {measured['area_m2']:.4g} m^2. Fresh "
            "craters raise the density on their rims and ejecta above the background model, "
            "so a site near one lies above the line.")
        data["rocks"] = dict(total=len(rocks), measured=measured)
    if descent:
        picked = [r for r in descent if r["frame"] in set(frames)] or descent[-1:]
        sec.tables.append((
            "Descent: finest layer drawn under the image centre", [
                "frame", "altitude (m)", "GSD at centre (m)", "layer", "layer pixel (m)",
                "layer pixel / GSD", "level-of-detail step", "drawn cell (m, at most)"],
            [[r["frame"], fmt(r["altitude_m"]), fmt(r["gsd_m"], 3), r["layer"],
              fmt(r["layer_resolution_m"], 3), fmt(r["ratio"], 3), r["lod_step"],
              fmt(r["cell_m"], 3)] for r in picked]))
        coarse = sum(1 for r in descent if not r["ratio"] <= 2.0)
        sec.checks.append(Check(
            "site", "frames whose finest drawn layer is coarser than 2x their GSD", coarse,
            0, "<=", "frames"))
        data["descent"] = descent
    sec.data = jsonable(data)
    return sec


def hazards_file_section(path, *, run=None, frames=(), stack=None) -> Section:
    """:func:`site_section` of a GeoTIFF written by ``craterscape terrain hazards``.

    Its tags name the lander and the source; where the source is a layer stack with rocks,
    the rocks of the hazard layer are drawn against their model, and with ``run`` (a
    :class:`render.rundir.RunReader` of a descent over that stack) the descent table is added.
    ``stack`` is that source stack where the caller has already read it (a campaign's
    evaluation has: reading 16 layers again takes a second); otherwise it is read here.
    """
    import json
    from pathlib import Path

    from terrain.core.errors import InvalidDEMError
    from terrain.io import read_dem
    from terrain.surface.hazards import HazardMap
    from terrain.surface.rocks import MIN_ROCK_PIXELS, RockModel

    path = Path(path)
    bands = [read_dem(path, band=b) for b in (1, 2, 3)]
    meta = bands[0].metadata
    try:
        params = json.loads(meta[mk.PARAMETERS])
        hazards = HazardMap(bands[0].heights, bands[1].heights, bands[2].heights,
                            float(params["lander_diameter"]), float(params["max_slope"]),
                            float(params["max_step"]))
    except (KeyError, ValueError, TypeError) as exc:
        raise InvalidDEMError(f"'{path}' is not a hazard map written by `craterscape terrain "
                              f"hazards` (tags: {exc})") from None
    tile = bands[0]
    layer = params.get("layer")
    kwargs: dict = {}
    source = Path(params.get("source", ""))
    if source.is_dir() and (source / "manifest.json").exists():
        from terrain.stack.store import read_stack

        stack = read_stack(source) if stack is None else stack
        if stack.rocks is not None and stack.info.get("rocks"):
            kwargs.update(rocks=stack.rocks, rock_model=RockModel.from_mapping(
                stack.info["rocks"]), rock_extent=(tile.bounds,
                                                   MIN_ROCK_PIXELS * tile.resolution))
        if run is not None:
            kwargs.update(descent=descent_layers(run, stack), frames=frames)
    png = path.with_suffix(".png")
    sec = site_section(hazards, png if png.exists() else None,
                       layer=None if layer is None else int(layer), resolution=tile.resolution,
                       **kwargs)
    return sec
