"""Draw the crater radial profiles, fresh and degraded (Martin et al. 2014, Fig. 3).

A simple 1 km crater (Martin et al. 2014) and complex craters of 40 km and 250 km (Pike 1977
depth, rim and floor; terraces; central peak and peak ring; :mod:`terrain.craters.crater`).

Run: .venv/bin/python docs/plot_profiles.py  (writes docs/crater_profiles.png and
docs/complex_crater_profiles.png)
"""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from terrain.craters.crater import CraterShape, profile  # noqa: E402
from terrain.craters.erosion import ErosionModel  # noqa: E402

D = 1000.0
AGES = [0.0, 0.25, 0.5, 1.0, 2.0, 4.0]


def main():
    erosion = ErosionModel.default()
    x = np.linspace(-1.0, 1.0, 2001)
    r = (x + 1.0) / 2.0 * D  # radial distance (m)
    fig, ax = plt.subplots(figsize=(8, 4.2), dpi=110)
    for age in AGES:
        qd, qr = erosion.factors(age, D)
        s = CraterShape.from_state(D, float(qd), float(qr))
        style = "--" if age == 0 else "-"
        ax.plot(r, profile(x, s), style, lw=1.6,
                label=f"{age:g} Gyr: H/H0={float(qd):.2f}, Hr/Hr0={float(qr):.2f}")
        if age == 1.0:
            for name, xv in (("alpha", s.alpha), ("beta", s.beta)):
                rv = (xv + 1) / 2 * D
                ax.plot([rv], profile(np.array([xv]), s), "ko", ms=4)
                ax.annotate(name, (rv, profile(np.array([xv]), s)[0]),
                            textcoords="offset points", xytext=(4, 6))
    ax.axhline(0, color="0.6", lw=0.8)
    ax.axvline(D / 2, color="0.8", lw=0.8, ls=":")
    ax.set_xlabel("radial distance r (m); rim at r = D/2, ejecta edge at r = D")
    ax.set_ylabel("height relative to the pre-impact terrain (m)")
    ax.set_title(f"Crater profile, D = {D:g} m, fresh (dashed) and degraded by Ross erosion")
    ax.legend(fontsize=7.5, loc="lower right")
    fig.tight_layout()
    out = Path(__file__).with_name("crater_profiles.png")
    fig.savefig(out)
    print(f"wrote {out}")
    complex_profiles()


def complex_profiles():
    """Complex craters in units of D: 40 km fresh and degraded, 250 km with a peak ring."""
    x = np.linspace(-1.0, 1.0, 4001)
    fig, ax = plt.subplots(figsize=(8, 4.2), dpi=110)
    for d, qd, qr, label in ((40e3, 1.0, 1.0, "40 km, fresh"),
                             (40e3, 0.6, 0.3, "40 km, H/H0 = 0.6, Hr/Hr0 = 0.3"),
                             (250e3, 1.0, 1.0, "250 km, fresh (peak ring)")):
        s = CraterShape.from_state(d, qd, qr)
        ax.plot((x + 1.0) / 2.0, profile(x, s) / 1000.0, lw=1.6, label=label)
    ax.axhline(0, color="0.6", lw=0.8)
    ax.axvline(0.5, color="0.8", lw=0.8, ls=":")
    ax.set_xlabel("radial distance r / D; rim at 0.5, ejecta edge at 1")
    ax.set_ylabel("height relative to the pre-impact terrain (km)")
    ax.set_title("Complex craters: flat floor, terraced wall, central peak or peak ring")
    ax.legend(fontsize=8, loc="lower right")
    fig.tight_layout()
    out = Path(__file__).with_name("complex_crater_profiles.png")
    fig.savefig(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
