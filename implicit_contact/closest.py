"""Static closest points of two convex bodies in given poses, from the KKT conditions of [GI].

Problem ([GI] eq 9)
-------------------
    (a1, a2) = argmin { |xi1 - xi2|^2 : f_i(xi1) <= 0 (body 1), g_j(xi2) <= 0 (body 2) },

with f_i, g_j the world-frame functions f(R^T (x - p)) of the shapes of shapes.py. Its KKT
conditions are eqs (24)-(27) with one multiplier per function ("hat" multipliers):

    a1 - a2 = - sum_i lh_i grad f_i(a1)                                                  (24)
    a1 - a2 =   sum_j lh_j grad g_j(a2)                                                  (25)
    0 <= lh_i _|_ -f_i(a1) >= 0,   0 <= lh_j _|_ -g_j(a2) >= 0                          (26-27)

At a1 = a2 all lh vanish and every common point solves (24)-(27), so [GI] divides by the
multiplier of one active surface k1 of body 1 (eqs 28-31; eqs 15-18 when body 1 is one
function): l_k1 = lh_k1, l_i = lh_i / lh_k1, l_j = lh_j / lh_k1, and

    a1 - a2 = -l_k1 (grad f_k1(a1) + sum_{i != k1} l_i grad f_i(a1))                   (28)
    grad f_k1(a1) + sum_{i != k1} l_i grad f_i(a1) = - sum_j l_j grad g_j(a2)           (29)
    0 <= l_i _|_ -f_i(a1) >= 0,    0 <= l_j _|_ -g_j(a2) >= 0                           (30-31)

which stays regular when the bodies touch (l_k1 = 0, the other l finite).

What is solved
--------------
All three systems are box MCPs for ncp.solve_mcp (positions free, multipliers in [0, inf)),
each with its exact Jacobian (Hessians of the shapes enter through the gradients):

* one body is a single function f: eqs (15)-(18) / (28)-(31) with that body as F, unknowns
  (a_F, a_G, l_F, l_G,j) -- k1 is known a priori ([GI] Sec. 7);
* body 1 an intersection, body 2 one function: the same with the roles swapped, converted back
  through the hat multipliers (lh_F = l_F, lh_i = l_F l_i);
* both bodies are intersections: the symmetric form (24)-(27), which needs no k1 and is valid
  for separated bodies; then k1 = the index of body 1's largest multiplier and a polish with
  (28)-(31), because in (24)-(27) every multiplier is proportional to the distance, so the
  ratios (and the normal) lose accuracy as the bodies close in;
* overlap and depth: the convex problem min_x max(max_i f_i(x), max_j g_j(x)) in epigraph form
  min t s.t. h_k(x) <= t, whose KKT system is
      sum_k mu_k grad h_k(x) = 0,   1 - sum_k mu_k = 0,   0 <= mu_k _|_ t - h_k(x) >= 0.
  Its optimal value t* is < 0 iff the interiors intersect, 0 iff the bodies touch, > 0 iff they
  are apart; the minimiser x* is a deepest common point in the algebraic sense, and the depth is
  reported as -t* (a length to first order since every f is a normalised signed distance near
  its surface, see shapes.py; it is not the Euclidean penetration depth). Two polyhedra make
  this a linear program with typically degenerate optima (an edge on a vertex), solved by
  scipy's HiGHS instead. When t* = 0 (touching) eqs (28)-(31) are solved once more from x*
  with k1 and ratios from the multipliers mu: they are regular there (Prop. 4.3).

Every solution of (15)-(18) with a1 != a2 is a KKT point of the convex problem (9), hence the
global minimum; the spurious roots of (15)-(18) for overlapping bodies all have a1 = a2 with
f(a1) < 0 (the reason [GI] adds eq 19). So a converged KKT solve with a positive distance is
final, and a zero distance is classified by f(a1) (touching iff f(a1) = 0) or by t*.

Scaling and start
-----------------
Positions are solved in units of L = the smaller finite length scale of the two shapes about
an origin near the bodies, so the solver's tolerance means the same for millimetre and metre
scenes; functions are divided by L (they are lengths), multipliers l_k1 and lh are lengths.
Newton on KKT needs a start near the solution. Against a half-space with normal n the other
body's closed-form support point along -n (shapes.support) and its projection on the plane
are the exact answer. Otherwise, when both shapes have closed-form support points, a few
fixed-point steps d <- s2(-d) - s1(d) from the line between the interior points (exact for two
spheres at once); when d.(s2 - s1) > 0 this also proves the bodies apart. Failing that, each
body's point is the exit of the ray from its interior point towards the other's; if the two
rays share a stretch of the segment, the bodies overlap and only the depth problem is solved.
Multipliers start from (15)-(16) by non-negative least squares over near-active members.

Normal: unit, world, from body 1 towards body 2, always from gradients: grad f_k1(a1) +
sum l_i grad f_i(a1) normalised ([GI] Sec. 4.1 notes: never (a1 - a2)/|a1 - a2|). When
overlapping, the body-1 part sum mu_i grad f_i(x*) of the depth problem (or minus the body-2
part, or the line between the interior points if both vanish).
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
import math

import numpy as np
from scipy.optimize import linprog, nnls

from . import ncp
from . import shape_kernels as sk
from ._jit import kernel, lean_kernel
from .ncp import SolverOptions, Status, solve_mcp
from .shapes import (ConvexFunction, HalfPlane, HalfSpace, Intersection, Union, _Ball, _EllipsoidBase,
                     _HalfSpaceBase, _nonzero, _PowerSumBase)

__all__ = ["closest_points", "ClosestPointResult", "ClosestPointOptions"]

NEAR_ACTIVE = 0.1          # [L] members within this of the surface get a starting multiplier
ROTATION_TOL = 1e-9        # accepted |R^T R - I|_max of a pose
SMALL_HAT_DISTANCE = 1e-6  # [L] below this a distance from eqs (24)-(27) alone is re-checked
SUPPORT_STEPS = 4          # fixed-point steps d <- s2(-d) - s1(d) of the support-point start
POLYTOPE_SUM_WEIGHT = 1e5  # weight of the sum-to-one rows of the polytopes' vertex NNLS (positions in L)
POLYTOPE_ACTIVE = 1e-9     # [L] a plane this close to the closest point is active (its multiplier may be > 0)
POLYTOPE_RESIDUAL = 1e-8   # [L] largest residual of eqs (24)-(27) the vertex QP's answer may leave
PATIENT_FACTOR = 20        # the last KKT solve of bodies shown apart gets this many times the iterations


@dataclass(frozen=True)
class ClosestPointOptions:
    """Options of closest_points.

    solver: options of ncp.solve_mcp; its tol bounds the natural residual in units of the
        length scale L (nominal 1e-12..1e-9).
    touch_tol: relative to L: a distance, |f(a1)| or depth below touch_tol * L counts as
        touching, > 0, nominal 1e-10..1e-6.
    depth_tol: natural-residual tolerance of the depth problem (units of L), used when larger
        than solver.tol: its minimum can be degenerate (flat minima of high exponents, polytope
        faces), where Newton is only linear; nominal 1e-11..1e-8, must exceed 0 and stay below
        touch_tol so that touching and overlapping stay distinguishable.
    """

    solver: SolverOptions = field(default_factory=lambda: SolverOptions(tol=1e-12, max_iterations=60))
    touch_tol: float = 1e-9
    depth_tol: float = 1e-10

    def __post_init__(self):
        if not isinstance(self.solver, SolverOptions):
            raise ValueError(f"solver must be an ncp.SolverOptions, got {type(self.solver).__name__}")
        if isinstance(self.touch_tol, bool) or not isinstance(self.touch_tol, (int, float)) \
                or not (math.isfinite(self.touch_tol) and self.touch_tol > 0):
            raise ValueError(f"touch_tol must be a positive finite number, got {self.touch_tol!r}")
        if isinstance(self.depth_tol, bool) or not isinstance(self.depth_tol, (int, float)) \
                or not (0 < self.depth_tol < self.touch_tol):
            raise ValueError(f"depth_tol must lie in (0, touch_tol = {self.touch_tol}), got {self.depth_tol!r}")


@dataclass(frozen=True)
class ClosestPointResult:
    """Closest points of body 1 and body 2 (world frame).

    a1, a2: closest points (both = a deepest common point x* when overlapping).
    l1, l2: multipliers of eqs (28)-(31) with k1 on body 1: l1[k1] = l_k1 (a length), the other
        entries dimensionless ratios lh / lh_k1; one entry per function of each shape (for a
        single-function body 1, l1 = [l1] and l2 are those of eqs 15-18). When touching or
        overlapping l1[k1] = 0 and the ratios come from the depth problem's multipliers.
    k1: index of the active surface of body 1 used in (28).
    distance: |a1 - a2| (0 when touching or overlapping).
    normal: unit, world, from body 1 towards body 2, from gradients.
    overlapping: interiors intersect; depth: -min_x max(f, g) >= 0 (algebraic, length units).
    success/status/iterations/residual/message: the last solve (iterations summed over solves);
        success is also True when the depth problem stopped short on a flat minimum but its
        iterate is inside both bodies (the overlap is then certain and depth a lower bound;
        status keeps the solver's, message says so).
    form: which system gave the answer: "eq15-18" (body 1 one function), "eq15-18 swapped"
        (body 2 one function, converted), "eq28-31" (both intersections: eqs 24-27 then a
        polish with k1), "eq24-27" (the polish failed), "eq28-31 touching" (depth problem at
        t* = 0, then polished), "depth" (overlapping, or touching unpolished), "polytopes" (two
        bounded polytopes apart: the vertex quadratic program, _Solver.polytopes), "failed".
    """

    a1: np.ndarray
    a2: np.ndarray
    l1: np.ndarray
    l2: np.ndarray
    k1: int
    distance: float
    normal: np.ndarray
    overlapping: bool
    depth: float
    success: bool
    status: Status
    iterations: int
    residual: float
    message: str
    form: str


# --------------------------------------------------------------------------------------------
# world-frame functions in scaled coordinates
# --------------------------------------------------------------------------------------------
class _Body:
    """The functions of one posed shape in coordinates y = (x_world - o) / L."""

    def __init__(self, shape, R, p, o, L):
        self.shape = shape
        self.functions = shape.functions
        self.m = len(self.functions)
        self.dim = shape.dim
        self.R, self.p, self.L, self.o = R, p, L, o
        self._b0 = R.T @ (o - p)        # body point of y = 0
        self._B = L * R.T               # d x_body / d y
        self._H = None
        self._linear = None
        if self.m > 1 and all(isinstance(f, (HalfSpace, HalfPlane)) for f in self.functions):
            # a polytope: values N y - b, gradients N, Hessians 0 (one product, not m calls)
            N, b = self.linear_rows()
            N.flags.writeable = b.flags.writeable = False
            zero = np.zeros((self.m, self.dim, self.dim))
            zero.flags.writeable = False
            self._linear = (N, b, zero)
        if self.m == 1 and self.functions[0].constant_hessian:
            # quadrics and planes: the scaled world Hessian L R H R^T is fixed for the solve
            H = self.functions[0].hessian(self._b0)
            self._H = (L * (R @ H @ R.T))[None]

    @property
    def par(self):
        """shape_kernels' row of a single function (its kernel parameters)."""
        return self.functions[0].kernel_params

    def to_body(self, y):
        return self._b0 + self._B @ y

    @property
    def vertices(self):
        """Scaled world vertices (k, dim) of a bounded polytope, else None."""
        if self._linear is None or not self.shape.bounded:
            return None
        V = self.shape.face_points()
        if len(V) == 0:
            return None
        return (V @ self.R.T + self.p - self.o) / self.L

    def world(self, y):
        return self.o + self.L * y

    def scaled(self, x_world):
        return (x_world - self.o) / self.L

    def eval(self, y, order=2):
        """Scaled values (m,), gradients (m, dim), Hessians (m, dim, dim) at y."""
        xb = self.to_body(y)
        R, L, m, d = self.R, self.L, self.m, self.dim
        if m == 1:
            f = self.functions[0]
            if order >= 2 and self._H is not None:
                fv, fg = f.value_gradient(xb)
                return np.array([fv / L]), (R @ fg)[None], self._H
            if order >= 2:
                fv, fg, fh = f.value_gradient_hessian(xb)
                return np.array([fv / L]), (R @ fg)[None], (L * (R @ fh @ R.T))[None]
            fv, fg = f.value_gradient(xb)
            return np.array([fv / L]), (R @ fg)[None], None
        if self._linear is not None:
            N, b, zero = self._linear
            return N @ y - b, N, (zero if order >= 2 else None)
        v = np.empty(m)
        G = np.empty((m, d))
        H = np.empty((m, d, d)) if order >= 2 else None
        for i, f in enumerate(self.functions):
            if order >= 2:
                fv, fg, fh = f.value_gradient_hessian(xb)
                H[i] = L * (R @ fh @ R.T)
            else:
                fv, fg = f.value_gradient(xb)
            v[i] = fv / L
            G[i] = R @ fg
        return v, G, H

    def values(self, y):
        if self._linear is not None:
            return self._linear[0] @ y - self._linear[1]
        xb = self.to_body(y)
        return np.array([f.value(xb) for f in self.functions]) / self.L

    @property
    def plane(self):
        """(unit world normal, scaled offset) if the body is one half-space, else None."""
        if self.m != 1 or not isinstance(self.functions[0], (HalfSpace, HalfPlane)):
            return None
        n_b, d_b = self.functions[0].plane()
        n = self.R @ n_b
        return n, (d_b + float(n @ self.p) - float(n @ self.o)) / self.L

    def linear_rows(self):
        """(N, b) with the scaled functions N y - b, if every function is a half-space."""
        if not all(isinstance(f, (HalfSpace, HalfPlane)) for f in self.functions):
            return None
        rows = [f.plane() for f in self.functions]
        N = np.array([self.R @ n for n, _ in rows])
        b = np.array([(d + float((self.R @ n) @ (self.p - self.o))) / self.L for n, d in rows])
        return N, b

    def support(self, direction):
        """Scaled support point along a world direction, or None without a closed form."""
        if not self.shape.bounded:
            return None
        try:
            # (the shape's support without its input check: the direction is made here)
            xb = self.shape._support_point(_nonzero(self.R.T @ direction))
        except NotImplementedError:
            return None
        return (self.R @ xb + self.p - self.o) / self.L

    def ray_exit(self, origin_y, target_y) -> float:
        """Fraction s in [0, inf] of the segment origin -> target where the ray leaves the body."""
        ob = self.to_body(origin_y)
        ub = self._B @ (target_y - origin_y)
        return float(self.shape._ray_exit(ob, _nonzero(ub)))     # (unchecked: ob and ub are made here)

    def ray_origin(self, target_y, interior_y):
        """A point strictly inside, near the target: the interior point for a bounded body; for
        an unbounded one, Newton projection of the target onto the surface pushed one L inside
        (exact for a half-space)."""
        if self.shape.bounded:
            return interior_y
        y = np.array(target_y, dtype=float)
        for _ in range(8):
            v, G, _ = self.eval(y, order=1)
            k = int(np.argmax(v))
            if v[k] < -0.5:
                return y
            gg = float(G[k] @ G[k])
            if gg == 0.0:
                break
            y = y - (v[k] + 1.0) * G[k] / gg
        return y if float(np.max(self.values(y))) < 0.0 else interior_y


def _check_pose(pose, dim, name):
    try:
        R, p = pose
        R = np.asarray(R, dtype=float)
        p = np.asarray(p, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair (R ({dim},{dim}), p ({dim},)), got {pose!r}") from None
    if R.shape != (dim, dim) or p.shape != (dim,):
        raise ValueError(f"{name} must be a pair (R ({dim},{dim}), p ({dim},)) for {dim}D shapes, got "
                         f"shapes {R.shape} and {p.shape}")
    bad = _pose_error(R, p, ROTATION_TOL)
    if bad == 1:
        raise ValueError(f"{name} must be finite")
    if bad == 2:
        raise ValueError(f"{name} rotation must be a proper rotation (orthonormal, det +1)")
    return R, p


@lean_kernel
def _pose_error(R, p, tol):
    """_check_pose's test of a pose of the right shapes: 0 if R is a proper rotation (|R^T R -
    I|_max <= tol, det > 0) and R and p are finite, 1 if not finite, 2 if not a rotation (one
    compiled call: the numpy expression cost 25 us of a ~100 us closest_points)."""
    dim = p.shape[0]
    for i in range(dim):
        if not np.isfinite(p[i]):
            return 1
        for j in range(dim):
            if not np.isfinite(R[i, j]):
                return 1
    for i in range(dim):
        for j in range(dim):
            acc = -1.0 if i == j else 0.0
            for k in range(dim):
                acc += R[k, i] * R[k, j]
            if abs(acc) > tol:
                return 2
    if dim == 2:
        det = R[0, 0] * R[1, 1] - R[0, 1] * R[1, 0]
    else:
        det = (R[0, 0] * (R[1, 1] * R[2, 2] - R[1, 2] * R[2, 1]) - R[0, 1] * (R[1, 0] * R[2, 2] - R[1, 2] * R[2, 0])
               + R[0, 2] * (R[1, 0] * R[2, 1] - R[1, 1] * R[2, 0]))
    return 2 if det < 0.0 else 0


def _check_shape(shape, name):
    if isinstance(shape, Union):
        raise ValueError(f"{name} is a Union: closest points are defined per convex part; "
                         "call closest_points for each part of shape.parts")
    if not isinstance(shape, (ConvexFunction, Intersection)):
        raise ValueError(f"{name} must be a ConvexFunction or an Intersection, got {type(shape).__name__}")


# --------------------------------------------------------------------------------------------
# the three MCPs
# --------------------------------------------------------------------------------------------
def _weighted(w: np.ndarray, H: np.ndarray) -> np.ndarray:
    """sum_k w_k H_k."""
    return w[0] * H[0] if len(w) == 1 else np.einsum("k,kij->ij", w, H)


@lean_kernel
def _body_eval(z, off, dim, L, par, b0, B, R, xb, gb, Hb, G, Hw, order):
    """_Body.eval of a single function at y = z[off:off + dim]: its scaled value f / L (returned),
    (order >= 1) world gradient G = R grad f and (order 2) scaled world Hessian Hw = L R Hess f R^T."""
    for i in range(3):
        xb[i] = 0.0
    for i in range(dim):
        acc = b0[i]
        for j in range(dim):
            acc += B[i, j] * z[off + j]
        xb[i] = acc
    v = sk.evaluate(par, xb, gb, Hb, order)
    if order >= 1:
        for i in range(dim):
            acc = 0.0
            for j in range(dim):
                acc += R[i, j] * gb[j]
            G[i] = acc
    if order >= 2:
        for i in range(dim):
            for j in range(dim):
                acc = 0.0
                for k in range(dim):
                    for m in range(dim):
                        acc += R[i, k] * Hb[k, m] * R[j, m]
                Hw[i, j] = L * acc
    return v / L


@lean_kernel
def _static_rows(z, dim, L, par1, b01, B1, R1, par2, b02, B2, R2, N2, c2, F, J, need_jac, xb, gb, Hb, G1, H1, H2,
                 V2, G2):
    """_scaled_form's rows (eqs 15-18, k1 = 0) for a single-function body 1 and, as body 2, a
    single function (par2, b02, B2, R2) if N2 has no rows, else the polytope of the scaled
    functions N2 y - c2 (gradients N2, Hessians 0); z = [a1, a2, l1, l2 (m2)]. V2 (m2) and G2
    (m2, dim) receive body 2's values and gradients."""
    order = 2 if need_jac else 1
    fv = _body_eval(z, 0, dim, L, par1, b01, B1, R1, xb, gb, Hb, G1, H1, order)
    single = N2.shape[0] == 0
    m2 = 1 if single else N2.shape[0]
    if single:
        V2[0] = _body_eval(z, dim, dim, L, par2, b02, B2, R2, xb, gb, Hb, G2[0], H2, order)
    else:
        for j in range(m2):
            acc = 0.0
            for i in range(dim):
                G2[j, i] = N2[j, i]
                acc += N2[j, i] * z[dim + i]
            V2[j] = acc - c2[j]
    lk = z[2 * dim]
    o2 = 2 * dim + 1
    for i in range(dim):
        F[i] = z[i] - z[dim + i] + lk * G1[i]
        acc = G1[i]
        for j in range(m2):
            acc += z[o2 + j] * G2[j, i]
        F[dim + i] = acc
    F[2 * dim] = -fv
    for j in range(m2):
        F[o2 + j] = -V2[j]
    if not need_jac:
        return
    n = o2 + m2
    for i in range(n):
        for j in range(n):
            J[i, j] = 0.0
    for i in range(dim):
        for j in range(dim):
            J[i, j] = lk * H1[i, j]
            J[dim + i, j] = H1[i, j]
            if single:
                J[dim + i, dim + j] = z[o2] * H2[i, j]
        J[i, i] += 1.0
        J[i, dim + i] = -1.0
        J[i, 2 * dim] = G1[i]
        J[2 * dim, i] = -G1[i]
        for j in range(m2):
            J[dim + i, o2 + j] = G2[j, i]
            J[o2 + j, dim + i] = -G2[j, i]


@kernel
def _solve_single(dim, L, par1, b01, B1, R1, par2, b02, B2, R2, N2, c2, x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit,
                  d, g, da, db, zk, Jz, history, steps, info, fbuf, work, J, H):
    """One solve of eqs (15)-(18) with body 1 a single function, by ncp.mcp_iterations, every
    request answered inside the call (as step_solver._solve_dense); the outcome in the ncp
    buffers; body 2 as in _static_rows."""
    n = x0.shape[0]
    Fj = np.empty(n)
    xb, gb, Hb = np.zeros(3), np.zeros(3), np.zeros((3, 3))
    m2 = max(N2.shape[0], 1)
    G1, H1, H2 = np.zeros(dim), np.zeros((dim, dim)), np.zeros((dim, dim))
    V2, G2 = np.zeros(m2), np.zeros((m2, dim))
    for req in ncp.mcp_iterations(x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz, history,
                                  steps, info, fbuf, work):
        if req == ncp.REQ_F:
            _static_rows(xt, dim, L, par1, b01, B1, R1, par2, b02, B2, R2, N2, c2, Ft, J, False, xb, gb, Hb, G1, H1,
                         H2, V2, G2)
        elif req == ncp.REQ_J:
            _static_rows(x, dim, L, par1, b01, B1, R1, par2, b02, B2, R2, N2, c2, Fj, J, True, xb, gb, Hb, G1, H1,
                         H2, V2, G2)
            info[ncp.I_BAD] = ncp.nonfinite(J)
        else:
            ncp.dense_request(req, J, zk, Jz, da, db, Phi, H, g, d, info, fbuf)


# --------------------------------------------------------------------------------------------
# two single functions, end to end in one compiled call
# --------------------------------------------------------------------------------------------
# The driver's path for two single-function bodies (support-point or ray start, then eqs 15-18)
# written once more as kernels over the functions' par rows, so that a new pair's static closest
# points (the stepper's seed of every new pair) cost one call instead of ~60 small numpy calls:
# measured at 576 us per seed in the 100-superquadric box, 17 % of its steps. The arithmetic is
# the Python path's, operation for operation, except the order of a few sums (norms and 3x3
# products: round-off). Whatever this path does not finish (overlap, a failed or spurious KKT
# solve, a shape without a closed-form support) returns FAST_FALLBACK and the Python driver
# solves the pair from the start, so the two can differ only by round-off.
FAST_OK, FAST_FALLBACK = 0, 1
_FAST_CODES = (sk.BALL, sk.ELLIPSOID, sk.POWER, sk.BARR, sk.PLANE)
_MACHINE_EPS = sk.MACHINE_EPS


@lean_kernel
def _support(par, R, p, o, L, dirw, out, w):
    """_Body.support: the scaled world support point of a bounded function along the world
    direction dirw (dim,), into out. w: (5, 3) scratch."""
    dim = int(par[sk.DIM])
    db, dl, xl = w[0], w[1], w[2]
    for i in range(dim):                         # body frame R^T d, then local R0^T (R^T d)
        acc = 0.0
        for k in range(dim):
            acc += R[k, i] * dirw[k]
        db[i] = acc
    for i in range(dim):
        acc = 0.0
        for k in range(dim):
            acc += db[k] * par[sk.R0 + 3 * k + i]
        dl[i] = acc
    sk.support_local(par, dl, xl, w[3], w[4])
    for i in range(dim):                         # body point c0 + R0 xl
        acc = 0.0
        for k in range(dim):
            acc += par[sk.R0 + 3 * i + k] * xl[k]
        db[i] = par[sk.C0 + i] + acc
    for i in range(dim):
        acc = 0.0
        for k in range(dim):
            acc += R[i, k] * db[k]
        out[i] = (acc + p[i] - o[i]) / L


@lean_kernel
def _polytope_support(V, R, p, o, L, dirw, out, w):
    """_Body.support of a bounded polytope with body-frame vertices V: the first vertex of
    largest V (R^T dirw), scaled world, into out. w: (5, 3) scratch."""
    dim = V.shape[1]
    db = w[0]
    for i in range(dim):
        acc = 0.0
        for k in range(dim):
            acc += R[k, i] * dirw[k]
        db[i] = acc
    best = 0
    top = -np.inf
    for j in range(V.shape[0]):
        acc = 0.0
        for i in range(dim):
            acc += V[j, i] * db[i]
        if acc > top:
            best, top = j, acc
    for i in range(dim):
        acc = 0.0
        for k in range(dim):
            acc += R[i, k] * V[best, k]
        out[i] = (acc + p[i] - o[i]) / L


@kernel
def _nnls(A, b, x):
    """Non-negative least squares min |A x - b|, x >= 0 (Lawson and Hanson's active set method, as
    scipy.optimize.nnls) for the few columns of a start's multipliers (_start_multipliers); x is
    written. The least-squares subproblems by the normal equations (at most dim x dim here)."""
    m, n = A.shape
    for j in range(n):
        x[j] = 0.0
    if n == 0:
        return
    scale = 0.0
    for j in range(n):
        colsum = 0.0
        for i in range(m):
            colsum += abs(A[i, j])
        scale = max(scale, colsum)
    tol = 10.0 * max(m, n) * _MACHINE_EPS * scale
    passive = np.zeros(n, np.bool_)
    z = np.zeros(n)
    r = np.zeros(m)
    G = np.zeros((n, n))
    rhs = np.zeros(n)
    idx = np.zeros(n, np.int64)
    for _ in range(3 * n):
        for i in range(m):
            acc = b[i]
            for j in range(n):
                acc -= A[i, j] * x[j]
            r[i] = acc
        enter = -1
        top = tol
        for j in range(n):
            if not passive[j]:
                acc = 0.0
                for i in range(m):
                    acc += A[i, j] * r[i]
                if acc > top:
                    enter, top = j, acc
        if enter < 0:
            return
        passive[enter] = True
        for _inner in range(3 * n):
            # least squares on the passive columns: (A_P^T A_P) z_P = A_P^T b, Gaussian elimination
            k = 0
            for j in range(n):
                if passive[j]:
                    idx[k] = j
                    k += 1
            for a in range(k):
                ja = idx[a]
                acc = 0.0
                for i in range(m):
                    acc += A[i, ja] * b[i]
                rhs[a] = acc
                for c in range(k):
                    jc = idx[c]
                    acc = 0.0
                    for i in range(m):
                        acc += A[i, ja] * A[i, jc]
                    G[a, c] = acc
            singular = False
            for c in range(k):
                piv = c
                for a in range(c + 1, k):
                    if abs(G[a, c]) > abs(G[piv, c]):
                        piv = a
                if not abs(G[piv, c]) > tol * tol:
                    singular = True
                    break
                if piv != c:
                    for e in range(k):
                        G[c, e], G[piv, e] = G[piv, e], G[c, e]
                    rhs[c], rhs[piv] = rhs[piv], rhs[c]
                for a in range(c + 1, k):
                    f = G[a, c] / G[c, c]
                    for e in range(c, k):
                        G[a, e] -= f * G[c, e]
                    rhs[a] -= f * rhs[c]
            if singular:                    # the entering column depends on the others: stop here
                passive[enter] = False
                return
            for c in range(k - 1, -1, -1):
                acc = rhs[c]
                for e in range(c + 1, k):
                    acc -= G[c, e] * z[idx[e]]
                z[idx[c]] = acc / G[c, c]
            for j in range(n):
                if not passive[j]:
                    z[j] = 0.0
            feasible = True
            for a in range(k):
                if not z[idx[a]] > 0.0:
                    feasible = False
            if feasible:
                for j in range(n):
                    x[j] = z[j]
                break
            alpha = np.inf
            for a in range(k):
                j = idx[a]
                if not z[j] > 0.0:
                    alpha = min(alpha, x[j] / (x[j] - z[j]))
            for j in range(n):
                x[j] += alpha * (z[j] - x[j])
                if passive[j] and not x[j] > tol:
                    passive[j] = False
                    x[j] = 0.0


@kernel
def _single_run(dim, L, o, par1, R1, p1, b01, B1, par2, R2, p2, b02, B2, N2b, d2b, V2b, c1, c2, tol, x0, lo, hi,
                opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz, history, steps, info, fbuf, work, J, H, out):
    """_Solver.run for a single-function body 1 and, as body 2, a single function (par2; either
    may be a half-space) or, if N2b has rows, the bounded polytope of the body-frame planes
    N2b x <= d2b with vertices V2b (body 1 then not a half-space): the start from support points
    (a half-space: the other's support along its normal; against a polytope also the ray exits,
    the closer pair kept) or ray exits, eqs (15)-(18) by _solve_single (body 2's multipliers
    started by NNLS over its near-active planes), the spurious-root check and the normal. Writes
    out = [a1 (3), a2 (3), normal (3), l1, l2 (m2)] (world, a1 and a2 unscaled) and the solve into
    the ncp buffers; returns FAST_OK, or FAST_FALLBACK for what the Python driver must do (an
    overlap, the depth problem, a failed solve), having changed nothing else."""
    w = np.zeros((6, 3))
    xb, gb, Hb = np.zeros(3), np.zeros(3), np.zeros((3, 3))
    a1, a2, dd, n = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
    poly2 = N2b.shape[0] > 0
    m2 = N2b.shape[0] if poly2 else 1
    plane1 = int(par1[sk.CODE]) == sk.PLANE
    plane2 = (not poly2) and int(par2[sk.CODE]) == sk.PLANE
    # body 2's scaled world planes N2 y <= c2 (_Body.linear_rows)
    N2 = np.zeros((N2b.shape[0], dim))
    cl2 = np.zeros(N2b.shape[0])
    for j in range(N2b.shape[0]):
        acc2 = 0.0
        for i in range(dim):
            acc = 0.0
            for k in range(dim):
                acc += R2[i, k] * N2b[j, k]
            N2[j, i] = acc
            acc2 += acc * (p2[i] - o[i])
        cl2[j] = (d2b[j] + acc2) / L
    started = False
    # -- supports(): a half-space first (body 1, then body 2) --------------------------------
    for which in range(2):
        is_plane = plane1 if which == 0 else plane2
        if not is_plane:
            continue
        Pp, PR, Qp, QR, Qpos = (par1, R1, par2, R2, p2) if which == 0 else (par2, R2, par1, R1, p1)
        for i in range(dim):                     # world normal R n_b, scaled offset
            acc = 0.0
            for k in range(dim):
                acc += PR[i, k] * Pp[sk.NORMAL + k]
            n[i] = acc
        Ppos = p1 if which == 0 else p2
        offset = (Pp[sk.OFFSET] + sk.dot(n, Ppos, dim) - sk.dot(n, o, dim)) / L
        for i in range(dim):
            dd[i] = -n[i]
        aQ = a2 if which == 0 else a1
        aP = a1 if which == 0 else a2
        _support(Qp, QR, Qpos, o, L, dd, aQ, w)
        gap = -offset
        for i in range(dim):
            gap += n[i] * aQ[i]
        if gap < -tol:
            return FAST_FALLBACK                 # the other body's deepest point is below the plane
        for i in range(dim):
            aP[i] = aQ[i] - gap * n[i]
        started = True
        break
    if not started:
        # -- supports(): fixed-point steps d <- s2(-d) - s1(d) ---------------------------------
        anyd = False
        for i in range(dim):
            dd[i] = c2[i] - c1[i]
            anyd = anyd or dd[i] != 0.0
        if anyd:
            started = True
            for _ in range(SUPPORT_STEPS):
                _support(par1, R1, p1, o, L, dd, a1, w)
                for i in range(dim):
                    n[i] = -dd[i]
                if poly2:
                    _polytope_support(V2b, R2, p2, o, L, n, a2, w)
                else:
                    _support(par2, R2, p2, o, L, n, a2, w)
                along = 0.0
                ss = 0.0
                d2 = 0.0
                for i in range(dim):
                    sep = a2[i] - a1[i]
                    along += sep * dd[i]
                    ss += sep * sep
                    d2 += dd[i] * dd[i]
                if along <= 0.0:
                    started = False              # d does not separate: the rays decide
                    break
                if along * along >= (1.0 - 1e-15) * ss * d2:
                    break
                for i in range(dim):
                    dd[i] = a2[i] - a1[i]
        if poly2 or not started:
            # -- rays(c2, c1): exits of the segment between the interior points -----------------
            # (against a polytope also after support points, which are vertices: a poor start
            # for a face contact; the closer of the two pairs is kept)
            inside2 = False
            if poly2:
                top = -np.inf
                for j in range(m2):
                    acc = 0.0
                    for i in range(dim):
                        acc += N2[j, i] * c1[i]
                    top = max(top, acc - cl2[j])
                inside2 = top < 0.0
            else:
                inside2 = _body_eval(c1, 0, dim, L, par2, b02, B2, R2, xb, gb, Hb, gb, Hb, 0) < 0.0
            if inside2 or _body_eval(c2, 0, dim, L, par1, b01, B1, R1, xb, gb, Hb, gb, Hb, 0) < 0.0:
                return FAST_FALLBACK
            ob, ub = w[5], np.zeros(3)
            s12 = np.zeros(2)
            for which in range(2):
                b0, B, oi, ti = (b01, B1, c1, c2) if which == 0 else (b02, B2, c2, c1)
                for i in range(dim):
                    acc = b0[i]
                    accu = 0.0
                    for k in range(dim):
                        acc += B[i, k] * oi[k]
                        accu += B[i, k] * (ti[k] - oi[k])
                    ob[i] = acc
                    ub[i] = accu
                anyu = False
                for i in range(dim):
                    anyu = anyu or ub[i] != 0.0
                if not anyu:
                    return FAST_FALLBACK
                if which == 1 and poly2:         # min over the half-spaces' exits
                    s = np.inf
                    for j in range(m2):
                        nu = 0.0
                        no = 0.0
                        for i in range(dim):
                            nu += N2b[j, i] * ub[i]
                            no += N2b[j, i] * ob[i]
                        gap = d2b[j] - no
                        e = 0.0 if gap <= 0.0 else (gap / nu if nu > 0.0 else np.inf)
                        s = min(s, e)
                    s12[1] = s
                else:
                    s12[which] = sk.ray_exit(par1 if which == 0 else par2, ob, ub, w, Hb)
            s1, s2 = s12[0], s12[1]
            if s1 + s2 > 1.0 + tol:
                return FAST_FALLBACK             # the rays share a stretch: overlapping
            r1, r2 = np.zeros(3), np.zeros(3)
            dr = 0.0
            ds = 0.0
            for i in range(dim):
                r1[i] = c1[i] + min(s1, 1.0) * (c2[i] - c1[i])
                r2[i] = c2[i] + min(s2, 1.0) * (c1[i] - c2[i])
                dr += (r1[i] - r2[i]) ** 2
                ds += (a1[i] - a2[i]) ** 2
            if not started or dr < ds:
                for i in range(dim):
                    a1[i], a2[i] = r1[i], r2[i]
    # -- kkt(): eqs (15)-(18) from the start -------------------------------------------------
    G1 = w[0]
    _body_eval(a1, 0, dim, L, par1, b01, B1, R1, xb, gb, Hb, G1, Hb, 1)
    gg = sk.dot(G1, G1, dim)
    gd = 0.0
    for i in range(dim):
        gd += G1[i] * (a2[i] - a1[i])
    lk = max(gd, 0.0) / gg if gg > 0.0 else 0.0
    l2 = np.zeros(m2)                            # _start_multipliers(G2, -G1, v2)
    G2 = np.zeros((m2, dim))
    v2 = np.zeros(m2)
    if poly2:
        for j in range(m2):
            acc = 0.0
            for i in range(dim):
                G2[j, i] = N2[j, i]
                acc += N2[j, i] * a2[i]
            v2[j] = acc - cl2[j]
        top = -np.inf
        for j in range(m2):
            top = max(top, v2[j])
        near = 0
        for j in range(m2):
            if v2[j] >= top - NEAR_ACTIVE:
                near += 1
        A = np.zeros((dim, near))
        k = 0
        for j in range(m2):
            if v2[j] >= top - NEAR_ACTIVE:
                for i in range(dim):
                    A[i, k] = G2[j, i]
                k += 1
        rhs = np.zeros(dim)
        for i in range(dim):
            rhs[i] = -G1[i]
        sol = np.zeros(near)
        _nnls(A, rhs, sol)
        k = 0
        for j in range(m2):
            if v2[j] >= top - NEAR_ACTIVE:
                l2[j] = sol[k]
                k += 1
    else:
        v2[0] = _body_eval(a2, 0, dim, L, par2, b02, B2, R2, xb, gb, Hb, G2[0], Hb, 1)
        cc = sk.dot(G2[0], G2[0], dim)
        cr = 0.0
        for i in range(dim):
            cr += G2[0, i] * -G1[i]
        l2[0] = max(cr / cc, 0.0) if cc > 0.0 else 0.0
    positive = False
    for j in range(m2):
        positive = positive or l2[j] > 0.0
    if not positive:
        kmax = 0
        for j in range(m2):
            if v2[j] > v2[kmax]:
                kmax = j
        l2[kmax] = math.sqrt(gg) / max(math.sqrt(sk.dot(G2[kmax], G2[kmax], dim)), 1e-300)
    for i in range(dim):
        x0[i] = a1[i]
        x0[dim + i] = a2[i]
    x0[2 * dim] = lk
    for j in range(m2):
        x0[2 * dim + 1 + j] = l2[j]
    for i in range(x0.shape[0]):
        if not np.isfinite(x0[i]):
            return FAST_FALLBACK
    _solve_single(dim, L, par1, b01, B1, R1, par2, b02, B2, R2, N2, cl2, x0, lo, hi, opt, x, F,
                  xt, Ft, Phi, Phit, d, g, da, db, zk, Jz, history, steps, info, fbuf, work, J, H)
    if info[ncp.I_STATUS] != ncp.S_CONVERGED:
        return FAST_FALLBACK
    dist2 = 0.0
    for i in range(dim):
        dist2 += (x[i] - x[dim + i]) ** 2
    if math.sqrt(dist2) <= tol and -_body_eval(x, 0, dim, L, par1, b01, B1, R1, xb, gb, Hb, gb, Hb, 0) > tol:
        return FAST_FALLBACK                     # a spurious root inside body 1: overlapping
    # -- result(): world points, multipliers, the normal from body 1's gradient ------------------
    _body_eval(x, 0, dim, L, par1, b01, B1, R1, xb, gb, Hb, G1, Hb, 1)
    nn = sk.dot(G1, G1, dim)
    if not nn > 0.0:
        return FAST_FALLBACK
    nn = math.sqrt(nn)
    for i in range(3):
        out[i] = out[3 + i] = out[6 + i] = 0.0
    for i in range(dim):
        out[i] = o[i] + L * x[i]
        out[3 + i] = o[i] + L * x[dim + i]
        out[6 + i] = G1[i] / nn
    out[9] = x[2 * dim] * L
    for j in range(m2):
        out[10 + j] = x[2 * dim + 1 + j]
    return FAST_OK


def _scaled_form(B1: _Body, B2: _Body, k1: int):
    """Eqs (28)-(31) with the active surface k1 of body 1 (eqs 15-18 when body 1 is one
    function): z = [a1, a2, l1 (m1, l1[k1] = l_k1), l2 (m2)].

    With w = l1 but w[k1] = 1, c = sum_i w_i grad f_i(a1) and Hc = sum_i w_i Hess f_i(a1):
        r28 = a1 - a2 + l_k1 c,          r29 = c + sum_j l_j grad g_j(a2),
        r30 = -f_i(a1),                  r31 = -g_j(a2);
    d r28 = [I + l_k1 Hc, -I, c (l_k1), l_k1 grad f_i (l_i)], d r29 = [Hc, sum l_j Hg_j,
    grad f_i (l_i), grad g_j (l_j)].

    Two single-function bodies, and a single function (not a half-space) against a polytope,
    are solved with these rows compiled (_static_rows, through _Solver.solve_single and
    solve_polytope); these serve the rest. (One compiled kernel for every case changes the
    round-off of intersections' solves, and with it the path of the face campaign's guard run of
    recovery.resume_watched, which then no longer needs that recovery: left for when the guard has
    a new run.)
    """
    d, m1, m2 = B1.dim, B1.m, B2.m
    n = 2 * d + m1 + m2
    i1, i2, j1, j2 = slice(0, d), slice(d, 2 * d), slice(2 * d, 2 * d + m1), slice(2 * d + m1, n)
    col_k1 = 2 * d + k1
    others = [2 * d + i for i in range(m1) if i != k1]
    other_idx = [i for i in range(m1) if i != k1]
    eye = np.eye(d)
    cache = {}

    def evaluate(z):
        key = z.tobytes()
        if cache.get("key") != key:
            cache["key"] = key
            cache["1"] = B1.eval(z[i1])
            cache["2"] = B2.eval(z[i2])
        return cache["1"], cache["2"]

    def weights(z):
        w = z[j1].copy()
        w[k1] = 1.0
        return w

    def fun(z):
        (fv, fG, _), (gv, gG, _) = evaluate(z)
        w = weights(z)
        c = w @ fG
        r = np.empty(n)
        r[i1] = z[i1] - z[i2] + z[col_k1] * c
        r[i2] = c + z[j2] @ gG
        r[j1] = -fv
        r[j2] = -gv
        return r

    def jac(z):
        (fv, fG, fH), (gv, gG, gH) = evaluate(z)
        w = weights(z)
        lk = z[col_k1]
        c = w @ fG
        Hc = _weighted(w, fH)
        J = np.zeros((n, n))
        J[i1, i1] = eye + lk * Hc
        J[i1, i2] = -eye
        J[i1, col_k1] = c
        J[i2, i1] = Hc
        J[i2, i2] = _weighted(z[j2], gH)
        J[i2, j2] = gG.T
        if other_idx:
            J[i1, others] = lk * fG[other_idx].T
            J[i2, others] = fG[other_idx].T
        J[j1, i1] = -fG
        J[j2, i2] = -gG
        return J

    return (fun, jac) + _point_bounds(d, m1, m2)


def _point_bounds(d, m1, m2):
    """The bounds of z = [a1, a2, l1 (m1), l2 (m2)] in _scaled_form and _hat_form: points free,
    multipliers >= 0."""
    n = 2 * d + m1 + m2
    return np.concatenate([np.full(2 * d, -np.inf), np.zeros(m1 + m2)]), np.full(n, np.inf)


def _hat_form(B1: _Body, B2: _Body):
    """Eqs (24)-(27): z = [a1, a2, lh1 (m1), lh2 (m2)]."""
    d, m1, m2 = B1.dim, B1.m, B2.m
    n = 2 * d + m1 + m2
    i1, i2, j1, j2 = slice(0, d), slice(d, 2 * d), slice(2 * d, 2 * d + m1), slice(2 * d + m1, n)
    eye = np.eye(d)
    cache = {}

    def evaluate(z):
        key = z.tobytes()
        if cache.get("key") != key:
            cache["key"] = key
            cache["1"] = B1.eval(z[i1])
            cache["2"] = B2.eval(z[i2])
        return cache["1"], cache["2"]

    def fun(z):
        (fv, fG, _), (gv, gG, _) = evaluate(z)
        a1, a2 = z[i1], z[i2]
        r = np.empty(n)
        r[i1] = a1 - a2 + z[j1] @ fG
        r[i2] = a2 - a1 + z[j2] @ gG
        r[j1] = -fv
        r[j2] = -gv
        return r

    def jac(z):
        (fv, fG, fH), (gv, gG, gH) = evaluate(z)
        J = np.zeros((n, n))
        J[i1, i1] = eye + _weighted(z[j1], fH)
        J[i1, i2] = -eye
        J[i1, j1] = fG.T
        J[i2, i1] = -eye
        J[i2, i2] = eye + _weighted(z[j2], gH)
        J[i2, j2] = gG.T
        J[j1, i1] = -fG
        J[j2, i2] = -gG
        return J

    return (fun, jac) + _point_bounds(d, m1, m2)


def _depth_form(B1: _Body, B2: _Body):
    """min t s.t. h_k(y) <= t: z = [y (dim), t, mu (m1 + m2)]."""
    d, m1, m2 = B1.dim, B1.m, B2.m
    K = m1 + m2
    n = d + 1 + K
    iy, it, im = slice(0, d), d, slice(d + 1, n)
    cache = {}

    def evaluate(z):
        key = z.tobytes()
        if cache.get("key") != key:
            cache["key"] = key
            v1, G1, H1 = B1.eval(z[iy])
            v2, G2, H2 = B2.eval(z[iy])
            cache["v"] = (np.concatenate([v1, v2]), np.vstack([G1, G2]), np.concatenate([H1, H2]))
        return cache["v"]

    def fun(z):
        v, G, _ = evaluate(z)
        mu = z[im]
        r = np.empty(n)
        r[iy] = mu @ G
        r[it] = 1.0 - mu.sum()
        r[im] = z[it] - v
        return r

    def jac(z):
        v, G, H = evaluate(z)
        J = np.zeros((n, n))
        J[iy, iy] = _weighted(z[im], H)
        J[iy, im] = G.T
        J[it, im] = -1.0
        J[im, iy] = -G
        J[im, it] = 1.0
        return J

    lower = np.concatenate([np.full(d + 1, -np.inf), np.zeros(K)])
    return fun, jac, lower, np.full(n, np.inf)


def _middle_of_closest_faces(V1, V2, a1, a2, B1, B2, centre):
    """Of all closest point pairs of two polytopes apart, the one under the bodies' centre or
    else the middle one.

    With n = (a2 - a1)/|a2 - a1|, the closest pairs are (x, x + (a2 - a1)) for x in
    F1 cap (F2 - (a2 - a1)), F1 and F2 the faces of the polytopes that support n and -n; when
    that set is more than a point (a face over a face, an edge over a face, parallel edges) the
    vertex program's answer is one of its corners, a poor start for a contact that will press on
    the whole set. The projection of centre (between the interior points) along n is taken
    when it lies in the set; else the set is clipped in the plane of n (Sutherland-Hodgman) and
    its vertex mean taken. The given pair when the set is a point or the point found is not
    within POLYTOPE_ACTIVE of both surfaces."""
    d = a2 - a1
    n = d / np.linalg.norm(d)
    dim = len(n)

    def on_both(x):
        return float(np.max(B1.values(x))) <= POLYTOPE_ACTIVE and float(np.max(B2.values(x + d))) <= POLYTOPE_ACTIVE

    x = centre - float((centre - a1) @ n) * n
    if on_both(x):
        return x, x + d
    F1 = V1[V1 @ n >= float(np.max(V1 @ n)) - POLYTOPE_ACTIVE]
    F2 = V2[V2 @ n <= float(np.min(V2 @ n)) + POLYTOPE_ACTIVE] - d
    if len(F1) < 2 or len(F2) < 2:
        return a1, a2
    if dim == 2:
        e = np.array([-n[1], n[0]])
        s1, s2 = F1 @ e, F2 @ e
        lo, hi = max(s1.min(), s2.min()), min(s1.max(), s2.max())
        if not hi > lo:
            return a1, a2
        x = a1 + (0.5 * (lo + hi) - float(a1 @ e)) * e
    else:
        e1 = np.cross(n, np.eye(3)[int(np.argmin(np.abs(n)))])
        e1 /= np.linalg.norm(e1)
        E = np.array([e1, np.cross(n, e1)])
        poly1, poly2 = _ordered(F1 @ E.T), _ordered(F2 @ E.T)
        if len(poly1) < 3 and len(poly2) < 3:
            return a1, a2                       # crossing or parallel edges: left as they are
        clip, subject = (poly1, poly2) if len(poly1) >= 3 else (poly2, poly1)
        region = _clip(subject, clip)
        if len(region) < 2:
            return a1, a2
        c = region.mean(axis=0)
        x = a1 + E.T @ (c - E @ a1)
    return (x, x + d) if on_both(x) else (a1, a2)


def _ordered(P):
    """The convex hull of the 2D points P, counter-clockwise (Andrew's monotone chain); a
    segment's two ends when the points are collinear, one point when they coincide."""
    Q = np.unique(P, axis=0)                     # sorted by x, then y
    if len(Q) <= 2:
        return Q
    spread = float(np.max(np.ptp(Q, axis=0)))
    eps = 1e-12 * spread * spread

    def chain(points):
        out = []
        for q in points:
            while len(out) >= 2 and _cross(out[-2], out[-1], q) <= eps:
                out.pop()
            out.append(q)
        return out

    lower, upper = chain(Q), chain(Q[::-1])
    hull = np.array(lower[:-1] + upper[:-1])
    if len(hull) < 3:                            # collinear: the two ends
        return np.array([Q[0], Q[-1]])
    return hull


def _cross(o, a, b):
    return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])


