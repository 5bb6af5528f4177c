"""Convex implicit surfaces f(x) <= 0 in the body frame, with exact derivatives.

[GI] Sec. 4.1 models each body by one convex C^2 function f with f < 0 inside, f = 0 on the
surface and f > 0 outside; Sec. 4.3 allows a body to be the intersection of several such
functions, one KKT multiplier each (eqs 24-31); Sec. 6.4 builds a non-convex part as a union
of convex pieces (a disc and six exponent-4 superellipses, eqs 56-57) and a fingertip as the
intersection of two half-planes meeting at a vertex (eqs 58-61).

Normalisation
-------------
The closest-point equations (15)-(18) and the gap (19) put f(a), grad f(a) and positions into
one Newton system. Two raw functions of very different magnitude (a plane n.x - d against a
quartic |x/a|^4 + |y/b|^4 - 1 of a millimetre tooth) give rows whose scale differs by orders of
magnitude, which ruins the solver's merit function and tolerances. So every function is scaled
to be a first-order signed distance near its surface: for g homogeneous of degree n about the
shape centre (g = 1 on the surface) and s a length of the shape,

    f = (s / n) (g(x) - 1),    grad f = (s / n) grad g,   |grad f| = s / a_i at the tip of axis i.

The formula for each shape (X = R0^T (x - c0) / a componentwise, local scaled coordinates):

    Sphere / Disc        f = (|x - c0|^2 - r^2) / (2 r)              |grad f| = 1 on the surface
    Ellipsoid / Ellipse  f = (s/2) (sum X_i^2 - 1),  s = (prod a_i)^(1/dim)   (geometric mean)
    Superquadric         f = (s/n1) (g(X) - 1),      s = (a b c)^(1/3),
                         g = (|X|^n2 + |Y|^n2)^(n1/n2) + |Z|^n1            (Barr's form)
    Superellipse         f = (s/n) (|X|^n + |Y|^n - 1),  s = sqrt(a b)
    HalfSpace/HalfPlane  f = n.x - d with |n| = 1 (both divided by the given |n|): exact
                         signed distance
    InfiniteCylinder     f = (x^2 + y^2 - r^2) / (2 r) in the cylinder frame (axis = local z)

With s the geometric mean, |grad f| on the surface lies between s/a_max and s/a_min: exactly 1
for round shapes and of order one otherwise, which is what the solver's scaling needs.

Smoothness of the superquadric
------------------------------
|t|^n is C^2 for n >= 2 (its second derivative n(n-1)|t|^(n-2) is continuous). In Barr's form
w = (|X|^n2 + |Y|^n2)^(1/n2) is a norm of (X, Y), smooth away from the z axis, and w^n1 is
homogeneous of degree n1, so its Hessian is homogeneous of degree n1 - 2. On the z axis
(X = Y = 0) that Hessian is continuous iff n1 > 2 (it tends to 0) or w^2 is a quadratic form,
i.e. n2 = 2. With n1 = 2 < n2 the function is only C^{1,1} there (the second directional
derivative at the axis depends on the direction), so the constructor requires
n1 >= 2, n2 >= 2 and (n1 > 2 or n2 == 2). The derivatives are evaluated in the form
    dg/dX     = n1 w^(n1-1) rho_X^(n2-1) sgn X,                       rho_X = |X| / w,
    d2g/dX2   = n1 w^(n1-2) [(n1 - n2) rho_X^(2 n2 - 2) + (n2 - 1) rho_X^(n2 - 2)],
    d2g/dXdY  = n1 (n1 - n2) w^(n1-2) rho_X^(n2-1) rho_Y^(n2-1) sgn X sgn Y,
which has no 0 * inf even on the axis (0 <= rho <= 1).

Placement, poses, frames
------------------------
A primitive may be placed inside its body by center c0 and rotation R0 (3x3 proper rotation in
3D, angle in rad in 2D): f(x) = f0(R0^T (x - c0)), grad f = R0 grad f0, Hess f = R0 H0 R0^T.
aabb(R, t) is the world box of the body posed by x_world = R x_body + t.

Axis-aligned boxes (tight where stated)
--------------------------------------
Sphere/Ellipsoid: half width along world axis k is the support of the posed shape, |M_k diag(a)|
with M = R R0 (tight). Superquadric/superellipse: the support of the unit ball of g in direction
u is a dual norm, h(u) = || ( ||(u_x, u_y)||_{n2*}, u_z ) ||_{n1*} with 1/p + 1/p* = 1 (tight).
Polytopes use their vertices (tight); capped cylinders the closed form
|u_k| h + r sqrt(1 - u_k^2) (tight); other intersections intersect their bounded members' boxes.

Mass properties
---------------
Closed forms; the superquadric ones come from Dirichlet integrals (Liouville's formula):
for the unit p-disc A_p = 4 G(1+1/p)^2 / G(1+2/p) and its second moment
M_p = int X^2 = 4 G(3/p) G(1/p) / (p^2 G(1+4/p)); slicing the unit superquadric at height Z gives a
p-disc of radius (1 - |Z|^q)^(1/q) (q = n1, p = n2), hence
    V   = (2/q) A_p B(1/q, 2/q + 1),
    int X^2 = (2/q) M_p B(1/q, 4/q + 1),     int Z^2 = (2/q) A_p B(3/q, 2/q + 1),
scaled by a b c, a^3 b c, a b^3 c, a b c^3. In 2D (per unit thickness) the area is a b A_n and
int x^2 = a^3 b M_n. Polytopes: a fan of tetrahedra (triangles) from an interior point with
int x x^T = vol/20 (sum v v^T + (sum v)(sum v)^T)  (tetrahedron; /12 for a triangle).

Beyond the shared contract
--------------------------
value_gradient(x) and value_gradient_hessian(x) evaluate at the cost of one call;
constant_hessian marks quadrics and planes (the Hessian does not depend on x);
support(d) is a boundary point maximising d.x where a closed form exists (the gradient of the
dual norm for superquadrics, a vertex for polytopes); ray_exit(o, u) is where the ray o + tau u
leaves the body (closed forms for quadrics and planes, monotone 1-D Newton otherwise). The
closest-point solver uses the last two for its starting points.
"""
from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from itertools import combinations
import math
from types import MappingProxyType
from typing import Sequence

import numpy as np
from scipy.optimize import linprog, minimize, nnls
from scipy.spatial import ConvexHull, HalfspaceIntersection

from . import shape_kernels as _sk

__all__ = [
    "MassProperties", "ConvexFunction", "Sphere", "Ellipsoid", "Superquadric", "HalfSpace",
    "InfiniteCylinder", "Disc", "Ellipse", "Superellipse", "HalfPlane", "Intersection", "Union",
    "shape_from_dict",
]

ROTATION_TOL = 1e-9        # |R^T R - I|_max and |det R - 1| accepted for a rotation matrix
PARALLEL_TOL = 1e-12       # 1 - |n.u| below which a half-space normal counts as along an axis
CONE_TOL = 1e-12           # relative NNLS residual for "direction lies in the cone of normals"
INTERIOR_TOL = 1e-9        # depth (in length units of the offsets, at least 1) an intersection
                           # must have: smaller counts as empty or degenerate
UNBOUNDED_INTERIOR_DEPTH = 1.0   # how deep (length units) an interior point of an unbounded
                                 # body is placed: any positive depth is "strictly inside"
MAX_VERTEX_COMBINATIONS = 20000  # unbounded polyhedra: vertex enumeration limit before LPs
FACE_SAMPLES = 64               # points per rim circle of a capped cylinder's face (patch.py):
                                # the cap's polygon has 0.16 % less area than its disc
RAY_NEWTON_ITERATIONS = _sk.RAY_NEWTON_ITERATIONS   # 1-D Newton from outside on a convex function


