"""Building an asteroid from a recipe, and writing what a user gets.

``build`` runs the stages in the paper's order: the base (Perlin noise, two-phase faulting
or a shape model; section IV), the stretch, the craters in age order (section V.A-B), then
the boulders on the finished surface (section V.C). Every stage is keyed by the recipe's
seed, so the same recipe gives the same bytes.

Outputs of ``craterscape asteroid build -o BODY.EXT`` (:func:`output_paths`):

``BODY.EXT``
    The mesh (``.ply``, ``.obj``, ``.stl`` or ``.glb``): the body, then the boulders at their
    finest level of detail. With ``-o BODY.npz`` only the native model is written.
``BODY.npz``
    The native model (:func:`asteroid.body.save_native`): radii, mesh parameters,
    provenance, and both catalogues.
``BODY_craters.csv``, ``BODY_boulders.csv``
    The ground-truth catalogues (:mod:`asteroid.catalog`), when craters or boulders were
    asked for.

Example
-------
>>> from asteroid.recipe import KEEP_NON_STAR_FRACTION, Recipe
>>> result = build(Recipe(magnitude=8, radius=500.0, seed=1, base="perlin"))
>>> result.body.mesh.n_vertices, result.craters is None
(386, True)
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from asteroid.body import Body, load_native, save_native
from asteroid.boulders import Boulders, BoulderSettings, place_boulders
from asteroid.catalog import BoulderCatalog, CraterCatalog, save_table
from asteroid.craters import add_craters, sample_craters
from asteroid.errors import InvalidShapeError
from asteroid.meshio.export import MESH_FORMATS, mesh_format, write_mesh
from asteroid.recipe import KEEP_NON_STAR_FRACTION, Recipe
from asteroid.shape import ShapeModel
from asteroid.sphere import SphereMesh
from asteroid.surface import MeshBody, MeshBoulders
from terrain.core import memory
from terrain.core.errors import InvalidParameterError
from terrain.core.metakeys import version
from terrain.core.progress import Progress
from terrain.io import check_output_path

__all__ = ["BuildResult", "OutputPaths", "build", "export_model", "output_paths",
           "write_outputs"]

log = logging.getLogger(__name__)

#: Peak bytes per mesh vertex of a build and its export (directions, radii and working
#: copies, the face array, the exporter's copies).
BUILD_BYTES_PER_VERTEX = 260


@dataclass(frozen=True, eq=False)
class BuildResult:
    """A built asteroid.

    Parameters
    ----------
    body : Body
    craters : asteroid.catalog.CraterCatalog, or None
        The crater catalogue.
    boulders : Boulders, or None
    report : dict
        Figures for the user (counts, timings, the shape's non-star-shaped fraction).
    """

    body: Body | MeshBody
    craters: CraterCatalog | dict | None = None
    boulders: Boulders | MeshBoulders | None = None
    report: dict = field(default_factory=dict)

    def tables(self) -> dict:
        """Catalogues for the native file."""
        out = {}
        if isinstance(self.craters, CraterCatalog):
            out["craters"] = self.craters.as_dict()
        if isinstance(self.boulders, Boulders):
            out["boulders"] = self.boulders.catalog.as_dict()
        return out


def build(recipe: Recipe, *, progress: Progress | None = None) -> BuildResult:
    """Build the asteroid a recipe describes.

    Parameters
    ----------
    recipe : Recipe
    progress : callable, optional
        ``progress(done, total, stage)`` with stage "base", "craters" or "boulders"
        (:class:`terrain.core.progress.Progress`).
    """
    if recipe.base == "packing":
        return build_mesh_body(recipe, progress=progress)
    mesh = SphereMesh(recipe.magnitude)
    memory.require(mesh.n_vertices * float(BUILD_BYTES_PER_VERTEX),
                   f"building a magnitude {recipe.magnitude} asteroid "
                   f"({mesh.n_vertices:,} vertices)")
    report: dict = dict(vertices=mesh.n_vertices, triangles=mesh.n_faces)
    t0 = time.perf_counter()

    def stage_progress(stage):
        if progress is None:
            return None
        return lambda done, total: progress(done, total, stage)

    meta = dict(craterscape_version=version(), seed=recipe.seed, recipe=recipe.as_dict())
    if recipe.base == "perlin":
        radius = recipe.base_radius
        radii = recipe.perlin.radii(mesh, radius, seed=recipe.seed, stretch=recipe.stretch)
    elif recipe.base == "faulting":
        radius = recipe.base_radius
        radii = recipe.faulting.radii(mesh, radius, seed=recipe.seed, stretch=recipe.stretch,
                                      progress=stage_progress("base"))
    else:
        shape = ShapeModel.read(recipe.shape_file, units=recipe.shape_units,
                                centre=recipe.shape_centre)
        report["shape_volume_m3"] = shape.volume
        if recipe.radius is not None:
            shape = shape.scaled(recipe.radius / shape.equivalent_radius)
        if not recipe.stretch.is_identity:
            shape = shape.stretched(recipe.stretch)
        radius = shape.equivalent_radius
        projection = shape.project(mesh)
        keep = recipe.shape_keep == "always" or (
            recipe.shape_keep == "auto"
            and projection.non_star_fraction > KEEP_NON_STAR_FRACTION)
        if keep:
            log.info("shape model %s: %.3f %% of directions are not star-shaped; keeping its "
                     "mesh", shape.source, 100 * projection.non_star_fraction)
            return build_mesh_body(recipe, shape=shape, progress=progress,
                                   non_star_fraction=projection.non_star_fraction)
        radii = projection.radii
        report["non_star_fraction"] = projection.non_star_fraction
        meta["shape"] = dict(source=shape.source, centre_m=shape.centre.tolist(),
                             volume_m3=shape.volume,
                             non_star_fraction=projection.non_star_fraction)
    body = Body(mesh, radius, radii, meta)
    report["base_s"] = time.perf_counter() - t0
    craters = None
    if recipe.craters is not None:
        t1 = time.perf_counter()
        spacing = mesh.mean_spacing * body.radius
        population = recipe.craters.population(body.radius, spacing)
        if population.dmax < 2.0 * population.dmin:
            log.warning("the crater range %.4g..%.4g m is narrow at magnitude %d (dmin defaults "
                        "to 4 vertex spacings); raise the magnitude or set dmin",
                        population.dmin, population.dmax, recipe.magnitude)
        settings = recipe.craters.settings()
        placement = sample_craters(population, body, seed=recipe.seed, settings=settings)
        result = add_craters(body, placement, seed=recipe.seed, settings=settings,
                             progress=stage_progress("craters"))
        body = result.body.replace(crater_population=population.as_dict())
        craters = result.catalog
        report["craters"] = len(placement)
        report["craters_applied"] = int(craters.applied.sum())
        report["craters_s"] = time.perf_counter() - t1
    boulders = None
    if recipe.boulders is not None:
        t2 = time.perf_counter()
        population = recipe.boulders.population(mesh.mean_spacing * body.radius)
        boulders = place_boulders(body, population, seed=recipe.seed,
                                  settings=recipe.boulders.settings)
        body = body.replace(boulders=dict(population=population.as_dict(), seed=recipe.seed,
                                          settings=recipe.boulders.settings.as_dict(),
                                          count=len(boulders)))
        report["boulders"] = len(boulders)
        report["boulders_s"] = time.perf_counter() - t2
    report["total_s"] = time.perf_counter() - t0
    return BuildResult(body, craters, boulders, report)


def build_mesh_body(recipe: Recipe, *, shape: ShapeModel | None = None, progress=None,
                    non_star_fraction: float | None = None) -> BuildResult:
    """Build a body kept as its own closed mesh (a shape model, or a packing preset).

    The magnitude sets the feature scale as on the latitude/longitude mesh: the default
    smallest crater spans 4 and the smallest boulder 1 of that mesh's vertex spacings, and the
    mesh is refined locally where craters need it (:mod:`asteroid.surface`).
    """
    from asteroid.packing import packing_body
    from asteroid.surface import (
        CRATER_SITE_STREAM,
        MeshBody,
        add_mesh_craters,
        place_mesh_boulders,
        sample_sites,
    )

    t0 = time.perf_counter()
    meta = dict(craterscape_version=version(), seed=recipe.seed, recipe=recipe.as_dict())
    if shape is None:
        cells = recipe.packing_cells or min(256, max(32, 2 * recipe.magnitude))
        body = packing_body(str(recipe.packing), radius=recipe.base_radius, seed=recipe.seed,
                            cells=cells)
        if not recipe.stretch.is_identity:
            body = body.replace(body.vertices * recipe.stretch.factors)
        body = body.replace(**meta)
    else:
        body = MeshBody(shape.vertices, shape.faces,
                        dict(meta, shape=dict(source=shape.source,
                                              centre_m=shape.centre.tolist(),
                                              volume_m3=shape.volume,
                                              non_star_fraction=non_star_fraction)))
    body.check_closed()
    radius = body.equivalent_radius
    spacing = SphereMesh(recipe.magnitude).mean_spacing * radius
    report: dict = dict(vertices=body.n_vertices, triangles=len(body.faces),
                        base_vertices=body.n_vertices, mesh_body=True)
    if non_star_fraction is not None:
        report["non_star_fraction"] = non_star_fraction
    report["base_s"] = time.perf_counter() - t0

    def stage_progress(stage):
        if progress is None:
            return None
        return lambda done, total: progress(done, total, stage)

    craters = None
    if recipe.craters is not None:
        t1 = time.perf_counter()
        population = recipe.craters.population(radius, spacing)
        sites = sample_sites(body.vertices, body.faces, population, seed=recipe.seed,
                             stream=CRATER_SITE_STREAM)
        result = add_mesh_craters(body, sites, seed=recipe.seed,
                                  settings=recipe.craters.settings(),
                                  progress=stage_progress("craters"))
        body = result.body.replace(crater_population=population.as_dict())
        craters = result.catalog
        report["craters"] = len(sites)
        report["craters_applied"] = int(craters["applied"].sum())
        report["refine_rounds"] = result.refine_rounds
        report["craters_s"] = time.perf_counter() - t1
    boulders = None
    if recipe.boulders is not None:
        t2 = time.perf_counter()
        population = recipe.boulders.population(spacing)
        boulders = place_mesh_boulders(body, population, seed=recipe.seed,
                                       settings=recipe.boulders.settings)
        body = body.replace(boulders=dict(population=population.as_dict(), seed=recipe.seed,
                                          settings=recipe.boulders.settings.as_dict(),
                                          count=len(boulders)))
        report["boulders"] = len(boulders)
        report["boulders_s"] = time.perf_counter() - t2
    report["vertices"] = body.n_vertices
    report["triangles"] = len(body.faces)
    report["total_s"] = time.perf_counter() - t0
    return BuildResult(body, craters, boulders, report)


@dataclass(frozen=True)
class OutputPaths:
    """Where a build writes: the mesh (None for native only), the native model, catalogues.

    ``stale`` lists the files of an earlier build under the same name that this build does not
    write (its catalogues after a rebuild with ``--craters none``, its mesh in another format
    or beside a native-only rebuild): they are removed when it commits, so no later reader
    takes an old body's mesh for the new one. An input (a shape model) is never among them.
    """

    mesh: Path | None
    native: Path
    craters: Path | None
    boulders: Path | None
    stale: tuple = ()

    def all(self) -> list[Path]:
        """Return every path of the set that is written (the optional ones only when present)."""
        return [p for p in (self.mesh, self.native, self.craters, self.boulders)
                if p is not None]


def output_paths(output, *, craters: bool, boulders: bool, inputs=()) -> OutputPaths:
    """Return the files ``-o output`` names, checked before any work (folder exists, no input)."""
    output = Path(output)
    if output.suffix.lower() == ".npz":
        mesh = None
    else:
        mesh_format(output)
        mesh = output
    stem = output.with_suffix("")
    crater_csv = stem.with_name(stem.name + "_craters.csv")
    boulder_csv = stem.with_name(stem.name + "_boulders.csv")
    stale = [p for p, wanted in ((crater_csv, craters), (boulder_csv, boulders)) if not wanted]
    given = {Path(p).resolve() for p in inputs}
    stale += [p for p in (stem.with_suffix(s) for s in MESH_FORMATS)
              if p != mesh and p.resolve() not in given]
    paths = OutputPaths(mesh, output.with_suffix(".npz"), crater_csv if craters else None,
                        boulder_csv if boulders else None, tuple(stale))
    for p in (*paths.all(), *stale):
        check_output_path(p, inputs)
    return paths


def _parts(body, boulders, level=None):
    if getattr(body, "faces", None) is not None and not isinstance(body, Body):
        parts = [("body", body.vertices, body.faces)]
        if boulders is not None and len(boulders):
            parts.append(("boulders", boulders.vertices, boulders.faces))
        return parts
    parts = [("body", body.vertices(), body.mesh.faces())]
    if boulders is not None and len(boulders):
        v, f = boulders.mesh(level)
        parts.append(("boulders", v, f))
    return parts


def write_outputs(result: BuildResult, paths: OutputPaths, *, inputs=()) -> list[Path]:
    """Write a build's files as one set; returns the paths written.

    The mesh, the native model and the catalogues appear together or not at all, and stale
    catalogues of an earlier build are removed in the same commit
    (:func:`terrain.core.outputs.transaction`); a killed build leaves the previous set.
    """
    from terrain.core.outputs import transaction

    folder = paths.native.parent if str(paths.native.parent) else Path(".")
    with transaction(stale=paths.stale, folders=[folder]):
        return _write_all(result, paths, inputs)


def _write_all(result: BuildResult, paths: OutputPaths, inputs) -> list[Path]:
    written = []
    inputs = list(inputs)
    meta = dict(seed=result.body.metadata.get("seed"),
                recipe=result.body.metadata.get("recipe"),
                craterscape_version=result.body.metadata.get("craterscape_version"))
    if paths.mesh is not None:
        write_mesh(paths.mesh, _parts(result.body, result.boulders), metadata=meta,
                   inputs=inputs)
        written.append(paths.mesh)
    if not isinstance(result.body, Body):
        from asteroid.surface import save_columns, save_mesh_native

        tables: dict[str, dict] = {}
        if isinstance(result.craters, dict):
            tables["craters"] = result.craters
        if result.boulders is not None and isinstance(result.boulders.catalog, dict):
            tables["boulders"] = result.boulders.catalog
        save_mesh_native(paths.native, result.body, tables, inputs=inputs)
        written.append(paths.native)
        for path, table in ((paths.craters, tables.get("craters")),
                            (paths.boulders, tables.get("boulders"))):
            if path is not None and table is not None:
                save_columns(path, table, inputs=inputs)
                written.append(path)
        return written
    save_native(paths.native, result.body, result.tables(), inputs=inputs)
    written.append(paths.native)
    if paths.craters is not None and isinstance(result.craters, CraterCatalog):
        save_table(paths.craters, result.craters, inputs=inputs)
        written.append(paths.craters)
    if paths.boulders is not None and isinstance(result.boulders, Boulders):
        save_table(paths.boulders, result.boulders.catalog, inputs=inputs)
        written.append(paths.boulders)
    return written


def boulders_of(native) -> Boulders | None:
    """Return the boulders stored in a native model (regenerated from catalogue and settings)."""
    table = native.tables.get("boulders")
    info = native.body.metadata.get("boulders")
    if table is None or info is None:
        return None
    settings = info["settings"]
    settings = BoulderSettings(**{**settings, "flattening": tuple(settings["flattening"]),
                                  "elongation": tuple(settings["elongation"])})
    return Boulders(BoulderCatalog.from_columns(table), settings, int(info["seed"]))


def export_model(native_path, output, *, boulders: bool = True, level: int | None = None) \
        -> Path:
    """Write a native model as a mesh file (body, and boulders at ``level`` of detail)."""
    from asteroid.surface import MESH_FORMAT, native_format

    native_path = Path(native_path)
    mesh_format(output)
    check_output_path(output, [native_path])
    if native_format(native_path) == MESH_FORMAT:
        return _export_mesh_body(native_path, output, boulders=boulders, level=level)
    native = load_native(native_path)
    b = boulders_of(native) if boulders else None
    if level is not None and b is None:
        raise InvalidParameterError(f"'{native_path}' has no boulders to export at a level")
    meta = dict(seed=native.body.metadata.get("seed"), recipe=native.body.metadata.get("recipe"),
                source=str(native_path))
    return write_mesh(output, _parts(native.body, b, level), metadata=meta,
                      inputs=[native_path])


def _export_mesh_body(native_path: Path, output, *, boulders: bool, level: int | None) -> Path:
    """Write a mesh body's ``.npz`` as a mesh file (body, boulders rebuilt from the catalogue)."""
    from asteroid.surface import boulder_settings, load_mesh_native, mesh_boulder_geometry

    body, tables = load_mesh_native(native_path)
    recorded = boulder_settings(body.metadata)
    table = tables.get("boulders")
    have = boulders and recorded is not None and table is not None
    if level is not None and not have:
        raise InvalidParameterError(f"'{native_path}' has no boulders to export at a level")
    parts = [("body", body.vertices, body.faces)]
    if have:
        assert recorded is not None and table is not None
        v, f = mesh_boulder_geometry(table, recorded[0], recorded[1], level)
        if len(f):
            parts.append(("boulders", v, f))
    meta = dict(seed=body.metadata.get("seed"), recipe=body.metadata.get("recipe"),
                source=str(native_path))
    return write_mesh(output, parts, metadata=meta, inputs=[native_path])


def describe_model(path) -> dict:
    """Describe a native ``.npz`` of either kind: size, volume, catalogues, provenance.

    Parameters
    ----------
    path : str or Path
        A latitude/longitude body or a mesh body, as ``craterscape asteroid build`` writes.

    Returns
    -------
    dict
        ``file``, ``kind`` (``"latlon"`` or ``"mesh"``), the body's summary, ``tables``
        (rows per catalogue) and ``metadata``.
    """
    from asteroid.surface import MESH_FORMAT, load_mesh_native, native_format

    path = Path(path)
    if native_format(path) == MESH_FORMAT:
        body, tables = load_mesh_native(path)
        r = np.linalg.norm(body.vertices, axis=1)
        try:
            body.check_closed()
            closed = True
        except InvalidShapeError:
            closed = False
        summary = dict(kind="mesh", vertices=body.n_vertices, triangles=len(body.faces),
                       volume_m3=body.volume(), area_m2=body.area(),
                       equivalent_radius_m=body.equivalent_radius, mean_edge_m=body.mean_edge(),
                       min_radius_m=float(r.min()), max_radius_m=float(r.max()),
                       mean_radius_m=float(r.mean()), closed=closed)
        metadata = dict(body.metadata)
    else:
        native = load_native(path)
        summary = dict(kind="latlon", **native.body.summary())
        tables = dict(native.tables)
        metadata = dict(native.body.metadata)
    rows = {name: len(next(iter(cols.values()))) if cols else 0 for name, cols in tables.items()}
    return dict(file=str(path), **summary, tables=rows, metadata=metadata)
