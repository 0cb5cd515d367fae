"""The stages on a finished surface: `terrain rocks` and `terrain hazards`.

Called through :func:`terrain.stages.runner.run`.
"""

from __future__ import annotations

import csv
import json
import logging
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from terrain.core import metakeys as mk
from terrain.core.errors import InvalidParameterError, MissingInputError
from terrain.core.outputs import transaction
from terrain.stages.dems import check_outputs, write_result
from terrain.stages.runner import Execution, ProgressFactory, Written
from terrain.stages.specs import HazardsSpec, RocksSpec

__all__ = ["hazards", "read_crater_list", "rocks"]

log = logging.getLogger(__name__)


def read_crater_list(path: Path) -> Any:
    """Return the craters of a CSV: a craterscape catalogue or a plain list.

    A catalogue has (at least) the columns x_m, y_m, diameter_m, age_gyr; a plain list x, y,
    diameter and optionally age (:func:`terrain.craters.catalog.read_circles`).
    """
    from terrain.craters.catalog import CraterTable, read_circles, read_columns

    if not Path(path).exists():
        raise MissingInputError(f"crater catalogue '{path}' does not exist")
    try:
        with open(path, newline="", encoding="utf-8") as f:
            header = next(csv.reader(f), [])
    except (UnicodeDecodeError, csv.Error) as exc:
        raise InvalidParameterError(
            f"crater catalogue '{path}' is not a CSV text file ({exc})") from None
    if not {"x_m", "y_m", "diameter_m", "age_gyr"} <= set(header):
        return read_circles(path)
    try:
        cat = read_columns(path)
    except ValueError as exc:
        raise InvalidParameterError(f"crater catalogue '{path}' is malformed: {exc}") from None
    n = len(cat["x_m"])
    return CraterTable(cat["x_m"], cat["y_m"], cat["diameter_m"], cat["age_gyr"],
                       cat.get("id", np.zeros(n, np.uint64)), np.zeros(n, np.int64))


def rocks(spec: RocksSpec, source: Path, output: Path, execution: Execution, *,
          catalog: Path | None, progress: ProgressFactory) -> Written:
    """`terrain rocks` (:class:`~terrain.stages.specs.RocksSpec`)."""
    from terrain.core.presets import preset
    from terrain.io import read_dem
    from terrain.surface.rocks import DEFAULT_MODEL, MIN_ROCK_PIXELS, RockModel, add_rocks

    check_outputs(output, catalog, [source, spec.craters])
    values = {key: getattr(spec, key) for key in ("model", "k", "a", "b", "dmin", "dmax")
              if getattr(spec, key) is not None}
    if spec.model is None:
        values["model"] = (preset(spec.terrain).rock_model if spec.terrain is not None
                           else DEFAULT_MODEL)
    if spec.no_crater_rocks:
        values["craters"] = False
    craters = None if spec.craters is None else read_crater_list(spec.craters)
    tile = read_dem(source, band=spec.band)
    if spec.window is not None:
        spec.window.check_inside(*tile.shape)
    smallest = MIN_ROCK_PIXELS * tile.resolution
    defaults: dict = dict(dmin=smallest)
    if spec.terrain is not None:  # the terrain's regolith decides which craters throw blocks
        defaults["regolith_m"] = preset(spec.terrain).regolith_m
    model = RockModel.from_mapping(values, defaults=defaults)
    if model.dmax is not None and model.dmax <= smallest:
        log.warning("no rock of this model (dmax %.3g m) is two pixels (%.3g m) wide: the "
                    "heights will not change", model.dmax, smallest)
    out, cat = add_rocks(tile, model, seed=spec.seed, craters=craters, window=spec.window)

    params = dict(input=str(source), band=spec.band, seed=spec.seed, rocks=model.as_dict(),
                  terrain=spec.terrain,
                  craters=str(spec.craters) if spec.craters else None,
                  window=spec.as_dict()["window"])
    done = write_result(SimpleNamespace(tile=out, catalog=cat), output, catalog, [source],
                        "terrain rocks", params, "rocks")
    return Written(done.paths,
                   done.message if catalog else f"{done.message} ({len(cat)} rocks)")


def hazards(spec: HazardsSpec, source: Path, output: Path, execution: Execution, *,
            catalog: Path | None, progress: ProgressFactory) -> Written:
    """`terrain hazards` (:class:`~terrain.stages.specs.HazardsSpec`): a DEM or a stack."""
    from terrain.io import (
        DEM_SUFFIXES,
        PNG_SUFFIXES,
        check_output_path,
        read_dem,
        write_bands,
        write_png,
    )
    from terrain.surface.hazards import hazard_image, hazard_map, pick_layer
    from terrain.surface.hillshade import hillshade

    check_output_path(output, [source], suffixes=DEM_SUFFIXES,
                      what="GeoTIFF")
    png = spec.png or output.with_suffix(".png")
    check_output_path(png, [source, output], suffixes=PNG_SUFFIXES, what="PNG")
    layer = spec.layer
    if source.is_dir():
        from terrain.stack.store import read_stack

        stack = read_stack(source)
        if layer is None:
            layer = pick_layer([t.resolution for t in stack.tiles], spec.lander_diameter)
        if not 0 <= layer < len(stack.tiles):
            raise InvalidParameterError(
                f"layer {layer} does not exist; the stack has layers 0..{len(stack.tiles) - 1}")
        tile = stack.tiles[layer]
    else:
        if layer is not None:
            raise InvalidParameterError("--layer applies to a layer-stack folder, not a DEM")
        tile = read_dem(source, band=spec.band)
    result = hazard_map(tile, lander_diameter=spec.lander_diameter, max_slope=spec.max_slope,
                        max_step=spec.max_step)
    params = dict(source=str(source), layer=layer, lander_diameter=spec.lander_diameter,
                  max_slope=spec.max_slope, max_step=spec.max_step)
    tags = dict(result.tags(), **{mk.COMMAND: "terrain hazards", mk.VERSION: mk.version(),
                                  mk.PARAMETERS: json.dumps(params, sort_keys=True)})
    shade = hillshade(tile, azimuth=315.0, altitude=30.0)
    with transaction(folders=[Path(output).parent]):  # the GeoTIFF and its PNG as one set
        write_bands([result.slope, result.step, result.safe], tile.replace(metadata={}),
                    output, descriptions=("slope (deg)", "step above plane (m)",
                                          "safe (1) / unsafe (0)"), tags=tags, inputs=[source])
        write_png(hazard_image(result, shade), png, inputs=[source, output])
    return Written((output, png), f"wrote {output} and {png} ({100 * result.safe_fraction:.1f} "
                   f"% safe of the {100 * result.known_fraction:.1f} % known, "
                   f"{tile.resolution:.4g} m pixels)")