@dataclass(frozen=True)
class MassProperties:
    """Rigid-body mass data of a shape of uniform density.

    mass: kg (3D, density in kg/m^3) or kg per unit thickness (2D, areal density kg/m^2).
    com: (dim,) centre of mass in the body frame.
    inertia: 3D: (3, 3) inertia tensor about the com in body axes [kg m^2];
             2D: scalar moment of inertia about the com and the z axis [kg m^2 per m].
    """

    mass: float
    com: np.ndarray
    inertia: np.ndarray | float


# --------------------------------------------------------------------------------------------
# input checks
# --------------------------------------------------------------------------------------------
def _finite_vector(value, dim: int | None, name: str) -> np.ndarray:
    try:
        v = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a vector of finite numbers, got {value!r}") from None
    if v.ndim != 1 or (dim is not None and v.shape[0] != dim):
        want = f"length {dim}" if dim is not None else "1-D"
        raise ValueError(f"{name} must be a {want} vector of finite numbers, got shape {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must contain finite numbers only, got {v.tolist()}")
    return v


def _nonzero_direction(value, dim: int) -> np.ndarray:
    return _nonzero(_finite_vector(value, dim, "direction"))


def _nonzero(d: np.ndarray) -> np.ndarray:
    """d, a float vector made by the caller, if it is not zero (a direction)."""
    if not d.any():
        raise ValueError("direction must be a non-zero vector")
    return d


def _finite_scalar(value, name: str) -> float:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a finite real number, got {value!r}")
    x = float(value)
    if not math.isfinite(x):
        raise ValueError(f"{name} must be a finite real number, got {value!r}")
    return x


def _positive(value, name: str) -> float:
    x = _finite_scalar(value, name)
    if x <= 0.0:
        raise ValueError(f"{name} must be a positive finite length, got {value!r}")
    return x


def _positive_vector(value, dim: int, name: str) -> np.ndarray:
    v = _finite_vector(value, dim, name)
    if np.any(v <= 0.0):
        raise ValueError(f"{name} must be {dim} positive finite lengths, got {v.tolist()}")
    return v


def _rotation_matrix(rotation, dim: int) -> np.ndarray:
    """3D: a proper rotation matrix (checked); 2D: an angle in rad."""
    if dim == 2:
        angle = _finite_scalar(rotation, "rotation (a 2D angle in rad)")
        c, s = math.cos(angle), math.sin(angle)
        return np.array([[c, -s], [s, c]])
    try:
        R = np.array(rotation, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"rotation must be a 3x3 rotation matrix, got {rotation!r}") from None
    if R.shape != (3, 3) or not np.all(np.isfinite(R)):
        raise ValueError(f"rotation must be a finite 3x3 rotation matrix, got shape {R.shape}")
    if np.max(np.abs(R.T @ R - np.eye(3))) > ROTATION_TOL or abs(np.linalg.det(R) - 1.0) > ROTATION_TOL:
        raise ValueError("rotation must be orthonormal with determinant +1 (a proper rotation, "
                         f"within {ROTATION_TOL}), got {R.tolist()}")
    return R


def _check_pose(rotation, translation, dim: int) -> tuple[np.ndarray, np.ndarray]:
    R = np.asarray(rotation, dtype=float)
    t = np.asarray(translation, dtype=float)
    if R.shape != (dim, dim) or t.shape != (dim,):
        raise ValueError(f"a pose of a {dim}D shape is a ({dim},{dim}) rotation and a ({dim},) "
                         f"translation, got shapes {R.shape} and {t.shape}")
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise ValueError("pose rotation and translation must be finite")
    if np.max(np.abs(R.T @ R - np.eye(dim))) > ROTATION_TOL or np.linalg.det(R) < 0.0:
        raise ValueError(f"pose rotation must be a proper rotation (orthonormal, det +1), got {R.tolist()}")
    return R, t


def _least_aligned_axis(u: np.ndarray) -> np.ndarray:
    """The coordinate axis least aligned with u (layout's tangent bases use it too)."""
    e = np.zeros(len(u))
    e[int(np.argmin(np.abs(u)))] = 1.0
    return e


def _points(x, dim: int) -> np.ndarray:
    x = np.asarray(x, dtype=float)
    if x.ndim == 0 or x.shape[-1] != dim:
        raise ValueError(f"points of a {dim}D shape must have shape (..., {dim}), got {x.shape}")
    return x


def _density(density) -> float:
    rho = _finite_scalar(density, "density")
    if rho <= 0.0:
        raise ValueError(f"density must be a positive finite number, got {density!r}")
    return rho


def _as_float(v):
    return float(v) if np.ndim(v) == 0 else v


def _plain(value):
    """numpy -> plain floats / lists for JSON."""
    if value is None:
        return None
    a = np.asarray(value, dtype=float)
    return float(a) if a.ndim == 0 else a.tolist()


def _beta(x: float, y: float) -> float:
    return math.exp(math.lgamma(x) + math.lgamma(y) - math.lgamma(x + y))


def _dual(p: float) -> float:
    return p / (p - 1.0)


def _pnorm(v: np.ndarray, p: float, axis: int = -1) -> np.ndarray:
    """||v||_p along axis, scaled to avoid overflow for large p."""
    a = np.abs(v)
    if a.ndim == 1:         # (one vector: the same arithmetic without the broadcasting, 3x cheaper)
        m = a.max()
        return m * ((a / m) ** p).sum() ** (1.0 / p) if m > 0.0 else m
    m = np.max(a, axis=axis, keepdims=True)
    safe = np.where(m > 0.0, m, 1.0)
    return np.squeeze(m, axis=axis) * np.sum((a / safe) ** p, axis=axis) ** (1.0 / p)


# --------------------------------------------------------------------------------------------
# the abstract function
# --------------------------------------------------------------------------------------------
class ConvexFunction(ABC):
    """One convex C^2 function f of the body-frame point x; body = {x : f(x) <= 0}.

    value(x): (..., dim) -> (...) (a float for one point); gradient -> (..., dim);
    hessian -> (..., dim, dim); value_gradient_hessian returns all three at the cost of one.
    """

    dim: int
    bounded: bool
    constant_hessian: bool = False   # quadrics and planes: the Hessian does not depend on x

    @property
    def functions(self) -> tuple["ConvexFunction", ...]:
        return (self,)

    def value_gradient(self, x):
        """(value, gradient) at the cost of one evaluation."""
        return self.value(x), self.gradient(x)

    @abstractmethod
    def value_gradient_hessian(self, x): ...

    @abstractmethod
    def value(self, x): ...

    @abstractmethod
    def gradient(self, x): ...

    @abstractmethod
    def hessian(self, x): ...

    @abstractmethod
    def aabb(self, rotation, translation) -> tuple[np.ndarray, np.ndarray]: ...

    @property
    @abstractmethod
    def interior_point(self) -> np.ndarray: ...

    @property
    @abstractmethod
    def length_scale(self) -> float: ...

    @abstractmethod
    def mass_properties(self, density) -> MassProperties: ...

    @abstractmethod
    def to_dict(self) -> dict: ...

    def support(self, direction) -> np.ndarray:
        """A boundary point maximising direction . x (body frame), where a closed form exists."""
        return self._support_point(_nonzero_direction(direction, self.dim))

    def _support_point(self, d: np.ndarray) -> np.ndarray:
        """support of a checked direction (a non-zero float vector of length dim): for callers
        that made it themselves (closest.py's start, many calls per pair)."""
        raise NotImplementedError(f"{type(self).__name__} has no closed-form support point "
                                  "(unbounded or no formula).")

    def face_points(self) -> np.ndarray | None:
        """Body-frame points whose hull along any normal spans the face a contact can press on
        (patch.py); a curved function has none: it touches in a point."""
        return np.empty((0, self.dim))

    def ray_exit(self, origin, direction) -> float:
        """tau >= 0 with f(origin + tau direction) = 0 for an origin inside (inf if never).

        Generic: Newton on the convex phi(tau) = f(origin + tau u) from a tau where phi > 0;
        from the right of the root a convex increasing phi makes Newton monotone.
        """
        return self._ray_exit(_finite_vector(origin, self.dim, "origin"), _nonzero_direction(direction, self.dim))

    def _ray_exit(self, o: np.ndarray, u: np.ndarray) -> float:
        """ray_exit of a checked origin and direction (float vectors of length dim, u != 0)."""
        if self.value(o) >= 0.0:
            return 0.0
        tau = self.length_scale / float(np.linalg.norm(u))
        for _ in range(200):
            if self.value(o + tau * u) > 0.0:
                break
            tau *= 2.0
        else:
            return math.inf
        def phi(s):
            v, grad = self.value_gradient(o + s * u)
            return v, float(grad @ u)

        return _newton_from_right(phi, tau)


