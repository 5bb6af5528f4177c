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
``J`` stops it with status NOT_FINITE at the last finite iterate (``shorten_nonfinite``: a
non-finite trial point of a line search instead shortens the step, like a failed Armijo test).  ``ValueError`` is raised for
malformed input only.  There is no row scaling: the caller scales rows so that ``tol`` means the
same on every row.  To keep the per-call overhead small (this runs every time step) nothing is
copied that need not be: ``fun`` and ``jac`` must return arrays they do not modify afterwards.
"""
from __future__ import annotations

import enum
import math
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from . import block_elimination
from . import sparse_lu
from ._jit import generator_kernel, kernel, lean_kernel

__all__ = ["solve_mcp", "solve_proximal", "newton_min_map", "SolverOptions", "McpResult", "Status"]


class Status(enum.Enum):
    """Why the solver stopped."""

    CONVERGED = "converged"                    # natural residual <= tol
    MAX_ITERATIONS = "max_iterations"          # iteration budget spent, residual > tol
    LINE_SEARCH_FAILED = "line_search_failed"  # no direction decreased the merit
    SINGULAR = "singular"                      # ... and the Newton system was singular there
    NOT_FINITE = "not_finite"                  # fun or jac returned NaN / inf
    HANDED_OVER = "handed_over"                # the caller's stop test ended it (solve_mcp's stop)


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
    shorten_nonfinite: a trial point of a line search where ``fun`` is NaN or inf counts as an
        infinite merit and the step is halved (the rows are undefined far from the last iterate,
        not at it); False stops with NOT_FINITE there. A non-finite start or Jacobian always
        stops.
    watch: the iteration at which a stalled solve stops, >= 0 (0: never): if the best merit of its
        last STALL_WINDOW iterations is above STALL_GAIN times the best before them, the solve
        stops there with status MAX_ITERATIONS (its message says it stalled), so that a caller with
        a better start for the stalled case (the stepper's recovery.restart_sliding) need not
        wait for max_iterations; otherwise it goes on, the same iterations as without the watch.
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
    shorten_nonfinite: bool = False
    watch: int = 0

    def __post_init__(self):
        for name in ("tol", "armijo", "min_newton_step", "min_step", "descent_rho",
                     "descent_power", "lm_factor", "fb_lambda"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value):
                raise ValueError(f"SolverOptions.{name} must be a finite number, got {value!r}")
        for name in ("max_iterations", "nonmonotone_memory", "watch"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ValueError(f"SolverOptions.{name} must be an integer, got {value!r}")
        if not isinstance(self.shorten_nonfinite, bool):
            raise ValueError(f"SolverOptions.shorten_nonfinite must be True or False, got {self.shorten_nonfinite!r}")
        if not self.tol > 0:
            raise ValueError(f"SolverOptions.tol must be positive, got {self.tol}")
        if self.max_iterations < 0:
            raise ValueError("SolverOptions.max_iterations must be >= 0, "
                             f"got {self.max_iterations}")
        if not 0 < self.armijo < 0.5:
            raise ValueError(f"SolverOptions.armijo must lie in (0, 0.5), got {self.armijo}")
        if self.watch < 0:
            raise ValueError(f"SolverOptions.watch must be >= 0 (0: never), got {self.watch}")
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
    steps: one letter per accepted step: N Newton, L Levenberg-Marquardt, G projected gradient
    (newton_min_map: N its Newton steps, W its watchdog's full step).
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


# Stand-in for an infinite bound inside phi: phi_lam(BIG - x, b) = b to within two roundings for
# |b| << BIG with lam = 1, w = 0 on that level, so a missing bound needs no branch and no inf - inf;
# products with BIG stay finite for |b| < 1e150.
BIG = 1e150


# ---------------------------------------------------------------------------------------------
# The iteration, once, as a compiled generator that asks its caller for what it needs
# ---------------------------------------------------------------------------------------------
# Reverse communication. ``mcp_iterations`` is the whole algorithm above (reformulation,
# generalized Jacobian, Newton / Levenberg-Marquardt / projected gradient, nonmonotone line
# search, statuses) as a numba generator over preallocated buffers. It never sees F or J: it
# yields a request and the caller answers it in the buffers before asking for the next one.
# solve_mcp below answers with Python callables (dense J through the kernels below, sparse J
# through scipy); step_solver.py answers a step's MCP inside compiled code, with no Python
# between iterations. One algorithm, several drivers.
REQ_F = 1          # Ft = F(xt)
REQ_J = 2          # J = F'(x); set info[I_BAD] = 1 if J has NaN / inf
REQ_JZ = 3         # Jz = J @ zk
REQ_NEWTON = 4     # H = diag(da) + diag(db) J; g = H^T Phi; d = solve(H, -Phi), info[I_SINGULAR]
REQ_LM = 5         # d = solve(H^T H + (mu + 16 eps max diag(H^T H)) I, -g), mu = fbuf[F_MU]
REQ_HG = 6         # fbuf[F_HGSQ] = |H g|^2

# info (int64) entries: outcome and flags
I_STATUS, I_ITER, I_NFEV, I_NJEV, I_WHY, I_SINGULAR, I_BAD = 0, 1, 2, 3, 4, 5, 6
NINFO = 7
# fbuf (float64) entries
F_RESIDUAL, F_MU, F_HGSQ, F_PSI = 0, 1, 2, 3
NFBUF = 4
# options (float64) entries
(O_TOL, O_MAXIT, O_ARMIJO, O_MEMORY, O_MIN_NEWTON, O_MIN_STEP, O_RHO, O_POWER, O_LM, O_LAMBDA, O_SHORTEN,
 O_WATCH) = range(12)
NOPT = 12
# status codes (Status below) and why a NOT_FINITE / failed stop happened
S_CONVERGED, S_MAX_ITERATIONS, S_LINE_SEARCH_FAILED, S_SINGULAR, S_NOT_FINITE = 0, 1, 2, 3, 4
S_HANDED_OVER = 5       # set by a driver, never by mcp_iterations (solve_mcp's stop)
WHY_START, WHY_TRIAL, WHY_JAC, WHY_STALLED = 1, 2, 3, 4
STALL_WINDOW = 5        # iterations (SolverOptions.watch)
STALL_GAIN = 0.5       # a best merit that fell by less than this factor over the window has stalled
STEP_NEWTON, STEP_LM, STEP_GRADIENT = 1, 2, 3


def options_array(options: SolverOptions) -> np.ndarray:
    o = np.zeros(NOPT)
    o[O_TOL], o[O_MAXIT], o[O_ARMIJO] = options.tol, options.max_iterations, options.armijo
    o[O_MEMORY], o[O_MIN_NEWTON], o[O_MIN_STEP] = options.nonmonotone_memory, options.min_newton_step, options.min_step
    o[O_RHO], o[O_POWER], o[O_LM], o[O_LAMBDA] = (options.descent_rho, options.descent_power, options.lm_factor,
                                                  options.fb_lambda)
    o[O_SHORTEN] = 1.0 if options.shorten_nonfinite else 0.0
    o[O_WATCH] = options.watch
    return o


@lean_kernel
def _phi(a, b, lam, w):
    """phi_lam(a, b) for a >= 0 without cancellation (w = 1 - lam on a bounded level, 0 on an
    absent one)."""
    r = math.hypot(a, b)
    s = a + b
    fb = 2.0 * a * b / (s + r) if s > 0.0 else s - r
    if w == 0.0:
        return lam * fb
    return lam * fb + (w * a) * max(b, 0.0)


@lean_kernel
def _partials(a, b, lam, w):
    """(d phi / da, d phi / db, kink) of phi_lam; at a kink the FB part is left at 1."""
    r = math.hypot(a, b)
    kink = r == 0.0
    if kink:
        r = 1.0
    pa = 1.0 - a / r
    pb = 1.0 - b / r
    if w != 0.0:
        pa = lam * pa + w * max(b, 0.0)
        pb = lam * pb + (w * a) * (1.0 if b > 0.0 else 0.0)
    return pa, pb, kink


@lean_kernel
def _levels(lo, hi, lam, lo0, hi0, lam_in, w_in, lam_out, w_out):
    """Per row: finite stand-ins of the bounds and the FB / penalty weights of each level; returns
    whether any row has an upper bound (two levels)."""
    n = lo.shape[0]
    two = _two_levels(hi)
    for i in range(n):
        lo0[i] = max(lo[i], -BIG)
        hi0[i] = min(hi[i], BIG)
        if lam != 1.0 and lo[i] > -np.inf:
            lam_out[i], w_out[i] = lam, 1.0 - lam
        else:
            lam_out[i], w_out[i] = 1.0, 0.0
        if lam != 1.0 and two and hi[i] < np.inf:
            lam_in[i], w_in[i] = lam, 1.0 - lam
        else:
            lam_in[i], w_in[i] = 1.0, 0.0
    return two


@lean_kernel
def _two_levels(hi):
    """Whether any row has an upper bound (Phi then has two levels)."""
    for i in range(hi.shape[0]):
        if hi[i] < np.inf:
            return True
    return False


ITERATE = -1     # first_point: the start is not a solution; Newton iterations follow


@lean_kernel
def start_point(x0, lo, hi, xt):
    """The solve's first point: x0 clipped to the bounds, into xt (never writes x0)."""
    for i in range(x0.shape[0]):
        xt[i] = min(max(x0[i], lo[i]), hi[i])