def _clip(subject, polygon):
    """Sutherland-Hodgman: the part of the polygon (or segment) subject inside the convex
    counter-clockwise polygon."""
    out = list(subject)
    k = len(polygon)
    for i in range(k):
        p, q = polygon[i], polygon[(i + 1) % k]
        pts, out = out, []
        closed = len(pts) >= 3
        for j in range(len(pts)):
            cur = pts[j]
            if j == 0 and not closed:
                if _cross(p, q, cur) >= 0.0:
                    out.append(cur)
                continue
            prev = pts[j - 1]
            ci, pi = _cross(p, q, cur), _cross(p, q, prev)
            if ci >= 0.0:
                if pi < 0.0:
                    out.append(prev + (cur - prev) * (pi / (pi - ci)))
                out.append(cur)
            elif pi >= 0.0:
                out.append(prev + (cur - prev) * (pi / (pi - ci)))
        if not out:
            break
    return np.array(out)


def _start_multipliers(columns: np.ndarray, rhs: np.ndarray, values: np.ndarray) -> np.ndarray:
    """l >= 0 with sum_j l_j columns_j ~ rhs over the members near their surface."""
    m = len(values)
    near = np.flatnonzero(values >= float(np.max(values)) - NEAR_ACTIVE)
    lam = np.zeros(m)
    if m == 1:
        cc = float(columns[0] @ columns[0])
        lam[0] = max(float(columns[0] @ rhs) / cc, 0.0) if cc > 0 else 0.0
    else:
        sol, _ = nnls(columns[near].T, rhs)
        lam[near] = sol
    if not np.any(lam > 0):
        k = int(np.argmax(values))
        lam[k] = float(np.linalg.norm(rhs)) / max(float(np.linalg.norm(columns[k])), 1e-300)
    return lam