def _newton_from_right(phi, tau: float) -> float:
    """Newton on phi(tau) = 0 from a tau right of the root; phi(t) -> (value, derivative), one
    evaluation of the function for both; each step is shape_kernels.newton_from_right_step, as
    in the compiled ray exits."""
    for _ in range(RAY_NEWTON_ITERATIONS):
        v, d = phi(tau)
        tau, done = _sk.newton_from_right_step(float(tau), float(v), float(d))
        if done:
            break
    return float(tau)


# --------------------------------------------------------------------------------------------
# primitives with a placement
# --------------------------------------------------------------------------------------------
class _Primitive(ConvexFunction):
    """Placement f(x) = f0(R0^T (x - c0)); subclasses give f0 as a shape_kernels row."""

    _DIM: int = 3

    def __init__(self, center, rotation):
        self.dim = self._DIM
        self._center_in = None if center is None else _finite_vector(center, self.dim, "center")
        if rotation is None:
            self._rotation_in = None
        elif self.dim == 2:
            self._rotation_in = _finite_scalar(rotation, "rotation (a 2D angle in rad)")
        else:
            self._rotation_in = _rotation_matrix(rotation, 3)
        self._c0 = np.zeros(self.dim) if self._center_in is None else self._center_in.copy()
        self._R0 = np.eye(self.dim) if rotation is None else _rotation_matrix(self._rotation_in, self.dim)
        self._shifted = bool(np.any(self._c0 != 0.0))
        self._rotated = bool(np.any(self._R0 != np.eye(self.dim)))

    # -- placement ---------------------------------------------------------------------------
    @property
    def center(self) -> np.ndarray:
        return self._c0.copy()

    @property
    def rotation(self):
        """3D: the 3x3 rotation matrix R0; 2D: the angle in rad."""
        if self.dim == 2:
            return 0.0 if self._rotation_in is None else float(self._rotation_in)
        return self._R0.copy()

    @property
    def rotation_matrix(self) -> np.ndarray:
        return self._R0.copy()

    def _to_local(self, x: np.ndarray) -> np.ndarray:
        if self._shifted:
            x = x - self._c0
        if self._rotated:
            x = x @ self._R0
        return x

    @abstractmethod
    def _kernel_params(self) -> np.ndarray:
        """This function's row of shape_kernels (its code, placement and parameters)."""

    @property
    def kernel_params(self) -> np.ndarray:
        """The shape_kernels row of this function (a copy: the step packs it into its tables)."""
        par = self.__dict__.get("_par")
        if par is None:
            par = self.__dict__["_par"] = self._kernel_params()
        return par.copy()

    def _kernel_row(self) -> np.ndarray:
        """The shape_kernels row of this function itself (not a copy: read it, never write it)."""
        par = self.__dict__.get("_par")
        if par is None:
            self.kernel_params
            par = self.__dict__["_par"]
        return par

    def _eval(self, x, order: int):
        """Values, gradients and Hessians (body frame) of shape_kernels at the points x."""
        par = self._kernel_row()
        if (type(x) is np.ndarray and x.ndim == 1 and x.shape[0] == self.dim and x.dtype == np.float64
                and x.flags.c_contiguous):
            # one point, the most frequent call (closest.py's start): the same kernel on a (1, dim)
            # view, without the conversions below (10.4 -> 2.4 us)
            v, g, H = _sk.evaluate_many(par, x[None], order)
            return v.reshape(()), g[0], H[0]
        x = _points(x, self.dim)
        X = np.ascontiguousarray(x.reshape(-1, self.dim), dtype=float)
        v, g, H = _sk.evaluate_many(par, X, order)
        lead = x.shape[:-1]
        return v.reshape(lead), g.reshape(lead + (self.dim,)), H.reshape(lead + (self.dim, self.dim))

    def value(self, x):
        return _as_float(self._eval(x, 0)[0])

    def gradient(self, x):
        return self._eval(x, 1)[1]

    def hessian(self, x):
        return self._eval(x, 2)[2]

    def value_gradient(self, x):
        v, g, _ = self._eval(x, 1)
        return _as_float(v), g

    def value_gradient_hessian(self, x):
        v, g, H = self._eval(x, 2)
        return _as_float(v), g, H

    def _placed(self, code, **par) -> np.ndarray:
        return _sk.pack(code, self.dim, center=self._c0, rotation=self._R0, **par)

    def _support_point(self, d: np.ndarray) -> np.ndarray:
        xl = self._local_support(d @ self._R0 if self._rotated else d)
        return self._c0 + (self._R0 @ xl if self._rotated else xl)

    def _local_support(self, d: np.ndarray) -> np.ndarray:
        return ConvexFunction._support_point(self, d)

    def _world_placement(self, rotation, translation):
        R, t = _check_pose(rotation, translation, self.dim)
        return R @ self._R0, R @ self._c0 + t

    def _placed_mass(self, mass: float, inertia_local):
        if self.dim == 3:
            inertia = self._R0 @ np.asarray(inertia_local) @ self._R0.T
        else:
            inertia = float(inertia_local)
        return MassProperties(float(mass), self._c0.copy(), inertia)

    def _placement_dict(self) -> dict:
        rot = self._rotation_in
        return {"center": _plain(self._center_in), "rotation": _plain(rot)}

    @property
    def interior_point(self) -> np.ndarray:
        return self._c0.copy()

    def __repr__(self) -> str:
        d = self.to_dict()
        args = ", ".join(f"{k}={v}" for k, v in d.items() if k != "type" and v is not None)
        return f"{d['type']}({args})"


class _ClosedForms:
    """Support point and ray exit of a bounded primitive from shape_kernels (support_local,
    ray_exit): the same kernels the step's static closest points run (closest._single_run)."""

    def _local_support(self, d):
        return _sk.local_support(self._kernel_row(), np.ascontiguousarray(d, dtype=float))

    def _ray_exit(self, o, u):
        return float(_sk.ray_exit_from(self._kernel_row(), np.ascontiguousarray(o, dtype=float),
                                       np.ascontiguousarray(u, dtype=float)))


class _Ball(_ClosedForms, _Primitive):
    """f = (|x|^2 - r^2) / (2 r) in local coordinates: exact unit gradient on the surface."""

    bounded = True
    constant_hessian = True

    def __init__(self, radius, center=None, rotation=None):
        super().__init__(center, rotation)
        self.radius = _positive(radius, "radius")

    def _kernel_params(self):
        return self._placed(_sk.BALL, radius=self.radius)

    def aabb(self, rotation, translation):
        _, c = self._world_placement(rotation, translation)
        return c - self.radius, c + self.radius

    @property
    def length_scale(self) -> float:
        return self.radius

    def to_dict(self):
        return {"type": type(self).__name__, "radius": self.radius, **self._placement_dict()}


