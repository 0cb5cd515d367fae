"""The bodies a synthetic DEM can lie on, and the projections it can carry.

A synthetic DEM given a body (``craterscape terrain synth --body moon``) carries a CRS on that
body's reference sphere, so GDAL and QGIS place it and ``--site-lonlat`` works on it. The map
frame stays the synthetic one (metres, lower-left corner at 0, 0); the projection's centre
(a pole, or a site for an orthographic CRS) lies at the tile's centre through the CRS's false
easting and northing, so the heights and every map coordinate are those of the same DEM
without a CRS.
"""

from __future__ import annotations

from terrain.core.checks import text
from terrain.core.errors import InvalidParameterError

__all__ = ["BODY_RADII", "PROJECTIONS", "check_projection"]

#: Mean radii of the bodies synthesis knows (m; IAU WGCCRE 2015, Archinal et al. 2018).
BODY_RADII = {"moon": 1_737_400.0, "mars": 3_389_500.0, "mercury": 2_439_400.0}
#: Projections by name: the south or north pole, or ``ortho:LON,LAT`` (a site, degrees).
PROJECTIONS = ("south-polar", "north-polar", "ortho:LON,LAT")


def check_projection(body: str | None, projection: str | None) -> tuple | None:
    """Return the projection of a synthetic DEM, checked: ``(kind, *numbers)`` or None.

    Parameters
    ----------
    body : str or None
        A key of :data:`BODY_RADII`; None for a local frame without a CRS.
    projection : str or None
        One of :data:`PROJECTIONS` (default: ``"south-polar"`` where a body is given).

    Returns
    -------
    tuple or None
        ``("stere", lat0)`` or ``("ortho", lon, lat)``; None without a body.

    Examples
    --------
    >>> check_projection("moon", None)
    ('stere', -90.0)
    >>> check_projection("moon", "ortho:30,-45")
    ('ortho', 30.0, -45.0)
    """
    if body is None:
        if projection is not None:
            raise InvalidParameterError("--crs needs --body (the sphere the CRS lies on)")
        return None
    text(body, "--body", choices=BODY_RADII)
    projection = projection or "south-polar"
    if projection in ("south-polar", "north-polar"):
        return ("stere", -90.0 if projection == "south-polar" else 90.0)
    if projection.startswith("ortho:"):
        try:
            lon, lat = (float(v) for v in projection[6:].split(","))
        except ValueError:
            lon = lat = float("nan")
        if not (-360.0 <= lon <= 360.0 and -90.0 <= lat <= 90.0):
            raise InvalidParameterError(f"--crs ortho:LON,LAT needs a longitude and a latitude "
                                        f"in degrees, e.g. ortho:0,-85; got {projection!r}")
        return ("ortho", lon, lat)
    raise InvalidParameterError(f"unknown --crs {projection!r}; expected one of "
                                f"{list(PROJECTIONS)}")