@dataclass(frozen=True)
class _LpOutcome:
    """The fields of an ncp.McpResult that the driver reads, for the linear-program path."""

    x: np.ndarray
    status: Status
    iterations: int
    residual: float
    message: str

    @property
    def success(self) -> bool:
        return self.status is Status.CONVERGED


# --------------------------------------------------------------------------------------------
# the driver
# --------------------------------------------------------------------------------------------
_DEFAULT_OPTIONS = ClosestPointOptions()


def closest_points(shape1, pose1, shape2, pose2, options: ClosestPointOptions | None = None) -> ClosestPointResult:
    """Closest points of shape1 posed by pose1 = (R1, p1) and shape2 posed by pose2 (body -> world).

    shapes: ConvexFunction or Intersection of the same dim, not both unbounded. Never raises for
    a failed solve (see result.success / status); ValueError for malformed input.
    """
    options = _DEFAULT_OPTIONS if options is None else options
    if not isinstance(options, ClosestPointOptions):
        raise ValueError(f"options must be a ClosestPointOptions, got {type(options).__name__}")
    _check_shape(shape1, "shape1")
    _check_shape(shape2, "shape2")
    if shape1.dim != shape2.dim:
        raise ValueError(f"both shapes must have the same dim, got {shape1.dim} and {shape2.dim}")
    dim = shape1.dim
    R1, p1 = _check_pose(pose1, dim, "pose1")
    R2, p2 = _check_pose(pose2, dim, "pose2")
    if not (shape1.bounded or shape2.bounded):
        raise ValueError("at least one of the two shapes must be bounded: the distance between two "
                         "unbounded shapes (half-spaces, infinite cylinders, fingertips) is not "
                         "supported")

    c1 = R1 @ shape1.interior_point + p1
    c2 = R2 @ shape2.interior_point + p2
    L = min(s for s in (shape1.length_scale, shape2.length_scale) if math.isfinite(s))
    o = 0.5 * (c1 + c2) if shape1.bounded and shape2.bounded else (c1 if shape1.bounded else c2)
    fast = _single_functions(shape1, R1, p1, shape2, R2, p2, c1, c2, o, L, options)
    if fast is not None:
        return fast
    B1, B2 = _Body(shape1, R1, p1, o, L), _Body(shape2, R2, p2, o, L)
    return _Solver(B1, B2, B1.scaled(c1), B2.scaled(c2), options).run()