def _quadric_exit(p: np.ndarray, u: np.ndarray) -> float:
    """Largest tau with |p + tau u| = 1 for |p| < 1 (scaled coordinates)."""
    uu = float(u @ u)
    if uu == 0.0:
        raise ValueError("direction must be a non-zero vector")
    pu = float(p @ u)
    pp = float(p @ p)
    if pp >= 1.0:
        return 0.0
    disc = pu * pu + uu * (1.0 - pp)
    # Cancellation-free root: tau = (1 - pp) / (pu + sqrt(disc)) when pu >= 0.
    sq = math.sqrt(disc)
    return (1.0 - pp) / (pu + sq) if pu >= 0.0 else (sq - pu) / uu


class Sphere(_Ball):
    """Sphere of radius r about the placement centre: f = (|x - c0|^2 - r^2) / (2 r)."""

    _DIM = 3

    def mass_properties(self, density):
        rho = _density(density)
        m = rho * 4.0 / 3.0 * math.pi * self.radius ** 3
        return self._placed_mass(m, np.eye(3) * 0.4 * m * self.radius ** 2)


class Disc(_Ball):
    """Disc of radius r (2D): f = (|x - c0|^2 - r^2) / (2 r)."""

    _DIM = 2

    def mass_properties(self, density):
        rho = _density(density)
        m = rho * math.pi * self.radius ** 2
        return self._placed_mass(m, 0.5 * m * self.radius ** 2)


class _EllipsoidBase(_ClosedForms, _Primitive):
    """f = (s/2)(sum (x_i/a_i)^2 - 1), s = geometric mean of the semi-axes."""

    bounded = True
    constant_hessian = True

    def __init__(self, semi_axes, center=None, rotation=None):
        super().__init__(center, rotation)
        self.semi_axes = _positive_vector(semi_axes, self.dim, "semi_axes")
        self._s = float(np.prod(self.semi_axes) ** (1.0 / self.dim))

    def _kernel_params(self):
        return self._placed(_sk.ELLIPSOID, semi_axes=self.semi_axes, scale=self._s)

    def aabb(self, rotation, translation):
        M, c = self._world_placement(rotation, translation)
        half = np.linalg.norm(M * self.semi_axes, axis=1)
        return c - half, c + half

    @property
    def length_scale(self) -> float:
        return float(np.max(self.semi_axes))

    def to_dict(self):
        return {"type": type(self).__name__, "semi_axes": self.semi_axes.tolist(), **self._placement_dict()}


class Ellipsoid(_EllipsoidBase):
    """Ellipsoid with semi-axes (a, b, c) along the placement axes."""

    _DIM = 3

    def mass_properties(self, density):
        rho = _density(density)
        a, b, c = self.semi_axes
        m = rho * 4.0 / 3.0 * math.pi * a * b * c
        return self._placed_mass(m, np.diag([b * b + c * c, a * a + c * c, a * a + b * b]) * m / 5.0)


class Ellipse(_EllipsoidBase):
    """Ellipse with semi-axes (a, b) (2D)."""

    _DIM = 2

    def mass_properties(self, density):
        rho = _density(density)
        a, b = self.semi_axes
        m = rho * math.pi * a * b
        return self._placed_mass(m, m * (a * a + b * b) / 4.0)


def _exponent(value, name: str) -> float:
    n = _finite_scalar(value, name)
    if n < 2.0:
        raise ValueError(f"{name} must be a finite number >= 2 (so that f is C^2), got {value!r}")
    return n


def _p_disc_moments(p: float) -> tuple[float, float]:
    """Area and int X^2 of the unit p-disc |X|^p + |Y|^p <= 1 (Dirichlet integrals)."""
    area = 4.0 * math.gamma(1.0 + 1.0 / p) ** 2 / math.gamma(1.0 + 2.0 / p)
    second = 4.0 * math.gamma(3.0 / p) * math.gamma(1.0 / p) / (p * p * math.gamma(1.0 + 4.0 / p))
    return area, second


class _PowerSumBase(_ClosedForms, _Primitive):
    """Superquadric in Barr's form, f = (s/n1)(g - 1), g = (|X|^n2 + |Y|^n2)^(n1/n2) + |Z|^n1.

    With n1 == n2 = n this is sum |X_i|^n (also the 2D superellipse)."""

    bounded = True

    def __init__(self, semi_axes, center=None, rotation=None):
        super().__init__(center, rotation)
        self.semi_axes = _positive_vector(semi_axes, self.dim, "semi_axes")
        self._s = float(np.prod(self.semi_axes) ** (1.0 / self.dim))

    def _set_exponents(self, n1: float, n2: float):
        self._n1, self._n2 = n1, n2
        self._single = n1 == n2

    def _kernel_params(self):
        code = _sk.POWER if self._single else _sk.BARR
        return self._placed(code, semi_axes=self.semi_axes, n1=self._n1, n2=self._n2, scale=self._s)

    def _support(self, dirs: np.ndarray) -> np.ndarray:
        """Support h(u) of the unit ball of g along each row u (scaled coordinates)."""
        q, p = self._n1, self._n2
        if self._single:
            return _pnorm(dirs, _dual(q))
        wxy = _pnorm(dirs[:, :2], _dual(p))
        return _pnorm(np.stack([wxy, dirs[:, 2]], axis=-1), _dual(q))

    def aabb(self, rotation, translation):
        M, c = self._world_placement(rotation, translation)
        half = self._support(M * self.semi_axes)
        return c - half, c + half

    @property
    def length_scale(self) -> float:
        return float(np.max(self.semi_axes))


class Superquadric(_PowerSumBase):
    """Superellipsoid with semi-axes (a, b, c).

    exponent: a number n >= 2 (g = |X|^n + |Y|^n + |Z|^n) or a pair (n1, n2) for Barr's form
    g = (|X|^n2 + |Y|^n2)^(n1/n2) + |Z|^n1 (n1 = 2/eps1, n2 = 2/eps2 in Barr's notation) with
    n1, n2 >= 2 and (n1 > 2 or n2 == 2), which is what makes f C^2 on the z axis.
    """

    _DIM = 3

    def __init__(self, semi_axes, exponent, center=None, rotation=None):
        super().__init__(semi_axes, center, rotation)
        if np.ndim(exponent) == 0:
            n = _exponent(exponent, "exponent")
            self._exponent_in = n
            self._set_exponents(n, n)
        else:
            e = _finite_vector(exponent, 2, "exponent (n1, n2)")
            n1 = _exponent(e[0], "exponent n1")
            n2 = _exponent(e[1], "exponent n2")
            if not (n1 > 2.0 or n2 == 2.0):
                raise ValueError("Barr exponents (n1, n2) must satisfy n1 > 2 or n2 == 2: with n1 = 2 "
                                 f"and n2 > 2 f is not C^2 on the z axis; got ({n1}, {n2})")
            self._exponent_in = [n1, n2]
            self._set_exponents(n1, n2)

    @property
    def exponents(self) -> tuple[float, float]:
        """(n1, n2) of Barr's form; equal for a single exponent."""
        return self._n1, self._n2

    def mass_properties(self, density):
        rho = _density(density)
        q, p = self._n1, self._n2
        area, second = _p_disc_moments(p)
        vol = 2.0 / q * area * _beta(1.0 / q, 2.0 / q + 1.0)
        sxx = 2.0 / q * second * _beta(1.0 / q, 4.0 / q + 1.0)
        szz = 2.0 / q * area * _beta(3.0 / q, 2.0 / q + 1.0)
        a, b, c = self.semi_axes
        abc = a * b * c
        m = rho * abc * vol
        ixx, iyy, izz = rho * abc * a * a * sxx, rho * abc * b * b * sxx, rho * abc * c * c * szz
        return self._placed_mass(m, np.diag([iyy + izz, ixx + izz, ixx + iyy]))

    def to_dict(self):
        return {"type": "Superquadric", "semi_axes": self.semi_axes.tolist(),
                "exponent": _plain(self._exponent_in), **self._placement_dict()}


