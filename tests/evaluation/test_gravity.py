"""Polyhedron gravity against the analytic fields of a sphere and of a homogeneous cube."""

import math

import numpy as np
import pytest
import trimesh

from evaluation.gravity import (
    _CUBE_FACES,
    GRAVITATIONAL_CONSTANT,
    LANES,
    Polyhedron,
    centrifugal,
    closed_chain,
    coarsen,
    signed_volume,
)
from terrain.core.errors import InvalidParameterError

G = GRAVITATIONAL_CONSTANT
RHO = 2000.0


def prism_attraction(point, lo, hi, density):
    """Closed-form attraction of a homogeneous rectangular prism (Nagy et al. 2000, J. Geod.
    74, 552, eqs. for the first derivatives): with x, y, z the prism corners relative to the
    point, g_x = -G rho sum_corners s [y ln(z + r) + z ln(y + r) - x atan(y z / (x r))],
    s = +1 at the upper and -1 at the lower limit of each axis; g_y, g_z by cycling axes."""
    p = np.asarray(point, float)
    lim = [(lo[k] - p[k], hi[k] - p[k]) for k in range(3)]
    g = np.zeros(3)
    for axis in range(3):
        a, b, c = axis, (axis + 1) % 3, (axis + 2) % 3
        total = 0.0
        for i, x in enumerate(lim[a]):
            for j, y in enumerate(lim[b]):
                for k, z in enumerate(lim[c]):
                    s = (1 if i else -1) * (1 if j else -1) * (1 if k else -1)
                    r = math.sqrt(x * x + y * y + z * z)
                    term = y * math.log(z + r) + z * math.log(y + r)
                    if x != 0:
                        term -= x * math.atan(y * z / (x * r))
                    total += s * term
        g[a] = -G * density * total
    return g


def gauss_legendre_attraction(point, lo, hi, density, n=40):
    """The same integral by n^3-point Gauss-Legendre quadrature (points outside the prism)."""
    x, w = np.polynomial.legendre.leggauss(n)
    axes = [0.5 * (hi[k] - lo[k]) * x + 0.5 * (hi[k] + lo[k]) for k in range(3)]
    weights = [0.5 * (hi[k] - lo[k]) * w for k in range(3)]
    qx, qy, qz = np.meshgrid(*axes, indexing="ij")
    ww = np.einsum("i,j,k->ijk", *weights)
    d = np.stack([qx, qy, qz], -1) - np.asarray(point, float)
    r3 = np.linalg.norm(d, axis=-1) ** 3
    return G * density * np.einsum("ijk,ijkl->l", ww / r3, d)


def cube(side=2.0):
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], float) - 0.5
    return v * side, _CUBE_FACES.copy()


def test_the_closed_form_reference_agrees_with_quadrature():
    lo, hi = (-1.0, -1.0, -1.0), (1.0, 1.0, 1.0)
    for p in [(0.3, 2.5, -0.4), (3.0, 2.0, 1.0), (0.0, 0.0, 1.8)]:
        exact = prism_attraction(p, lo, hi, RHO)
        quad = gauss_legendre_attraction(p, lo, hi, RHO)
        assert np.linalg.norm(exact - quad) < 1e-9 * np.linalg.norm(exact)


def test_cube_field_matches_the_closed_form_inside_on_and_outside():
    v, f = cube(2.0)
    body = Polyhedron.build(v, f, RHO)
    rng = np.random.default_rng(1)
    points = np.concatenate([
        rng.uniform(-0.95, 0.95, (20, 3)),          # inside
        rng.uniform(-3.0, 3.0, (40, 3)),            # anywhere around
        [[1.0, 0.2, 0.3], [0.4, -1.0, 0.1]],        # on faces
        [[5.0, 0.0, 0.0], [0.0, 0.0, -30.0]],       # far
    ])
    _, g = body.field(points)
    expected = np.array([prism_attraction(p, (-1, -1, -1), (1, 1, 1), RHO) for p in points])
    scale = G * RHO * 2.0  # about the surface field of the cube
    assert np.max(np.linalg.norm(g - expected, axis=1)) < 1e-9 * scale


def test_a_points_field_does_not_depend_on_the_points_computed_with_it():
    """The kernel carries points in blocks of lanes: a point alone, in any block, in any
    position and with any company (the last block padded) gets the same bits."""
    v, f = cube(2.0)
    body = Polyhedron.build(v, f, RHO)
    rng = np.random.default_rng(7)
    points = np.concatenate([rng.uniform(-3.0, 3.0, (2 * LANES + 5, 3)),
                             [[1.0, 0.2, 0.3], [1.0, 1.0, 0.0]]])  # on a face, on an edge
    u, g = body.field(points)
    for k in range(len(points)):
        uk, gk = body.field(points[k:k + 1])
        assert uk[0] == u[k] and np.array_equal(gk[0], g[k])
    order = rng.permutation(len(points))
    u2, g2 = body.field(points[order])
    assert np.array_equal(u2, u[order]) and np.array_equal(g2, g[order])
    assert np.all(np.isfinite(g))