@lean_kernel
def first_point(lo, hi, opt, x, F, xt, Ft, Phi, history, info, fbuf, work):
    """The solve at its first point xt (start_point) once Ft = F(xt) is known: the counters, x
    and F, the levels of Phi (work), the merit history[0] = psi and fbuf's residual and psi.
    Returns S_CONVERGED when xt solves the problem to tol, S_NOT_FINITE when F is not finite
    (info's status and reason set as mcp_iterations sets them), else ITERATE. A driver that
    answers F itself calls it before mcp_iterations(..., started=True) and skips the generator
    when the start already solves the problem: the rolling disc's repeated step starts at its
    solution, and its solve took 4.4 us through the generator, 2.5 us without."""
    n = x.shape[0]
    info[I_NFEV] = 1
    info[I_NJEV] = 0
    info[I_ITER] = 0
    info[I_WHY] = 0
    for i in range(n):
        x[i] = xt[i]
        F[i] = Ft[i]
    if not _finite(F):
        info[I_STATUS], info[I_WHY] = S_NOT_FINITE, WHY_START
        fbuf[F_RESIDUAL] = np.nan
        history[0] = np.nan
        return S_NOT_FINITE
    lo0, hi0, lam_in, w_in, lam_out, w_out = work[0], work[1], work[2], work[3], work[4], work[5]
    two = _levels(lo, hi, opt[O_LAMBDA], lo0, hi0, lam_in, w_in, lam_out, w_out)
    psi = _reformulate(x, F, lo0, hi0, lam_in, w_in, lam_out, w_out, two, Phi)
    residual = _natural_residual(x, F, lo, hi)
    history[0] = psi
    fbuf[F_RESIDUAL], fbuf[F_PSI] = residual, psi
    if residual <= opt[O_TOL]:
        info[I_STATUS] = S_CONVERGED
        return S_CONVERGED
    return ITERATE


@lean_kernel
def _reformulate(x, F, lo0, hi0, lam_in, w_in, lam_out, w_out, two, Phi):
    """Phi(x) (Billups' box function, penalised); returns psi = |Phi|^2 / 2."""
    psi = 0.0
    for i in range(x.shape[0]):
        if two:
            b = -_phi(hi0[i] - x[i], -F[i], lam_in[i], w_in[i])
        else:
            b = F[i]
        v = _phi(x[i] - lo0[i], b, lam_out[i], w_out[i])
        Phi[i] = v
        psi += v * v
    return 0.5 * psi


@lean_kernel
def _natural_residual(x, F, lo, hi):
    res = 0.0
    for i in range(x.shape[0]):
        y = min(max(x[i] - F[i], lo[i]), hi[i])
        res = max(res, abs(x[i] - y))
    return res


@lean_kernel
def _stalled(history, nhist):
    """Whether the best of the last STALL_WINDOW merits in history[:nhist] is above STALL_GAIN
    times the best before them (Newton in its quadratic basin gains orders of magnitude an
    iteration)."""
    if nhist <= STALL_WINDOW:
        return False
    before = history[0]
    for k in range(nhist - STALL_WINDOW):
        before = min(before, history[k])
    last = history[nhist - STALL_WINDOW]
    for k in range(nhist - STALL_WINDOW, nhist):
        last = min(last, history[k])
    return last > STALL_GAIN * before


@lean_kernel
def _finite(v):
    acc = 0.0
    for i in range(v.shape[0]):
        acc += v[i] * v[i]
    if math.isfinite(acc):
        return True
    for i in range(v.shape[0]):
        if not math.isfinite(v[i]):
            return False
    return True


