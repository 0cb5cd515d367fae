"""The stages that make or change one DEM: synth, craters, add-crater, expand, fill, hillshade.

Each takes its spec, its input (or None), the output path, the execution and the run's
companions, and returns what it wrote (:class:`~terrain.stages.runner.Written`); call them
through :func:`terrain.stages.runner.run`, which picks them by the spec's type.
"""

from __future__ import annotations

import dataclasses
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from terrain.core import metakeys as mk
from terrain.core.errors import InvalidParameterError
from terrain.core.outputs import transaction
from terrain.stages.runner import (
    WORKING_BYTES_PER_PIXEL,
    Execution,
    ProgressFactory,
    Written,
    chunked_requested,
    fits_in_memory,
    input_fits,
    run_chunked,
    run_dask,
    run_out_of_core,
)
from terrain.stages.specs import (
    MAX_CRATER_TO_DEM,
    AddCraterSpec,
    CratersSpec,
    ExpandSpec,
    FillSpec,
    HillshadeSpec,
    SynthSpec,
)

__all__ = ["add_crater", "crater_model", "craters", "expand", "fill", "hillshade",
           "population", "preset_relief", "repose", "synth", "terrain_preset"]

#: RMD fractal dimension and relief (m) of `terrain synth` without a preset.
DEFAULT_FRACTAL_DIMENSION = 2.2
DEFAULT_RELIEF = 30.0
#: Median |N(0, 1)|: the median of a Gaussian height difference over its standard deviation.
_MEDIAN_ABS_GAUSSIAN = 0.6744897501960817
#: Hurst exponent of a base above the preset's self-affine range: there LOLA's slopes fall
#: faster than the law (Rosenburg et al. 2011, Figs. 5-8); 0.5 (independent increments) puts
#: a 1024 km tile's corner heights at ~5 km, the Moon's km-scale relief.
HURST_ABOVE_SELF_AFFINE = 0.5


def terrain_preset(spec: Any) -> Any:
    """Return the :class:`~terrain.core.presets.TerrainPreset` a spec names (None without one).

    Any stage spec with a ``terrain`` field (synth, craters; enhance and rocks where they have
    one) is read the same way.
    """
    from terrain.core.presets import preset

    name = getattr(spec, "terrain", None)
    return None if name is None else preset(name)


def repose(spec: Any) -> Any:
    """Return the :class:`~terrain.surface.repose.Repose` a spec asks for (None without).

    A spec's own ``repose`` angle (synth) wins over its terrain preset's.
    """
    from terrain.surface.repose import Repose

    angle = getattr(spec, "repose", None)
    if angle is not None:
        return Repose(angle_deg=angle)
    p = terrain_preset(spec)
    return None if p is None else Repose(angle_deg=p.repose_deg)


def preset_relief(p: Any, size: int, resolution: float) -> tuple[float, float]:
    """RMD fractal dimension and relief whose median slope at one pixel follows the preset.

    The median bidirectional slope of the LOLA law at baseline L (up to the preset's
    self-affine range) is ``atan(tan(s17) (L / 17 m)^(H - 1))``; beyond the range the base
    uses :data:`HURST_ABOVE_SELF_AFFINE`. An RMD tile of W = size - 1 pixels has the
    variogram ``2 c^2 (L / W)^(2h)`` (:mod:`terrain.fractal.rmd`, ``c = R sqrt(1 -
    2^(2h - 2))``), so a height difference over one pixel is Gaussian with standard deviation
    ``sqrt(2) c W^-h`` and median absolute value 0.6745 times that: R follows.

    Parameters
    ----------
    p : TerrainPreset
    size : int
        Tile side (2^n + 1 pixels).
    resolution : float
        Metres per pixel.

    Returns
    -------
    fractal_dimension, relief : float
        F = 3 - h and R (metres).
    """
    law_top = min(resolution, p.self_affine_max_m)
    tan_s = math.tan(math.radians(p.slope_17m_deg)) * (law_top / 17.0) ** (p.hurst - 1.0)
    h = p.hurst if resolution <= p.self_affine_max_m else HURST_ABOVE_SELF_AFFINE
    if resolution > p.self_affine_max_m:
        tan_s *= (resolution / p.self_affine_max_m) ** (h - 1.0)
    sigma = tan_s * resolution / _MEDIAN_ABS_GAUSSIAN
    c = sigma * (size - 1) ** h / math.sqrt(2.0)
    return 3.0 - h, c / math.sqrt(1.0 - 2.0 ** (2.0 * h - 2.0))

log = logging.getLogger(__name__)


