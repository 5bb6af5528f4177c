"""Tests of implicit_contact.shapes: derivatives, geometry, boxes, mass, serialisation, errors.

Oracles: central finite differences, closed-form points on the surfaces, scipy's SLSQP for
support values, Monte Carlo integration for mass properties.
"""
import json
import math

import numpy as np
import pytest
from scipy.optimize import minimize
from scipy.spatial.transform import Rotation

from implicit_contact import shapes as S

FD_STEP = 1e-5           # central-difference step relative to the shape's length scale
RTOL_FD = 2e-6           # central differences with step 1e-5: O(h^2 f''') + O(eps |f| / h)
ATOL_PSD = 1e-10         # smallest Hessian eigenvalue allowed, relative to |H|
ATOL_SURFACE = 1e-12     # |f| on analytically known surface points (length units ~ 1)
ATOL_AABB = 1e-9         # slack of "sample inside AABB" and tightness of closed-form boxes
RTOL_SUPPORT = 1e-6      # AABB vs SLSQP support value (SLSQP ftol 1e-12)
MC_SAMPLES = 400_000     # Monte Carlo mass properties; tolerance = 5 standard errors
MC_SIGMAS = 5.0
ATOL_MC_MOMENT = 5e-3    # com [L] by Monte Carlo: ~5 standard errors at 4e5 samples
RTOL_MC_COVARIANCE = 2e-2   # second moments by Monte Carlo: ~4 standard errors at 4e5 samples
                            # when only 1/6 of them fall inside (tetrahedron in its box)
RTOL_BATCH = 1e-13       # batched vs single-point evaluation: rounding of matrix products only

RNG_SEED = 20240611


def rot(seed):
    return Rotation.random(random_state=seed).as_matrix()


def shapes_3d():
    R1, R2, R3 = rot(1), rot(2), rot(3)
    return {
        "sphere": S.Sphere(0.7, center=[0.1, -0.2, 0.3]),
        "ellipsoid": S.Ellipsoid([1.0, 0.5, 0.3], center=[0.2, 0.0, -0.1], rotation=R1),
        "superquadric4": S.Superquadric([0.6, 0.9, 0.4], 4.0, rotation=R2),
        "superquadric_barr": S.Superquadric([0.6, 0.9, 0.4], [3.0, 5.0], center=[0.0, 0.3, 0.0], rotation=R3),
        "superquadric_barr_p2": S.Superquadric([0.5, 0.7, 0.9], [4.0, 2.0]),
        "superquadric2.5": S.Superquadric([0.5, 0.7, 0.9], 2.5, rotation=R1),
        "halfspace": S.HalfSpace([0.3, -0.2, 1.0], 0.4, rotation=R2),
        "cylinder": S.InfiniteCylinder(0.4, center=[0.1, 0.0, 0.0], rotation=R3),
    }


def shapes_2d():
    return {
        "disc": S.Disc(0.8, center=[0.3, -0.1]),
        "ellipse": S.Ellipse([1.2, 0.4], center=[0.0, 0.2], rotation=0.7),
        "superellipse": S.Superellipse([2.3, 1.1], 4.0, rotation=-0.3),
        "superellipse3": S.Superellipse([0.5, 0.9], 3.0),
        "halfplane": S.HalfPlane([1.0, 2.0], -0.5, rotation=0.2),
    }


ALL_FUNCTIONS = {**shapes_3d(), **shapes_2d()}


def sample_points(shape, rng, n=12):
    """Points near the surface (inside and outside), on it, and far away; never the centre."""
    dim = shape.dim
    c = shape.interior_point
    scale = shape.length_scale if math.isfinite(shape.length_scale) else 1.0
    out = []
    for _ in range(n):
        u = rng.normal(size=dim)
        tau = shape.ray_exit(c, u)
        if not math.isfinite(tau):
            tau = scale
        for factor in (0.7, 0.97, 1.0, 1.03, 2.5):
            out.append(c + factor * tau * u)
    return np.array(out)


def fd_gradient(f, x, h):
    g = np.zeros_like(x)
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = h
        g[i] = (f(x + e) - f(x - e)) / (2 * h)
    return g


def fd_jacobian(g, x, h):
    J = np.zeros((x.size, x.size))
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = h
        J[:, i] = (g(x + e) - g(x - e)) / (2 * h)
    return J


# --------------------------------------------------------------------------------------------
# derivatives
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(ALL_FUNCTIONS))
def test_gradient_and_hessian_match_central_differences(name):
    shape = ALL_FUNCTIONS[name]
    rng = np.random.default_rng(RNG_SEED)
    scale = shape.length_scale if math.isfinite(shape.length_scale) else 1.0
    h = FD_STEP * scale
    X = sample_points(shape, rng)
    for x in X:
        g = shape.gradient(x)
        H = shape.hessian(x)
        g_fd = fd_gradient(shape.value, x, h)
        H_fd = fd_jacobian(shape.gradient, x, h)
        assert np.allclose(g, g_fd, rtol=RTOL_FD, atol=RTOL_FD * max(1.0, abs(shape.value(x)))), (name, x)
        assert np.allclose(H, H_fd, rtol=RTOL_FD, atol=RTOL_FD * max(1.0, np.abs(g).max()) / scale), (name, x)
        assert np.allclose(H, H.T, atol=0.0)