class Superellipse(_PowerSumBase):
    """Superellipse |X|^n + |Y|^n <= 1 with semi-axes (a, b), n >= 2 (2D; gear teeth: n = 4)."""

    _DIM = 2

    def __init__(self, semi_axes, exponent, center=None, rotation=None):
        super().__init__(semi_axes, center, rotation)
        n = _exponent(exponent, "exponent")
        self.exponent = n
        self._set_exponents(n, n)

    def mass_properties(self, density):
        rho = _density(density)
        area, second = _p_disc_moments(self.exponent)
        a, b = self.semi_axes
        m = rho * a * b * area
        return self._placed_mass(m, rho * a * b * (a * a + b * b) * second)

    def to_dict(self):
        return {"type": "Superellipse", "semi_axes": self.semi_axes.tolist(),
                "exponent": self.exponent, **self._placement_dict()}


class _HalfSpaceBase(_Primitive):
    """{x : n.x <= d}, stored as the exact signed distance n.x/|n| - d/|n|."""

    bounded = False
    constant_hessian = True

    def __init__(self, normal, offset, center=None, rotation=None):
        super().__init__(center, rotation)
        n = _finite_vector(normal, self.dim, "normal")
        norm = float(np.linalg.norm(n))
        if norm == 0.0:
            raise ValueError("normal must be a non-zero vector (the outward normal of the boundary)")
        self._normal_in = n
        self._offset_in = _finite_scalar(offset, "offset")
        self.normal = n / norm
        self.offset = self._offset_in / norm

    def face_points(self):
        """None: the whole plane is its face (patch.py)."""
        return None

    def plane(self) -> tuple[np.ndarray, float]:
        """(unit normal, offset) of the boundary in the body frame (placement applied)."""
        n = self._R0 @ self.normal
        return n, float(self.offset + n @ self._c0)

    def _kernel_params(self):
        n, d = self.plane()
        return _sk.pack(_sk.PLANE, self.dim, normal=n, offset=d)

    def aabb(self, rotation, translation):
        R, t = _check_pose(rotation, translation, self.dim)
        n_b, d_b = self.plane()
        n = R @ n_b
        d = d_b + float(n @ t)
        lo, hi = np.full(self.dim, -np.inf), np.full(self.dim, np.inf)
        nz = np.flatnonzero(n)
        if nz.size == 1:
            k = nz[0]
            if n[k] > 0.0:
                hi[k] = d / n[k]
            else:
                lo[k] = d / n[k]
        return lo, hi

    @property
    def interior_point(self) -> np.ndarray:
        n, d = self.plane()
        return self._c0 - (float(n @ self._c0) - d + UNBOUNDED_INTERIOR_DEPTH) * n

    @property
    def length_scale(self) -> float:
        return math.inf

    def _ray_exit(self, o, u):
        n, d = self.plane()
        nu = float(n @ u)
        gap = d - float(n @ o)
        if gap <= 0.0:
            return 0.0
        return gap / nu if nu > 0.0 else math.inf

    def mass_properties(self, density):
        raise NotImplementedError(f"a {type(self).__name__} is unbounded and has no finite mass; "
                                  "use it for fixed bodies only.")

    def to_dict(self):
        return {"type": type(self).__name__, "normal": self._normal_in.tolist(),
                "offset": self._offset_in, **self._placement_dict()}


class HalfSpace(_HalfSpaceBase):
    """{x : normal . x <= offset} (3D); f = n.x - d with n, d divided by |normal|."""

    _DIM = 3


class HalfPlane(_HalfSpaceBase):
    """{x : normal . x <= offset} (2D); f = n.x - d with n, d divided by |normal|."""

    _DIM = 2


class InfiniteCylinder(_Primitive):
    """Infinite circular cylinder about the local z axis: f = (x^2 + y^2 - r^2) / (2 r)."""

    _DIM = 3
    bounded = False
    constant_hessian = True

    def __init__(self, radius, center=None, rotation=None):
        super().__init__(center, rotation)
        self.radius = _positive(radius, "radius")

    @property
    def axis(self) -> np.ndarray:
        """Unit axis direction in the body frame."""
        return self._R0[:, 2].copy()

    def _kernel_params(self):
        return self._placed(_sk.CYLINDER, radius=self.radius)

    def aabb(self, rotation, translation):
        M, c = self._world_placement(rotation, translation)
        u = M[:, 2]
        lo, hi = np.full(3, -np.inf), np.full(3, np.inf)
        flat = u == 0.0
        lo[flat] = c[flat] - self.radius
        hi[flat] = c[flat] + self.radius
        return lo, hi

    @property
    def length_scale(self) -> float:
        return self.radius

    def _ray_exit(self, o, u):
        o = self._to_local(o)
        u = u @ self._R0 if self._rotated else u
        if not np.any(u[:2]):
            return 0.0 if o[0] ** 2 + o[1] ** 2 >= self.radius ** 2 else math.inf
        return _quadric_exit(o[:2] / self.radius, u[:2] / self.radius)

    def mass_properties(self, density):
        raise NotImplementedError("an InfiniteCylinder is unbounded and has no finite mass; cap it "
                                  "with Intersection.capped_cylinder for a finite body.")

    def to_dict(self):
        return {"type": "InfiniteCylinder", "radius": self.radius, **self._placement_dict()}


# --------------------------------------------------------------------------------------------
# polyhedra (the half-space members of an intersection)
# --------------------------------------------------------------------------------------------
class _Polyhedron:
    """{x : A x <= b} with unit rows: feasibility, interior point, boundedness, vertices."""

    def __init__(self, A: np.ndarray, b: np.ndarray):
        self.A, self.b = A, b
        self.dim = A.shape[1]
        scale = max(1.0, float(np.max(np.abs(b))))
        res = linprog(np.r_[np.zeros(self.dim), -1.0], A_ub=np.c_[A, np.ones(len(b))], b_ub=b,
                      bounds=[(None, None)] * self.dim + [(0.0, UNBOUNDED_INTERIOR_DEPTH * scale)],
                      method="highs")
        if res.status != 0 or -res.fun <= INTERIOR_TOL * scale:
            raise ValueError("the half-spaces of an intersection must enclose a region with a "
                             "non-empty interior (the given ones are infeasible or degenerate)")
        self.center = res.x[: self.dim]
        self.depth = float(res.x[-1])
        self.bounded = self._positively_spanning()
        self.vertices = None
        self.pointed = bool(np.linalg.matrix_rank(A) == self.dim)
        if self.bounded:
            hs = HalfspaceIntersection(np.c_[A, -b], self.center)
            self.vertices = np.unique(np.round(hs.intersections, 14), axis=0)
        elif self.pointed and math.comb(len(b), self.dim) <= MAX_VERTEX_COMBINATIONS:
            self.vertices = self._enumerate_vertices(scale)

    def _positively_spanning(self) -> bool:
        """{d : A d <= 0} = {0} iff rank A = dim and A^T y = 0 for some y > 0 (Stiemke)."""
        m = self.A.shape[0]
        if np.linalg.matrix_rank(self.A) < self.dim:
            return False
        res = linprog(np.r_[np.zeros(m), -1.0],
                      A_ub=np.c_[-np.eye(m), np.ones(m)], b_ub=np.zeros(m),
                      A_eq=np.c_[self.A.T, np.zeros(self.dim)], b_eq=np.zeros(self.dim),
                      bounds=[(0.0, None)] * m + [(None, 1.0)], method="highs")
        return res.status == 0 and -res.fun > 1e-9

    def _enumerate_vertices(self, scale: float) -> np.ndarray:
        found = []
        for rows in combinations(range(len(self.b)), self.dim):
            Ai = self.A[list(rows)]
            if abs(np.linalg.det(Ai)) < 1e-12:
                continue
            v = np.linalg.solve(Ai, self.b[list(rows)])
            if np.all(self.A @ v <= self.b + 1e-9 * scale):
                found.append(v)
        return np.unique(np.round(np.array(found), 14), axis=0)

    def world_aabb(self, R: np.ndarray, t: np.ndarray):
        lo, hi = np.full(self.dim, -np.inf), np.full(self.dim, np.inf)
        if self.bounded:
            W = self.vertices @ R.T + t
            return W.min(axis=0), W.max(axis=0)
        for k in range(self.dim):
            for sign in (1.0, -1.0):
                d = sign * R[k]              # direction in the body frame
                value = self._support(d)
                if sign > 0:
                    hi[k] = value + t[k]
                else:
                    lo[k] = -value + t[k]
        return lo, hi

    def _support(self, d: np.ndarray) -> float:
        """sup {d.x : A x <= b}: finite iff d is in the cone of the normals."""
        if self.vertices is not None and len(self.vertices):
            _, resid = nnls(self.A.T, d)
            if resid > CONE_TOL * max(1.0, float(np.linalg.norm(d))):
                return math.inf
            return float(np.max(self.vertices @ d))
        res = linprog(-d, A_ub=self.A, b_ub=self.b, bounds=[(None, None)] * self.dim, method="highs")
        return -float(res.fun) if res.status == 0 else math.inf