def crater_model(spec: Any) -> Any:
    """Return the :class:`~terrain.craters.cratering.CraterModel` a spec's model fields ask for."""
    from terrain.craters.crater import (
        DEFAULT_PEAK_RING_DIAMETER,
        DEFAULT_TRANSITION_DIAMETER,
        Morphology,
    )
    from terrain.craters.cratering import CraterModel
    from terrain.craters.diffusion import DiffusionModel
    from terrain.craters.erosion import DEFAULT_CRITICAL_SLOPE_DEG, ErosionModel, SlopeDegradation

    p = terrain_preset(spec)
    kwargs = {} if spec.erosion_exponent is None else {"exponent": spec.erosion_exponent}
    erosion: Any
    if spec.erosion_profile is not None:
        erosion = ErosionModel.from_csv(spec.erosion_profile, **kwargs)
    elif p is not None and not kwargs:
        erosion = DiffusionModel(p.diffusivity_m2_per_myr, p.visible_depth_ratio)
    else:
        erosion = ErosionModel.default(**kwargs)
    visible = erosion.visible_depth_ratio if isinstance(erosion, DiffusionModel) else 0.0
    transition = spec.transition_diameter
    transition = DEFAULT_TRANSITION_DIAMETER if transition is None else transition
    morphology = Morphology(transition, max(DEFAULT_PEAK_RING_DIAMETER, 2.0 * transition),
                            enabled=not spec.simple_craters_only)
    # A preset's diffusivity is measured on real, sloping ground, and its equilibrium is the
    # density counted there: faster degradation on slopes would count the slopes twice (and
    # thin the visible craters below the equilibrium); slopes above repose are relaxed instead.
    slope = SlopeDegradation(enabled=not spec.no_slope_degradation and p is None,
                             critical_slope_deg=DEFAULT_CRITICAL_SLOPE_DEG if p is None
                             else p.repose_deg)
    model = CraterModel(erosion=erosion, morphology=morphology, slope=slope,
                        min_depth_ratio=visible)
    return model.smooth() if spec.no_roughness else model


def population(spec: Any, *, resolution: float, extent: float, warn_small: bool = True) -> Any:
    """Return the crater population a spec asks for on a DEM (None without one).

    Parameters
    ----------
    spec : spec with crater fields
        ``population`` (a TOML file, overridden by the fields) and ``dmin``, ``dmax``,
        ``density``, ``sfd_exponent``, ``max_age``.
    resolution : float, metres per pixel
        Sets the default ``dmin`` (3 pixels).
    extent : float, metres
        Sets the default ``dmax`` (a quarter of it).
    warn_small : bool
        Warn when ``dmin`` is below two pixels.
    """
    from terrain.core.presets import TRASK_EQUILIBRIUM
    from terrain.craters.chronology import neukum_n1
    from terrain.craters.diffusion import DiffusionModel
    from terrain.craters.population import Population

    p = terrain_preset(spec)
    if spec.population is None and spec.density is None and p is None:
        return None
    overrides = dict(dmin=spec.dmin, dmax=spec.dmax, density=spec.density,
                     sfd_exponent=spec.sfd_exponent, max_age=spec.max_age)
    defaults: dict[str, Any] = dict(dmin=3.0 * resolution, dmax=extent / 4.0)
    if p is not None:
        # the visible population: equilibrium density, each size living until diffusion
        # takes it below the visible d/D, and no more than the surface's age produced
        dmin = defaults["dmin"] if spec.dmin is None else spec.dmin
        defaults.update(
            density=p.crater_equilibrium * TRASK_EQUILIBRIUM * 1e6 * float(dmin) ** -2,
            max_age=p.surface_age_gyr,
            lifetime_coefficient=DiffusionModel(
                p.diffusivity_m2_per_myr, p.visible_depth_ratio).lifetime_coefficient,
            production_n1=neukum_n1(p.surface_age_gyr))
    if spec.population is not None:
        pop = Population.from_toml(spec.population, defaults=defaults, **overrides)
    else:
        pop = Population(**{**defaults, **{k: v for k, v in overrides.items() if v is not None}})
    if warn_small and pop.dmin < 2.0 * resolution:
        log.warning("dmin %.3g m is below two pixels (%.3g m): such craters are aliased",
                    pop.dmin, 2.0 * resolution)
    return pop


def _window_list(window: Any) -> list | None:
    return None if window is None else [window.col, window.row, window.width, window.height]