@generator_kernel
def mcp_iterations(x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz, history, steps, info, fbuf,
                   work, started=False):
    """The solver (module docstring) as a generator of requests REQ_* (see above). x0 is the
    start; the outcome is left in x, F, info, fbuf, history (merits, length max_iterations + 1)
    and steps (STEP_* codes). work: (7, n) scratch. started: the caller has taken the first
    point itself (start_point, Ft = F(xt), first_point returning ITERATE), so the generator
    begins with the first Newton iteration (see first_point)."""
    n = x0.shape[0]
    tol, maxit, armijo = opt[O_TOL], int(opt[O_MAXIT]), opt[O_ARMIJO]
    memory, min_newton, min_step = int(opt[O_MEMORY]), opt[O_MIN_NEWTON], opt[O_MIN_STEP]
    rho, power, lm_factor = opt[O_RHO], opt[O_POWER], opt[O_LM]
    shorten = opt[O_SHORTEN] != 0.0
    watch = int(opt[O_WATCH])
    lo0, hi0, lam_in, w_in, lam_out, w_out, gd = work[0], work[1], work[2], work[3], work[4], work[5], work[6]
    if not started:
        start_point(x0, lo, hi, xt)
        yield REQ_F
        if first_point(lo, hi, opt, x, F, xt, Ft, Phi, history, info, fbuf, work) != ITERATE:
            return
    two = _two_levels(hi)          # (first_point has set the levels in work)
    psi, residual = history[0], fbuf[F_RESIDUAL]
    nhist = 1
    eps = np.finfo(np.float64).eps
    while True:
        fbuf[F_RESIDUAL], fbuf[F_PSI] = residual, psi
        if residual <= tol:
            info[I_STATUS] = S_CONVERGED
            return
        if info[I_ITER] >= maxit:
            info[I_STATUS] = S_MAX_ITERATIONS
            return
        if watch > 0 and info[I_ITER] == watch and _stalled(history, nhist):
            info[I_STATUS], info[I_WHY] = S_MAX_ITERATIONS, WHY_STALLED
            return
        info[I_BAD] = 0
        yield REQ_J
        info[I_NJEV] += 1
        if info[I_BAD] != 0:
            info[I_STATUS], info[I_WHY] = S_NOT_FINITE, WHY_JAC
            return
        # generalized Jacobian element H = diag(da) + diag(db) J
        any_kink = False
        for i in range(n):
            fixed = two and lo[i] == hi[i]
            if two:
                ai, bi = hi0[i] - x[i], -F[i]
                pa_in, pb_in, kin = _partials(ai, bi, lam_in[i], w_in[i])
                s_in = _phi(ai, bi, lam_in[i], w_in[i])
                b_out = -s_in
            else:
                pa_in, pb_in, kin = 0.0, 1.0, False
                b_out = F[i]
            pa_out, pb_out, kout = _partials(x[i] - lo0[i], b_out, lam_out[i], w_out[i])
            if fixed:
                kin = kout = False
            zk[i] = (1.0 if kout else 0.0) - (1.0 if kin else 0.0)
            if kin or kout:
                any_kink = True
            # kept for the kink pass: inner partials in da, db; outer ones in Jz and gd
            da[i], db[i] = pa_in, pb_in
            Jz[i], gd[i] = pa_out, pb_out
            if kout:
                Jz[i] = np.nan          # marks an outer kink (its partials are replaced)
            if kin:
                db[i] = np.nan          # marks an inner kink
        pa_out_store = d                # scratch: the outer partials while Jz is requested
        for i in range(n):
            pa_out_store[i] = Jz[i]
        if any_kink:
            yield REQ_JZ                # Jz = J zk, zk = +1 at outer kinks, -1 at inner ones
        for i in range(n):
            pa_in, pb_in = da[i], db[i]
            pa_out, pb_out = pa_out_store[i], gd[i]
            if two and math.isnan(pb_in):
                # inner level: a = u - x, b = -F; along z (z_i = -1): (a', b') = (1, -(J z)_i)
                dbz = -Jz[i]
                nrm = math.hypot(1.0, dbz)
                pa_in = lam_in[i] * (1.0 - 1.0 / nrm)
                pb_in = lam_in[i] * (1.0 - dbz / nrm)
            if math.isnan(pa_out):
                # outer level (z_i = +1): a = x - l, b = -s, s' z = -(phi_a^in + phi_b^in (J z)_i)
                dbz = pa_in + pb_in * Jz[i]
                nrm = math.hypot(1.0, dbz)
                pa_out = lam_out[i] * (1.0 - 1.0 / nrm)
                pb_out = lam_out[i] * (1.0 - dbz / nrm)
            if two:
                da[i] = pa_out + pb_out * pa_in
                db[i] = pb_out * pb_in
            else:
                da[i], db[i] = pa_out, pb_out
            if two and lo[i] == hi[i]:
                da[i], db[i] = 1.0, 0.0
        # the nonmonotone reference
        start = max(0, nhist - memory)
        psi_ref = history[start]
        for k in range(start, nhist):
            psi_ref = max(psi_ref, history[k])
        if nhist > memory:
            recent = history[start]
            for k in range(start, nhist):
                recent = min(recent, history[k])
            older = history[0]
            for k in range(0, start):
                older = min(older, history[k])
            if recent >= older:
                psi_ref = psi      # no new best merit in `memory` steps: step monotonically
        # 1. Newton, 2. Levenberg-Marquardt, 3. projected gradient, each with its line search
        info[I_SINGULAR] = 0
        yield REQ_NEWTON               # g = H^T Phi and d = -H^{-1} Phi
        singular = info[I_SINGULAR] != 0
        accepted = False
        kind = STEP_NEWTON
        while kind <= STEP_GRADIENT and not accepted:
            usable = False
            t_min = min_step
            slope = 0.0
            if kind == STEP_NEWTON:
                if not singular:
                    slope = 0.0
                    dd = 0.0
                    for i in range(n):
                        slope += g[i] * d[i]
                        dd += d[i] * d[i]
                    usable = slope <= -rho * dd ** (0.5 * power)
                    t_min = min_newton
            elif kind == STEP_LM:
                fbuf[F_MU] = lm_factor * math.sqrt(2.0 * psi)
                info[I_SINGULAR] = 0
                yield REQ_LM
                if info[I_SINGULAR] == 0:
                    slope = 0.0
                    for i in range(n):
                        slope += g[i] * d[i]
                    usable = slope < 0.0
            else:
                yield REQ_HG
                usable = True
            if not usable:
                kind += 1
                continue
            if kind != STEP_GRADIENT:
                # projected nonmonotone Armijo search along d, quadratic-interpolation backtracking
                t = 1.0
                while t >= t_min:
                    for i in range(n):
                        xt[i] = min(max(x[i] + t * d[i], lo[i]), hi[i])
                    yield REQ_F
                    info[I_NFEV] += 1
                    if not _finite(Ft):
                        if shorten:
                            t *= 0.5
                            continue
                        info[I_STATUS], info[I_WHY] = S_NOT_FINITE, WHY_TRIAL
                        return
                    psit = _reformulate(xt, Ft, lo0, hi0, lam_in, w_in, lam_out, w_out, two, Phit)
                    if psit <= psi_ref + armijo * t * slope:
                        accepted = True
                        break
                    # minimiser of the quadratic through psi(0), psi'(0) = slope and psi(t), kept
                    # in [0.1 t, 0.5 t] so that a bad model neither stalls nor overshoots
                    curvature = psit - psi - t * slope
                    t_new = -slope * t * t / (2.0 * curvature) if curvature > 0.0 else 0.5 * t
                    t = min(max(t_new, 0.1 * t), 0.5 * t)
            else:
                # projected gradient path P[x - t g], Armijo on the actual displacement
                gg = 0.0
                xmax = 0.0
                for i in range(n):
                    gg += g[i] * g[i]
                    xmax = max(xmax, abs(x[i]))
                hg = fbuf[F_HGSQ]
                t = gg / hg if hg > 0.0 else 1.0
                floor = 4.0 * eps * (1.0 + xmax)
                while True:
                    big = 0.0
                    gstep = 0.0
                    for i in range(n):
                        xt[i] = min(max(x[i] - t * g[i], lo[i]), hi[i])
                        big = max(big, abs(xt[i] - x[i]))
                        gstep += g[i] * (xt[i] - x[i])
                    if big <= floor:
                        break
                    yield REQ_F
                    info[I_NFEV] += 1
                    if not _finite(Ft):
                        if shorten:
                            t *= 0.5
                            continue
                        info[I_STATUS], info[I_WHY] = S_NOT_FINITE, WHY_TRIAL
                        return
                    psit = _reformulate(xt, Ft, lo0, hi0, lam_in, w_in, lam_out, w_out, two, Phit)
                    if psit <= psi_ref + armijo * gstep:
                        accepted = True
                        break
                    t *= 0.5
            if not accepted:
                kind += 1
        if not accepted:
            info[I_STATUS] = S_SINGULAR if singular else S_LINE_SEARCH_FAILED
            return
        for i in range(n):
            x[i] = xt[i]
            F[i] = Ft[i]
            Phi[i] = Phit[i]
        psi = psit
        steps[info[I_ITER]] = kind
        info[I_ITER] += 1
        history[nhist] = psi
        nhist += 1
        residual = _natural_residual(x, F, lo, hi)


# ---------------------------------------------------------------------------------------------
# dense linear algebra of the requests (compiled; shared by every dense driver)
# ---------------------------------------------------------------------------------------------
@kernel
def dense_solve(A, rhs, out):
    """out = A^{-1} rhs by LU with partial pivoting (LAPACK through numpy); False when A is
    exactly singular or the result is not finite."""
    try:
        sol = np.linalg.solve(A, rhs)
    except Exception:  # numpy.linalg.LinAlgError: singular matrix
        return False
    acc = 0.0
    for i in range(sol.shape[0]):
        acc += sol[i] * sol[i]
    if not math.isfinite(acc):
        return False
    for i in range(sol.shape[0]):
        out[i] = sol[i]
    return True


@kernel
def dense_newton(J, da, db, Phi, H, g, d):
    """H = diag(da) + diag(db) J; g = H^T Phi; d = solve(H, -Phi). Returns False if singular."""
    n = J.shape[0]
    for i in range(n):
        for j in range(n):
            H[i, j] = J[i, j] * db[i]
        H[i, i] += da[i]
    for j in range(n):
        acc = 0.0
        for i in range(n):
            acc += H[i, j] * Phi[i]
        g[j] = acc
    rhs = np.empty(n)
    for i in range(n):
        rhs[i] = -Phi[i]
    return dense_solve(H, rhs, d)


