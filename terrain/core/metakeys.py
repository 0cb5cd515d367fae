"""The registry of craterscape metadata keys: every ``CRATERSCAPE_*`` tag, named once.

A DEM tile's metadata (:attr:`terrain.core.tile.DEMTile.metadata`) travels into GeoTIFF tags and
Zarr attributes; these are the keys the stages write and read. Code names a key through this
module (``mk.SEED``), never by spelling its string, so a reader finds every writer and reader
of a key with one search, and a misspelt key is an ``AttributeError`` rather than a silently
missing tag.

Examples
--------
>>> from terrain.core import metakeys as mk
>>> mk.SEED
'CRATERSCAPE_SEED'
>>> mk.is_key("CRATERSCAPE_SEED"), mk.is_key("AREA_OR_POINT")
(True, False)
"""

from __future__ import annotations

__all__ = ["KEYS", "PREFIX", "is_key", "version"]

#: Every craterscape tag starts with this; :func:`terrain.io.read_dem` keeps only these tags.
PREFIX = "CRATERSCAPE_"

# --- provenance
#: File a tile was read from (written by :mod:`terrain.io`).
SOURCE = "CRATERSCAPE_SOURCE"
#: Stored dtype of a file whose heights were converted on reading.
SOURCE_DTYPE = "CRATERSCAPE_SOURCE_DTYPE"
#: Datum radius (m) subtracted from absolute radii on reading (SLDEM/LDEM offsets).
DATUM_RADIUS = "CRATERSCAPE_DATUM_RADIUS"
#: The command that wrote an output (e.g. ``"terrain synth"``).
COMMAND = "CRATERSCAPE_COMMAND"
#: The command's parameters (JSON).
PARAMETERS = "CRATERSCAPE_PARAMETERS"
#: The craterscape version that wrote an output.
VERSION = "CRATERSCAPE_VERSION"
#: The seed keying every random draw of the stage that wrote the tile.
SEED = "CRATERSCAPE_SEED"

# --- terrain stages
#: Random midpoint displacement parameters of a synthetic base (JSON).
RMD = "CRATERSCAPE_RMD"
#: The window (``col,row,width,height``) a tile was computed for.
WINDOW = "CRATERSCAPE_WINDOW"
#: The crater population added (JSON, :func:`terrain.craters.cratering.describe_craters`).
CRATERS = "CRATERSCAPE_CRATERS"
#: The crater morphology and erosion model (JSON).
CRATER_MODEL = "CRATERSCAPE_CRATER_MODEL"
#: Relaxation to the angle of repose (JSON, :class:`terrain.surface.repose.Repose`).
REPOSE = "CRATERSCAPE_REPOSE"
#: The terrain preset a DEM was made with (:mod:`terrain.core.presets`).
TERRAIN_PRESET = "CRATERSCAPE_TERRAIN_PRESET"
#: Fractal expansion parameters and level count (JSON).
EXPANSION = "CRATERSCAPE_EXPANSION"
#: Gap filling record (JSON): roughness used and pixels filled.
FILL = "CRATERSCAPE_FILL"
#: Craters rebuilt inside gaps (JSON).
CRATER_GAPS = "CRATERSCAPE_CRATER_GAPS"
#: Despiking record (JSON).
DESPIKE = "CRATERSCAPE_DESPIKE"
#: Denoising record (JSON).
DENOISE = "CRATERSCAPE_DENOISE"
#: Index of a layer in its layer stack (0 is the base).
LAYER = "CRATERSCAPE_LAYER"
#: Marks a tile as layer k of a layer stack read by the evaluation commands.
STACK_LAYER = "CRATERSCAPE_STACK_LAYER"
#: The rock model (JSON).
ROCKS = "CRATERSCAPE_ROCKS"

# --- hazard maps
#: Fraction of known pixels safe for the lander.
SAFE_FRACTION = "CRATERSCAPE_SAFE_FRACTION"
#: Fraction of pixels whose hazard is known.
KNOWN_FRACTION = "CRATERSCAPE_KNOWN_FRACTION"
#: Lander footprint diameter (m).
LANDER_DIAMETER_M = "CRATERSCAPE_LANDER_DIAMETER_M"
#: Largest safe slope (degrees).
MAX_SLOPE_DEG = "CRATERSCAPE_MAX_SLOPE_DEG"
#: Largest safe step (m).
MAX_STEP_M = "CRATERSCAPE_MAX_STEP_M"

# --- evaluation products
#: What a derived raster holds (e.g. ``"Horn slope (degrees)"``).
QUANTITY = "CRATERSCAPE_QUANTITY"
#: Slope histogram bin edges (degrees).
SLOPE_EDGES = "CRATERSCAPE_SLOPE_EDGES"
#: Pixel size (m) of the tile a resampled tile came from.
RESAMPLED_FROM_M = "CRATERSCAPE_RESAMPLED_FROM_M"
#: Hurst exponent of a reference fractional Brownian surface.
HURST = "CRATERSCAPE_HURST"
#: Name of the generator of a reference surface.
GENERATOR = "CRATERSCAPE_GENERATOR"

#: Every registered key: constant name -> tag name.
KEYS: dict[str, str] = {
    name: value for name, value in dict(globals()).items()
    if isinstance(value, str) and value.startswith(PREFIX) and name.isupper() and name != "PREFIX"
}


def is_key(name: str) -> bool:
    """Whether a tag name is a craterscape metadata key (it carries :data:`PREFIX`).

    Parameters
    ----------
    name : str
        A GeoTIFF tag or metadata key.

    Returns
    -------
    bool
        True for ``CRATERSCAPE_*`` names, registered or written by an older version.
    """
    return name.startswith(PREFIX)


def version() -> str:
    """Return the installed craterscape version, recorded under :data:`VERSION` in outputs.

    Returns
    -------
    str
        The package version, or ``"unknown"`` when running from a checkout never installed.
    """
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as package_version

    try:
        return package_version("craterscape")
    except PackageNotFoundError:  # pragma: no cover - running from a bare checkout
        return "unknown"
