r"""Fresh craters' block fields in a layer stack: where they lie and how many blocks they hold.

A layer stack's rocks are drawn from two parts (:mod:`terrain.surface.rocks`): the background
of the VIPER law everywhere, and the block fields of fresh craters, which hold far more and
larger rocks than the plains around them. Judging every rock against the background law alone
mistakes a young crater's field for a rock excess, so the validation separates them by place
and judges each part against what it was drawn from:

* a field's **footprint** is the disc of ``reach`` crater radii around a crater that has a
  field (the rock model's own definition: no block lies farther out); rocks outside every
  footprint are background only;
* rocks inside the footprints are background plus blocks, and the blocks expected there are
  computed here from the stack's crater catalogue (positions, diameters, ages) and the
  published calibration, written from the papers rather than by calling the generator.

The expected blocks of one crater of diameter Dc and age t, of diameter d and more:

* rock share of the excavated volume ``s = (1 - h / (0.1 Dc))^2`` below a regolith h thick,
  0 where ``0.1 Dc <= h`` (excavation depth 0.1 Dc, Melosh 1989, Impact Cratering, ch. 5;
  Quaide and Oberbeck 1968);
* ``N(>=d) = 12,000 s (d / d_ref)^-4.03`` with ``d_ref = 4.4 m (Dc / 2.2 km)^0.66``: Linne
  (Dc 2.2 km) has 12,000 boulders >= 4.4 m of cumulative index -4.03 (Pajola et al. 2019,
  Planet. Space Sci. 165, 99), and block sizes scale as Dc^0.66 (Bart and Melosh 2010,
  Icarus 209, 337);
* the field runs from the size of which one block is expected (the law less that one block
  above it) down to the size at which the blocks cover ``cover`` of the footprint: the area
  under blocks of d and more is ``(pi / 4) K (-a) / (-a - 2) d^(a + 2)`` for
  ``N(>=d) = K d^a``, so no smaller block is expected;
* survival ``2^(-t / 0.06 Gyr)`` (median boulder survival 40-80 Myr, Basilevsky et al. 2013,
  Planet. Space Sci. 89, 118);
* places: uniform inside the rim and falling as ``r^-3`` out to ``reach`` radii (ejecta
  thickness, McGetchin et al. 1973), so the share inside a layer is the integral of that
  density over the layer's rectangle.

Block counts of a region are Poisson given the catalogue (each crater's blocks are a Poisson
number, thinned by survival and place), so the validation's tolerance is Poisson-aware.

Examples
--------
>>> site = BlockSite(regolith_m=10.0)
>>> linne = FreshCraters.from_columns([0.0], [0.0], [2200.0], [0.0], site)
>>> # Linne's 12,000 blocks >= 4.4 m (Pajola et al. 2019), scaled by its rock share
>>> round(expected_blocks(linne, site, (-5e3, -5e3, 5e3, 5e3), 4.4) / linne.rock_share[0])
11999
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from terrain.core.errors import InvalidParameterError
from terrain.surface.rocks import (
    BLOCK_COUNT,
    BLOCK_COVER,
    BLOCK_HALF_LIFE_GYR,
    BLOCK_INDEX,
    BLOCK_MIN_SURVIVAL,
    BLOCK_REACH,
    BLOCK_SIZE_EXPONENT,
    EXCAVATION_DEPTH,
    LINNE_BLOCK,
    LINNE_DIAMETER,
)

__all__ = ["BlockSite", "FreshCraters", "expected_blocks", "footprint_area", "in_footprints"]

#: Sample points per side of the grid that measures the footprints' area inside a layer
#: (the area's error is about a footprint's perimeter times a sample spacing: under 1 % of a
#: footprint wider than 1/10 of the layer).
FOOTPRINT_SAMPLES = 1024
#: Quadrature points in radius and angle of a field's spatial density.
_QUADRATURE = 256


@dataclass(frozen=True)
class BlockSite:
    """The site and geometry of the block fields a stack was built with.

    Parameters
    ----------
    regolith_m : float
        Regolith thickness (m): craters excavate rock below it.
    reach : float
        Footprint radius, crater radii (>= 1).
    cover : float
        Largest share of a footprint the blocks cover (sets the smallest block), 0 < cover < 1.
    enabled : bool
        Whether the stack's rock model drew block fields at all.
    """

    regolith_m: float
    reach: float = BLOCK_REACH
    cover: float = BLOCK_COVER
    enabled: bool = True

    def __post_init__(self):
        for name in ("regolith_m", "reach", "cover"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float, np.number)) \
                    or not math.isfinite(float(v)) or float(v) <= 0:
                raise InvalidParameterError(f"block field {name} must be a positive number; "
                                            f"got {v!r}")
            object.__setattr__(self, name, float(v))
        if self.reach < 1 or self.cover >= 1:
            raise InvalidParameterError(f"block field reach must be >= 1 and cover < 1; got "
                                        f"reach {self.reach:g}, cover {self.cover:g}")

    @classmethod
    def of_stack(cls, stack, regolith_m: float) -> BlockSite:
        """Read the site from the rock model a stack recorded (``info["rocks"]``).

        ``regolith_m`` (the terrain preset's) is used where the stack recorded none.
        """
        rec = (getattr(stack, "info", None) or {}).get("rocks") or {}
        return cls(regolith_m=float(rec.get("regolith_m", regolith_m)),
                   reach=float(rec.get("reach", BLOCK_REACH)),
                   cover=float(rec.get("block_cover", BLOCK_COVER)),
                   enabled=bool(rec.get("craters", True)))


@dataclass(frozen=True, eq=False)
class FreshCraters:
    """The craters of a catalogue that have a block field, with their field's law.

    ``N(>=d) = law_k d^BLOCK_INDEX`` fresh, between ``smallest`` and ``largest`` (m), times
    ``survival``; every array is (n,) float64.
    """

    x: np.ndarray
    y: np.ndarray
    diameter: np.ndarray
    survival: np.ndarray
    rock_share: np.ndarray
    law_k: np.ndarray
    smallest: np.ndarray
    largest: np.ndarray

    def __len__(self) -> int:
        return len(self.x)

    @classmethod
    def from_columns(cls, x, y, diameter, age_gyr, site: BlockSite) -> FreshCraters:
        """Keep the craters that have a field (module docstring) and give each its law."""
        x, y, dc, age = (np.atleast_1d(np.asarray(v, dtype=np.float64)) for v in
                         (x, y, diameter, age_gyr))
        depth = EXCAVATION_DEPTH * dc  # Melosh 1989, ch. 5
        share = np.where(depth > site.regolith_m,
                         (1.0 - site.regolith_m / np.maximum(depth, 1e-300)) ** 2, 0.0)
        survival = 2.0 ** (-np.maximum(age, 0.0) / BLOCK_HALF_LIFE_GYR)  # Basilevsky et al. 2013
        # Pajola et al. 2019 (Linne) with sizes as Dc^0.66 (Bart and Melosh 2010)
        d_ref = LINNE_BLOCK * (dc / LINNE_DIAMETER) ** BLOCK_SIZE_EXPONENT
        k = BLOCK_COUNT * share * d_ref ** -BLOCK_INDEX
        a = BLOCK_INDEX
        with np.errstate(divide="ignore", invalid="ignore"):
            largest = (1.0 / k) ** (1.0 / a)  # one block expected
            footprint = math.pi / 4 * (site.reach * dc) ** 2
            smallest = (site.cover * footprint * (-a - 2) / (math.pi / 4 * k * -a)) \
                ** (1.0 / (a + 2))
        keep = (share > 0) & (survival >= BLOCK_MIN_SURVIVAL) & (smallest < largest)
        if not site.enabled:
            keep[:] = False
        return cls(x[keep], y[keep], dc[keep], survival[keep], share[keep], k[keep],
                   smallest[keep], largest[keep])

    @classmethod
    def of_catalog(cls, catalog, site: BlockSite) -> FreshCraters:
        """Return a catalogue's fresh craters (``x_m``, ``y_m``, ``diameter_m``, ``age_gyr``)."""
        return cls.from_columns(catalog.x_m, catalog.y_m, catalog.diameter_m, catalog.age_gyr,
                                site)

    def touching(self, extent, site: BlockSite) -> FreshCraters:
        """Return the craters whose footprint reaches into ``extent`` (xmin, ymin, xmax, ymax)."""
        xmin, ymin, xmax, ymax = extent
        gx = np.maximum(np.maximum(xmin - self.x, 0.0), self.x - xmax)
        gy = np.maximum(np.maximum(ymin - self.y, 0.0), self.y - ymax)
        i = np.flatnonzero(np.hypot(gx, gy) < site.reach * self.diameter / 2)
        return FreshCraters(*(getattr(self, f)[i] for f in (
            "x", "y", "diameter", "survival", "rock_share", "law_k", "smallest", "largest")))

    def fresh_count(self, d: float) -> np.ndarray:
        """Blocks of d (m) and more each field holds before its age thins it."""
        dd = np.maximum(float(d), self.smallest)
        return np.where(dd <= self.largest, self.law_k * dd ** BLOCK_INDEX - 1.0, 0.0)


def in_footprints(craters: FreshCraters, site: BlockSite, x, y) -> np.ndarray:
    """Whether each point (map metres) lies inside a fresh crater's footprint, (n,) bool."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    out = np.zeros(x.shape, dtype=bool)
    for cx, cy, dc in zip(craters.x, craters.y, craters.diameter, strict=True):
        out |= np.hypot(x - cx, y - cy) < site.reach * dc / 2
    return out


def footprint_area(craters: FreshCraters, site: BlockSite, extent,
                   samples: int = FOOTPRINT_SAMPLES) -> float:
    """Area (m^2) of ``extent`` inside the union of the footprints (overlaps counted once).

    Measured on a ``samples`` x ``samples`` grid of points over the extent.

    >>> site = BlockSite(regolith_m=1.0)
    >>> one = FreshCraters.from_columns([0.0], [0.0], [100.0], [0.0], site)
    >>> round(footprint_area(one, site, (-200, -200, 200, 200)) / (math.pi * 100.0**2), 2)
    1.0
    """
    xmin, ymin, xmax, ymax = (float(v) for v in extent)
    area = (xmax - xmin) * (ymax - ymin)
    near = craters.touching(extent, site)
    if not len(near) or area <= 0:
        return 0.0
    u = (np.arange(samples) + 0.5) / samples
    gx, gy = np.meshgrid(xmin + u * (xmax - xmin), ymin + u * (ymax - ymin))
    return float(np.mean(in_footprints(near, site, gx, gy))) * area


def _share_inside(cx: float, cy: float, dc: float, reach: float, extent) -> float:
    """Share of one field's blocks centred in ``extent``: uniform inside the rim, r^-3 beyond."""
    xmin, ymin, xmax, ymax = extent
    rad = 0.5 * dc
    # P(r' < r) = (r / R)^2 w inside the rim, w (1 + 2 (1 - R / r)) beyond, w = 1 / (3 - 2 / reach)
    w = 1.0 / (3.0 - 2.0 / reach)
    p = (np.arange(_QUADRATURE) + 0.5) / _QUADRATURE
    r = np.where(p < w, rad * np.sqrt(p / w), rad / (1.0 - (p - w) / (2.0 * w)))
    th = 2.0 * math.pi * (np.arange(_QUADRATURE) + 0.5) / _QUADRATURE
    x = cx + r[:, None] * np.cos(th)
    y = cy + r[:, None] * np.sin(th)
    return float(np.mean((x >= xmin) & (x <= xmax) & (y >= ymin) & (y <= ymax)))


def expected_blocks(craters: FreshCraters, site: BlockSite, extent, d: float) -> float:
    """Blocks of diameter d (m) and more expected centred in ``extent``, over every field.

    Each crater's surviving blocks of d and more times the share of its field inside the
    extent (module docstring).
    """
    near = craters.touching(extent, site)
    n = near.fresh_count(d) * near.survival
    return float(sum(float(n[i]) * _share_inside(near.x[i], near.y[i], near.diameter[i],
                                                 site.reach, extent)
                     for i in np.flatnonzero(n > 0)))