@kernel
def dense_lm(H, g, mu, d):
    """d = solve(H^T H + (mu + 16 eps max diag) I, -g). Returns False if singular."""
    n = H.shape[0]
    A = H.T @ H
    big = A[0, 0]
    for i in range(n):
        big = max(big, A[i, i])
    mu = mu + 16.0 * np.finfo(np.float64).eps * big
    for i in range(n):
        A[i, i] += mu
    rhs = np.empty(n)
    for i in range(n):
        rhs[i] = -g[i]
    return dense_solve(A, rhs, d)


@lean_kernel
def dense_hg_sq(H, g):
    acc = 0.0
    for i in range(H.shape[0]):
        v = 0.0
        for j in range(H.shape[1]):
            v += H[i, j] * g[j]
        acc += v * v
    return acc


@lean_kernel
def matvec(J, v, out):
    for i in range(J.shape[0]):
        acc = 0.0
        for j in range(J.shape[1]):
            acc += J[i, j] * v[j]
        out[i] = acc


# ---------------------------------------------------------------------------------------------
# the Python driver: F and J from callables
# ---------------------------------------------------------------------------------------------
@lean_kernel
def nonfinite(J) -> int:
    """1 if an entry of J is NaN or inf, else 0 (ncp's I_BAD)."""
    for i in range(J.shape[0]):
        for j in range(J.shape[1]):
            if not np.isfinite(J[i, j]):
                return 1
    return 0


@kernel
def dense_request(req, J, zk, Jz, da, db, Phi, H, g, d, info, fbuf):
    """mcp_iterations' linear-algebra requests (J z, the Newton and Levenberg-Marquardt
    solves, |H g|^2) on a dense J, answered by ncp's dense kernels."""
    if req == REQ_JZ:
        matvec(J, zk, Jz)
    elif req == REQ_NEWTON:
        info[I_SINGULAR] = 0 if dense_newton(J, da, db, Phi, H, g, d) else 1
    elif req == REQ_LM:
        info[I_SINGULAR] = 0 if dense_lm(H, g, fbuf[F_MU], d) else 1
    elif req == REQ_HG:
        fbuf[F_HGSQ] = dense_hg_sq(H, g)


class Buffers:
    """The preallocated buffers of one solve of size n (mcp_iterations' arguments)."""

    def __init__(self, n: int, max_iterations: int):
        self.x, self.F, self.xt, self.Ft = (np.zeros(n) for _ in range(4))
        self.Phi, self.Phit, self.d, self.g = (np.zeros(n) for _ in range(4))
        self.da, self.db, self.zk, self.Jz = (np.zeros(n) for _ in range(4))
        self.history = np.zeros(max_iterations + 1)
        self.steps = np.zeros(max(max_iterations, 1), np.int64)
        self.info = np.zeros(NINFO, np.int64)
        self.fbuf = np.zeros(NFBUF)
        self.work = np.zeros((7, n))

    def generator(self, x0, lo, hi, opt):
        return _iterations(x0, lo, hi, opt, self.x, self.F, self.xt, self.Ft, self.Phi, self.Phit, self.d,
                           self.g, self.da, self.db, self.zk, self.Jz, self.history, self.steps, self.info,
                           self.fbuf, self.work)


def dense_buffers(n: int, options: SolverOptions):
    """What one compiled dense solve of n unknowns writes into: (Buffers, J and H (n, n)
    workspaces, options_array(options))."""
    return Buffers(n, options.max_iterations), np.empty((n, n)), np.empty((n, n)), options_array(options)


@kernel
def _iterations(x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz, history, steps, info, fbuf,
                work):
    """mcp_iterations for a Python driver (see _jit.generator_kernel)."""
    return mcp_iterations(x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz, history, steps, info,
                          fbuf, work)


_STEP_LETTERS = {STEP_NEWTON: "N", STEP_LM: "L", STEP_GRADIENT: "G"}
_STATUS = {S_CONVERGED: Status.CONVERGED, S_MAX_ITERATIONS: Status.MAX_ITERATIONS,
           S_LINE_SEARCH_FAILED: Status.LINE_SEARCH_FAILED, S_SINGULAR: Status.SINGULAR,
           S_NOT_FINITE: Status.NOT_FINITE, S_HANDED_OVER: Status.HANDED_OVER}


def result_from_buffers(buf: Buffers, options: SolverOptions) -> McpResult:
    """The McpResult (with its one-sentence message) of a finished mcp_iterations."""
    status, iterations, residual, message = outcome_from_buffers(buf, options)
    info = buf.info
    history = tuple(buf.history[: iterations + 1].tolist())
    steps = "".join([_STEP_LETTERS[k] for k in buf.steps[:iterations].tolist()])
    return McpResult(buf.x.copy(), buf.F.copy(), status, iterations, residual, history, message, steps,
                     int(info[I_NFEV]), int(info[I_NJEV]))


def outcome_from_buffers(buf: Buffers, options: SolverOptions) -> tuple:
    """(status, iterations, residual, message) of a finished mcp_iterations: what a caller that
    reads its solution from the buffers needs of McpResult (closest._single_functions)."""
    info = buf.info
    status = _STATUS[int(info[I_STATUS])]
    iterations = int(info[I_ITER])
    residual = float(buf.fbuf[F_RESIDUAL])
    tol = options.tol
    why = int(info[I_WHY])
    if status is Status.CONVERGED:
        message = f"Converged in {iterations} iterations: natural residual {residual:.3g} <= tol {tol:.3g}."
    elif status is Status.MAX_ITERATIONS and why == WHY_STALLED:
        message = (f"Stopped after {iterations} iterations (watch): stalled, natural residual "
                   f"{residual:.3g} > tol {tol:.3g}.")
    elif status is Status.HANDED_OVER:
        message = (f"Handed over after {iterations} iterations (the caller's stop test) at natural residual "
                   f"{residual:.3g}.")
    elif status is Status.MAX_ITERATIONS:
        message = (f"Stopped after {iterations} iterations (max_iterations) with natural residual "
                   f"{residual:.3g} > tol {tol:.3g}.")
    elif status is Status.NOT_FINITE:
        if why == WHY_START:
            message = "fun returned NaN or inf at the (projected) starting point."
        elif why == WHY_TRIAL:
            message = (f"Stopped after {iterations} iterations: fun returned NaN or inf at a trial point of "
                       "the line search; x is the last finite iterate.")
        else:
            message = f"Stopped after {iterations} iterations: jac returned NaN or inf at the current iterate."
    else:
        cause = ("the Newton system is singular and neither a Levenberg-Marquardt nor a gradient step "
                 "decreases the merit" if status is Status.SINGULAR else
                 "no Newton, Levenberg-Marquardt or gradient step decreases the merit (a stationary point "
                 "of the merit that is not a solution)")
        message = f"Stopped after {iterations} iterations: {cause}; natural residual {residual:.3g}."
    return status, iterations, residual, message


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


def check_problem(x0, lower, upper, options):
    """(x0, lo, hi) as float arrays, or ValueError for malformed input."""
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
    return np.ascontiguousarray(x), np.ascontiguousarray(lo), np.ascontiguousarray(hi)