def check_outputs(output: Path, catalog: Path | None, inputs: list) -> None:
    """Refuse a DEM output or catalogue that is not a GeoTIFF/CSV or would replace an input."""
    from terrain.io import DEM_SUFFIXES, check_output_path

    check_output_path(output, inputs, suffixes=DEM_SUFFIXES, what="GeoTIFF")
    if catalog is not None:
        check_output_path(catalog, [*inputs, output], suffixes=(".csv",), what="CSV")
        if Path(catalog).resolve() == Path(output).resolve():
            raise InvalidParameterError("--catalog must differ from --output")


def write_result(result: Any, output: Path, catalog: Path | None, inputs: list, command: str,
                 params: dict, noun: str = "craters") -> Written:
    """Write a DEM and its catalogue, committed together (:func:`~.outputs.transaction`)."""
    from terrain.core.outputs import atomic_path
    from terrain.io import write_dem

    tile = result.tile.with_metadata(**{mk.COMMAND: command, mk.PARAMETERS: params,
                                        mk.VERSION: mk.version()})
    with transaction(folders={Path(output).parent}):
        write_dem(tile, output, inputs=inputs)
        if catalog is not None:
            with atomic_path(catalog, [*inputs, output]) as tmp:
                result.catalog.to_csv(tmp)
    if catalog is None:
        return Written((output,), f"wrote {output}")
    return Written((output, catalog),
                   f"wrote {output} and {catalog} ({len(result.catalog)} {noun})")


def synth(spec: SynthSpec, source: None, output: Path, execution: Execution, *,
          catalog: Path | None, progress: ProgressFactory) -> Written:
    """`terrain synth` (:class:`~terrain.stages.specs.SynthSpec`)."""
    from terrain.fractal.synthetic import synthesize_tile

    crs = None
    if spec.projection is not None:
        from terrain.io import synthetic_crs

        half = spec.size * spec.resolution / 2
        crs = synthetic_crs(*spec.projection, (half, half))
    chunked = chunked_requested(output, execution, spec.window)
    if not chunked:
        check_outputs(output, catalog, [])
    pop = population(spec, resolution=spec.resolution, extent=(spec.size - 1) * spec.resolution)
    if pop is None and catalog is not None:
        raise InvalidParameterError("--catalog needs craters: give --density or --population")
    model = crater_model(spec)
    p = terrain_preset(spec)
    fd, relief = ((DEFAULT_FRACTAL_DIMENSION, DEFAULT_RELIEF) if p is None
                  else preset_relief(p, spec.size, spec.resolution))
    fd = fd if spec.fractal_dimension is None else spec.fractal_dimension
    relief = relief if spec.relief is None else spec.relief
    relax = repose(spec)
    if chunked or (spec.window is None
                   and not fits_in_memory(spec.size ** 2 * WORKING_BYTES_PER_PIXEL)):
        from terrain.execution.chunked import SynthSource

        return run_dask(SynthSource(spec.size, spec.resolution, fd, relief, spec.seed, pop,
                                    model, crs, relax), output,
                        execution, "synth", progress=progress, catalog=catalog)
    with progress("craters", "class") as update:
        result = synthesize_tile(spec.size, resolution=spec.resolution,
                                 fractal_dimension=fd, relief=relief,
                                 seed=spec.seed, craters=pop, model=model, window=spec.window,
                                 progress=update, crs=crs, repose=relax)
    params = dict(size=spec.size, resolution=spec.resolution, terrain=spec.terrain,
                  fractal_dimension=fd, relief=relief, seed=spec.seed,
                  **({} if relax is None else {"repose": relax.as_dict()}),
                  population=pop.as_dict() if pop else None,
                  **({"body": spec.body, "crs": spec.crs or "south-polar"} if crs else {}),
                  window=_window_list(spec.window))
    return write_result(result, output, catalog, [], "terrain synth", params)


def craters(spec: CratersSpec, source: Path, output: Path, execution: Execution, *,
            catalog: Path | None, progress: ProgressFactory) -> Written:
    """`terrain craters` (:class:`~terrain.stages.specs.CratersSpec`)."""
    from terrain.craters.cratering import add_craters
    from terrain.io import read_dem

    chunked = chunked_requested(output, execution, spec.window)
    if not chunked:
        check_outputs(output, catalog, [source])
    if chunked or (spec.window is None and not input_fits(source, spec.band)):
        from terrain.execution.chunked import CraterSource, open_reader

        reader = open_reader(source, spec.band)
        pop = population(spec, resolution=reader.resolution,
                         extent=min(reader.shape) * reader.resolution)
        return run_dask(CraterSource(reader, pop, spec.seed, crater_model(spec)), output,
                        execution, "craters", progress=progress, catalog=catalog,
                        inputs=[source])
    tile = read_dem(source, band=spec.band, exact=True)
    if spec.window is not None:
        spec.window.check_inside(*tile.shape)
    pop = population(spec, resolution=tile.resolution,
                     extent=min(tile.shape) * tile.resolution)
    with progress("craters", "class") as update:
        result = add_craters(tile, pop, seed=spec.seed, model=crater_model(spec),
                             window=spec.window, progress=update)
    params = dict(input=str(source), band=spec.band, seed=spec.seed, population=pop.as_dict(),
                  window=_window_list(spec.window))
    return write_result(result, output, catalog, [source], "terrain craters", params)