@pytest.mark.parametrize("name", sorted(ALL_FUNCTIONS))
def test_vectorised_evaluation_matches_single_points(name):
    shape = ALL_FUNCTIONS[name]
    X = sample_points(shape, np.random.default_rng(RNG_SEED + 1), n=4).reshape(4, 5, shape.dim)
    v, g, H = shape.value(X), shape.gradient(X), shape.hessian(X)
    assert v.shape == (4, 5) and g.shape == (4, 5, shape.dim) and H.shape == (4, 5, shape.dim, shape.dim)
    v1, g1, H1 = shape.value_gradient_hessian(X[2, 3])
    assert isinstance(shape.value(X[2, 3]), float)
    # batched and single matrix products may round differently (BLAS): a few ulps
    assert v1 == pytest.approx(v[2, 3], rel=RTOL_BATCH, abs=RTOL_BATCH)
    assert np.allclose(g1, g[2, 3], rtol=RTOL_BATCH, atol=RTOL_BATCH)
    assert np.allclose(H1, H[2, 3], rtol=RTOL_BATCH, atol=RTOL_BATCH)


@pytest.mark.parametrize("name", sorted(ALL_FUNCTIONS))
def test_hessian_is_positive_semidefinite(name):
    shape = ALL_FUNCTIONS[name]
    X = sample_points(shape, np.random.default_rng(RNG_SEED + 2))
    for H in shape.hessian(X):
        lam = np.linalg.eigvalsh(H)
        assert lam.min() >= -ATOL_PSD * max(1.0, np.abs(lam).max())


def test_superquadric_is_c2_on_its_axes():
    # Barr form with n1 > 2: on the z axis (x = y = 0) the Hessian tends to its value there.
    sq = S.Superquadric([0.6, 0.9, 0.4], [3.0, 5.0])
    on_axis = np.array([0.0, 0.0, 0.3])
    H0 = sq.hessian(on_axis)
    for eps in (1e-4, 1e-6, 1e-8):
        for d in (np.array([1.0, 0.0, 0.0]), np.array([0.6, 0.8, 0.0]), np.array([-0.3, 0.2, 0.0])):
            assert np.allclose(sq.hessian(on_axis + eps * d), H0, atol=10 * eps ** 0.5)
    # n2 = 2 with n1 = 4: w^4 with w the Euclidean norm is C^2 too; the value at the axis is finite
    sq2 = S.Superquadric([0.5, 0.7, 0.9], [4.0, 2.0])
    assert np.all(np.isfinite(sq2.hessian([0.0, 0.0, 0.1])))
    assert np.allclose(sq2.hessian([1e-7, 0.0, 0.1])[:2, :2], sq2.hessian([0.0, 0.0, 0.1])[:2, :2], atol=1e-10)


def test_intersection_value_and_derivatives_are_the_active_members():
    box = S.Intersection.box([1.0, 2.0, 3.0], rotation=rot(4))
    cyl = S.Intersection.capped_cylinder(0.5, 1.0, center=[0.0, 0.0, 0.2], rotation=rot(5))
    mixed = S.Intersection([S.Ellipsoid([1.0, 1.0, 2.0]), S.HalfSpace([0.0, 0.0, 1.0], 0.5)])
    rng = np.random.default_rng(RNG_SEED + 3)
    for inter in (box, cyl, mixed):
        X = rng.normal(size=(50, 3)) * 2.0
        vals = np.array([[f.value(x) for f in inter.functions] for x in X])
        assert np.allclose(inter.value(X), vals.max(axis=1), atol=0.0)
        for x, row in zip(X, vals):
            k = int(np.argmax(row))
            assert np.array_equal(inter.gradient(x), inter.functions[k].gradient(x))
            assert np.array_equal(inter.hessian(x), inter.functions[k].hessian(x))