def solve_mcp(fun: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], object],
              x0, lower, upper, options: SolverOptions = SolverOptions(), blocks=None, stop=None) -> McpResult:
    """Solve MCP(F, l, u): ``l <= x <= u`` with ``F_i(x) = 0`` strictly inside, ``>= 0`` at ``l_i``,
    ``<= 0`` at ``u_i``.

    fun(x) -> F(x), shape (n,).  jac(x) -> dF/dx, a dense (n, n) array or a scipy.sparse matrix
    (then sparse LU is used).  x0: warm start, projected onto the box.  lower, upper: shape (n,)
    or scalars, entries may be -inf / +inf.  blocks: None or (bptr, bidx), groups of unknowns
    (group g: bidx[bptr[g]:bptr[g + 1]]) whose diagonal blocks of a sparse Newton matrix are
    coupled to each other only through the other unknowns; each Newton step then eliminates them
    first (block_elimination.py) and factorises the reduced matrix.  stop: None or stop(x, F,
    residual) -> bool, asked at every iterate that is not a solution before its Newton step (x
    and F are the solver's buffers: read, do not keep); True ends the solve there with status
    HANDED_OVER, for a caller that already knows what it will do with the solution (the
    stepper's friction_rows: recovery.row_switch_test).  Never raises for non-convergence: see
    result.status.
    """
    x, lo, hi = check_problem(x0, lower, upper, options)
    n = x.shape[0]
    buf = Buffers(n, options.max_iterations)
    J = H = pattern = None
    for req in buf.generator(x, lo, hi, options_array(options)):
        if req == REQ_F:
            buf.Ft[:] = _check_f(fun(buf.xt.copy()), n)
        elif req == REQ_J:
            if stop is not None and stop(buf.x, buf.F, float(buf.fbuf[F_RESIDUAL])):
                buf.info[I_STATUS] = S_HANDED_OVER
                break
            J = jac(buf.x.copy())
            if sp.issparse(J):
                J = J.tocsr()
                if J.shape != (n, n):
                    raise ValueError(f"jac(x) must return shape ({n}, {n}), got {J.shape}")
                finite = bool(np.isfinite(J.data).all())
            else:
                J = np.ascontiguousarray(J, dtype=float)
                if J.shape != (n, n):
                    raise ValueError(f"jac(x) must return shape ({n}, {n}), got {J.shape}")
                finite = bool(np.isfinite(J).all())
            buf.info[I_BAD] = 0 if finite else 1
        elif req == REQ_JZ:
            buf.Jz[:] = J @ buf.zk if sp.issparse(J) else _matvec(J, buf.zk)
        elif req == REQ_NEWTON:
            if sp.issparse(J):
                if pattern is None or not pattern.matches(J):
                    pattern = _SparsePattern(J, blocks)
                d = pattern.newton(J, buf.da, buf.db, buf.Phi, buf.g)
                H = pattern                       # (as a matrix only if LM or |H g| asks for it)
                buf.info[I_SINGULAR] = d is None
                if d is not None:
                    buf.d[:] = d
            else:
                H = np.empty((n, n))
                buf.info[I_SINGULAR] = not dense_newton(J, buf.da, buf.db, buf.Phi, H, buf.g, buf.d)
        elif req == REQ_LM:
            if isinstance(H, _SparsePattern):
                H = H.matrix()
            if sp.issparse(H):
                d = _sparse_lm(H.tocsr(), buf.g, buf.fbuf[F_MU])
                buf.info[I_SINGULAR] = d is None
                if d is not None:
                    buf.d[:] = d
            else:
                buf.info[I_SINGULAR] = not dense_lm(H, buf.g, buf.fbuf[F_MU], buf.d)
        elif req == REQ_HG:
            if isinstance(H, _SparsePattern):
                H = H.matrix()
            if sp.issparse(H):
                Hg = H @ buf.g
                buf.fbuf[F_HGSQ] = float(Hg @ Hg)
            else:                             # (the compiled drivers' kernel: the same round-off)
                buf.fbuf[F_HGSQ] = dense_hg_sq(H, buf.g)
    return result_from_buffers(buf, options)


PROXIMAL_OUTER = 100    # solve_proximal's outer steps at most (each takes one iteration or more)


def solve_proximal(fun: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], object],
                   x0, lower, upper, weight, options: SolverOptions = SolverOptions(),
                   max_outer: int = PROXIMAL_OUTER, inner=None) -> McpResult:
    """MCP(F, l, u) by the proximal point method (R. T. Rockafellar, SIAM J. Control Optim. 14,
    1976): x_{k+1} solves MCP(F + W_k (. - x_k), l, u) by :func:`solve_mcp` from x_k, until x_{k+1}
    solves MCP(F, l, u) itself (natural residual <= options.tol). W_k = diag(min(weight, r_k)),
    r_k the natural residual at x_k: the regularisation vanishes with the residual, as the
    Levenberg-Marquardt damping of solve_mcp does, so the outer steps converge superlinearly once
    r_k is below the flat directions' slopes (a fixed weight converges linearly there).

    For problems whose solution is not unique in some unknowns, or nearly so: a contact impulse
    shared by constraints that are (nearly) redundant, e.g. four feet sticking on the ground, whose
    warp mode and torsions the sticking tangential rows already fix. There the Jacobian is singular
    or its smallest singular values are far below ||Phi|| (1e-13..1e-6 against rows of O(1)), and
    Newton, Levenberg-Marquardt and the merit's gradient all crawl along the flat directions. Each
    regularised problem is strongly monotone in the weighted unknowns where F is flat in them (its
    Jacobian gains W_k on the diagonal), so Newton converges on it; in a direction where F moves by
    s per unit, the outer step closes the fraction s / (s + w_k) of the distance to the solution
    set, and along an exact null direction it stays where it was (one of the solutions). A weight
    of zero leaves a row as it is.

    options.max_iterations bounds the inner iterations of all outer steps together. The result
    is the last outer step's (steps and merit histories concatenated) with F and the residual of
    the unregularised problem: CONVERGED as soon as that residual is <= tol; an inner solve that
    fails ends it with that failure; MAX_ITERATIONS when the outer steps or the iterations run out.

    inner: None, or inner(x_k, W_k, options) -> the McpResult of solve_mcp on MCP(F + W_k (. - x_k),
    l, u) from x_k, computed faster by the caller (step_solver's compiled dense solve); it must be
    that solve's result.
    """
    x, lo, hi = check_problem(x0, lower, upper, options)
    n = x.shape[0]
    w = _as_bound(weight, n, "weight")
    if not (np.isfinite(w).all() and (w >= 0.0).all()):
        raise ValueError("weight must be finite and >= 0")
    if isinstance(max_outer, bool) or not isinstance(max_outer, int) or max_outer < 1:
        raise ValueError(f"max_outer must be an int >= 1, got {max_outer!r}")
    x = np.clip(x, lo, hi)
    iterations, steps, history, nfev, njev = 0, "", [], 0, 0
    F = _check_f(fun(x.copy()), n)
    residual = _natural_residual(x, F, lo, hi)
    nfev += 1
    for outer in range(max_outer):
        left = options.max_iterations - iterations
        centre = x.copy()
        wk = np.minimum(w, residual)

        def fun_k(z):
            return _check_f(fun(z), n) + wk * (z - centre)

        def jac_k(z):
            J = jac(z)
            if sp.issparse(J):
                return (J + sp.diags(wk, format="csr")).tocsr()
            return np.asarray(J, dtype=float) + np.diag(wk)

        solved = (solve_mcp(fun_k, jac_k, centre, lo, hi, replace(options, max_iterations=left)) if inner is None
                  else inner(centre, wk, replace(options, max_iterations=left)))
        iterations, steps, nfev, njev = (iterations + solved.iterations, steps + solved.steps,
                                         nfev + solved.nfev + 1, njev + solved.njev)
        history.extend(solved.merit_history)
        x = solved.x
        F = _check_f(fun(x.copy()), n)
        residual = _natural_residual(x, F, lo, hi)
        if solved.status is not Status.CONVERGED:
            return McpResult(x, F, solved.status, iterations, residual, tuple(history),
                             f"Proximal step {outer + 1} failed: {solved.message}", steps, nfev, njev)
        if residual <= options.tol:
            return McpResult(x, F, Status.CONVERGED, iterations, residual, tuple(history),
                             f"Converged in {outer + 1} proximal steps ({iterations} iterations): natural "
                             f"residual {residual:.3g} <= tol {options.tol:.3g}.", steps, nfev, njev)
        if iterations >= options.max_iterations:
            break
    return McpResult(x, F, Status.MAX_ITERATIONS, iterations, residual, tuple(history),
                     f"Stopped after {outer + 1} proximal steps ({iterations} iterations) with natural "
                     f"residual {residual:.3g} > tol {options.tol:.3g}.", steps, nfev, njev)