# the single functions _single_run knows: their closed-form supports and ray exits are its own
_FAST_CLASSES = (_Ball, _EllipsoidBase, _PowerSumBase, _HalfSpaceBase)
_FAST_BUFFERS = {}
_NO_VERTICES = np.zeros((0, 3))


def _fast_polytope(shape):
    """(body-frame plane normals (m, dim), offsets (m,), vertices) of a bounded polytope whose
    closed-form support is its vertices (shapes.Intersection._support_point), else None; kept
    on the shape (an Intersection does not change)."""
    kept = shape.__dict__.get("_fast_polytope", False)
    if kept is not False:
        return kept
    poly = getattr(shape, "_poly", None)
    planes = None
    fs = shape.functions
    if (len(fs) > 1 and all(isinstance(f, _HalfSpaceBase) for f in fs) and poly is not None and poly.bounded
            and len(poly.b) == len(fs)):
        rows = [f.plane() for f in fs]
        planes = (np.array([n for n, _ in rows], float), np.array([dv for _, dv in rows], float),
                  np.ascontiguousarray(poly.vertices, dtype=float))
    shape.__dict__["_fast_polytope"] = planes
    return planes


def _single_functions(shape1, R1, p1, shape2, R2, p2, c1, c2, o, L, options):
    """closest_points by _single_run of a single function (ball, ellipsoid, superquadric,
    half-space) and a single function or, if the first is not a half-space, a bounded polytope;
    None where the Python driver must solve the pair (see _single_run)."""
    f1, f2 = shape1.functions, shape2.functions
    if len(f1) != 1 or not isinstance(f1[0], _FAST_CLASSES):
        return None
    dim = shape1.dim
    if len(f2) == 1 and isinstance(f2[0], _FAST_CLASSES):
        par2, N2b, d2b, V2b, m2 = f2[0].kernel_params, _NO_PLANES, _NO_OFFSETS, _NO_VERTICES, 1
    elif isinstance(f1[0], _HalfSpaceBase) or isinstance(shape2, ConvexFunction):
        return None
    else:
        planes = _fast_polytope(shape2)
        if planes is None:
            return None
        par2, (N2b, d2b, V2b), m2 = _NO_PAR, planes, len(planes[1])
    opts = options.solver
    key = (dim, m2, id(opts))
    held = _FAST_BUFFERS.get(key)
    if held is None or held[-1] is not opts:
        if len(_FAST_BUFFERS) > 64:
            _FAST_BUFFERS.clear()
        n = 2 * dim + 1 + m2
        held = _FAST_BUFFERS[key] = ncp.dense_buffers(n, opts) + _point_bounds(dim, 1, m2) + (
            np.empty(n), np.empty(10 + m2), opts)
    buf, J, H, opt, lo, hi, x0, out, _ = held
    c = np.ascontiguousarray
    status = _single_run(dim, float(L), o, f1[0].kernel_params, c(R1), p1, R1.T @ (o - p1), c(L * R1.T),
                         par2, c(R2), p2, R2.T @ (o - p2), c(L * R2.T), N2b, d2b, V2b, (c1 - o) / L, (c2 - o) / L,
                         float(options.touch_tol), x0, lo, hi, opt, buf.x, buf.F, buf.xt, buf.Ft, buf.Phi, buf.Phit,
                         buf.d, buf.g, buf.da, buf.db, buf.zk, buf.Jz, buf.history, buf.steps, buf.info, buf.fbuf,
                         buf.work, J, H, out)
    if status != FAST_OK:
        return None
    status, iterations, residual, message = ncp.outcome_from_buffers(buf, opts)
    a1, a2 = out[:dim].copy(), out[3:3 + dim].copy()
    return ClosestPointResult(
        a1=a1, a2=a2, l1=out[9:10].copy(), l2=out[10:10 + m2].copy(), k1=0, distance=float(np.linalg.norm(a1 - a2)),
        normal=out[6:6 + dim].copy(), overlapping=False, depth=0.0, success=True, status=status,
        iterations=iterations, residual=residual, message=message, form="eq15-18")


