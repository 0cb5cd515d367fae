r"""Boulder populations as measured on visited asteroids.

Each preset is a cumulative power law ``N(>= D) = n_ref (D / d_ref)^k`` per km^2, written as
the recipe's ``c`` (``N_cum = c D^k`` per m^2, D in metres) so that any ``dmin`` can be asked
for, and block shapes near the measured mean axis ratios a : b : c = 2 : 1.4 : 1 (Michikami
et al. 2010, Icarus 207, Itokawa's and Eros's boulders; Michikami et al. 2019 find the same
on Ryugu). With :class:`asteroid.boulders.BoulderSettings`' axes
``(sqrt(e), 1 / sqrt(e), f)`` that ratio is ``e = a / b = 1.43`` and
``f = c / sqrt(a b) = 0.60``; the ranges below are centred on them.

=========  =======  ==========================  ==========================================
body       k        n_ref per km^2 (D >= d_ref)  source
=========  =======  ==========================  ==========================================
Ryugu      -2.65    1600 (5 m)                  Michikami et al. 2019, Icarus 331
Bennu      -2.9     260 (10 m)                  DellaGiustina et al. 2019 (index); Walsh
                                                et al. 2019 (>200 boulders >= 10 m on
                                                0.78 km^2)
Itokawa    -3.1     950 (5 m)                   Michikami et al. 2008, EPS 60 (-3.05..-3.1)
Eros       -3.25    6 (15 m)                    Thomas et al. 2001, Nature 413
=========  =======  ==========================  ==========================================

Use them as ``--boulders ryugu`` (more keys may follow: ``--boulders ryugu,dmin=2``).

>>> round(BOULDER_PRESETS["ryugu"]["c"] * 5.0 ** -2.65 * 1e6)
1600
"""

from __future__ import annotations

__all__ = ["BOULDER_PRESETS", "MEASURED"]

#: Measured populations: (cumulative index k, boulders per km^2 at or above d_ref, d_ref m).
MEASURED = {
    "ryugu": (-2.65, 1600.0, 5.0),
    "bennu": (-2.9, 260.0, 10.0),
    "itokawa": (-3.1, 950.0, 5.0),
    "eros": (-3.25, 6.0, 15.0),
}

#: Block shapes near 2 : 1.4 : 1 (elongation a / b, flattening c / sqrt(a b)).
MEASURED_SHAPES = dict(elongation=[1.2, 1.7], flattening=[0.45, 0.75])


def _preset(k: float, n_ref: float, d_ref: float) -> dict:
    return dict(k=k, c=n_ref * 1e-6 * d_ref ** (-k), dmin=d_ref, **MEASURED_SHAPES)


#: Recipe ``[boulders]`` tables of the measured populations.
BOULDER_PRESETS = {name: _preset(*values) for name, values in MEASURED.items()}