# An endgame for solves that stall next to a solution (newton_min_map).
ENDGAME_ITERATIONS = 10     # Newton steps at most
ENDGAME_BACKTRACKS = 4      # step lengths 1, 1/4, 1/16, 1/64 tried before it gives up
ENDGAME_RCOND = 1e-12       # singular values below this times the largest are taken as zero
ENDGAME_WATCHDOG = 2        # Newton steps a refused full step gets to come below the residual before it


def newton_min_map(fun: Callable[[np.ndarray], np.ndarray], jac: Callable[[np.ndarray], object],
                   x0, lower, upper, tol: float, max_iterations: int = ENDGAME_ITERATIONS) -> McpResult:
    """MCP(F, l, u) from a start near a solution, by Newton's method on the natural residual
    r(x) = x - mid(l, u, x - F(x)) with minimum-norm steps: an endgame for solve_mcp's stalls.

    r is piecewise smooth; the piece active at x is chosen by where x - F(x) lies:

        x_i - F_i <= l_i:  r_i = x_i - l_i       (at its lower bound)
        x_i - F_i >= u_i:  r_i = x_i - u_i       (at its upper bound)
        otherwise:         r_i = F_i(x)          (free)

    and its Jacobian (rows e_i or J_i) is an element of r's B-subdifferential, so the iteration
    is the B-Newton method of the min-map (J.-S. Pang, Math. Oper. Res. 15, 1990; L. Qi, Math.
    Oper. Res. 18, 1993), quadratic near a BD-regular solution. The bound rows fix their step;
    the free rows' block, J_II d_I = -F_I - J_IA d_A, is solved in the least-squares sense with
    the least norm (LAPACK's SVD-based gelsd, singular values below ENDGAME_RCOND of the largest
    dropped). Where solutions are not isolated (redundant contacts: four feet sticking, an edge
    lying on a face, whose impulses or contact point the rows leave free in some directions),
    J_II is singular and solve_mcp's Fischer-Burmeister Newton falls back on
    Levenberg-Marquardt steps that crawl (their damping is tied to ||Phi||, which is what
    stalls); the minimum-norm step is the Gauss-Newton step of a consistent underdetermined
    system, which keeps the quadratic rate where the rank stays constant (A. Ben-Israel, J. Math.
    Anal. Appl. 15, 1966).

    A step is taken at the first length in 1, 1/4, 1/16, ... (ENDGAME_BACKTRACKS of them) that
    lowers ||r||_inf, projected onto the box. When none does, the full step is taken once anyway,
    a watchdog (R. M. Chamberlain, M. J. D. Powell, C. Lemarechal & H. C. Pedersen, Math. Prog.
    Study 16, 1982): if one of the ENDGAME_WATCHDOG Newton steps after it comes below the
    residual before it, the endgame goes on from there, else it returns to that iterate and
    stops. The case: a four-legged table landing (tests/test_indeterminate_impulses.py) whose
    endgame, at ||r|| = 5e-10 > tol = 1e-10 after one step, had a least-norm step of 1e-5 that
    raised ||r|| to 5e-8 at full length and to no less than 8e-10 at the shorter ones (the
    linear model holds only to O(|d|^2) along the weakly determined directions of a resting
    foot); from the full step, the next Newton step reached 3e-11. (Measured on one machine;
    on another the round-off let the plain line search through.) The endgame also stops after
    max_iterations steps. There is no globalisation beyond that: it is for starts where
    solve_mcp already came close (its caller decides how close). CONVERGED exactly when
    ||r(x)||_inf <= tol, the measure and the bound solve_mcp uses; otherwise the status is
    MAX_ITERATIONS or LINE_SEARCH_FAILED at the best iterate, and NOT_FINITE if fun or jac
    returned NaN or inf. Steps: N a Newton step, W the watchdog's full step.
    jac may return a sparse matrix; it is densified (for problems of up to a few hundred
    unknowns). The result's merit_history holds ||r||_inf at the start and after every step."""
    x, lo, hi = check_problem(x0, lower, upper, SolverOptions(tol=tol, max_iterations=max_iterations))
    n = x.shape[0]
    x = np.clip(x, lo, hi)
    F = np.array(_check_f(fun(x.copy()), n))
    nfev, njev, steps, status, why = 1, 0, "", Status.MAX_ITERATIONS, ""
    if not np.isfinite(F).all():
        return McpResult(x, F, Status.NOT_FINITE, 0, math.nan, (), "F is not finite at the start.", "", 1, 0)
    r = _natural_residual(x, F, lo, hi)
    history = [r]
    watch, best = 0, None       # a watchdog's steps left and the iterate before it (x, F, r, steps, history)
    watched = False
    for _ in range(max_iterations):
        if best is not None:
            if r < best[2]:
                best = None                         # the watchdog's steps came below: go on from here
            elif watch == 0:
                status, why = Status.LINE_SEARCH_FAILED, "no step length lowered the residual (watchdog tried)."
                break
            else:
                watch -= 1
        if r <= tol:
            break
        y = x - F
        at_lo = y <= lo
        at_hi = (y >= hi) & ~at_lo
        free = ~(at_lo | at_hi)
        J = jac(x.copy())
        njev += 1
        J = J.toarray() if sp.issparse(J) else np.asarray(J, dtype=float)
        if J.shape != (n, n):
            raise ValueError(f"jac(x) must return shape ({n}, {n}), got {J.shape}")
        if not np.isfinite(J).all():
            status, why = Status.NOT_FINITE, "J is not finite."
            break
        d = np.zeros(n)
        d[at_lo], d[at_hi] = lo[at_lo] - x[at_lo], hi[at_hi] - x[at_hi]
        bound = ~free
        rhs = -F[free] - J[np.ix_(free, bound)] @ d[bound]
        d[free] = np.linalg.lstsq(J[np.ix_(free, free)], rhs, rcond=ENDGAME_RCOND)[0]
        t, taken, full = 1.0, False, None
        for _ in range(ENDGAME_BACKTRACKS):
            xt = np.clip(x + t * d, lo, hi)
            Ft = np.array(_check_f(fun(xt.copy()), n))
            nfev += 1
            if np.isfinite(Ft).all():
                rt = _natural_residual(xt, Ft, lo, hi)
                if full is None and t == 1.0:
                    full = (xt, Ft, rt)
                if rt < r:
                    x, F, r, taken = xt, Ft, rt, True
                    break
            t *= 0.25
        if not taken and full is not None and not watched and ENDGAME_WATCHDOG > 0:
            # the watchdog: the full step, the iterate before it kept
            best, watch, watched = (x, F, r, steps, list(history)), ENDGAME_WATCHDOG, True
            x, F, r = full
            steps += "W"
            history.append(r)
            continue
        if not taken:
            status, why = Status.LINE_SEARCH_FAILED, "no step length lowered the residual."
            break
        steps += "N"
        history.append(r)
    if best is not None and r >= best[2]:
        # the watchdog's steps did not come below the iterate before them: back to it
        x, F, r, steps, history = best
        if status is Status.NOT_FINITE:
            status, why = Status.LINE_SEARCH_FAILED, "J is not finite after the watchdog's step."
    iterations = len(steps)
    if r <= tol:
        return McpResult(x, F, Status.CONVERGED, iterations, r, tuple(history),
                         f"Converged in {iterations} min-map Newton steps: natural residual {r:.3g} <= tol "
                         f"{tol:.3g}.", steps, nfev, njev)
    return McpResult(x, F, status, iterations, r, tuple(history),
                     f"Min-map Newton stopped after {iterations} steps with natural residual {r:.3g} > tol "
                     f"{tol:.3g}" + (f": {why}" if why else "."), steps, nfev, njev)


