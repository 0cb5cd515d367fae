"""`terrain enhance`: a layer stack around a landing site, in memory or chunked on Dask.

Called through :func:`terrain.stages.runner.run`. A stack too large for memory (or any stack
run with workers, a scheduler or a chunk size) is built chunk by chunk, bitwise equal to the
in-memory build; an interrupted chunked build resumes when run again.
"""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path
from typing import Any

import numpy as np

from terrain.core import metakeys as mk
from terrain.core.errors import InvalidParameterError
from terrain.stages.dems import crater_model, population, repose
from terrain.stages.runner import Execution, ProgressFactory, Written
from terrain.stages.specs import EnhanceSpec

__all__ = ["default_population", "enhance"]

log = logging.getLogger(__name__)

#: Default halo (pixels) of a chunked build.
DEFAULT_HALO = 256


def default_population(spec: EnhanceSpec, base_resolution: float, finest: float) -> Any:
    """Return the small craters a DEM cannot resolve, from the spec's terrain preset.

    Diameters from ``min_crater_pixels`` pixels of the finest layer (or ``dmin``) up to as
    many pixels of the base (or ``dmax``; what the DEM resolves,
    :func:`terrain.stack.plan.layer_craters`), at the preset's multiple of the empirical
    equilibrium and ages up to the preset's surface age; None when the stack has no finer
    layer.

    Parameters
    ----------
    spec : EnhanceSpec
    base_resolution, finest : float
        Metres per pixel of the base and of the finest layer.

    Returns
    -------
    Population or None
    """
    from terrain.core.presets import EQUILIBRIUM_EXPONENT, equilibrium_density, preset
    from terrain.craters.chronology import neukum_n1
    from terrain.craters.diffusion import DiffusionModel
    from terrain.craters.population import Population

    dmin = spec.min_crater_pixels * finest if spec.dmin is None else spec.dmin
    dmax = spec.min_crater_pixels * base_resolution if spec.dmax is None else spec.dmax
    if not dmax > dmin:
        return None
    terrain = preset(spec.terrain)
    per_m2 = terrain.crater_equilibrium * float(equilibrium_density(dmin))
    # the visible population, as synth's (terrain.stages.dems.population): each size lives
    # until diffusion takes it below the visible d/D, no more than the surface produced
    return Population(dmin=dmin, dmax=dmax, density=per_m2 * 1e6,
                      sfd_exponent=EQUILIBRIUM_EXPONENT, max_age=terrain.surface_age_gyr,
                      lifetime_coefficient=DiffusionModel(
                          terrain.diffusivity_m2_per_myr,
                          terrain.visible_depth_ratio).lifetime_coefficient,
                      production_n1=neukum_n1(terrain.surface_age_gyr))


def _regolith(spec: EnhanceSpec) -> Any:
    """Return the regolith law below a metre (None with ``no_regolith``)."""
    from terrain.fractal.regolith import RegolithLaw

    return None if spec.no_regolith else RegolithLaw()


def _slope_law(spec: EnhanceSpec) -> Any:
    """Return the preset whose slope law the layers follow (None where F or H is given)."""
    from terrain.core.presets import preset

    if spec.fractal_dimension is not None or spec.height_scale is not None:
        return None
    return preset(spec.terrain)


def _site(spec: EnhanceSpec, reader: Any) -> tuple[float, float]:
    """Return the landing site in map coordinates: given, from LON,LAT, or the DEM's centre."""
    from terrain.io import lonlat_to_xy

    if spec.site_lonlat is not None:
        return lonlat_to_xy(reader.crs, *spec.site_lonlat)
    if spec.site is not None:
        return spec.site
    ny, nx = reader.shape
    x, y = reader.transform @ (nx / 2.0, ny / 2.0)
    return float(x), float(y)


def _levels(spec: EnhanceSpec, resolution: float) -> int:
    from terrain.stack.plan import levels_for_resolution

    if spec.finest_resolution is not None:
        return levels_for_resolution(resolution, spec.finest_resolution)
    assert spec.levels is not None  # the spec holds exactly one of the two
    return spec.levels


def _content(spec: EnhanceSpec, resolution: float, shape: tuple, levels: int) -> tuple:
    """Return the rocks, crater population and crater model the stack gets."""
    finest = resolution / 2**levels
    rocks = None
    if spec.rocks is not None:
        from terrain.core.presets import preset
        from terrain.surface.rocks import MIN_ROCK_PIXELS, RockModel

        # the terrain's regolith decides which craters throw out blocks (an explicit key wins)
        rocks = RockModel.from_spec(spec.rocks, defaults=dict(
            dmin=MIN_ROCK_PIXELS * finest, regolith_m=preset(spec.terrain).regolith_m))
    pop = population(spec, resolution=finest, extent=min(shape) * resolution, warn_small=False)
    if spec.population is None and spec.density is None:
        pop = default_population(spec, resolution, finest)
    return rocks, pop, crater_model(spec)


def _fits(spec: EnhanceSpec, source: Path) -> bool:
    """Whether the in-memory build of this stack fits in memory (else it runs chunked)."""
    from terrain.core.zarrstore import is_zarr
    from terrain.execution.chunked import open_reader
    from terrain.io import RasterReader
    from terrain.stack.chunkedlayers import stack_fits_in_memory
    from terrain.stack.plan import GridShape, layer_plan

    if source.is_dir() and is_zarr(source):
        return False  # a Zarr base is read by window
    reader = RasterReader(source, spec.band)
    if reader.wide:
        return True  # read exactly in memory (a chunked run would round it)
    try:
        base = open_reader(source, spec.band)
        _, _, shapes, _ = layer_plan(GridShape(tuple(base.shape), base.transform),
                                     _site(spec, base), _levels(spec, base.resolution),
                                     spec.layer_size)
    except InvalidParameterError:
        return True  # the in-memory path reports it
    return stack_fits_in_memory(reader.shape, shapes)