# --------------------------------------------------------------------------------------------
# inside / on / outside, normalisation
# --------------------------------------------------------------------------------------------
def test_known_points_inside_on_outside_3d():
    sph = S.Sphere(2.0, center=[1.0, 0.0, 0.0])
    assert sph.value([1.0, 0.0, 0.0]) == pytest.approx(-1.0)           # -r/2 at the centre
    assert abs(sph.value([3.0, 0.0, 0.0])) <= ATOL_SURFACE
    assert sph.value([3.5, 0.0, 0.0]) > 0
    assert np.linalg.norm(sph.gradient([1.0, 2.0, 0.0])) == pytest.approx(1.0, abs=1e-15)

    ell = S.Ellipsoid([1.0, 2.0, 4.0])
    s = 2.0                                                           # (1 * 2 * 4)^(1/3)
    for k, a in enumerate([1.0, 2.0, 4.0]):
        tip = np.eye(3)[k] * a
        assert abs(ell.value(tip)) <= ATOL_SURFACE
        assert np.linalg.norm(ell.gradient(tip)) == pytest.approx(s / a, rel=1e-14)
    assert ell.value([0.0, 0.0, 0.0]) < 0 and ell.value([0.9, 1.9, 0.0]) > 0

    n = 4.0
    sq = S.Superquadric([1.0, 2.0, 3.0], n)
    corner = np.array([1.0, 2.0, 3.0]) * 3.0 ** (-1.0 / n)            # on the surface
    assert abs(sq.value(corner)) <= ATOL_SURFACE
    assert sq.value(0.999 * corner) < 0 < sq.value(1.001 * corner)
    barr = S.Superquadric([1.0, 2.0, 3.0], [3.0, 5.0])
    p = np.array([2.0 ** (-1 / 5), 2.0 ** (-1 / 5) * 2.0, 0.0])       # |X|^5 + |Y|^5 = 1, Z = 0
    assert abs(barr.value(p)) <= ATOL_SURFACE
    assert abs(barr.value([0.0, 0.0, 3.0])) <= ATOL_SURFACE

    hs = S.HalfSpace([0.0, 0.0, 2.0], 1.0)                            # z <= 0.5
    assert hs.value([5.0, -3.0, 1.5]) == pytest.approx(1.0)          # exact signed distance
    assert hs.value([0.0, 0.0, 0.5]) == 0.0
    cyl = S.InfiniteCylinder(0.5, rotation=Rotation.from_euler("x", 90, degrees=True).as_matrix())
    assert abs(cyl.value([0.5, 100.0, 0.0])) <= ATOL_SURFACE          # axis is body y now
    assert cyl.value([0.0, -50.0, 0.4]) < 0 < cyl.value([0.0, 0.0, 0.6])

    box = S.Intersection.box([1.0, 2.0, 3.0], center=[1.0, 1.0, 1.0])
    assert abs(box.value([2.0, 3.0, 4.0])) <= ATOL_SURFACE
    assert box.value([1.0, 1.0, 1.0]) == pytest.approx(-1.0)
    assert box.value([2.5, 1.0, 1.0]) == pytest.approx(0.5)
    cc = S.Intersection.capped_cylinder(1.0, 2.0)
    assert abs(cc.value([1.0, 0.0, 2.0])) <= ATOL_SURFACE and cc.value([0.0, 0.0, 2.1]) > 0


def test_known_points_inside_on_outside_2d():
    disc = S.Disc(1.5, center=[0.0, 1.0])
    assert abs(disc.value([1.5, 1.0])) <= ATOL_SURFACE and disc.value([0.0, 1.0]) == pytest.approx(-0.75)
    ell = S.Ellipse([2.0, 1.0], rotation=math.pi / 2)                 # long axis along y now
    assert abs(ell.value([0.0, 2.0])) <= ATOL_SURFACE and ell.value([1.5, 0.0]) > 0
    se = S.Superellipse([2.3, 1.1], 4.0)
    assert abs(se.value(np.array([2.3, 1.1]) * 2.0 ** -0.25)) <= ATOL_SURFACE
    hp = S.HalfPlane([0.0, 1.0], 0.0)
    assert hp.value([3.0, -2.0]) == -2.0
    rect = S.Intersection.rectangle([1.0, 0.5], center=[1.0, 0.0], rotation=math.pi / 2)
    assert abs(rect.value([1.5, 1.0])) <= ATOL_SURFACE and rect.value([2.0, 0.0]) > 0
    # [GI] eqs 58-59: right gripper {y <= 0, x >= q4}
    q4 = 13.7
    tip = S.Intersection.fingertip([q4, 0.0], [0.0, 1.0], [-1.0, 0.0])
    assert tip.value([q4, 0.0]) == 0.0
    assert tip.value([q4 + 1.0, -1.0]) < 0 and tip.value([q4 - 0.1, -1.0]) > 0 and tip.value([q4 + 1, 0.1]) > 0
    assert not tip.bounded


def test_union_is_inside_when_inside_any_part():
    # [GI] eqs 56-57: the gear is a disc and teeth on its rim (one tooth here).
    R = 20.75
    th = 4.103727
    tooth = S.Superellipse([2.3, 1.1], 4.0, center=[R * math.cos(th), R * math.sin(th)], rotation=th)
    gear = S.Union([S.Disc(R), tooth])
    tip = np.array([(R + 2.3) * math.cos(th), (R + 2.3) * math.sin(th)])
    assert abs(gear.value(tip)) <= 1e-9
    assert gear.value(0.99 * tip) < 0 < gear.value(1.01 * tip)
    assert gear.value([0.0, 0.0]) < 0
    lo, hi = gear.aabb(np.eye(2), np.zeros(2))
    assert np.all(lo <= tip) and np.all(tip <= hi)
    assert gear.bounded and len(gear.parts) == 2