# the arguments _solve_single does not read for the other kind of body 2 (typed as those it does)
_NO_PAR, _NO_OFFSETS = np.zeros(0), np.zeros(0)
_NO_MATRIX, _NO_PLANES = np.zeros((0, 0)), np.zeros((0, 3))


def single_batch_ready(shape1, shape2) -> bool:
    """Whether closest_points solves this pair by _single_run of two single functions (the pairs
    closest_points_batch takes)."""
    f1, f2 = shape1.functions, shape2.functions
    return (len(f1) == 1 and len(f2) == 1 and isinstance(f1[0], _FAST_CLASSES) and isinstance(f2[0], _FAST_CLASSES)
            and (shape1.bounded or shape2.bounded))


def closest_points_batch(shapes1, poses1, shapes2, poses2):
    """closest_points of many pairs of single functions (single_batch_ready, one dim) in one
    compiled call, at the default options: per pair whether _single_run solved it (False: ask
    closest_points, which falls back where _single_run does), a1, a2, the unit normal from body
    1 to body 2, and both functions' world gradients at a1 and a2 (n, dim each). The points are
    those closest_points returns, to round-off (the same kernel; its inputs formed in loops
    instead of numpy's products)."""
    n = len(shapes1)
    dim = shapes1[0].dim if n else 3
    par1, par2 = np.empty((n, sk.NPAR)), np.empty((n, sk.NPAR))
    R1, R2 = np.zeros((n, 3, 3)), np.zeros((n, 3, 3))
    p1, p2, c1, c2 = np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3)), np.zeros((n, 3))
    L, bounded = np.empty(n), np.empty((n, 2), np.bool_)
    for k, (s1, (Ra, pa), s2, (Rb, pb)) in enumerate(zip(shapes1, poses1, shapes2, poses2)):
        par1[k], par2[k] = s1.functions[0].kernel_params, s2.functions[0].kernel_params
        R1[k, :dim, :dim], p1[k, :dim], R2[k, :dim, :dim], p2[k, :dim] = Ra, pa, Rb, pb
        c1[k, :dim], c2[k, :dim] = s1.interior_point, s2.interior_point
        L[k] = min(s for s in (s1.length_scale, s2.length_scale) if math.isfinite(s))
        bounded[k] = s1.bounded, s2.bounded
    opts = _DEFAULT_OPTIONS.solver
    size = 2 * dim + 2
    buf, J, H, opt = ncp.dense_buffers(size, opts)
    lo, hi = _point_bounds(dim, 1, 1)
    ok = np.zeros(n, np.bool_)
    out = np.zeros((n, 15))
    _single_batch(dim, par1, R1, p1, c1, par2, R2, p2, c2, L, bounded, float(_DEFAULT_OPTIONS.touch_tol),
                  np.empty(size), lo, hi, opt, buf.x, buf.F, buf.xt, buf.Ft, buf.Phi, buf.Phit, buf.d, buf.g, buf.da,
                  buf.db, buf.zk, buf.Jz, buf.history, buf.steps, buf.info, buf.fbuf, buf.work, J, H, ok, out)
    return ok, out[:, :dim], out[:, 3:3 + dim], out[:, 6:6 + dim], out[:, 9:9 + dim], out[:, 12:12 + dim]