def _matvec(J, v):
    out = np.empty(J.shape[0])
    matvec(J, v, out)
    return out


@lean_kernel
def sparse_newton_matrix(indptr, indices, Jdata, da, db, diag, Phi, data, g):
    """H = diag(da) + diag(db) J on J's CSR pattern (diag: the position of each row's diagonal
    entry) into data, and g = H^T Phi; returns H's number of nonzero entries."""
    n = indptr.shape[0] - 1
    for i in range(n):
        g[i] = 0.0
    for i in range(n):
        for p in range(indptr[i], indptr[i + 1]):
            data[p] = Jdata[p] * db[i]
        data[diag[i]] += da[i]
    nonzero = 0
    for i in range(n):
        for p in range(indptr[i], indptr[i + 1]):
            v = data[p]
            g[indices[p]] += v * Phi[i]
            if v != 0.0:
                nonzero += 1
    return nonzero


# _SparsePattern keeps a column order while the factors it gives stay within this factor of the
# entries the first one gave (the nonzeros of H change with the active pieces of the FB rows)
ORDER_REFILL = 1.5


class _SparsePattern:
    """The Newton step of solve_mcp on a sparse J, kept per CSR pattern of J (a step problem's is
    fixed while its layout is, formulation.StepProblem._sparse_pattern): H = diag(da) + diag(db) J
    is formed on J's own data (every row of J stores its diagonal), and its CSR arrays, read as
    CSC, are H^T, which sparse_lu factorises as they are (its stored zeros skipped); H d = -Phi
    is then solved with the transposed factors. Without it, each iteration built H, a diagonal
    matrix, their sum and a CSC copy as scipy objects: 0.4 ms of Python an iteration next to
    SuperLU's 0.9 ms (27 superquadrics in a box, ~700 unknowns). The column order is SuperLU's
    COLAMD of the first iterate's nonzeros, kept for the solve until the factors grow by
    ORDER_REFILL (per solve, not shared between solves: a solve's round-off then depends on its
    problem and start alone, and a campaign run replays the same in a fresh process). sparse_lu against SuperLU (scipy.sparse.linalg.splu, COLAMD), the
    factorisations of 40 steps of those superquadrics (n median 826): 0.67 ms against 0.96 ms,
    factors 1.07 times as large at the median (at most 1.85); bench_many_bodies' landed steps,
    the same Newton iterations: 42 -> 30 ms (30 bodies), 175 -> 139 ms (100 bodies). A pattern
    without every diagonal entry takes scipy's general route.

    With solve_mcp's blocks (a step problem's closest-point blocks, layout.closest_point_blocks,
    from step_solver.ELIMINATE_MIN_UNKNOWNS unknowns) each Newton step first eliminates them
    (block_elimination.py) and factorises the reduced matrix; the whole matrix's LU above is the
    fallback where a local block or the reduced matrix is singular or the direction does not
    solve to ELIMINATED_SOLVE_TOL. Measured on 27 superquadrics in a box (2026-12-06, the commit
    before alternated): a Newton step 1.06 -> 0.66 ms (n ~730 -> ~310 unknowns factorised);
    median contact step 46.5-51.2 -> 37.6-44.9 ms; five layouts of 20-40 bodies, 60 steps each,
    26.2-27.1 -> 22.0-22.7 s in all. At 100 bodies the step did not move (136-141 against 138-145
    ms): there the whole matrix hardly fills in, and forming the reduced one costs what its LU
    saves."""

    def __init__(self, J, blocks=None):
        n = J.shape[0]
        self.indptr, self.indices = J.indptr.copy(), J.indices.copy()
        self.rows = np.repeat(np.arange(n), np.diff(self.indptr))
        diagonal = np.flatnonzero(self.indices == self.rows)
        self.diag = diagonal if len(diagonal) == n and np.array_equal(self.rows[diagonal], np.arange(n)) else None
        self.ip64, self.ix64 = self.indptr.astype(np.int64), self.indices.astype(np.int64)
        self.factors = sparse_lu.KeptOrder(n, ORDER_REFILL)
        self.elimination = None
        if blocks is not None and self.diag is not None and len(blocks[1]):
            structure = block_elimination.structure(self.ip64, self.ix64, blocks[0], blocks[1])
            if structure.ok:
                self.elimination = block_elimination.Elimination(structure, ORDER_REFILL)

    @property
    def order(self):
        """The column order the whole matrix's LU keeps (sparse_lu.KeptOrder), None before one."""
        return self.factors.order

    def matches(self, J) -> bool:
        return (J.indptr.shape == self.indptr.shape and J.indices.shape == self.indices.shape
                and np.array_equal(J.indptr, self.indptr) and np.array_equal(J.indices, self.indices))

    def newton(self, J, da, db, Phi, g):
        """d = -H^{-1} Phi, or None if H is singular; sets g = H^T Phi and keeps H (matrix())."""
        n = J.shape[0]
        if self.diag is None:
            self.H = (sp.csr_matrix((J.data * db[self.rows], J.indices, J.indptr), shape=(n, n))
                      + sp.diags(da, format="csr"))
            g[:] = self.H.T @ Phi
            return _sparse_solve(self.H, -Phi)
        data = self.data = np.empty(len(J.data))
        nonzero = sparse_newton_matrix(self.ip64, self.ix64, J.data, da, db, self.diag, Phi, data, g)
        self.H = None
        if self.elimination is not None:
            # the local blocks eliminated first; the whole matrix's LU below if that fails
            d = self.elimination.solve(data, -Phi)
            if d is not None and sparse_lu.residual_ok(self.ip64, self.ix64, data, d, -Phi, ELIMINATED_SOLVE_TOL):
                return d
        # H's CSR arrays read as CSC are H^T: factorised as they are, H d = -Phi is solved with the
        # transposed factors (sparse_lu skips the stored zeros)
        lu = self.factors.factor(self.ip64, self.ix64, data, nonzero)
        if not lu.ok:
            return None
        d = lu.solve(-Phi, "T")
        return d if sparse_lu.residual_ok(self.ip64, self.ix64, data, d, -Phi, SPARSE_SOLVE_TOL) else None

    def matrix(self):
        """The last Newton step's H as a CSR matrix."""
        if self.H is None:
            n = len(self.indptr) - 1
            self.H = sp.csr_matrix((self.data, self.indices, self.indptr), shape=(n, n))
        return self.H