# --------------------------------------------------------------------------------------------
# ray exits, boundedness, interior points
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(ALL_FUNCTIONS))
def test_ray_exit_lands_on_the_surface(name):
    shape = ALL_FUNCTIONS[name]
    rng = np.random.default_rng(RNG_SEED + 4)
    c = shape.interior_point
    assert shape.value(c) < 0
    for _ in range(10):
        u = rng.normal(size=shape.dim)
        tau = shape.ray_exit(c, u)
        if math.isfinite(tau):
            assert abs(shape.value(c + tau * u)) <= 1e-12 * max(1.0, np.linalg.norm(u) * tau)


def test_ray_exit_from_off_centre_origin_superquadric():
    sq = S.Superquadric([0.6, 0.9, 0.4], [3.0, 5.0], rotation=rot(7))
    o = np.array([0.1, -0.2, 0.05])
    assert sq.value(o) < 0
    for u in np.random.default_rng(3).normal(size=(10, 3)):
        tau = sq.ray_exit(o, u)
        assert abs(sq.value(o + tau * u)) <= 1e-12


def test_boundedness_and_interior_points():
    assert S.Intersection.box([1, 1, 1]).bounded
    assert S.Intersection.capped_cylinder(1, 1).bounded
    assert S.Intersection([S.HalfSpace([0, 0, 1], 0), S.Sphere(1.0, center=[0, 0, 0.5])]).bounded
    assert not S.Intersection([S.HalfSpace([0, 0, 1], 0), S.HalfSpace([0, 1, 0], 0)]).bounded
    assert not S.Intersection([S.InfiniteCylinder(1.0), S.HalfSpace([0, 0, 1], 0)]).bounded
    # a hand-built capped cylinder (cylinder along x, caps x = +-2) is recognised
    Rx = Rotation.from_euler("y", 90, degrees=True).as_matrix()
    cc = S.Intersection([S.InfiniteCylinder(0.5, rotation=Rx), S.HalfSpace([1, 0, 0], 2.0), S.HalfSpace([-1, 0, 0], 2.0)])
    assert cc.bounded and cc.length_scale == pytest.approx(2.0)
    tet = S.Intersection.polytope([[1, 1, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], [1, 0, 0, 0])
    assert tet.bounded and np.all(np.array([f.value(tet.interior_point) for f in tet.functions]) < 0)
    for shape in list(ALL_FUNCTIONS.values()) + [cc, tet, S.Intersection.fingertip([0, 0], [0, 1], [-1, 0])]:
        assert shape.value(shape.interior_point) < 0


# --------------------------------------------------------------------------------------------
# axis-aligned boxes
# --------------------------------------------------------------------------------------------
def surface_samples(shape, rng, n=300):
    c = shape.interior_point
    pts = []
    for u in rng.normal(size=(n, shape.dim)):
        tau = shape.ray_exit(c, u)
        if math.isfinite(tau):
            pts.append(c + tau * u)
    return np.array(pts)


BOUNDED = {
    "sphere": S.Sphere(0.7, center=[0.1, -0.2, 0.3]),
    "ellipsoid": S.Ellipsoid([1.0, 0.5, 0.3], center=[0.2, 0.0, -0.1], rotation=rot(1)),
    "superquadric": S.Superquadric([0.6, 0.9, 0.4], 4.0, rotation=rot(2)),
    "superquadric_barr": S.Superquadric([0.6, 0.9, 0.4], [3.0, 5.0], center=[0.0, 0.3, 0.0], rotation=rot(3)),
    "box": S.Intersection.box([0.3, 0.6, 0.9], center=[0.5, 0.0, 0.0], rotation=rot(4)),
    "capped_cylinder": S.Intersection.capped_cylinder(0.3, 0.8, center=[0.0, 0.2, 0.0], rotation=rot(5)),
    "polytope": S.Intersection.polytope([[1, 1, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], [1, 0, 0, 0]),
    "sphere_cut": S.Intersection([S.Sphere(1.0), S.HalfSpace([0.0, 0.0, 1.0], 0.2)]),
    "disc": S.Disc(0.8, center=[0.3, -0.1]),
    "ellipse": S.Ellipse([1.2, 0.4], center=[0.0, 0.2], rotation=0.7),
    "superellipse": S.Superellipse([2.3, 1.1], 4.0, rotation=-0.3),
    "rectangle": S.Intersection.rectangle([1.0, 0.3], rotation=0.4),
}


@pytest.mark.parametrize("name", sorted(BOUNDED))
def test_aabb_contains_surface_samples_and_is_tight(name):
    shape = BOUNDED[name]
    rng = np.random.default_rng(RNG_SEED + 5)
    R = rot(11) if shape.dim == 3 else Rotation.from_euler("z", 0.9).as_matrix()[:2, :2]
    t = rng.normal(size=shape.dim)
    lo, hi = shape.aabb(R, t)
    assert np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))
    W = surface_samples(shape, rng) @ R.T + t
    assert np.all(W >= lo - ATOL_AABB) and np.all(W <= hi + ATOL_AABB)
    if name == "sphere_cut":
        return      # intersected member boxes: valid, not tight
    # Tightness: the support along each world axis by SLSQP on the body's functions.
    for k in range(shape.dim):
        for sign in (1.0, -1.0):
            d = sign * R[k]
            cons = [{"type": "ineq", "fun": (lambda x, f=f: -f.value(x)), "jac": (lambda x, f=f: -f.gradient(x))}
                    for f in shape.functions]
            res = minimize(lambda x: -d @ x, shape.interior_point, jac=lambda x: -d, constraints=cons,
                           method="SLSQP", options={"ftol": 1e-13, "maxiter": 500})
            support = -res.fun + sign * t[k]
            bound = hi[k] if sign > 0 else -lo[k]
            assert bound == pytest.approx(support, rel=RTOL_SUPPORT, abs=RTOL_SUPPORT), (k, sign)