@kernel
def _single_batch(dim, par1, R1, p1, ip1, par2, R2, p2, ip2, L, bounded, tol, x0, lo, hi, opt, x, F, xt, Ft, Phi,
                  Phit, d, g, da, db, zk, Jz, history, steps, info, fbuf, work, J, H, ok, out):
    """closest_points_batch's pairs one after the other as _single_functions calls _single_run
    (poses and interior points padded to 3; R (n, 3, 3), p, ip (n, 3)); ok[k]: converged, and
    then out[k] = [a1 (3), a2 (3), normal (3), grad f1(a1) (3), grad f2(a2) (3)] (world)."""
    one = np.zeros(15)
    c1, c2, o = np.zeros(dim), np.zeros(dim), np.zeros(dim)
    b01, b02, s1, s2 = np.zeros(dim), np.zeros(dim), np.zeros(dim), np.zeros(dim)
    Ra, Rb = np.zeros((dim, dim)), np.zeros((dim, dim))
    B1, B2 = np.zeros((dim, dim)), np.zeros((dim, dim))
    pa, pb = np.zeros(dim), np.zeros(dim)
    xb, gb, Hb, G = np.zeros(3), np.zeros(3), np.zeros((3, 3)), np.zeros(3)
    for k in range(par1.shape[0]):
        Lk = L[k]
        for i in range(dim):
            pa[i], pb[i] = p1[k, i], p2[k, i]
            for j in range(dim):
                Ra[i, j], Rb[i, j] = R1[k, i, j], R2[k, i, j]
        for i in range(dim):
            acc1 = acc2 = 0.0
            for j in range(dim):
                acc1 += Ra[i, j] * ip1[k, j]
                acc2 += Rb[i, j] * ip2[k, j]
            c1[i], c2[i] = acc1 + pa[i], acc2 + pb[i]
        for i in range(dim):
            if bounded[k, 0] and bounded[k, 1]:
                o[i] = 0.5 * (c1[i] + c2[i])
            else:
                o[i] = c1[i] if bounded[k, 0] else c2[i]
        for i in range(dim):
            acc1 = acc2 = 0.0
            for j in range(dim):
                acc1 += Ra[j, i] * (o[j] - pa[j])
                acc2 += Rb[j, i] * (o[j] - pb[j])
                B1[i, j], B2[i, j] = Lk * Ra[j, i], Lk * Rb[j, i]
            b01[i], b02[i] = acc1, acc2
            s1[i], s2[i] = (c1[i] - o[i]) / Lk, (c2[i] - o[i]) / Lk
        status = _single_run(dim, Lk, o, par1[k], Ra, pa, b01, B1, par2[k], Rb, pb, b02, B2, _NO_PLANES,
                             _NO_OFFSETS, _NO_VERTICES, s1, s2, tol, x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g,
                             da, db, zk, Jz, history, steps, info, fbuf, work, J, H, one)
        ok[k] = status == FAST_OK
        if not ok[k]:
            continue
        for i in range(9):
            out[k, i] = one[i]
        # the functions' world gradients at the solution (x: scaled a1, a2), as _single_run's normal
        _body_eval(x, 0, dim, Lk, par1[k], b01, B1, Ra, xb, gb, Hb, G, Hb, 1)
        for i in range(dim):
            out[k, 9 + i] = G[i]
        _body_eval(x, dim, dim, Lk, par2[k], b02, B2, Rb, xb, gb, Hb, G, Hb, 1)
        for i in range(dim):
            out[k, 12 + i] = G[i]