def add_crater(spec: AddCraterSpec, source: Path, output: Path, execution: Execution, *,
               catalog: Path | None, progress: ProgressFactory) -> Written:
    """`terrain add-crater` (:class:`~terrain.stages.specs.AddCraterSpec`)."""
    from terrain.core.rng import hash64, stream_id
    from terrain.craters.catalog import Crater, CraterTable
    from terrain.craters.cratering import add_craters
    from terrain.io import read_dem

    check_outputs(output, catalog, [source])
    tile = read_dem(source, band=spec.band, exact=True)
    (x, y), diameter = spec.at, spec.diameter
    left, bottom, right, top = tile.bounds
    extent = math.hypot(right - left, top - bottom)
    if diameter > MAX_CRATER_TO_DEM * extent:
        raise InvalidParameterError(
            f"--diameter {diameter:g} m is more than {MAX_CRATER_TO_DEM:g} times the DEM's "
            f"extent ({extent:.6g} m)")
    if x + diameter < left or x - diameter > right or y + diameter < bottom or \
            y - diameter > top:
        raise InvalidParameterError(
            f"crater at {x},{y} with diameter {diameter} m does not touch the DEM, whose "
            f"extent is x {left:.6g}..{right:.6g}, y {bottom:.6g}..{top:.6g}")
    uid = int(hash64(spec.seed, stream_id("add-crater"), 0, int(round(x * 1000)),
                     int(round(y * 1000)), int(round(diameter * 1000))))
    table = CraterTable.from_craters([Crater(x, y, diameter, spec.age, uid)])
    result = add_craters(tile, table, seed=spec.seed, model=crater_model(spec))
    params = dict(input=str(source), band=spec.band, seed=spec.seed, x=x, y=y,
                  diameter=diameter, age=spec.age, roughness=not spec.no_roughness)
    return write_result(result, output, catalog, [source], "terrain add-crater", params)


def _expansion_too_large(source: Path, band: int, times: int) -> bool:
    """Whether expanding the input ``times`` times needs more memory than is available."""
    from terrain.core.zarrstore import is_zarr
    from terrain.fractal.expand import expanded_shape
    from terrain.io import RasterReader

    if source.is_dir() and is_zarr(source):
        return True
    reader = RasterReader(source, band)
    ny, nx = expanded_shape(reader.shape, times)
    return not fits_in_memory(ny * nx * (4 * 2 + 1 * 2) + reader.shape[0] * reader.shape[1] * 20)


def expand(spec: ExpandSpec, source: Path, output: Path, execution: Execution, *,
           catalog: Path | None, progress: ProgressFactory) -> Written:
    """`terrain expand` (:class:`~terrain.stages.specs.ExpandSpec`)."""
    from terrain.fractal.expand import expand as run_expand
    from terrain.fractal.expand import expanded_known
    from terrain.fractal.roughness import LOCAL_BOX, RoughnessChoice
    from terrain.io import check_output_path, read_dem_exact, write_dem

    if chunked_requested(output, execution, spec.window) or (
            spec.window is None and _expansion_too_large(source, spec.band, spec.times)):
        from terrain.execution.chunked import ExpandSource, estimate_parameters, open_reader

        reader = open_reader(source, spec.band)
        params = estimate_parameters(reader, spec.fractal_dimension, spec.height_scale,
                                     0 if spec.uniform_roughness else LOCAL_BOX)
        return run_dask(ExpandSource(reader, spec.times, spec.seed, params), output,
                        execution, "expand", progress=progress, inputs=[source])
    check_output_path(output, [source])
    tile, exact = read_dem_exact(source, band=spec.band)
    if spec.window is not None:
        spec.window.check_inside(*tile.shape)
    params = RoughnessChoice(spec.fractal_dimension, spec.height_scale,
                             spec.uniform_roughness).for_tile(tile)
    with progress("expand", "level") as bar:
        out = run_expand(tile, spec.times, seed=spec.seed, params=params, window=spec.window,
                         progress=bar)
    out = out.with_metadata(**{mk.COMMAND: "terrain expand", mk.VERSION: mk.version(),
                               mk.PARAMETERS: dict(input=str(source), times=spec.times,
                                                   seed=spec.seed, **params.as_dict())})
    known = None
    if exact is not None:  # the input's float64 heights go back bitwise, in a float64 file
        w = spec.window
        known = expanded_known(exact, out.shape, spec.times,
                               (0, 0) if w is None else (w.row * 2**spec.times,
                                                         w.col * 2**spec.times))
    with transaction():
        write_dem(out, output, inputs=[source], known=known)
    return Written((output,), f"wrote {output} ({out.shape[1]}x{out.shape[0]} at "
                   f"{out.resolution:.6g} m; F={params.fractal_dimension:.3f}, "
                   f"H={params.height_scale:.4g})")