def test_aabb_closed_forms_sphere_and_box():
    R, t = rot(12), np.array([1.0, -2.0, 0.5])
    lo, hi = S.Sphere(0.7, center=[0.1, 0.2, 0.3]).aabb(R, t)
    c = R @ [0.1, 0.2, 0.3] + t
    assert np.allclose(lo, c - 0.7, atol=ATOL_AABB) and np.allclose(hi, c + 0.7, atol=ATOL_AABB)
    h = np.array([0.3, 0.6, 0.9])
    lo, hi = S.Intersection.box(h).aabb(R, t)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h @ R.T + t
    assert np.allclose(lo, corners.min(axis=0), atol=ATOL_AABB)
    assert np.allclose(hi, corners.max(axis=0), atol=ATOL_AABB)


def test_aabb_of_unbounded_shapes():
    lo, hi = S.HalfSpace([0, 0, 1], 0.5).aabb(np.eye(3), np.array([0.0, 0.0, 1.0]))
    assert np.array_equal(lo, [-np.inf] * 3) and np.array_equal(hi, [np.inf, np.inf, 1.5])
    lo, hi = S.HalfSpace([0, 0, 1], 0.5).aabb(rot(1), np.zeros(3))
    assert np.all(np.isinf(lo)) and np.all(np.isinf(hi))
    lo, hi = S.InfiniteCylinder(0.5).aabb(np.eye(3), np.array([1.0, 2.0, 3.0]))
    assert np.allclose(lo[:2], [0.5, 1.5]) and np.allclose(hi[:2], [1.5, 2.5]) and np.isinf(lo[2]) and np.isinf(hi[2])
    tip = S.Intersection.fingertip([13.7, 0.0], [0.0, 1.0], [-1.0, 0.0])
    lo, hi = tip.aabb(np.eye(2), np.array([0.0, -1.0]))
    assert lo[0] == pytest.approx(13.7) and hi[1] == pytest.approx(-1.0) and np.isinf(hi[0]) and np.isinf(lo[1])
    slab = S.Intersection([S.HalfSpace([0, 0, 1], 1.0), S.HalfSpace([0, 0, -1], 1.0)])
    lo, hi = slab.aabb(np.eye(3), np.zeros(3))
    assert lo[2] == pytest.approx(-1.0) and hi[2] == pytest.approx(1.0) and np.isinf(lo[0])


# --------------------------------------------------------------------------------------------
# mass properties
# --------------------------------------------------------------------------------------------
def monte_carlo(shape, rho, rng):
    """Mass, com and inertia by uniform samples in the body-frame box, with a standard error."""
    lo, hi = shape.aabb(np.eye(shape.dim), np.zeros(shape.dim))
    X = rng.uniform(lo, hi, size=(MC_SAMPLES, shape.dim))
    inside = shape.value(X) <= 0
    box = float(np.prod(hi - lo))
    frac = inside.mean()
    mass = rho * box * frac
    mass_se = rho * box * math.sqrt(frac * (1 - frac) / MC_SAMPLES)
    P = X[inside]
    com = P.mean(axis=0)
    D = P - com
    if shape.dim == 3:
        cov = D.T @ D / len(P) * mass
        inertia = np.trace(cov) * np.eye(3) - cov
    else:
        inertia = float(np.sum(D * D) / len(P) * mass)
    return mass, mass_se, com, inertia


