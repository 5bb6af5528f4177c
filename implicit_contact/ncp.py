"""Box-constrained mixed complementarity problems by projected semismooth Newton (PATH's interface).

Problem
-------
Given ``F: R^n -> R^n`` with Jacobian ``J = F'`` and bounds ``l <= u`` (entries may be infinite),
find ``x`` with ``l <= x <= u`` such that for every ``i``::

    l_i <  x_i <  u_i  =>  F_i(x) =  0
    x_i =  l_i         =>  F_i(x) >= 0                                        MCP(F, l, u)
    x_i =  u_i         =>  F_i(x) <= 0

Free rows (``l_i = -inf, u_i = +inf``) are equations, ``[0, inf)`` rows are NCP rows, ``l_i = u_i``
fixes ``x_i`` and leaves ``F_i`` unconstrained. MCP(F, l, u) holds iff the natural residual

    r(x) = x - mid(l, u, x - F(x)),      mid = componentwise median,

vanishes; ``||r(x)||_inf`` is what the solver reports and what ``tol`` bounds.

Reformulation
-------------
The Fischer-Burmeister (FB) function, written with the sign of ``min(a, b)``,

    phi(a, b) = a + b - sqrt(a^2 + b^2),

satisfies ``phi(a, b) = 0  <=>  a >= 0, b >= 0, a b = 0`` and
``(2 - sqrt 2) |min(a, b)| <= |phi(a, b)| <= (2 + sqrt 2) |min(a, b)|``.  The natural residual of
one row is ``mid(x_i - l_i, x_i - u_i, F_i) = min(x_i - l_i, -min(u_i - x_i, -F_i))``; replacing
each ``min`` by ``phi`` gives Billups' box function (S. C. Billups, PhD thesis, Wisconsin 1995)

    Phi_i(x) = phi(x_i - l_i, -phi(u_i - x_i, -F_i(x)))     (l_i, u_i finite, l_i < u_i)
    Phi_i(x) = phi(x_i - l_i, F_i(x))                       (only l_i finite)
    Phi_i(x) = -phi(u_i - x_i, -F_i(x))                     (only u_i finite)
    Phi_i(x) = F_i(x)                                       (free)
    Phi_i(x) = x_i - l_i                                    (fixed, l_i = u_i)

and ``Phi(x) = 0  <=>  x solves MCP(F, l, u)``.

What is actually used is the penalised FB function of Chen, Chen & Kanzow (Math. Prog. 88, 2000),

    phi_lam(a, b) = lam phi(a, b) + (1 - lam) max(a, 0) max(b, 0),      0 < lam <= 1,

with the same zero set (both terms are positive in the open positive quadrant and the second
vanishes elsewhere).  Plain FB (lam = 1) is nearly flat where both arguments are large and
positive, i.e. far from the solution on the wrong side of every row; the product term restores a
complementarity-violation slope there.  On the problems of comparisons/mcp_problems.py, 200 random
starts, lam = 0.9 solved 199 against 180 for lam = 1; the penalty is quadratic, so it relies on
rows scaled to comparable magnitudes (which the caller does anyway).  ``Phi`` is semismooth
(strongly semismooth when ``J`` is locally Lipschitz) and nondifferentiable only where
``Phi_i = 0``.

``phi`` is evaluated as ``2 a b / (a + b + r)`` when ``a + b > 0`` (the two forms are equal
because ``(a + b)^2 - r^2 = 2 a b``) and as ``a + b - r`` otherwise, so neither branch subtracts
nearly equal numbers: the direct form loses every digit at a nearly complementary pair such as
(1, 1e-17); ``r = hypot(a, b)`` avoids overflow of ``a^2``.  A missing bound is replaced by
``-+1e150`` with ``lam = 1`` on that level: ``phi(1e150 - x, b) = b`` to two roundings, so the five
cases above are one branch-free vectorised expression (fixed rows give ``Phi_i = 0`` exactly
because the iterates keep ``x_i = l_i``; their Jacobian rows are set to ``e_i``).

Generalized Jacobian
--------------------
With ``phi_a = lam (1 - a/r) + (1 - lam) b+ [a > 0]`` and
``phi_b = lam (1 - b/r) + (1 - lam) a+ [b > 0]`` (FB part in ``[0, 2 lam]``,
``phi_a + phi_b >= lam (2 - sqrt 2) > 0``) the chain rule through the two nested ``phi`` gives
every row of an element ``H`` of the generalized Jacobian the form

    H_i = da_i e_i^T + db_i J_i,
    da_i = phi_a^out + phi_b^out phi_a^in,     db_i = phi_b^out phi_b^in,

with ``(phi_a, phi_b) = (0, 1)`` for an absent level (single bound or free row) and
``(da, db) = (1, 0)`` for fixed rows.  At a kink ``a = b = 0`` (a touching contact: the variable at
its bound and ``F_i = 0``) the classic choice of De Luca, Facchinei & Kanzow (Math. Prog. 75, 1996)
is used: take ``z`` with ``z_i = 1`` on the kink rows (``-1`` at an upper bound, so that ``z``
points into the box), 0 elsewhere, and replace ``(a, b) / r`` by the unit direction of
``(a'(x) z, b'(x) z)`` (the penalty term has zero derivative there).  This is the limit of the
row's Jacobians along ``x + t z``, so ``H`` is a generalized Jacobian and, where the solution is
BD-regular, Newton keeps its quadratic rate at touching contacts.  Away from kinks ``a+ b+`` is
differentiated from inside the box (``a > 0``), where the iterates live.

Merit, Newton step, globalization
---------------------------------
The merit ``psi = 0.5 ||Phi||^2`` is continuously differentiable even though ``Phi`` is not (every
kink has ``Phi_i = 0``), with ``grad psi = H^T Phi`` for any ``H`` above; for an NCP with a P0
function its stationary points are solutions (Facchinei & Soares, SIAM J. Optim. 7, 1997).
One iteration:

1. Newton: solve ``H d = -Phi`` (dense LU, or ``scipy.sparse.linalg.splu`` when ``jac`` returns
   a sparse matrix).  Then ``grad psi . d = -||Phi||^2``.  The direction is used only if it passes
   the descent test ``grad psi . d <= -rho ||d||^p`` (``p > 2``), which rejects the huge steps
   that a nearly singular ``H`` produces.
2. Step ``x(t) = P[x + t d]``, ``P`` the projection onto the box, accepted by the nonmonotone
   Armijo rule of Grippo, Lampariello & Lucidi (SIAM J. Numer. Anal. 23, 1986):
   ``psi(x(t)) <= max(psi_k, ..., psi_{k-M+1}) + sigma t grad psi . d``, ``t`` from safeguarded
   quadratic interpolation.  The max-reference alone admits cycles (two points whose merits
   alternate below the max forever, seen on Josephy's problem from x0 = 100 e); when the last M
   merits contain no new best the reference falls back to ``psi_k`` (a monotone step).
   Keeping iterates in the box (as in Kanzow, Numer. Math. 89, 2001) is free near a solution
   ``x*``: ``||P[x + d] - x*|| <= ||x + d - x*||`` since ``x*`` lies in the box, so the local rate
   survives, and ``F`` is never evaluated where the model may be meaningless (negative impulses,
   negative prices).  The price: for non-P0 problems the merit restricted to the box can have
   extra stationary points on its boundary (plain FB with the monotone rule stops at one on
   Josephy's problem from 100 e); the penalised function and the nonmonotone rule avoid them on
   the test set.
3. If Newton is singular, fails the descent test, or needs ``t < min_newton_step``, a
   Levenberg-Marquardt step ``(H^T H + mu I) d = -H^T Phi`` with ``mu = lm_factor ||Phi||_2`` is
   tried with the same line search.  Tying ``mu`` to the residual (Fan & Yuan, Computing 74, 2005)
   makes it vanish at the solution, so the step keeps a superlinear rate on singular Jacobians and
   non-isolated solutions; a fixed ``mu`` (e.g. 1e-6) makes convergence linear with a rate near 1
   once ``||Phi||`` is comparable to ``mu`` and stalls at residuals 1e-12..1e-7.
4. If that fails too, a projected gradient step ``P[x - t grad psi]`` with Armijo rule on
   ``grad psi . (x(t) - x)``, starting from the Cauchy step ``||g||^2 / ||H g||^2`` of the
   Gauss-Newton model.  When even this cannot decrease ``psi`` the iterate is a stationary point of
   the merit over the box that is not a solution, and the solver stops with LINE_SEARCH_FAILED
   (SINGULAR if the Newton system was singular there).

The solver never raises for a failure to converge and never replaces NaN: a non-finite ``F`` or
``J`` stops it with status NOT_FINITE at the last finite iterate.  ``ValueError`` is raised for
malformed input only.  There is no row scaling: the caller scales rows so that ``tol`` means the
same on every row.  To keep the per-call overhead small (this runs every time step) nothing is
copied that need not be: ``fun`` and ``jac`` must return arrays they do not modify afterwards.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from scipy.linalg import lapack

__all__ = ["solve_mcp", "SolverOptions", "McpResult", "Status"]


class Status(enum.Enum):
    """Why the solver stopped."""

    CONVERGED = "converged"                    # natural residual <= tol
    MAX_ITERATIONS = "max_iterations"          # iteration budget spent, residual > tol
    LINE_SEARCH_FAILED = "line_search_failed"  # no direction decreased the merit
    SINGULAR = "singular"                      # ... and the Newton system was singular there
    NOT_FINITE = "not_finite"                  # fun or jac returned NaN / inf


@dataclass(frozen=True)
class SolverOptions:
    """Options of :func:`solve_mcp`.

    tol: bound on the natural residual ``||x - mid(l, u, x - F(x))||_inf``, in the units of ``x``
        and ``F`` (the caller scales rows so they are comparable); > 0, nominal 1e-12..1e-6.
    max_iterations: accepted steps (one ``jac`` call each), >= 0, nominal 10..200; 0 evaluates the
        start only.
    armijo: sufficient-decrease constant sigma of the line search, in (0, 0.5); nominal 1e-4.
    nonmonotone_memory: M, number of past merits whose maximum is the Armijo reference
        (Grippo-Lampariello-Lucidi), >= 1; 1 is the monotone rule; nominal 1..10.
    min_newton_step: smallest Newton step length tried before switching to Levenberg-Marquardt,
        in (0, 1]; nominal 1e-4..1e-1.
    min_step: smallest step length of the Levenberg-Marquardt and gradient line searches, in
        (0, min_newton_step]; nominal 1e-14..1e-8.
    descent_rho, descent_power: a Newton direction d is used only if
        ``grad psi . d <= -descent_rho ||d||^descent_power``; rho > 0 (nominal 1e-10..1e-6),
        power > 2 (nominal 2.1).
    lm_factor: c in the Levenberg-Marquardt damping ``mu = c ||Phi||_2`` [1 / units of Phi],
        > 0, nominal 1e-4..1.
    fb_lambda: lam of the penalised Fischer-Burmeister function, in (0, 1]; 1 is plain FB;
        nominal 0.8..0.95.
    """

    tol: float = 1e-10
    max_iterations: int = 50
    armijo: float = 1e-4
    nonmonotone_memory: int = 10
    min_newton_step: float = 1e-4
    min_step: float = 1e-12
    descent_rho: float = 1e-8
    descent_power: float = 2.1
    lm_factor: float = 1e-2
    fb_lambda: float = 0.9

    def __post_init__(self):
        for name in ("tol", "armijo", "min_newton_step", "min_step", "descent_rho",
                     "descent_power", "lm_factor", "fb_lambda"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise ValueError(f"SolverOptions.{name} must be a finite number, got {value!r}")
        for name in ("max_iterations", "nonmonotone_memory"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ValueError(f"SolverOptions.{name} must be an integer, got {value!r}")
        if not self.tol > 0:
            raise ValueError(f"SolverOptions.tol must be positive, got {self.tol}")
        if self.max_iterations < 0:
            raise ValueError("SolverOptions.max_iterations must be >= 0, "
                             f"got {self.max_iterations}")
        if not 0 < self.armijo < 0.5:
            raise ValueError(f"SolverOptions.armijo must lie in (0, 0.5), got {self.armijo}")
        if self.nonmonotone_memory < 1:
            raise ValueError("SolverOptions.nonmonotone_memory must be >= 1 (1 is monotone), "
                             f"got {self.nonmonotone_memory}")
        if not 0 < self.min_newton_step <= 1:
            raise ValueError("SolverOptions.min_newton_step must lie in (0, 1], "
                             f"got {self.min_newton_step}")
        if not 0 < self.min_step <= self.min_newton_step:
            raise ValueError("SolverOptions.min_step must lie in (0, min_newton_step], "
                             f"got {self.min_step}")
        if not self.descent_rho > 0:
            raise ValueError(f"SolverOptions.descent_rho must be positive, got {self.descent_rho}")
        if not self.descent_power > 2:
            raise ValueError("SolverOptions.descent_power must be > 2 (p > 2 keeps the fast local "
                             f"rate), got {self.descent_power}")
        if not 0 < self.fb_lambda <= 1:
            raise ValueError(f"SolverOptions.fb_lambda must lie in (0, 1], got {self.fb_lambda}")
        if not self.lm_factor > 0:
            raise ValueError(f"SolverOptions.lm_factor must be positive, got {self.lm_factor}")


@dataclass(frozen=True)
class McpResult:
    """Outcome of :func:`solve_mcp`.

    x: last iterate (always finite, inside the box).  f: F(x) (NaN-containing only for NOT_FINITE
    at the start).  residual: natural residual ``||x - mid(l, u, x - F(x))||_inf`` at x.
    merit_history: ``0.5 ||Phi||^2`` at the start and after every accepted step.
    steps: one letter per accepted step: N Newton, L Levenberg-Marquardt, G projected gradient.
    nfev, njev: calls of fun and jac.
    """

    x: np.ndarray
    f: np.ndarray
    status: Status
    iterations: int
    residual: float
    merit_history: tuple[float, ...]
    message: str
    steps: str
    nfev: int
    njev: int

    @property
    def success(self) -> bool:
        return self.status is Status.CONVERGED


class _NotFinite(Exception):
    """Internal: fun or jac produced NaN / inf at a point; carries a sentence for the result."""


# Stand-in for an infinite bound inside phi: phi_lam(BIG - x, b) = b to within two roundings for
# |b| << BIG with lam = 1, w = 0 on that level, so a missing bound needs no branch and no inf - inf;
# products with BIG stay finite for |b| < 1e150.
_BIG = 1e150


def _fb(a, b, lam, w):
    """phi_lam(a, b) for a >= 0 without cancellation.

    lam, w: per-row weights of the FB and penalty terms (w = 1 - lam on a bounded level,
    lam = 1, w = 0 on an absent one); w is None when no row is penalised.
    Returns (phi, (a, b, r, max(b, 0), w a)), the second item for `_fb_partials`."""
    r = np.hypot(a, b)
    s = a + b
    out = s - r
    np.divide(2.0 * a * b, s + r, out=out, where=s > 0.0)
    if w is None:
        return out, (a, b, r, None, None)
    bp = np.maximum(b, 0.0)
    wa = w * a          # a >= 0 inside the box, so a+ = a
    out *= lam
    out += wa * bp
    return out, (a, b, r, bp, wa)


def _fb_partials(level, lam, w):
    """(d phi_lam / da, d phi_lam / db, kink mask or None).  At a kink (r = 0) the FB part is left
    at 1 for the caller to replace.  a+ b+ is differentiated from inside the box (a > 0): an
    element of its B-subdifferential."""
    a, b, r, bp, wa = level
    kink = None
    if r.min() == 0.0:
        kink = r == 0.0
        r = r + kink
    pa = 1.0 - a / r
    pb = 1.0 - b / r
    if w is not None:
        pa *= lam
        pa += w * bp
        pb *= lam
        pb += wa * (b > 0.0)
    return pa, pb, kink


class _Box:
    """Bound classification of one call and the reformulation Phi built on it.

    Rows without an upper bound get the inner level ``phi(BIG - x, -F) = -F`` (identity), rows
    without a lower bound the outer identity, so one vectorised expression serves free, single-
    and double-bounded rows.  Fixed rows (l = u) come out as Phi_i = 0 exactly, because the
    projection keeps x_i = l_i; their Jacobian rows are replaced by e_i."""

    __slots__ = ("n", "lo0", "hi0", "two_level", "lam_in", "w_in", "lam_out", "w_out", "fixed",
                 "any_fixed")

    def __init__(self, lo, hi, lam):
        self.n = lo.shape[0]
        self.two_level = bool(hi.min() < np.inf)
        self.lo0 = np.maximum(lo, -_BIG)
        self.hi0 = np.minimum(hi, _BIG)
        self.lam_out = self.w_out = self.lam_in = self.w_in = None
        if lam != 1.0:
            # scalars when every row has the bound (the usual NCP case): cheaper than arrays
            if lo.max() == -np.inf:
                pass
            elif lo.min() > -np.inf:
                self.lam_out, self.w_out = lam, 1.0 - lam
            else:
                self.w_out = (1.0 - lam) * (lo > -np.inf)
                self.lam_out = 1.0 - self.w_out
            if self.two_level:
                if hi.max() < np.inf:
                    self.lam_in, self.w_in = lam, 1.0 - lam
                else:
                    self.w_in = (1.0 - lam) * (hi < np.inf)
                    self.lam_in = 1.0 - self.w_in
        # a fixed row needs a finite upper bound
        self.fixed = np.flatnonzero(lo == hi) if self.two_level else np.empty(0, dtype=int)
        self.any_fixed = self.fixed.size > 0

    def phi(self, x, F):
        """Phi(x) and the FB arguments it was built from (reused by `coefficients`)."""
        if self.two_level:
            s, inner = _fb(self.hi0 - x, -F, self.lam_in, self.w_in)
            b_out = -s
        else:
            inner = None
            b_out = F
        Phi, outer = _fb(x - self.lo0, b_out, self.lam_out, self.w_out)
        return Phi, (inner, outer)

    def coefficients(self, parts, J):
        """(da, db) with H = diag(da) + diag(db) J an element of the generalized Jacobian."""
        inner, outer = parts
        pa_out, pb_out, kout = _fb_partials(outer, self.lam_out, self.w_out)
        if self.two_level:
            pa_in, pb_in, kin = _fb_partials(inner, self.lam_in, self.w_in)
            if kin is not None or kout is not None:
                self._kinks(J, kin, kout, pa_in, pb_in, pa_out, pb_out)
            da = pa_out + pb_out * pa_in
            db = pb_out * pb_in
        else:
            if kout is not None:
                self._kinks(J, None, kout, 0.0, 1.0, pa_out, pb_out)
            da, db = pa_out, pb_out
        if self.any_fixed:
            da[self.fixed] = 1.0
            db[self.fixed] = 0.0
        return da, db

    def _kinks(self, J, kin, kout, pa_in, pb_in, pa_out, pb_out):
        """De Luca-Facchinei-Kanzow choice at a = b = 0, in place: the limit of Jacobians along
        x + t z, t -> 0+, with z_i = +1 at a lower-bound kink, -1 at an upper-bound kink (into
        the box), 0 elsewhere.  The penalty term has zero slope at a = b = 0."""
        n = self.n
        kin = np.zeros(n, bool) if kin is None else kin
        kout = np.zeros(n, bool) if kout is None else kout
        if self.any_fixed:
            kout[self.fixed] = False
            kin[self.fixed] = False
        kinks = kin | kout
        if not kinks.any():
            return
        Jz = np.asarray(J @ (kout.astype(float) - kin)).ravel()
        lam_in = 1.0 if self.lam_in is None else self.lam_in
        lam_out = 1.0 if self.lam_out is None else self.lam_out
        if kin.any():
            # inner level: a = u - x, b = -F; along z (z_i = -1): (a', b') = (1, -(J z)_i)
            db_z = -Jz[kin]
            norm = np.hypot(1.0, db_z)
            scale = lam_in if np.ndim(lam_in) == 0 else lam_in[kin]
            pa_in[kin] = scale * (1.0 - 1.0 / norm)
            pb_in[kin] = scale * (1.0 - db_z / norm)
        if kout.any():
            # outer level (z_i = +1): a = x - l, b = -s, s' z = -(phi_a^in + phi_b^in (J z)_i)
            if np.ndim(pa_in) == 0:
                db_z = pa_in + pb_in * Jz[kout]
            else:
                db_z = pa_in[kout] + pb_in[kout] * Jz[kout]
            norm = np.hypot(1.0, db_z)
            scale = lam_out if np.ndim(lam_out) == 0 else lam_out[kout]
            pa_out[kout] = scale * (1.0 - 1.0 / norm)
            pb_out[kout] = scale * (1.0 - db_z / norm)


def _as_bound(value, n, name):
    b = np.asarray(value, dtype=float)
    if b.ndim == 0:
        return np.full(n, float(b))
    if b.shape != (n,):
        raise ValueError(f"{name} must be a scalar or have shape ({n},) like x0, "
                         f"got shape {b.shape}")
    return b


def _check_f(F, n):
    F = np.asarray(F, dtype=float)
    if F.shape != (n,):
        raise ValueError(f"fun(x) must return an array of shape ({n},), got shape {F.shape}")
    return F


def _solve_dense(H, rhs):
    """LU solve; None when H is exactly singular or the result is not finite."""
    _, _, d, info = lapack.dgesv(H, rhs)
    if info != 0 or not math.isfinite(d @ d):
        return None
    return d


def _solve_sparse(H, rhs):
    try:
        d = spla.splu(H.tocsc()).solve(rhs)
    except RuntimeError:  # "Factor is exactly singular"
        return None
    if not math.isfinite(d @ d):
        return None
    return d


def solve_mcp(fun: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], object],
              x0, lower, upper, options: SolverOptions = SolverOptions()) -> McpResult:
    """Solve MCP(F, l, u): ``l <= x <= u`` with ``F_i(x) = 0`` strictly inside, ``>= 0`` at ``l_i``,
    ``<= 0`` at ``u_i``.

    fun(x) -> F(x), shape (n,).  jac(x) -> dF/dx, a dense (n, n) array or a scipy.sparse matrix
    (then sparse LU is used).  x0: warm start, projected onto the box.  lower, upper: shape (n,)
    or scalars, entries may be -inf / +inf.  Never raises for non-convergence: see result.status.
    """
    x = np.asarray(x0, dtype=float)
    if x.ndim != 1 or x.shape[0] == 0:
        raise ValueError(f"x0 must be a non-empty 1-D array, got shape {x.shape}")
    n = x.shape[0]
    lo = _as_bound(lower, n, "lower")
    hi = _as_bound(upper, n, "upper")
    # one pass for the common case; NaN fails every comparison and lands in the error branch
    if not ((lo <= hi).all() and lo.max() < np.inf and hi.min() > -np.inf):
        if np.isnan(lo).any() or np.isnan(hi).any():
            raise ValueError("lower and upper must not contain NaN (use -inf / +inf for no bound)")
        if not (lo <= hi).all():
            i = int(np.flatnonzero(~(lo <= hi))[0])
            raise ValueError(f"lower must be <= upper, got lower[{i}] = {lo[i]} > "
                             f"upper[{i}] = {hi[i]}")
        raise ValueError("lower must be < +inf and upper > -inf for every entry")
    if not math.isfinite(x @ x) and not np.isfinite(x).all():
        raise ValueError("x0 must be finite")
    if not isinstance(options, SolverOptions):
        raise ValueError(f"options must be a SolverOptions, got {type(options).__name__}")

    x = np.minimum(np.maximum(x, lo), hi)  # a new array: the caller's x0 is never written
    F = _check_f(fun(x), n)
    nfev, njev = 1, 0
    if not math.isfinite(float(F @ F)) and not np.isfinite(F).all():
        return McpResult(x, F, Status.NOT_FINITE, 0, math.nan, (math.nan,),
                         "fun returned NaN or inf at the (projected) starting point.", "", nfev,
                         njev)
    box = _Box(lo, hi, options.fb_lambda)
    Phi, parts = box.phi(x, F)
    psi = 0.5 * float(Phi @ Phi)
    residual = float(np.abs(x - np.minimum(np.maximum(x - F, lo), hi)).max())
    history = [psi]

    tol = options.tol
    sigma = options.armijo
    memory = options.nonmonotone_memory
    min_newton_step = options.min_newton_step
    min_step = options.min_step
    rho, power = options.descent_rho, options.descent_power
    lm_factor = options.lm_factor
    eye_stride = n + 1

    def trial(xt):
        """F, Phi and merit at a trial point; _NotFinite if F has NaN / inf there."""
        nonlocal nfev
        Ft = _check_f(fun(xt), n)
        nfev += 1
        # F.F is NaN / inf for a NaN / inf entry (and, rarely, on overflow: then check entries)
        if not math.isfinite(float(Ft @ Ft)) and not np.isfinite(Ft).all():
            raise _NotFinite("fun returned NaN or inf at a trial point of the line search; "
                             "x is the last finite iterate.")
        Phit, partst = box.phi(xt, Ft)
        psit = 0.5 * float(Phit @ Phit)
        return Ft, Phit, partst, psit

    def search(d, slope, psi_ref, t_min):
        """Projected nonmonotone Armijo search along d with quadratic-interpolation backtracking."""
        t = 1.0
        while t >= t_min:
            xt = np.minimum(np.maximum(x + t * d, lo), hi)
            Ft, Phit, partst, psit = trial(xt)
            if psit <= psi_ref + sigma * t * slope:
                return xt, Ft, Phit, partst, psit
            # minimiser of the quadratic through psi(0), psi'(0) = slope and psi(t), kept in
            # [0.1 t, 0.5 t] so that a bad model neither stalls nor overshoots
            curvature = psit - psi - t * slope
            t_new = -slope * t * t / (2.0 * curvature) if curvature > 0.0 else 0.5 * t
            t = min(max(t_new, 0.1 * t), 0.5 * t)
        return None

    def gradient_search(g, Hg_sq, psi_ref):
        """Projected gradient path P[x - t g], Armijo on the actual displacement."""
        gg = float(g @ g)
        t = gg / Hg_sq if Hg_sq > 0.0 else 1.0
        floor = 4.0 * np.finfo(float).eps * (1.0 + float(np.abs(x).max()))
        while True:
            xt = np.minimum(np.maximum(x - t * g, lo), hi)
            step = xt - x
            if float(np.abs(step).max()) <= floor:
                return None
            Ft, Phit, partst, psit = trial(xt)
            if psit <= psi_ref + sigma * float(g @ step):
                return xt, Ft, Phit, partst, psit
            t *= 0.5

    status = None
    message = ""
    iterations = 0
    steps = []
    try:
        while True:
            if residual <= tol:
                status = Status.CONVERGED
                message = (f"Converged in {iterations} iterations: natural residual {residual:.3g} "
                           f"<= tol {tol:.3g}.")
                break
            if iterations >= options.max_iterations:
                status = Status.MAX_ITERATIONS
                message = (f"Stopped after {iterations} iterations (max_iterations) with natural "
                           f"residual {residual:.3g} > tol {tol:.3g}.")
                break

            J = jac(x)
            njev += 1
            sparse = sp.issparse(J)
            if sparse:
                J = J.tocsr()
                if J.shape != (n, n):
                    raise ValueError(f"jac(x) must return shape ({n}, {n}), got {J.shape}")
                finite = bool(np.isfinite(J.data).all())
            else:
                J = np.asarray(J, dtype=float)
                if J.shape != (n, n):
                    raise ValueError(f"jac(x) must return shape ({n}, {n}), got {J.shape}")
                finite = bool(np.isfinite(J).all())
            if not finite:
                raise _NotFinite("jac returned NaN or inf at the current iterate.")

            da, db = box.coefficients(parts, J)
            if sparse:
                H = sp.csr_matrix((J.data * np.repeat(db, np.diff(J.indptr)), J.indices,
                                   J.indptr), shape=(n, n)) + sp.diags(da, format="csr")
            else:
                H = J * db[:, None]
                H.flat[::eye_stride] += da
            g = H.T @ Phi
            psi_ref = max(history[-memory:])
            if len(history) > memory and min(history[-memory:]) >= min(history[:-memory]):
                # no new best merit in `memory` steps: a nonmonotone cycle; step monotonically
                psi_ref = psi
            accepted = None

            # 1. Newton
            d = _solve_sparse(H, -Phi) if sparse else _solve_dense(H, -Phi)
            singular = d is None
            if not singular:
                slope = float(g @ d)
                if slope <= -rho * float(d @ d) ** (0.5 * power):
                    accepted = search(d, slope, psi_ref, min_newton_step)
                    kind = "N"

            # 2. Levenberg-Marquardt, damping tied to the residual
            if accepted is None:
                mu = lm_factor * math.sqrt(2.0 * psi)
                if sparse:
                    HtH = (H.T @ H).tocsr()
                    mu += 16.0 * np.finfo(float).eps * float(np.abs(HtH.diagonal()).max())
                    d = _solve_sparse(HtH + sp.diags(np.full(n, mu), format="csr"), -g)
                else:
                    HtH = H.T @ H
                    mu += 16.0 * np.finfo(float).eps * float(HtH.diagonal().max())
                    HtH.flat[::eye_stride] += mu
                    d = _solve_dense(HtH, -g)
                if d is not None:
                    slope = float(g @ d)
                    if slope < 0.0:
                        accepted = search(d, slope, psi_ref, min_step)
                        kind = "L"

            # 3. projected gradient
            if accepted is None:
                Hg = H @ g
                accepted = gradient_search(g, float(Hg @ Hg), psi_ref)
                kind = "G"

            if accepted is None:
                status = Status.SINGULAR if singular else Status.LINE_SEARCH_FAILED
                cause = ("the Newton system is singular and neither a Levenberg-Marquardt nor a "
                         "gradient step decreases the merit" if singular else
                         "no Newton, Levenberg-Marquardt or gradient step decreases the merit "
                         "(a stationary point of the merit that is not a solution)")
                message = (f"Stopped after {iterations} iterations: {cause}; natural residual "
                           f"{residual:.3g}.")
                break
            x, F, Phi, parts, psi = accepted
            iterations += 1
            history.append(psi)
            steps.append(kind)
            residual = float(np.abs(x - np.minimum(np.maximum(x - F, lo), hi)).max())
    except _NotFinite as exc:
        status = Status.NOT_FINITE
        message = f"Stopped after {iterations} iterations: {exc}"

    return McpResult(x, F, status, iterations, residual, tuple(history), message, "".join(steps),
                     nfev, njev)
