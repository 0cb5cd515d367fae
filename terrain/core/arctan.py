"""The azimuth of a direction, compiled: ``atan2`` by fdlibm's algorithm, in numba.

The crater stamp reads a periodic table at the azimuth of every pixel it changes, tens of
millions of azimuths per tile. The C library's ``atan2`` is a call the compiler cannot see
into; :func:`atan2` here is plain arithmetic that compiles into the caller, so a loop of
azimuths alone vectorises. It is the algorithm of Sun's fdlibm (``e_atan2.c``, ``s_atan.c``,
the reference of FreeBSD's and musl's libraries and Java's ``StrictMath``): ``t = |y / x|``
is folded into [0, 1] (``atan(t) = pi / 2 - atan(1 / t)``) and reduced about c = 0, 1/2 or
1 to ``atan(c) + atan(u)`` with ``|u| <= 7/16``, ``atan(c)`` held in two parts and
``atan(u)`` fdlibm's 11-term odd polynomial (under one unit in the last place). Within two
units in the last place of the C library's value (``tests/terrain/test_arctan.py``); exactly
its value along the axes.

Its values are the same on every machine, whatever the C library, and in a vector lane or
alone (IEEE operations only, no contraction or reassociation).

>>> import math
>>> abs(atan2(1.0, 1.0) - math.pi / 4) < 1e-16
True
>>> atan2(0.0, -2.0) == math.pi
True
"""

from __future__ import annotations

import math

import numba

__all__ = ["atan2"]

# fdlibm s_atan.c: atan(0.5), atan(1), atan(1.5), atan(inf) in high and low parts
_ATAN_HI = (4.63647609000806093515e-01, 7.85398163397448278999e-01,
            9.82793723247329054082e-01, 1.57079632679489655800e+00)
_ATAN_LO = (2.26987774529616870924e-17, 3.06161699786838301793e-17,
            1.39033110312309984516e-17, 6.12323399573676603587e-17)
# fdlibm s_atan.c: atan(t) = t - t^3 (aT0 + t^2 (aT1 + ...)) on |t| <= 7/16
_AT0 = 3.33333333333329318027e-01
_AT1 = -1.99999999998764832476e-01
_AT2 = 1.42857142725034663711e-01
_AT3 = -1.11111104054623557880e-01
_AT4 = 9.09088713343650656196e-02
_AT5 = -7.69187620504482999495e-02
_AT6 = 6.66107313738753120669e-02
_AT7 = -5.83357013379057348645e-02
_AT8 = 4.97687799461593236017e-02
_AT9 = -3.65315727442169155270e-02
_AT10 = 1.62858201153657823623e-02
# fdlibm e_atan2.c: pi and the part of it a double does not hold
_PI = 3.1415926535897931160e+00
_PI_LO = 1.2246467991473531772e-16


@numba.njit(cache=True, inline="always")
def atan2(y, x):
    """Return the azimuth of (x, y) in radians, in [-pi, pi], as the C library's ``atan2``.

    Parameters
    ----------
    y, x : float
        The direction's components (finite; not NaN).

    Returns
    -------
    float, radians
        Within about one unit in the last place of the exact value; exactly ``+-0`` or
        ``+-pi`` along the x axis, ``+-pi / 2`` along the y axis.
    """
    if y == 0.0:
        if x > 0.0 or (x == 0.0 and math.copysign(1.0, x) > 0.0):
            return y  # +-0, as atan2
        return math.copysign(_PI, y)
    ax = abs(x)
    ay = abs(y)
    steep = ay > ax
    # t = |y / x| folded into [0, 1] (atan(t) = pi / 2 - atan(1 / t) above 1)
    t = ax / ay if steep else ay / ax
    # fdlibm's reduction about c = 0, 1/2 or 1: atan(t) = atan(c) + atan(u), |u| <= 7/16;
    # selects rather than branches, so that neighbouring pixels of any azimuth run alike
    if t < 0.4375:  # 7/16
        num, den, hi, lo = t, 1.0, 0.0, 0.0
    elif t < 0.6875:  # 11/16
        num, den, hi, lo = 2.0 * t - 1.0, 2.0 + t, _ATAN_HI[0], _ATAN_LO[0]
    else:
        num, den, hi, lo = t - 1.0, t + 1.0, _ATAN_HI[1], _ATAN_LO[1]
    u = num / den
    z = u * u
    w = z * z
    s1 = z * (_AT0 + w * (_AT2 + w * (_AT4 + w * (_AT6 + w * (_AT8 + w * _AT10)))))
    s2 = w * (_AT1 + w * (_AT3 + w * (_AT5 + w * (_AT7 + w * _AT9))))
    a = hi - ((u * (s1 + s2) - lo) - u)
    if steep:
        a = _ATAN_HI[3] - (a - _ATAN_LO[3])
    if x < 0.0:
        a = _PI - (a - _PI_LO)
    return -a if y < 0.0 else a