MASS_SHAPES = {
    "sphere": S.Sphere(0.7, center=[0.1, -0.2, 0.3]),
    "ellipsoid": S.Ellipsoid([1.0, 0.5, 0.3], rotation=rot(1)),
    "superquadric4": S.Superquadric([0.6, 0.9, 0.4], 4.0, rotation=rot(2)),
    "superquadric_barr": S.Superquadric([0.6, 0.9, 0.4], [3.0, 5.0]),
    "superquadric_barr_inv": S.Superquadric([0.6, 0.9, 0.4], [6.0, 2.5], center=[0.1, 0.0, 0.0]),
    "box": S.Intersection.box([0.3, 0.6, 0.9], rotation=rot(4)),
    "capped_cylinder": S.Intersection.capped_cylinder(0.3, 0.8, center=[0.0, 0.2, 0.0], rotation=rot(5)),
    "tetrahedron": S.Intersection.polytope([[1, 1, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], [1, 0, 0, 0]),
    "disc": S.Disc(0.8, center=[0.3, -0.1]),
    "ellipse": S.Ellipse([1.2, 0.4], rotation=0.7),
    "superellipse": S.Superellipse([2.3, 1.1], 4.0, rotation=-0.3),
    "rectangle": S.Intersection.rectangle([1.0, 0.3], rotation=0.4),
}


@pytest.mark.parametrize("name", sorted(MASS_SHAPES))
def test_mass_properties_agree_with_monte_carlo(name):
    shape = MASS_SHAPES[name]
    rho = 2.5
    mp = shape.mass_properties(rho)
    m, se, com, inertia = monte_carlo(shape, rho, np.random.default_rng(RNG_SEED + 6))
    assert abs(mp.mass - m) <= MC_SIGMAS * se
    L = shape.length_scale
    assert np.allclose(mp.com, com, atol=ATOL_MC_MOMENT * L)
    # Compare the covariance C = int (x - com)(x - com)^T dm / m (I = tr(C) Id - C), entry by
    # entry relative to sqrt(C_ii C_jj), so thin axes are checked as tightly as long ones.
    if shape.dim == 3:
        C_mp = np.trace(mp.inertia) / 2 * np.eye(3) - mp.inertia
        C_mc = np.trace(inertia) / 2 * np.eye(3) - inertia
        C_mp, C_mc = C_mp / mp.mass, C_mc / m
        size = np.sqrt(np.outer(np.diag(C_mp), np.diag(C_mp)))
        assert np.all(np.abs(C_mp - C_mc) <= RTOL_MC_COVARIANCE * size)
    else:
        assert mp.inertia / mp.mass == pytest.approx(inertia / m, rel=RTOL_MC_COVARIANCE)


def test_mass_properties_closed_forms():
    rho = 3.0
    a, b, c = 0.3, 0.6, 0.9
    mp = S.Intersection.box([a, b, c]).mass_properties(rho)
    m = rho * 8 * a * b * c
    assert mp.mass == pytest.approx(m, rel=1e-12)
    assert np.allclose(mp.inertia, np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * m / 3, rtol=1e-12, atol=1e-15)
    mp = S.Intersection.rectangle([a, b]).mass_properties(rho)
    assert mp.mass == pytest.approx(rho * 4 * a * b) and mp.inertia == pytest.approx(rho * 4 * a * b * (a * a + b * b) / 3)
    # p = q = 2 superquadric is the ellipsoid; a large exponent tends to the box
    sq2 = S.Superquadric([a, b, c], 2.0).mass_properties(rho)
    el = S.Ellipsoid([a, b, c]).mass_properties(rho)
    assert sq2.mass == pytest.approx(el.mass, rel=1e-12) and np.allclose(sq2.inertia, el.inertia, rtol=1e-12)
    barr22 = S.Superquadric([a, b, c], [2.0, 2.0]).mass_properties(rho)
    assert barr22.mass == pytest.approx(el.mass, rel=1e-12)
    big = S.Superquadric([a, b, c], 400.0).mass_properties(rho)
    assert big.mass == pytest.approx(rho * 8 * a * b * c, rel=1e-2)
    se2 = S.Superellipse([a, b], 2.0).mass_properties(rho)
    ell = S.Ellipse([a, b]).mass_properties(rho)
    assert se2.mass == pytest.approx(ell.mass, rel=1e-12) and se2.inertia == pytest.approx(ell.inertia, rel=1e-12)
    sph = S.Sphere(0.5).mass_properties(rho)
    assert sph.mass == pytest.approx(rho * 4 / 3 * math.pi * 0.125) and np.allclose(sph.inertia, 0.4 * sph.mass * 0.25 * np.eye(3))
    disc = S.Disc(0.5).mass_properties(rho)
    assert disc.inertia == pytest.approx(0.5 * disc.mass * 0.25)
    # unit corner tetrahedron: vol 1/6, com 1/4, int x^2 = 1/60, int x y = 1/120
    tet = S.Intersection.polytope([[1, 1, 1], [-1, 0, 0], [0, -1, 0], [0, 0, -1]], [1, 0, 0, 0]).mass_properties(rho)
    second = np.full((3, 3), 1 / 120) + np.eye(3) / 120
    cov = rho * (second - np.full((3, 3), 1 / 16) / 6)
    assert tet.mass == pytest.approx(rho / 6, rel=1e-12) and np.allclose(tet.com, 0.25, atol=1e-15)
    assert np.allclose(tet.inertia, np.trace(cov) * np.eye(3) - cov, rtol=1e-12, atol=1e-15)
    cyl = S.Intersection.capped_cylinder(0.3, 0.8).mass_properties(rho)
    mc = rho * math.pi * 0.09 * 1.6
    assert cyl.mass == pytest.approx(mc) and np.allclose(np.diag(cyl.inertia), [mc * (3 * 0.09 + 2.56) / 12] * 2 + [mc * 0.09 / 2])


def test_mass_properties_not_available():
    for shape in (S.HalfSpace([0, 0, 1], 0), S.InfiniteCylinder(1.0), S.HalfPlane([0, 1], 0),
                  S.Intersection([S.Sphere(1.0), S.HalfSpace([0, 0, 1], 0.2)]),
                  S.Union([S.Disc(1.0), S.Disc(1.0, center=[1.0, 0.0])])):
        with pytest.raises(NotImplementedError):
            shape.mass_properties(1.0)
    with pytest.raises(ValueError):
        S.Sphere(1.0).mass_properties(0.0)
    with pytest.raises(ValueError):
        S.Sphere(1.0).mass_properties(float("nan"))


# --------------------------------------------------------------------------------------------
# serialisation
# --------------------------------------------------------------------------------------------
ROUND_TRIP = {**ALL_FUNCTIONS, **BOUNDED,
              "fingertip": S.Intersection.fingertip([13.7, 0.0], [0.0, 1.0], [-1.0, 0.0]),
              "union": S.Union([S.Disc(20.75), S.Superellipse([2.3, 1.1], 4.0, center=[0.0, -20.75], rotation=-math.pi / 2)]),
              "union3d": S.Union([S.Sphere(1.0), S.Intersection.box([1, 2, 3], center=[2.0, 0.0, 0.0])])}


@pytest.mark.parametrize("name", sorted(ROUND_TRIP))
def test_to_dict_round_trip_is_exact(name):
    shape = ROUND_TRIP[name]
    d = shape.to_dict()
    text = json.dumps(d)
    rebuilt = S.shape_from_dict(json.loads(text))
    assert type(rebuilt) is type(shape)
    assert rebuilt.to_dict() == d
    X = np.random.default_rng(RNG_SEED + 7).normal(size=(20, shape.dim))
    assert np.array_equal(rebuilt.value(X), shape.value(X))
    assert np.array_equal(rebuilt.gradient(X), shape.gradient(X))


# --------------------------------------------------------------------------------------------
# bad input
# --------------------------------------------------------------------------------------------
NAN = float("nan")


@pytest.mark.parametrize("make", [
    lambda: S.Sphere(0.0),
    lambda: S.Sphere(-1.0),
    lambda: S.Sphere(NAN),
    lambda: S.Sphere(math.inf),
    lambda: S.Sphere("1"),
    lambda: S.Disc(0.0),
    lambda: S.Ellipsoid([1.0, 0.0, 1.0]),
    lambda: S.Ellipsoid([1.0, 1.0]),
    lambda: S.Ellipse([1.0, -1.0]),
    lambda: S.Superquadric([1.0, 1.0, 1.0], 1.5),
    lambda: S.Superquadric([1.0, 1.0, 1.0], NAN),
    lambda: S.Superquadric([1.0, 1.0, 1.0], [2.0, 4.0]),      # not C^2 on the z axis
    lambda: S.Superquadric([1.0, 1.0, 1.0], [3.0, 1.0]),
    lambda: S.Superquadric([1.0, 1.0, 1.0], [3.0, 3.0, 3.0]),
    lambda: S.Superellipse([1.0, 1.0], 1.99),
    lambda: S.HalfSpace([0.0, 0.0, 0.0], 1.0),
    lambda: S.HalfSpace([0.0, 0.0, 1.0], NAN),
    lambda: S.HalfPlane([0.0, 1.0, 0.0], 1.0),
    lambda: S.InfiniteCylinder(0.0),
    lambda: S.Sphere(1.0, center=[0.0, 0.0]),
    lambda: S.Sphere(1.0, center=[0.0, NAN, 0.0]),
    lambda: S.Sphere(1.0, rotation=np.diag([1.0, 1.0, -1.0])),            # improper
    lambda: S.Sphere(1.0, rotation=np.eye(3) * 1.01),                      # not orthonormal
    lambda: S.Sphere(1.0, rotation=np.eye(2)),
    lambda: S.Disc(1.0, rotation=np.eye(2)),                               # 2D takes an angle
    lambda: S.Disc(1.0, rotation=math.inf),
    lambda: S.Intersection([]),
    lambda: S.Intersection([S.Sphere(1.0), S.Disc(1.0)]),
    lambda: S.Intersection([S.Sphere(1.0), "not a shape"]),
    lambda: S.Intersection(S.Sphere(1.0)),
    lambda: S.Intersection([S.HalfSpace([1, 0, 0], -1.0), S.HalfSpace([-1, 0, 0], -1.0)]),   # x <= -1, x >= 1
    lambda: S.Intersection([S.HalfSpace([1, 0, 0], 0.0), S.HalfSpace([-1, 0, 0], 0.0)]),     # the plane x = 0
    lambda: S.Intersection([S.Sphere(1.0), S.HalfSpace([0, 0, 1], -2.0)]),
    lambda: S.Intersection([S.Sphere(1.0), S.Sphere(1.0, center=[3.0, 0.0, 0.0])]),
    lambda: S.Intersection([S.Disc(1.0), S.Disc(1.0, center=[2.0, 0.0])]),                   # touch only
    lambda: S.Intersection([S.InfiniteCylinder(1.0), S.HalfSpace([0, 0, 1], -1.0), S.HalfSpace([0, 0, -1], -1.0)]),
    lambda: S.Intersection.box([1.0, 0.0, 1.0]),
    lambda: S.Intersection.rectangle([1.0, 1.0, 1.0]),
    lambda: S.Intersection.capped_cylinder(1.0, -1.0),
    lambda: S.Intersection.polytope([[1.0, 0.0, 0.0]], [1.0, 2.0]),
    lambda: S.Intersection.polytope([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]], [1.0, 1.0]),
    lambda: S.Intersection.fingertip([0.0, 0.0], [0.0, 1.0], [0.0, 2.0]),
    lambda: S.Intersection.fingertip([0.0, 0.0], [0.0, 1.0], [0.0, 0.0]),
    lambda: S.Intersection.fingertip([0.0, NAN], [0.0, 1.0], [1.0, 0.0]),
    lambda: S.Union([]),
    lambda: S.Union([S.Sphere(1.0), S.Disc(1.0)]),
    lambda: S.Union([3.0]),
    lambda: S.shape_from_dict({"type": "Torus"}),
    lambda: S.shape_from_dict({"radius": 1.0}),
    lambda: S.shape_from_dict({"type": "Sphere"}),
])
def test_bad_input_raises_value_error(make):
    with pytest.raises(ValueError):
        make()