def test_sphere_field_is_a_point_mass_outside_and_linear_inside():
    radius = 1000.0
    m = trimesh.creation.icosphere(subdivisions=5, radius=radius)  # 20,480 triangles
    body = Polyhedron.build(m.vertices, m.faces, RHO)
    assert body.volume == pytest.approx(4 / 3 * math.pi * radius**3, rel=2e-3)
    outside = np.array([[0, 0, 3000.0], [2000.0, 1000.0, 500.0], [-1500.0, 0, 0]])
    u, g = body.field(outside)
    r = np.linalg.norm(outside, axis=1)
    gm = G * body.mass
    point_mass = -gm * outside / r[:, None] ** 3
    assert np.all(np.linalg.norm(g - point_mass, axis=1) < 1e-6 * gm / r**2)
    assert np.allclose(u, gm / r, rtol=1e-6)
    inside = np.array([[0.0, 0.0, 0.0], [300.0, 200.0, 100.0], [0.0, 0.0, 600.0]])
    _, g = body.field(inside)
    # uniform sphere: g = -(4/3) pi G rho r; the polyhedron is within 0.1 % of it here
    expected = -4.0 / 3.0 * math.pi * G * RHO * inside
    assert np.max(np.linalg.norm(g - expected, axis=1)) < 1e-3 * 4 / 3 * math.pi * G * RHO \
        * 600.0


def test_laplacian_is_poissons_inside_and_zero_outside():
    v, f = cube(2.0)
    body = Polyhedron.build(v, f, RHO)
    h = 1e-3

    def laplacian(p):
        p = np.asarray(p, float)
        u0 = body.field(p[None])[0][0]
        total = 0.0
        for k in range(3):
            e = np.zeros(3)
            e[k] = h
            up = body.field((p + e)[None])[0][0]
            um = body.field((p - e)[None])[0][0]
            total += (up - 2 * u0 + um) / h**2
        return total

    assert laplacian([0.2, -0.3, 0.1]) == pytest.approx(-4 * math.pi * G * RHO, rel=1e-4)
    assert abs(laplacian([2.5, 0.3, -0.7])) < 1e-4 * 4 * math.pi * G * RHO


def test_open_or_inward_surfaces_are_refused():
    v, f = cube()
    with pytest.raises(InvalidParameterError, match="not closed"):
        Polyhedron.build(v, f[:-1], RHO)
    with pytest.raises(InvalidParameterError, match="wound inwards"):
        Polyhedron.build(v, f[:, ::-1], RHO)
    with pytest.raises(InvalidParameterError, match="density"):
        Polyhedron.build(v, f, -1.0)


def test_coarsening_keeps_a_closed_surface_and_its_field():
    m = trimesh.creation.icosphere(subdivisions=5, radius=1000.0)
    v = np.asarray(m.vertices) * [2.0, 1.0, 0.8]  # an ellipsoid
    f = np.asarray(m.faces)
    cv, cf = coarsen(v, f, 1500)
    assert closed_chain(cf)
    assert 0.75 * 1500 <= len(cf) <= 1.3 * 1500
    fine_volume = signed_volume(v, f)
    assert signed_volume(cv, cf) == pytest.approx(fine_volume, rel=0.03)
    fine = Polyhedron.build(v, f, RHO)
    coarse = Polyhedron.build(cv, cf, RHO * fine_volume / signed_volume(cv, cf))
    points = v[::97] * 1.001  # on the surface
    _, gf = fine.field(points)
    _, gc = coarse.field(points)
    cosang = np.einsum("ij,ij->i", gf, gc) / (np.linalg.norm(gf, axis=1)
                                             * np.linalg.norm(gc, axis=1))
    angle = np.degrees(np.arccos(np.clip(cosang, -1, 1)))
    assert np.median(angle) < 0.5 and angle.max() < 1.5
    with pytest.raises(InvalidParameterError, match="target faces"):
        coarsen(v, f, 10)


def test_centrifugal_term():
    a = centrifugal([[3.0, 4.0, 7.0], [0.0, 0.0, 5.0]], rate=2.0)
    assert np.allclose(a, [[12.0, 16.0, 0.0], [0.0, 0.0, 0.0]])
    b = centrifugal([[0.0, 0.0, 2.0]], rate=1.0, axis=(1, 0, 0), centre=(0, 1, 0))
    assert np.allclose(b, [[0.0, -1.0, 2.0]])