class _Solver:
    def __init__(self, B1, B2, c1, c2, options):
        self.B1, self.B2, self.c1, self.c2 = B1, B2, c1, c2
        self.opts = options
        self.solver_opts = options.solver     # (the patient retry of depth() raises its budget)
        self.tol = options.touch_tol
        self.iterations = 0

    # -- start -------------------------------------------------------------------------------
    def rays(self, target1, target2):
        """Ray-exit points a1, a2 and whether the bodies share a stretch of the segment."""
        o1 = self.B1.ray_origin(target1, self.c1)
        o2 = self.B2.ray_origin(target2, self.c2)
        if float(np.max(self.B2.values(o1))) < 0.0 or float(np.max(self.B1.values(o2))) < 0.0:
            return o1, o2, True, 0.5 * (o1 + o2)
        s1 = self.B1.ray_exit(o1, o2)
        s2 = self.B2.ray_exit(o2, o1)
        overlap = s1 + s2 > 1.0 + self.tol
        mid = o1 + 0.5 * (s1 + 1.0 - s2) * (o2 - o1)
        a1 = o1 + min(s1, 1.0) * (o2 - o1)
        a2 = o2 + min(s2, 1.0) * (o1 - o2)
        return a1, a2, overlap, mid

    def supports(self):
        """Start from support points: exact against a half-space; else a few fixed-point steps
        d <- s2(-d) - s1(d). None if unavailable or the bodies are not shown apart along d."""
        B1, B2 = self.B1, self.B2
        for P, Q, first in ((B1, B2, True), (B2, B1, False)):
            plane = P.plane
            if plane is None:
                continue
            n, offset = plane
            aQ = Q.support(-n)
            if aQ is None:
                return None
            gap = float(n @ aQ) - offset
            aP = aQ - gap * n
            if gap < -self.tol:
                return aQ, aQ, True, aQ     # the deepest point of Q below the plane
            return (aP, aQ, False, None) if first else (aQ, aP, False, None)
        d = self.c2 - self.c1
        if not np.any(d):
            return None
        for _ in range(SUPPORT_STEPS):
            a1, a2 = B1.support(d), B2.support(-d)
            if a1 is None or a2 is None:
                return None
            sep = a2 - a1
            along = float(sep @ d)
            if along <= 0.0:
                return None       # d does not separate: let the rays decide
            if along * along >= (1.0 - 1e-15) * float(sep @ sep) * float(d @ d):
                break             # the direction is a fixed point (two spheres: at once)
            d = sep
        return a1, a2, False, None

    # -- main --------------------------------------------------------------------------------
    def run(self) -> ClosestPointResult:
        V1, V2 = self.B1.vertices, self.B2.vertices
        if V1 is not None and V2 is not None:
            return self.polytopes(V1, V2)
        start = self.supports()
        if start is None or (not start[2] and (self.B1.m > 1 or self.B2.m > 1)
                             and self.B1.plane is None and self.B2.plane is None):
            # Support points of a polytope are vertices, a poor start for a face contact: keep
            # whichever of the two surface pairs is closer (both bound the distance from above).
            rays = self.rays(self.c2, self.c1)
            if start is None or rays[2] or np.linalg.norm(rays[0] - rays[1]) < np.linalg.norm(start[0] - start[1]):
                start = rays
        a1, a2, overlap, mid = start
        if overlap:
            return self.depth(mid)
        res = self.kkt(a1, a2)
        if res is not None:
            return res
        # The KKT solve failed or ended at a1 = a2 with a1 inside: classify by the depth problem.
        return self.depth(0.5 * (a1 + a2))

    def solve(self, fun, jac, z0, lo, hi):
        sol = solve_mcp(fun, jac, z0, lo, hi, self.solver_opts)
        self.iterations += sol.iterations
        self.last = sol
        return sol

    def solve_single(self, z0, lo, hi):
        """self.solve of _scaled_form for two single-function bodies, in one compiled call
        (_solve_single: the same rows and the same solver; the same points to round-off, 3e-16 over
        371 random pairs of ellipsoids, spheres, superquadrics and half-spaces). Measured on two
        exponent-4 superquadrics 5.7 cm apart (7 Newton iterations): closest_points 880 -> 497 us, of
        which this solve 30 us; the rest is the start (support points, ray exits) in Python."""
        B2 = self.B2
        c = np.ascontiguousarray
        return self._compiled(z0, lo, hi, B2.par, c(B2._b0, float), c(B2._B, float), c(B2.R, float),
                              _NO_PLANES, _NO_OFFSETS)

    def solve_polytope(self, z0, lo, hi):
        """The same for a single-function body 1 (not a half-space) and a polytope body 2
        (_static_rows). The case: the grasp study (comparisons.grasp), whose fingertips are
        polygons against a disc and superellipses; measured on a tooth 3 cm from a fingertip
        (2 Newton iterations), closest_points 596 -> 529 us: again the start is the cost."""
        N2, c2, _ = self.B2._linear
        c = np.ascontiguousarray
        return self._compiled(z0, lo, hi, _NO_PAR, _NO_OFFSETS, _NO_MATRIX, _NO_MATRIX, c(N2, float), c(c2, float))

    def _compiled(self, z0, lo, hi, par2, b02, B2, R2, N2, c2):
        x0, lo, hi = ncp.check_problem(z0, lo, hi, self.solver_opts)
        B1 = self.B1
        n = x0.shape[0]
        buf, J, H, opt = ncp.dense_buffers(n, self.solver_opts)
        c = np.ascontiguousarray
        _solve_single(B1.dim, float(B1.L), B1.par, c(B1._b0, float), c(B1._B, float), c(B1.R, float), par2, b02, B2,
                      R2, N2, c2, x0, lo, hi, opt, buf.x, buf.F, buf.xt, buf.Ft,
                      buf.Phi, buf.Phit, buf.d, buf.g, buf.da, buf.db, buf.zk, buf.Jz, buf.history, buf.steps,
                      buf.info, buf.fbuf, buf.work, J, H)
        sol = ncp.result_from_buffers(buf, self.solver_opts)
        self.iterations += sol.iterations
        self.last = sol
        return sol

    def scaled(self, a1, a2, l1, l2, k1, form):
        """Solve eqs (28)-(31) with body 1's surface k1 from a start: (result, why) with result
        None and why "failed" or "inside" (a root with a1 = a2 inside body 1: overlapping)."""
        B1, B2 = self.B1, self.B2
        dim = B1.dim
        z0 = np.concatenate([a1, a2, l1, l2])
        if B1.m == 1 and B2.m == 1:
            sol = self.solve_single(z0, *_point_bounds(dim, 1, 1))
        elif B1.m == 1 and B2._linear is not None and B1.plane is None:
            sol = self.solve_polytope(z0, *_point_bounds(dim, 1, B2.m))
        else:
            fun, jac, lo, hi = _scaled_form(B1, B2, k1)
            sol = self.solve(fun, jac, z0, lo, hi)
        if not sol.success:
            return None, "failed"
        z = sol.x
        a1, a2 = z[:dim], z[dim:2 * dim]
        l1, l2 = z[2 * dim:2 * dim + B1.m].copy(), z[2 * dim + B1.m:].copy()
        if float(np.linalg.norm(a1 - a2)) <= self.tol and -B1.values(a1)[k1] > self.tol:
            return None, "inside"     # a spurious root with a1 = a2 inside body 1: overlapping
        weights = l1.copy()
        weights[k1] = 1.0
        l1[k1] *= B1.L
        return self.result(a1, a2, l1, l2, k1, weights, overlapping=False, depth=0.0, form=form,
                           sol=sol), "ok"

    def kkt(self, a1, a2):
        B1, B2 = self.B1, self.B2
        dim = B1.dim
        if B1.m == 1:
            v1, G1, _ = B1.eval(a1, order=1)
            v2, G2, _ = B2.eval(a2, order=1)
            g = G1[0]
            gg = float(g @ g)
            lk = max(float(g @ (a2 - a1)), 0.0) / gg if gg > 0.0 else 0.0
            return self.scaled(a1, a2, np.array([lk]), _start_multipliers(G2, -g, v2), 0, "eq15-18")[0]
        if B2.m == 1:
            # k1 is not known on body 1: solve with body 2 as the single-function body F of
            # eqs (15)-(18) and convert through the hat multipliers: lh_F = l_F, lh_i = l_F l_i.
            v2, G2, _ = B2.eval(a2, order=1)
            v1, G1, _ = B1.eval(a1, order=1)
            g = G2[0]
            gg = float(g @ g)
            lk = max(float(g @ (a1 - a2)), 0.0) / gg if gg > 0.0 else 0.0
            fun, jac, lo, hi = _scaled_form(B2, B1, 0)
            sol = self.solve(fun, jac, np.concatenate([a2, a1, [lk], _start_multipliers(G1, -g, v1)]), lo, hi)
            if not sol.success:
                return None
            z = sol.x
            aF, aG, lF, lG = z[:dim], z[dim:2 * dim], z[2 * dim], z[2 * dim + 1:]
            if float(np.linalg.norm(aF - aG)) <= self.tol and -B2.values(aF)[0] > self.tol:
                return None
            k1 = int(np.argmax(lG))
            ratio1 = lG / lG[k1]
            l1 = ratio1.copy()
            l1[k1] = lF * lG[k1] * B2.L
            return self.result(aG, aF, l1, np.array([1.0 / lG[k1]]), k1, ratio1, overlapping=False,
                               depth=0.0, form="eq15-18 swapped", sol=sol)
        # Both intersections: eqs (24)-(27) need no k1; then k1 = the largest multiplier of
        # body 1 and a polish with eqs (28)-(31), whose ratios stay accurate at small distances
        # (in (24)-(27) every multiplier is proportional to the distance).
        v1, G1, _ = B1.eval(a1, order=1)
        v2, G2, _ = B2.eval(a2, order=1)
        fun, jac, lo, hi = _hat_form(B1, B2)
        z0 = np.concatenate([a1, a2, _start_multipliers(G1, a2 - a1, v1), _start_multipliers(G2, a1 - a2, v2)])
        sol = self.solve(fun, jac, z0, lo, hi)
        if not sol.success:
            return None
        z = sol.x
        a1, a2 = z[:dim], z[dim:2 * dim]
        lh1, lh2 = z[2 * dim:2 * dim + B1.m], z[2 * dim + B1.m:]
        if float(np.linalg.norm(a1 - a2)) <= self.tol:
            return None               # every common point solves (24)-(27): classify by depth
        k1 = int(np.argmax(lh1))
        l1 = lh1 / lh1[k1]
        l1[k1] = lh1[k1]
        polished, why = self.scaled(a1, a2, l1, lh2 / lh1[k1], k1, "eq28-31")
        if polished is not None:
            return polished
        if why == "inside" or float(np.linalg.norm(a1 - a2)) <= SMALL_HAT_DISTANCE:
            # (24)-(27) are satisfied to the tolerance by common points with tiny multipliers,
            # so a small distance from them alone is not trusted: classify by depth.
            return None
        ratio1 = lh1 / lh1[k1]
        l1 = ratio1.copy()
        l1[k1] = lh1[k1] * B1.L
        return self.result(a1, a2, l1, lh2 / lh1[k1], k1, ratio1, overlapping=False, depth=0.0,
                           form="eq24-27", sol=sol)

    def polytopes(self, V1, V2):
        """Two bounded polytopes: problem (9) is a convex quadratic program, and Newton on its
        KKT systems is fragile there (a face parallel to a face makes the closest points
        non-unique and the Jacobian singular: a UR10 link's 86-plane hull 1.5 mm above a ground
        box, at random poses, took 1331 iterations and 33 s and failed). Solved exactly instead,
        over the vertices: a1 = V1^T w1, a2 = V2^T w2 with w1, w2 on the unit simplices,

            min |V1^T w1 - V2^T w2|^2,

        as a non-negative least-squares problem (Lawson-Hanson, finite) whose two sum-to-one
        rows carry the weight POLYTOPE_SUM_WEIGHT; the weights are then renormalised, so a1 and
        a2 lie in the polytopes exactly. Apart: the multipliers of (24)-(25) by NNLS over the
        planes active at a1 and a2, polished with eqs (28)-(31) when that converges to the same
        distance, else the vertex answer in their form (form "polytopes"); touching or
        overlapping: the depth linear program (depth_lp)."""
        B1, B2 = self.B1, self.B2
        k1n = len(V1)
        W = POLYTOPE_SUM_WEIGHT
        A = np.zeros((B1.dim + 2, k1n + len(V2)))
        A[:B1.dim, :k1n], A[:B1.dim, k1n:] = V1.T, -V2.T
        A[B1.dim, :k1n] = A[B1.dim + 1, k1n:] = W
        rhs = np.zeros(B1.dim + 2)
        rhs[B1.dim:] = W
        w, _ = nnls(A, rhs)
        w1, w2 = w[:k1n], w[k1n:]
        s1, s2 = float(w1.sum()), float(w2.sum())
        if not (s1 > 0.0 and s2 > 0.0):
            return self.depth(0.5 * (self.c1 + self.c2))
        a1, a2 = V1.T @ w1 / s1, V2.T @ w2 / s2
        dist = float(np.linalg.norm(a2 - a1))
        if dist <= self.tol:
            return self.depth(0.5 * (a1 + a2))
        a1, a2 = _middle_of_closest_faces(V1, V2, a1, a2, B1, B2, 0.5 * (self.c1 + self.c2))
        v1, G1, _ = B1.eval(a1, order=1)
        v2, G2, _ = B2.eval(a2, order=1)
        lh1, lh2 = np.zeros(B1.m), np.zeros(B2.m)
        for lh, v, G, rhs_ in ((lh1, v1, G1, a2 - a1), (lh2, v2, G2, a1 - a2)):
            on = np.flatnonzero(v >= -POLYTOPE_ACTIVE)
            lh[on] = nnls(G[on].T, rhs_)[0]
        if not np.any(lh1 > 0.0):
            return self.failure(a1, a2, "no plane of body 1 is active at the closest point of two polytopes")
        fun, _, _, _ = _hat_form(B1, B2)
        z = np.concatenate([a1, a2, lh1, lh2])
        r = fun(z)
        # the natural residual of (24)-(27): stationarity, and min(lh, -f) of (26)-(27)
        d = B1.dim
        residual = max(float(np.max(np.abs(r[:2 * d]))), float(np.max(np.abs(np.minimum(z[2 * d:], r[2 * d:])))))
        ok = residual <= POLYTOPE_RESIDUAL
        sol = _LpOutcome(z, Status.CONVERGED if ok else Status.SINGULAR, 0, residual,
                         f"vertex quadratic program (NNLS): residual of eqs (24)-(27) {residual:.3g}")
        self.last = sol
        k1 = int(np.argmax(lh1))
        # In (24)-(27) the multipliers are proportional to the distance, so their ratios lose
        # accuracy as the polytopes close in: polish with (28)-(31) from here, as kkt does; the
        # polish may fail where the closest points are not unique (a face over a face).
        ratio1 = lh1 / lh1[k1]
        l1 = ratio1.copy()
        l1[k1] = lh1[k1]
        polished, _ = self.scaled(a1, a2, l1, lh2 / lh1[k1], k1, "eq28-31")
        if polished is not None and abs(polished.distance - dist * B1.L) <= self.tol * B1.L:
            return polished
        if not ok:
            return self.failure(a1, a2, "the vertex quadratic program of two polytopes is inaccurate")
        l1[k1] = lh1[k1] * B1.L
        return self.result(a1, a2, l1, lh2 / lh1[k1], k1, ratio1, overlapping=False, depth=0.0,
                           form="polytopes", sol=sol)

    def depth_start(self, y0):
        """Start of the depth problem. If the minimiser c of a single-function body (its centre,
        where grad f = 0) lies where the other body's functions are <= f(c), then c is the exact
        answer: max(f, g) >= f >= f(c) everywhere. That case (a small body well inside a large
        one) is also where the minimum can be flat (|x|^4 at the centre of a superellipse) and
        Newton would only be linear, so it is recognised here."""
        B1, B2 = self.B1, self.B2
        for B, other, c, offset in ((B1, B2, self.c1, 0), (B2, B1, self.c2, B1.m)):
            if B.m != 1:
                continue
            v, G, _ = B.eval(c, order=1)
            if float(np.abs(G).max()) > 1e-12 or float(np.max(other.values(c))) > v[0]:
                continue
            mu = np.zeros(B1.m + B2.m)
            mu[offset] = 1.0
            return np.concatenate([c, [v[0]], mu])
        v1, v2 = B1.values(y0), B2.values(y0)
        k1, k2 = int(np.argmax(v1)), int(np.argmax(v2))
        mu = np.zeros(B1.m + B2.m)
        mu[k1] = mu[B1.m + k2] = 0.5
        return np.concatenate([y0, [max(float(v1[k1]), float(v2[k2]))], mu])

    def depth_lp(self, rows1, rows2):
        """Two polyhedra: min t s.t. N y - b <= t is a linear program; its optimum is often
        degenerate (an edge on a vertex), where Newton on the KKT system stalls, so HiGHS."""
        N = np.vstack([rows1[0], rows2[0]])
        b = np.concatenate([rows1[1], rows2[1]])
        dim = N.shape[1]
        res = linprog(np.r_[np.zeros(dim), 1.0], A_ub=np.c_[N, -np.ones(len(b))], b_ub=b,
                      bounds=[(None, None)] * (dim + 1), method="highs")
        ok = res.status == 0
        x = res.x if ok else np.full(dim + 1 + len(b), np.nan)
        mu = -res.ineqlin.marginals if ok else np.full(len(b), np.nan)
        outcome = _LpOutcome(np.concatenate([x[:dim + 1], mu]),
                             Status.CONVERGED if ok else Status.SINGULAR, int(getattr(res, "nit", 0)),
                             0.0 if ok else math.inf, f"linprog (HiGHS): {res.message}")
        return outcome

    def depth(self, y0):
        B1, B2 = self.B1, self.B2
        dim = B1.dim
        rows1, rows2 = B1.linear_rows(), B2.linear_rows()
        if rows1 is not None and rows2 is not None:
            sol = self.depth_lp(rows1, rows2)
        else:
            fun, jac, lo, hi = _depth_form(B1, B2)
            solver = self.opts.solver
            if solver.tol < self.opts.depth_tol:
                solver = replace(solver, tol=self.opts.depth_tol)
            sol = solve_mcp(fun, jac, self.depth_start(y0), lo, hi, solver)
        self.iterations += sol.iterations
        self.last = sol
        if not sol.success and not np.all(np.isfinite(sol.x)):
            return self.failure(y0, y0, "the depth linear program failed")
        y, t, mu = sol.x[:dim], float(sol.x[dim]), sol.x[dim + 1:]
        mu1, mu2 = mu[:B1.m], mu[B1.m:]
        certified = False
        if not sol.success:
            t_y = max(float(np.max(B1.values(y))), float(np.max(B2.values(y))))
            if not t_y < -self.tol:
                return self.failure(y, y, "neither the KKT solve nor the depth problem converged")
            # y is strictly inside both bodies: the overlap is certain and -max(f, g)(y) is a
            # lower bound of the depth, short of optimal by about the residual (flat minimum).
            t, certified = t_y, True
        if t > self.tol:
            # Apart after all: restart the KKT solve from rays aimed at the separating point x*.
            a1, a2, overlap, _ = self.rays(y, y)
            res = self.kkt(a1, a2) if not overlap else None
            if res is None and not overlap:
                # Newton from these starts can crawl (LM and gradient steps) before its quadratic
                # phase: a box against a box 0.48 m away, rotated at random, converged after 105
                # iterations, a capped cylinder against a superquadric after 558 (1 and 2 of 3000
                # random separated poses of tests/test_closest.py): once more, patiently
                self.solver_opts = replace(self.opts.solver, max_iterations=PATIENT_FACTOR * self.opts.solver.max_iterations)
                try:
                    res = self.kkt(a1, a2)
                finally:
                    self.solver_opts = self.opts.solver
            if res is not None:
                return res
            return self.failure(a1, a2, "the KKT solve failed for bodies that the depth problem "
                                        f"finds apart (t* = {t * B1.L:.3g})")
        # Touching or overlapping: multipliers of (28)-(31) at a1 = a2 with l_k1 = 0, from
        # sum mu_i grad f_i = -sum mu_j grad g_j of the depth problem.
        if np.any(mu1 > 0):
            k1 = int(np.argmax(mu1))
            ratio1 = mu1 / mu1[k1]
            l2 = mu2 / mu1[k1]
        else:
            k1 = int(np.argmax(B1.values(y)))
            ratio1 = np.zeros(B1.m)
            ratio1[k1] = 1.0
            l2 = np.zeros(B2.m)
        l1 = ratio1.copy()
        l1[k1] = 0.0
        overlapping = t < -self.tol
        if not overlapping and np.any(mu1 > 0):
            # Touching: eqs (28)-(31) are regular there (Prop. 4.3); polish a1 = a2 and the ratios.
            polished, _ = self.scaled(y, y, l1, l2, k1, "eq28-31 touching")
            if polished is not None and polished.distance <= self.tol * B1.L:
                return polished
        return self.result(y, y, l1, l2, k1, ratio1 if np.any(mu1 > 0) else None,
                           overlapping=overlapping, depth=max(-t, 0.0) * B1.L if overlapping else 0.0,
                           form="depth", sol=sol, mu2=mu2, certified=certified)

    # -- output ------------------------------------------------------------------------------
    def normal(self, a1, weights1, mu2=None):
        B1, B2 = self.B1, self.B2
        n = None
        if weights1 is not None:
            _, G1, _ = B1.eval(a1, order=1)
            n = weights1 @ G1
        if (n is None or not np.any(n)) and mu2 is not None and np.any(mu2 > 0):
            _, G2, _ = B2.eval(a1, order=1)
            n = -(mu2 @ G2)
        if n is None or not np.any(n):
            n = self.c2 - self.c1
        if not np.any(n):
            n = np.eye(B1.dim)[0]
        return n / np.linalg.norm(n)

    def result(self, a1, a2, l1, l2, k1, weights1, overlapping, depth, form, sol, mu2=None,
               certified=False):
        B1 = self.B1
        w1, w2 = B1.world(a1), B1.world(a2)
        dist = 0.0 if form == "depth" else float(np.linalg.norm(w1 - w2))
        message = sol.message
        if certified:
            message = ("Overlap certified by a common interior point; the depth problem stopped "
                       f"short of optimal (flat minimum), so depth is a lower bound. {sol.message}")
        return ClosestPointResult(
            a1=w1, a2=w2, l1=np.asarray(l1, dtype=float), l2=np.asarray(l2, dtype=float), k1=int(k1),
            distance=dist, normal=self.normal(a1, weights1, mu2), overlapping=bool(overlapping),
            depth=float(depth), success=sol.success or certified, status=sol.status,
            iterations=self.iterations, residual=float(sol.residual), message=message, form=form)

    def failure(self, a1, a2, why):
        sol = self.last
        B1 = self.B1
        w1, w2 = B1.world(a1), B1.world(a2)
        return ClosestPointResult(
            a1=w1, a2=w2, l1=np.full(B1.m, np.nan), l2=np.full(self.B2.m, np.nan), k1=0,
            distance=float(np.linalg.norm(w1 - w2)), normal=np.full(B1.dim, np.nan),
            overlapping=False, depth=float("nan"), success=False, status=sol.status,
            iterations=self.iterations, residual=float(sol.residual),
            message=f"{why}; last solver message: {sol.message}", form="failed")