def test_bad_points_and_poses_raise_value_error():
    sph = S.Sphere(1.0)
    with pytest.raises(ValueError):
        sph.value([1.0, 2.0])
    with pytest.raises(ValueError):
        sph.gradient(np.zeros((4, 2)))
    with pytest.raises(ValueError):
        sph.aabb(np.eye(2), np.zeros(3))
    with pytest.raises(ValueError):
        sph.aabb(np.eye(3), [0.0, NAN, 0.0])
    with pytest.raises(ValueError):
        S.Intersection.box([1, 1, 1]).aabb(2 * np.eye(3), np.zeros(3))
    # NaN points are not hidden: they give NaN values
    assert math.isnan(sph.value([NAN, 0.0, 0.0]))


# --------------------------------------------------------------------------------------------
# support points
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(n for n in BOUNDED if n != "sphere_cut"))
def test_support_point_is_on_the_surface_and_maximal(name):
    shape = BOUNDED[name]
    rng = np.random.default_rng(RNG_SEED + 8)
    samples = surface_samples(shape, rng, n=400)
    for d in rng.normal(size=(10, shape.dim)):
        x = shape.support(d)
        assert abs(shape.value(x)) <= 1e-12
        assert d @ x >= np.max(samples @ d) - 1e-12
    # along the body axes the support is the AABB (checked against SLSQP above)
    lo, hi = shape.aabb(np.eye(shape.dim), np.zeros(shape.dim))
    for k in range(shape.dim):
        assert shape.support(np.eye(shape.dim)[k])[k] == pytest.approx(hi[k], abs=ATOL_AABB)
        assert shape.support(-np.eye(shape.dim)[k])[k] == pytest.approx(lo[k], abs=ATOL_AABB)


def test_support_point_is_not_available_without_a_closed_form():
    for shape in (S.HalfSpace([0, 0, 1], 0), S.InfiniteCylinder(1.0),
                  S.Intersection([S.Sphere(1.0), S.HalfSpace([0, 0, 1], 0.2)])):
        with pytest.raises(NotImplementedError):
            shape.support([0.0, 0.0, 1.0])
    with pytest.raises(ValueError):
        S.Sphere(1.0).support([0.0, 0.0, 0.0])


@pytest.mark.parametrize("name", sorted(ALL_FUNCTIONS))
def test_value_gradient_matches_separate_calls(name):
    shape = ALL_FUNCTIONS[name]
    for x in sample_points(shape, np.random.default_rng(RNG_SEED + 9), n=2):
        v, g = shape.value_gradient(x)
        assert v == shape.value(x) and np.array_equal(g, shape.gradient(x))
        if shape.constant_hessian:
            assert np.array_equal(shape.hessian(x), shape.hessian(x + 1.0))