# --------------------------------------------------------------------------------------------
# intersections and unions
# --------------------------------------------------------------------------------------------
class Intersection:
    """Convex body {x : f_i(x) <= 0 for all i} ([GI] Sec. 4.3, one multiplier per f_i).

    value = max_i f_i; gradient and Hessian are those of the (first) maximising member.
    """

    def __init__(self, functions: Sequence[ConvexFunction]):
        if isinstance(functions, (ConvexFunction, Intersection)):
            raise ValueError("Intersection takes a sequence of ConvexFunction objects, got a single shape")
        flat: list[ConvexFunction] = []
        for f in list(functions):
            if isinstance(f, Intersection):
                flat.extend(f.functions)
            elif isinstance(f, ConvexFunction):
                flat.append(f)
            else:
                raise ValueError("Intersection members must be ConvexFunction or Intersection objects, "
                                 f"got {type(f).__name__}")
        if not flat:
            raise ValueError("an Intersection needs at least one convex function")
        dims = {f.dim for f in flat}
        if len(dims) != 1:
            raise ValueError(f"all members of an Intersection must have the same dim, got {sorted(dims)}")
        self._functions = tuple(flat)
        self.dim = flat[0].dim
        self._analyse()

    # -- construction-time geometry ----------------------------------------------------------
    def _analyse(self):
        fs = self._functions
        halfspaces = [f for f in fs if isinstance(f, _HalfSpaceBase)]
        others = [f for f in fs if not isinstance(f, _HalfSpaceBase)]
        self._poly = None
        if halfspaces:
            planes = [h.plane() for h in halfspaces]
            self._poly = _Polyhedron(np.array([p[0] for p in planes]), np.array([p[1] for p in planes]))
        self._cylinder = self._capped_cylinder(halfspaces, others)
        if not others:
            # The vertex mean of a full-dimensional polytope is interior and more central than
            # the (non-unique) Chebyshev centre.
            self._interior = (self._poly.vertices.mean(axis=0) if self._poly.bounded
                              else self._poly.center.copy())
            self.bounded = self._poly.bounded
        elif self._cylinder is not None and self._cylinder[3]:
            self._interior = 0.5 * (self._cylinder[1] + self._cylinder[2])
            self.bounded = True
        else:
            self._interior = self._deepest_point()
            self.bounded = (any(f.bounded for f in fs) or self._cylinder is not None
                            or self._recession_cone_is_zero(halfspaces, others))
        self._body_box = self.aabb(np.eye(self.dim), np.zeros(self.dim)) if self.bounded else None

    def _capped_cylinder(self, halfspaces, others):
        """(radius, axis point p0, p1, members-are-exactly-this) if one InfiniteCylinder is capped
        on both sides by half-spaces normal to its axis."""
        cylinders = [f for f in others if isinstance(f, InfiniteCylinder)]
        if len(cylinders) != 1:
            return None
        cyl = cylinders[0]
        u, c = cyl.axis, cyl.center
        t_lo, t_hi = -math.inf, math.inf
        all_caps = True
        for h in halfspaces:
            n, d = h.plane()
            nu = float(n @ u)
            if abs(abs(nu) - 1.0) > PARALLEL_TOL:
                all_caps = False
                continue
            # n = +-u: (+-u).(c + tau u) <= d bounds tau on one side.
            bound = (d - float(n @ c)) / nu
            if nu > 0:
                t_hi = min(t_hi, bound)
            else:
                t_lo = max(t_lo, bound)
        if not (math.isfinite(t_lo) and math.isfinite(t_hi)):
            return None
        if t_hi - t_lo <= INTERIOR_TOL * max(1.0, cyl.radius):
            raise ValueError("the caps of a capped cylinder must leave a positive length between "
                             f"them, got length {t_hi - t_lo:.3g}: the intersection is empty")
        exact = all_caps and len(others) == 1
        return cyl.radius, c + t_lo * u, c + t_hi * u, exact

    def _deepest_point(self) -> np.ndarray:
        """argmin_x max_i f_i(x) (SLSQP on min t s.t. f_i(x) <= t); raises if it is not < 0."""
        fs = self._functions
        dim = self.dim
        finite = [f.length_scale for f in fs if math.isfinite(f.length_scale)]
        scale = max(finite) if finite else 1.0
        starts = [np.mean([f.interior_point for f in fs], axis=0)] + [f.interior_point for f in fs]
        if self._poly is not None:
            starts.append(self._poly.center)

        def cons(z):
            return z[dim] - np.array([f.value(z[:dim]) for f in fs])

        def cons_jac(z):
            G = np.array([f.gradient(z[:dim]) for f in fs])
            return np.c_[-G, np.ones(len(fs))]

        best_x, best_t = None, math.inf
        for x0 in starts:
            t0 = max(f.value(x0) for f in fs) + 1e-3 * scale
            res = minimize(lambda z: z[dim], np.r_[x0, t0], jac=lambda z: np.r_[np.zeros(dim), 1.0],
                           constraints=[{"type": "ineq", "fun": cons, "jac": cons_jac}],
                           bounds=[(None, None)] * dim + [(-UNBOUNDED_INTERIOR_DEPTH * scale, None)],
                           method="SLSQP", options={"ftol": 1e-12, "maxiter": 200})
            x = res.x[:dim]
            t = max(f.value(x) for f in fs)
            if np.isfinite(t) and t < best_t:
                best_x, best_t = x, t
            if best_t < -INTERIOR_TOL * scale and res.success:
                break
        if best_x is None or not best_t < -INTERIOR_TOL * scale:
            raise ValueError("the members of an Intersection must have a common interior point "
                             f"(min over x of max_i f_i(x) is {best_t:.3g}, not negative): the "
                             "intersection is empty or degenerate")
        return best_x

    def _recession_cone_is_zero(self, halfspaces, others) -> bool:
        """Unbounded members only: {d : n_h.d <= 0, d parallel to every cylinder axis} = {0}?"""
        A_ub = np.array([h.plane()[0] for h in halfspaces]) if halfspaces else None
        eq = [np.eye(3) - np.outer(f.axis, f.axis) for f in others if isinstance(f, InfiniteCylinder)]
        A_eq = np.vstack(eq) if eq else None
        for k in range(self.dim):
            for sign in (1.0, -1.0):
                res = linprog(-sign * np.eye(self.dim)[k], A_ub=A_ub,
                              b_ub=None if A_ub is None else np.zeros(len(A_ub)),
                              A_eq=A_eq, b_eq=None if A_eq is None else np.zeros(len(A_eq)),
                              bounds=[(-1.0, 1.0)] * self.dim, method="highs")
                if res.status != 0 or -res.fun > 1e-9:
                    return False
        return True

    # -- factories ---------------------------------------------------------------------------
    @classmethod
    def box(cls, half_extents, center=None, rotation=None) -> "Intersection":
        """Box |x_i| <= h_i as six half-spaces (optional placement in the body)."""
        h = _positive_vector(half_extents, 3, "half_extents")
        return cls([HalfSpace(s * np.eye(3)[k], h[k], center, rotation) for k in range(3) for s in (1.0, -1.0)])

    @classmethod
    def rectangle(cls, half_extents, center=None, rotation=None) -> "Intersection":
        """Rectangle |x_i| <= h_i as four half-planes (2D; rotation is an angle in rad)."""
        h = _positive_vector(half_extents, 2, "half_extents")
        return cls([HalfPlane(s * np.eye(2)[k], h[k], center, rotation) for k in range(2) for s in (1.0, -1.0)])

    @classmethod
    def capped_cylinder(cls, radius, half_height, center=None, rotation=None) -> "Intersection":
        """Solid cylinder about the local z axis, |z| <= half_height: cylinder and two caps."""
        r = _positive(radius, "radius")
        h = _positive(half_height, "half_height")
        return cls([InfiniteCylinder(r, center, rotation),
                    HalfSpace([0.0, 0.0, 1.0], h, center, rotation),
                    HalfSpace([0.0, 0.0, -1.0], h, center, rotation)])

    @classmethod
    def polytope(cls, normals, offsets, center=None, rotation=None) -> "Intersection":
        """Convex polytope {x : normals @ x <= offsets} (2D or 3D by the normals' width)."""
        try:
            N = np.array(normals, dtype=float)
            b = np.array(offsets, dtype=float)
        except (TypeError, ValueError):
            raise ValueError("polytope needs an (m, dim) array of normals and m offsets") from None
        if N.ndim != 2 or N.shape[1] not in (2, 3) or b.shape != (N.shape[0],) or N.shape[0] == 0:
            raise ValueError("polytope needs an (m, 2) or (m, 3) array of normals and m offsets, got "
                             f"shapes {N.shape} and {b.shape}")
        kind = HalfPlane if N.shape[1] == 2 else HalfSpace
        return cls([kind(n, d, center, rotation) for n, d in zip(N, b)])

    @classmethod
    def fingertip(cls, vertex, normal1, normal2) -> "Intersection":
        """2D wedge of two half-planes n_i.(x - vertex) <= 0 meeting at the vertex ([GI] eqs 58-61).

        The right gripper of Sec. 6.4 is fingertip((q4, 0), (0, 1), (-1, 0)); the left one
        fingertip((q5, 0), (0, 1), (1, 0)).
        """
        v = _finite_vector(vertex, 2, "vertex")
        n1 = _finite_vector(normal1, 2, "normal1")
        n2 = _finite_vector(normal2, 2, "normal2")
        l1, l2 = float(np.linalg.norm(n1)), float(np.linalg.norm(n2))
        if l1 == 0.0 or l2 == 0.0:
            raise ValueError("fingertip normals must be non-zero vectors")
        if abs(n1[0] * n2[1] - n1[1] * n2[0]) <= 1e-12 * l1 * l2:
            raise ValueError("fingertip normals must not be parallel: the two edges must meet at a vertex")
        return cls([HalfPlane(n1, float(n1 @ v)), HalfPlane(n2, float(n2 @ v))])

    # -- function interface ------------------------------------------------------------------
    @property
    def functions(self) -> tuple[ConvexFunction, ...]:
        return self._functions

    def _stack(self, x, order):
        x = _points(x, self.dim)
        if len(self._functions) == 1:
            f = self._functions[0]
            if order == 0:
                return f.value(x), None, None
            if order == 1:
                return f.value(x), f.gradient(x), None
            return f.value_gradient_hessian(x)
        if x.ndim == 1:
            vals = [f.value(x) for f in self._functions]
            k = int(np.argmax(vals))
            f = self._functions[k]
            if order == 0:
                return vals[k], None, None
            if order == 1:
                return vals[k], f.gradient(x), None
            return f.value_gradient_hessian(x)
        vals = np.stack([np.asarray(f.value(x)) for f in self._functions])
        k = np.argmax(vals, axis=0)
        v = np.take_along_axis(vals, k[None], axis=0)[0]
        g = H = None
        if order >= 1:
            G = np.stack([f.gradient(x) for f in self._functions])
            g = np.take_along_axis(G, k[None, ..., None], axis=0)[0]
        if order >= 2:
            HH = np.stack([f.hessian(x) for f in self._functions])
            H = np.take_along_axis(HH, k[None, ..., None, None], axis=0)[0]
        return v, g, H

    def value(self, x):
        return self._stack(x, 0)[0]

    def gradient(self, x):
        return self._stack(x, 1)[1]

    def hessian(self, x):
        return self._stack(x, 2)[2]

    def value_gradient_hessian(self, x):
        return self._stack(x, 2)

    def aabb(self, rotation, translation):
        R, t = _check_pose(rotation, translation, self.dim)
        lo, hi = np.full(self.dim, -np.inf), np.full(self.dim, np.inf)
        boxes = [f.aabb(R, t) for f in self._functions if f.bounded]
        if self._poly is not None and (self._poly.bounded or self._poly.vertices is not None
                                       or len(self._poly.b) == len(self._functions)):
            boxes.append(self._poly.world_aabb(R, t))
        if self._cylinder is not None:
            r, p0, p1, _ = self._cylinder
            w0, w1 = R @ p0 + t, R @ p1 + t
            u = (w1 - w0) / np.linalg.norm(w1 - w0)
            rad = r * np.sqrt(np.clip(1.0 - u * u, 0.0, 1.0))
            boxes.append((np.minimum(w0, w1) - rad, np.maximum(w0, w1) + rad))
        for b_lo, b_hi in boxes:
            lo, hi = np.maximum(lo, b_lo), np.minimum(hi, b_hi)
        return lo, hi

    @property
    def interior_point(self) -> np.ndarray:
        return self._interior.copy()

    @property
    def length_scale(self) -> float:
        """Half the largest side of the body-frame box if bounded, else the smallest finite
        member length (inf if none)."""
        if self.bounded and np.all(np.isfinite(self._body_box[0])) and np.all(np.isfinite(self._body_box[1])):
            return float(0.5 * np.max(self._body_box[1] - self._body_box[0]))
        finite = [f.length_scale for f in self._functions if math.isfinite(f.length_scale)]
        return min(finite) if finite else math.inf

    def support(self, direction) -> np.ndarray:
        """A boundary point maximising direction . x: a vertex of a polytope, the closed form of a
        capped cylinder; NotImplementedError for other intersections."""
        return self._support_point(_nonzero_direction(direction, self.dim))

    def _support_point(self, d: np.ndarray) -> np.ndarray:
        """support of a checked direction (ConvexFunction._support_point)."""
        if self._poly is not None and self._poly.bounded and len(self._poly.b) == len(self._functions):
            V = self._poly.vertices
            return V[int(np.argmax(V @ d))].copy()
        if self._cylinder is not None and self._cylinder[3]:
            r, p0, p1, _ = self._cylinder
            u = (p1 - p0) / np.linalg.norm(p1 - p0)
            end = p1 if float(d @ u) >= 0.0 else p0
            perp = d - float(d @ u) * u
            norm = float(np.linalg.norm(perp))
            return end + r * perp / norm if norm > 0.0 else end.copy()
        raise NotImplementedError("this Intersection has no closed-form support point (only bounded "
                                  "polytopes and capped cylinders have one).")

    def face_points(self, samples=FACE_SAMPLES) -> np.ndarray | None:
        """Body-frame points whose hull along any normal spans the face a contact can press on
        (patch.py): a polytope's vertices; a capped cylinder's rim circles sampled at samples
        points each (its cap is that polygon, its side a segment along the axis). [] (no face
        known: a contact touches in a point) for other intersections."""
        if self._poly is not None and self._poly.bounded and len(self._poly.b) == len(self._functions):
            return self._poly.vertices.copy()
        if self._cylinder is not None and self._cylinder[3] and self.dim == 3:
            r, p0, p1, _ = self._cylinder
            u = (p1 - p0) / np.linalg.norm(p1 - p0)
            e1 = np.cross(u, _least_aligned_axis(u))
            e1 /= np.linalg.norm(e1)
            e2 = np.cross(u, e1)
            t = 2.0 * math.pi * np.arange(samples) / samples
            ring = r * (np.cos(t)[:, None] * e1 + np.sin(t)[:, None] * e2)
            return np.r_[p0 + ring, p1 + ring]
        return np.empty((0, self.dim))

    def ray_exit(self, origin, direction) -> float:
        """First exit of the ray from the body: the smallest member exit (origin inside)."""
        return self._ray_exit(_finite_vector(origin, self.dim, "origin"), _nonzero_direction(direction, self.dim))

    def _ray_exit(self, o: np.ndarray, u: np.ndarray) -> float:
        """ray_exit of a checked origin and direction (ConvexFunction._ray_exit)."""
        return min(f._ray_exit(o, u) for f in self._functions)

    def mass_properties(self, density) -> MassProperties:
        rho = _density(density)
        if self._poly is not None and self._poly.bounded and len(self._poly.b) == len(self._functions):
            return _polytope_mass(self._poly.vertices, rho)
        if self._cylinder is not None and self._cylinder[3]:
            r, p0, p1, _ = self._cylinder
            L = float(np.linalg.norm(p1 - p0))
            u = (p1 - p0) / L
            m = rho * math.pi * r * r * L
            i_axis, i_perp = 0.5 * m * r * r, m * (3.0 * r * r + L * L) / 12.0
            inertia = i_perp * (np.eye(3) - np.outer(u, u)) + i_axis * np.outer(u, u)
            return MassProperties(m, 0.5 * (p0 + p1), inertia)
        raise NotImplementedError("mass properties have closed forms only for bounded polytopes and "
                                  "capped cylinders; give this body's mass and inertia explicitly.")

    def to_dict(self) -> dict:
        return {"type": "Intersection", "functions": [f.to_dict() for f in self._functions]}

    def __repr__(self) -> str:
        return "Intersection([" + ", ".join(repr(f) for f in self._functions) + "])"