def enhance(spec: EnhanceSpec, source: Path, output: Path, execution: Execution, *,
            catalog: Path | None, progress: ProgressFactory) -> Written:
    """`terrain enhance` (:class:`~terrain.stages.specs.EnhanceSpec`)."""
    from terrain.fractal.gapfill import despike
    from terrain.fractal.roughness import RoughnessChoice
    from terrain.io import read_dem_exact
    from terrain.stack.build import build_stack
    from terrain.stack.store import prepare_folder, write_stack

    asked = execution.chunked or spec.halo is not None
    if execution.cog is not None:
        raise InvalidParameterError("enhance writes a stack folder; it takes no --cog")
    if asked or not _fits(spec, source):
        return _chunked(spec, source, output, execution, auto=not asked, progress=progress)
    prepare_folder(output, inputs=[source])
    tile, exact = read_dem_exact(source, band=spec.band)
    levels = _levels(spec, tile.resolution)
    if spec.despike is not None:
        tile, dropped = despike(tile, spec.despike)
        if exact is not None:
            exact = np.where(dropped, np.nan, exact)
    rocks, pop, model = _content(spec, tile.resolution, tuple(tile.shape), levels)
    with progress("enhance", "step") as bar:
        stack = build_stack(tile, _site(spec, tile), levels=levels, layer_size=spec.layer_size,
                            seed=spec.seed, population=pop, model=model,
                            params=RoughnessChoice(spec.fractal_dimension, spec.height_scale,
                                                   spec.uniform_roughness, _regolith(spec)),
                            min_crater_pixels=spec.min_crater_pixels, progress=bar,
                            rocks=rocks, keep_known=True, repose=repose(spec),
                            slope_law=_slope_law(spec))
    stack = stack.with_info(source=str(source), command="terrain enhance",
                            craterscape_version=mk.version())
    write_stack(stack, output, inputs=[source], known=exact)
    n_rocks = "" if stack.rocks is None else f", {len(stack.rocks)} rocks"
    return Written((output,), f"wrote {len(stack.tiles)} layers to {output} (finest "
                   f"{stack.tiles[-1].resolution:.4g} m/pixel, {len(stack.catalog)} craters"
                   f"{n_rocks})")


def _chunked(spec: EnhanceSpec, source: Path, output: Path, execution: Execution, *,
             auto: bool, progress: ProgressFactory) -> Written:
    """Build the stack chunk by chunk (:func:`~terrain.stack.chunkedlayers.build_stack_chunked`)."""
    from terrain.execution.chunked import DEFAULT_CHUNK, dask_client, open_reader
    from terrain.fractal.roughness import LOCAL_BOX
    from terrain.stack.chunkedlayers import build_stack_chunked
    from terrain.stack.plan import GridShape, layer_plan
    from terrain.stack.store import prepare_folder

    if spec.despike is not None:
        raise InvalidParameterError("a chunked enhance takes no --despike; run `terrain fill "
                                    "--despike` on the DEM first")
    prepare_folder(output, inputs=[source], keep=(".craterscape.work",))
    reader = open_reader(source, spec.band)
    site, levels = _site(spec, reader), _levels(spec, reader.resolution)
    _, _, shapes, _ = layer_plan(GridShape(tuple(reader.shape), reader.transform),
                                 (float(site[0]), float(site[1])), levels, spec.layer_size)
    rocks, pop, model = _content(spec, reader.resolution, tuple(reader.shape), levels)
    law = _regolith(spec)
    estimate = dict(fractal_dimension=spec.fractal_dimension, height_scale=spec.height_scale,
                    local_box=0 if spec.uniform_roughness else LOCAL_BOX,
                    regolith=None if law is None else law.as_dict())
    pixels = sum(h * w for h, w in shapes)
    (log.warning if auto else log.info)(
        "enhance: building %d layers (%.3g Mpixel) chunk by chunk in %s%s", levels + 1,
        pixels / 1e6, output, " (the stack does not fit in memory)" if auto else "")
    with contextlib.ExitStack() as bars:
        def stage_progress(stage: str) -> Any:
            return bars.enter_context(progress(f"enhance {stage}", "chunk"))

        with dask_client(execution.workers, execution.scheduler,
                         processes=not execution.threads) as client:
            result = build_stack_chunked(
                reader, output, site, levels=levels, layer_size=spec.layer_size,
                seed=spec.seed, population=pop, model=model, estimate=estimate,
                min_crater_pixels=spec.min_crater_pixels, rocks=rocks,
                chunk=execution.chunk or DEFAULT_CHUNK, client=client,
                progress=stage_progress,
                halo=DEFAULT_HALO if spec.halo is None else spec.halo, inputs=[source],
                keep_known=True,
                repose=repose(spec), slope_law=_slope_law(spec),
                info=dict(source=str(source), command="terrain enhance",
                          craterscape_version=mk.version()))
    computed = sum(s["computed"] for s in result["stages"].values())
    total = sum(s["total"] for s in result["stages"].values())
    n_rocks = "" if result["rocks"] is None else f", {result['rocks']} rocks"
    return Written((output,), f"wrote {levels + 1} layers to {output} (finest "
                   f"{result['finest_resolution']:.4g} m/pixel, {result['craters']} craters"
                   f"{n_rocks}; chunked: {computed} of {total} chunks computed, "
                   f"{total - computed} already written)")