def fill(spec: FillSpec, source: Path, output: Path, execution: Execution, *,
         catalog: Path | None, progress: ProgressFactory) -> Written:
    """`terrain fill` (:class:`~terrain.stages.specs.FillSpec`)."""
    from terrain.execution.chunked import DEFAULT_CHUNK, FillSource, open_reader
    from terrain.io import check_output_path

    other = spec.craters_at is not None or spec.despike is not None or spec.denoise is not None
    halo = 256 if spec.halo is None else spec.halo
    if spec.halo is not None:  # a halo asks for a chunked run
        execution = dataclasses.replace(execution, chunk=execution.chunk or DEFAULT_CHUNK)
    if chunked_requested(output, execution):
        if other:
            raise InvalidParameterError("a chunked fill takes no --craters-at, --despike or "
                                        "--denoise; run those on the DEM first")
        return run_chunked(FillSource(open_reader(source, spec.band), halo, spec.seed,
                                      spec.roughness), output, execution, "fill",
                           progress=progress, inputs=[source], cog=execution.cog)
    if spec.halo is not None:
        raise InvalidParameterError("--halo is for chunked runs: give -o NAME.zarr or --chunk")
    check_output_path(output, [source, spec.craters_at])
    if not other and not input_fits(source, spec.band):
        return run_out_of_core(FillSource(open_reader(source, spec.band), 256, spec.seed,
                                          spec.roughness), output, execution, "fill",
                               progress=progress, inputs=[source])
    return _fill_in_memory(spec, source, output)


def _fill_in_memory(spec: FillSpec, source: Path, output: Path) -> Written:
    from terrain.craters.catalog import read_circles
    from terrain.fractal.gapfill import denoise, despike, fill_crater_gaps, fill_gaps
    from terrain.io import read_dem_exact, write_dem

    tile, exact = read_dem_exact(source, band=spec.band)
    circles = read_circles(spec.craters_at) if spec.craters_at is not None else None
    removed = 0
    if spec.despike is not None:
        tile, mask = despike(tile, spec.despike)
        removed = int(mask.sum())
    if spec.denoise is not None:
        tile = denoise(tile, spec.denoise)
        exact = None  # smoothing changes the known heights on purpose
    if circles is not None:
        result = fill_crater_gaps(tile, circles, seed=spec.seed, roughness=spec.roughness)
    else:
        result = fill_gaps(tile, seed=spec.seed, roughness=spec.roughness)
    out = result.tile.with_metadata(**{
        mk.COMMAND: "terrain fill", mk.VERSION: mk.version(),
        mk.PARAMETERS: dict(input=str(source), roughness=spec.roughness, seed=spec.seed,
                            despike=spec.despike, denoise=spec.denoise,
                            craters_at=str(spec.craters_at) if spec.craters_at else None)})
    known = None if exact is None else np.where(result.filled, np.nan, exact)
    with transaction():  # known heights a float32 tile rounds go back bitwise (float64 file)
        write_dem(out, output, inputs=[source], known=known)
    return Written((output,), f"wrote {output} ({int(result.filled.sum())} pixels filled"
                   + (f", {removed} spikes removed" if spec.despike is not None else "") + ")")


def hillshade(spec: HillshadeSpec, source: Path, output: Path, execution: Execution, *,
              catalog: Path | None, progress: ProgressFactory) -> Written:
    """`terrain hillshade` (:class:`~terrain.stages.specs.HillshadeSpec`)."""
    from terrain.io import PNG_SUFFIXES, check_output_path, read_dem, write_png
    from terrain.surface.hillshade import hillshade as shade

    check_output_path(output, [source], suffixes=PNG_SUFFIXES, what="PNG")
    tile = read_dem(source, band=spec.band)
    image = shade(tile, azimuth=spec.azimuth, altitude=spec.altitude, z_factor=spec.z_factor)
    with transaction():
        write_png(image, output, inputs=[source])
    return Written((output,), f"wrote {output}")