def _polytope_mass(V: np.ndarray, rho: float) -> MassProperties:
    dim = V.shape[1]
    hull = ConvexHull(V)
    pts = V[hull.vertices]
    c = pts.mean(axis=0)               # inside: every simplex with apex c has positive measure
    mass = 0.0
    first = np.zeros(dim)
    second = np.zeros((dim, dim))
    denom = 20.0 if dim == 3 else 12.0
    for simplex in hull.simplices:
        verts = np.vstack([c, V[simplex]])
        measure = abs(np.linalg.det(verts[1:] - c)) / math.factorial(dim)
        s = verts.sum(axis=0)
        mass += measure
        first += measure * s / (dim + 1)
        second += measure / denom * (verts.T @ verts + np.outer(s, s))
    com = first / mass
    cov = rho * (second - mass * np.outer(com, com))   # int (x-com)(x-com)^T dm
    m = rho * mass
    if dim == 3:
        inertia = np.trace(cov) * np.eye(3) - cov
    else:
        inertia = float(np.trace(cov))
    return MassProperties(float(m), com, inertia)


class Union:
    """Non-convex body: the union of convex parts ([GI] Sec. 6.4: the gear is a disc and teeth).

    value = min over parts (inside iff inside some part); gradient/Hessian of the minimising
    part (not smooth where parts meet). Contacts are formed per part.
    """

    def __init__(self, parts: Sequence[ConvexFunction | Intersection]):
        if isinstance(parts, (ConvexFunction, Intersection, Union)):
            raise ValueError("Union takes a sequence of convex parts, got a single shape")
        flat = []
        for p in list(parts):
            if isinstance(p, Union):
                flat.extend(p.parts)
            elif isinstance(p, (ConvexFunction, Intersection)):
                flat.append(p)
            else:
                raise ValueError(f"Union parts must be ConvexFunction or Intersection objects, got {type(p).__name__}")
        if not flat:
            raise ValueError("a Union needs at least one convex part")
        dims = {p.dim for p in flat}
        if len(dims) != 1:
            raise ValueError(f"all parts of a Union must have the same dim, got {sorted(dims)}")
        self.parts = tuple(flat)
        self.dim = flat[0].dim
        self.bounded = all(p.bounded for p in flat)

    def _pick(self, x, order):
        x = _points(x, self.dim)
        vals = np.stack([np.asarray(p.value(x)) for p in self.parts])
        k = np.argmin(vals, axis=0)
        v = np.take_along_axis(vals, np.asarray(k)[None], axis=0)[0]
        if order == 0:
            return _as_float(v)
        if x.ndim == 1:
            part = self.parts[int(k)]
            return part.gradient(x) if order == 1 else part.hessian(x)
        if order == 1:
            G = np.stack([p.gradient(x) for p in self.parts])
            return np.take_along_axis(G, k[None, ..., None], axis=0)[0]
        HH = np.stack([p.hessian(x) for p in self.parts])
        return np.take_along_axis(HH, k[None, ..., None, None], axis=0)[0]

    def value(self, x):
        return self._pick(x, 0)

    def gradient(self, x):
        return self._pick(x, 1)

    def hessian(self, x):
        return self._pick(x, 2)

    def aabb(self, rotation, translation):
        boxes = [p.aabb(rotation, translation) for p in self.parts]
        return np.min([b[0] for b in boxes], axis=0), np.max([b[1] for b in boxes], axis=0)

    @property
    def interior_point(self) -> np.ndarray:
        return self.parts[0].interior_point

    @property
    def length_scale(self) -> float:
        return max(p.length_scale for p in self.parts)

    def mass_properties(self, density) -> MassProperties:
        raise NotImplementedError("a Union's parts may overlap, so its mass properties have no closed "
                                  "form here; give the body's mass and inertia explicitly.")

    def to_dict(self) -> dict:
        return {"type": "Union", "parts": [p.to_dict() for p in self.parts]}

    def __repr__(self) -> str:
        return "Union([" + ", ".join(repr(p) for p in self.parts) + "])"