def _sparse_lm(H, g, mu0):
    """The Levenberg-Marquardt step of dense_lm on a sparse H: (H^T H + mu I) d = -g with
    mu = mu0 + 16 eps max_j |H e_j|^2, solved as the augmented system

        [ I    H   ] [r]   [0]
        [ H^T  -mu I] [d] = [g]      (r = -H d),

    whose LU needs no product H^T H: a skeleton's dense rows (its mass matrix couples every
    contact on it) make that product nearly dense. Measured on example-robot-data's alex_nub_hands
    at t = 0.141 s (~1700 Newton and 600 LM steps): forming H^T H took 18 of the step's 34 s.

    The matrix is symmetric with a symmetric pattern (quasi-definite, Vanderbei, SIAM J. Optim. 5,
    1995), so SuperLU orders it in its symmetric mode (minimum degree of K + K^T, built here
    directly in CSC) instead of COLAMD, with partial pivoting as before (LM_PIVOT_THRESHOLD).
    Measured on 60 LM steps of example-robot-data's talos_reduced at t = 0.594 s (n = 527),
    2026-12-07: 7.9 -> 3.3 ms a step (COLAMD of [[I, -H], [H^T, mu I]] from scipy.sparse.bmat
    before), the directions agreeing to 2e-12 relative (6e-14 at the median). K is built in one
    compiled pass over H (_quasi_definite_arrays): its stored zeros dropped, no scipy copies and
    conversions (0.50 -> 0.33 ms of a ~3 ms step on those talos steps)."""
    n = H.shape[0]
    indptr, indices, data, big = _quasi_definite_arrays(*_sorted_arrays(H))
    mu = mu0 + 16.0 * np.finfo(float).eps * float(big)
    K = _with_corner(indptr, indices, data, -mu)
    rhs = np.concatenate([np.zeros(n), g])
    try:
        x = spla.splu(K, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=LM_PIVOT_THRESHOLD,
                      options=dict(SymmetricMode=True)).solve(rhs)
    except RuntimeError:  # "Factor is exactly singular"
        return None
    # (K is symmetric: its CSC arrays read as CSR are K itself)
    if not sparse_lu.residual_ok(K.indptr, K.indices, K.data, x, rhs, SPARSE_SOLVE_TOL):
        return None
    return x[n:]


# _sparse_lm's SuperLU diag_pivot_thresh: partial pivoting. 0.01 (the diagonal kept unless below
# 1 % of its column's largest) was as fast, but on a singular 3 x 3 problem its round-off took one
# LM step more than the dense solver's (tests/test_ncp.py, stored zeros); 0 (LDL^T in the
# minimum-degree order, which a quasi-definite matrix admits) differed by 5e-8 relative on talos
LM_PIVOT_THRESHOLD = 1.0


def _quasi_definite(H, mu):
    """K = [[I, H], [H^T, -mu I]] (CSC, sorted; H's stored zeros dropped) from a scipy matrix H."""
    indptr, indices, data, _ = _quasi_definite_arrays(*_sorted_arrays(H))
    return _with_corner(indptr, indices, data, -mu)


def _with_corner(indptr, indices, data, value):
    """The CSC matrix of _quasi_definite_arrays' arrays with its corner diagonal set to value."""
    n = (len(indptr) - 1) // 2
    data[indptr[n + 1:] - 1] = value
    return sp.csc_matrix((data, indices, indptr), shape=(2 * n, 2 * n))


def _sorted_arrays(H):
    """H's CSR arrays (int64 indices, columns sorted within each row)."""
    H = H.tocsr()
    if not H.has_sorted_indices:
        H = H.copy()
        H.sort_indices()
    return H.indptr.astype(np.int64), H.indices.astype(np.int64), np.ascontiguousarray(H.data, dtype=float)


@kernel
def _quasi_definite_arrays(indptr, indices, data):
    """The CSC arrays of K = [[I, H], [H^T, 0 I]] (n + n columns: column j < n holds its 1, then
    row j of H at rows n + c; column n + j column j of H, then its corner, left 0 here) from H's
    CSR arrays (columns sorted within each row; stored zeros skipped), and max_j |H e_j|^2 (each
    column's squares summed in row order, as numpy.bincount sums them)."""
    n = indptr.shape[0] - 1
    # H's nonzeros first (a step problem's pattern stores ~10 entries for each nonzero)
    rp = np.empty(n + 1, np.int64)
    ci = np.empty(indptr[n], np.int64)
    cv = np.empty(indptr[n])
    nnz = 0
    rp[0] = 0
    for i in range(n):
        for p in range(indptr[i], indptr[i + 1]):
            if data[p] != 0.0:
                ci[nnz], cv[nnz] = indices[p], data[p]
                nnz += 1
        rp[i + 1] = nnz
    per_col = np.zeros(n, np.int64)
    sq = np.zeros(n)
    for q in range(nnz):
        per_col[ci[q]] += 1
        sq[ci[q]] += cv[q] * cv[q]
    Kp = np.empty(2 * n + 1, np.int64)
    Kp[0] = 0
    for j in range(n):
        Kp[j + 1] = Kp[j] + 1 + rp[j + 1] - rp[j]
    for j in range(n):
        Kp[n + j + 1] = Kp[n + j] + per_col[j] + 1
    Ki = np.empty(Kp[2 * n], np.int64)
    Kd = np.empty(Kp[2 * n])
    fill = np.empty(n, np.int64)
    for j in range(n):
        at = Kp[j]
        Ki[at], Kd[at] = j, 1.0
        for q in range(rp[j], rp[j + 1]):
            at += 1
            Ki[at], Kd[at] = n + ci[q], cv[q]
        fill[j] = Kp[n + j]
    for i in range(n):                     # rows in order: each column n + c gets its rows sorted
        for q in range(rp[i], rp[i + 1]):
            c = ci[q]
            Ki[fill[c]], Kd[fill[c]] = i, cv[q]
            fill[c] += 1
    for j in range(n):
        Ki[Kp[n + j + 1] - 1], Kd[Kp[n + j + 1] - 1] = n + j, 0.0
    big = 0.0
    for j in range(n):
        big = max(big, sq[j])
    return Kp, Ki, Kd, big


def _nonzeros(A):
    """A (a scipy matrix it may modify) without its stored zeros. A step problem's fixed
    pattern stores every entry its rows could have, and most are zero at any one iterate: a
    pair's rows against every unknown of the pair and of its skeletons (example-robot-data's
    alex_nub_hands at t = 0.142 s: 78319 stored entries, 3449 nonzero, n = 451). SuperLU orders
    and factorises what is stored: 7.7 ms a factorisation with the zeros, 1.4 ms without."""
    A.eliminate_zeros()
    return A


def _sparse_solve(H, rhs):
    H = _nonzeros(H.tocsc(copy=True))
    try:
        d = spla.splu(H).solve(rhs)
    except RuntimeError:  # "Factor is exactly singular"
        return None
    return d if _solves(H, d, rhs) else None


# A sparse solution is used only if ||H d - rhs|| <= SPARSE_SOLVE_TOL ||rhs||: an inexact Newton
# step with forcing term 1e-4 (Dembo, Eisenstat & Steihaug, SIAM J. Numer. Anal. 19, 1982) is
# still a descent direction of psi (grad psi . d <= -(1 - 1e-4) ||Phi||^2). SuperLU does not
# report a numerically singular H: on one (example-robot-data's alex_sake at t = 0.33 s, n = 367,
# rank 366, smallest pivot 2e-49) its supernodal updates call BLAS with invalid arguments
# ("On entry to DTRSV parameter number 6 had an illegal value"), skip them, and return a finite d
# with ||H d - rhs|| = 1e17 ||rhs||; 112 of 12320 solves of that run were such. Solves of the
# same run that SuperLU completes reach 1e-5 at worst.
SPARSE_SOLVE_TOL = 1e-4
# A direction of the eliminated solve (block_elimination.py) is taken only if it solves to 1e-10,
# else the whole matrix's LU gives it: a near-singular local block (a pair's closest-point rows
# where its points are barely determined) leaves S with cancellation, and such a direction would
# pass SPARSE_SOLVE_TOL while being less exact than the whole LU's.
ELIMINATED_SOLVE_TOL = 1e-10


def _solves(H, d, rhs) -> bool:
    """Whether d solves the scipy matrix H's system to SPARSE_SOLVE_TOL (sparse_lu.residual_ok, the
    check of _SparsePattern's own solves)."""
    H = H.tocsr()
    return bool(sparse_lu.residual_ok(H.indptr.astype(np.int64), H.indices.astype(np.int64), H.data,
                                      np.ascontiguousarray(d, dtype=float), np.ascontiguousarray(rhs, dtype=float),
                                      SPARSE_SOLVE_TOL))