# --------------------------------------------------------------------------------------------
# serialisation
# --------------------------------------------------------------------------------------------
_PRIMITIVES = MappingProxyType({
    "Sphere": (Sphere, ("radius",)),
    "Disc": (Disc, ("radius",)),
    "Ellipsoid": (Ellipsoid, ("semi_axes",)),
    "Ellipse": (Ellipse, ("semi_axes",)),
    "Superquadric": (Superquadric, ("semi_axes", "exponent")),
    "Superellipse": (Superellipse, ("semi_axes", "exponent")),
    "HalfSpace": (HalfSpace, ("normal", "offset")),
    "HalfPlane": (HalfPlane, ("normal", "offset")),
    "InfiniteCylinder": (InfiniteCylinder, ("radius",)),
})


def shape_from_dict(d: dict):
    """Rebuild a shape from its to_dict() (plain JSON types): the exact same shape."""
    if not isinstance(d, dict) or "type" not in d:
        raise ValueError(f"a shape dict has a 'type' key and the shape's parameters, got {d!r}")
    kind = d["type"]
    if kind == "Intersection":
        return Intersection([shape_from_dict(f) for f in d["functions"]])
    if kind == "Union":
        return Union([shape_from_dict(p) for p in d["parts"]])
    if kind not in _PRIMITIVES:
        raise ValueError(f"unknown shape type {kind!r}; known are {sorted(_PRIMITIVES) + ['Intersection', 'Union']}")
    cls, names = _PRIMITIVES[kind]
    missing = [n for n in names if n not in d]
    if missing:
        raise ValueError(f"a {kind} dict needs the keys {list(names)}, missing {missing}")
    return cls(*[d[n] for n in names], center=d.get("center"), rotation=d.get("rotation"))
