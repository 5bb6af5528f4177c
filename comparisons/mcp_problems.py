"""Standard mixed complementarity test problems with known solutions, shared by
tests/test_ncp.py and comparisons/bench_ncp.py.

Each entry of :func:`standard_problems` is an :class:`McpProblem`: F, its analytic Jacobian, the
bounds, several starting points, and an independent way to tell a right answer from a wrong one:
the published solution(s), or a closed-form description of the solution set, or the result of
Lemke's complementary pivoting (an exact, combinatorial method that shares nothing with the
semismooth Newton solver) polished by one linear solve on the identified active set.

Sources
-------
kojima_shindo  M. Kojima, S. Shindo, J. Oper. Res. Soc. Japan 29 (1986) 352-374; MCPLIB kojshin,
               its 8 starting points.  Two solutions: (1, 0, 3, 0) and the degenerate
               (sqrt(6)/2, 0, 0, 1/2) where x3 = F3 = 0.
josephy        N. H. Josephy (1979), MCPLIB josephy, same 8 starts; solution (sqrt(6)/2, 0, 0, 1/2).
mathiesen      L. Mathiesen, Math. Prog. 37 (1987) 1-18: one activity y turning goods 2, 3 into good
               1, Cobb-Douglas budget shares s = (0.9, 0.1, 0), endowment b = (0, 5, 3); unknowns
               (y, p1, p2, p3).  Solution y = 3, p = (6, 1, 5) with good 2 the numeraire (p2
               fixed to 1 by l = u: the l == u path of the solver; Walras' law makes the dropped
               row hold).
nash_cournot   F. H. Murphy, H. D. Sherali, A. L. Soyster, Math. Prog. 24 (1982) 92-106; P. T.
               Harker, Math. Prog. 41 (1988): 5 firms, marginal cost c_i + (L_i q_i)^(1/beta_i),
               inverse demand p(Q) = 5000^(1/gamma) Q^(-1/gamma); solution (15.4293, 12.4986,
               9.6635, 7.1651, 5.1326).
billups        S. C. Billups, MCPLIB billups: F(x) = (x - 1)^2 - 1.01, x >= 0; solution
               1 + sqrt(1.01).
               From x0 = 0 the start is a local minimiser of every merit built from the min or FB
               function over the box, so merit-descent methods (PATH included) stop there; it is in
               the table as the documented hard case.
nocedal_wright Nocedal & Wright, Numerical Optimization (2006), Example 16.4: KKT system of a convex
               QP as an MCP with free primal rows and NCP multiplier rows; x* = (1.4, 1.7),
               lambda* = (0.8, 0, 0).
rosenbrock_box KKT conditions of Rosenbrock's function on the box [-2, 0.5] x [-1, 2] (a box MCP
               with both bounds); unique KKT point (0.5, 0.25), x1 at its upper bound with F1 = -1.
               Hard start x0 = 0: every Newton step overshoots x1 = 0.5 and the line search keeps
               ~3 % of the merit per step along the bound; solve_mcp needs 96 iterations (> 50).
murty          K. G. Murty, Math. Prog. Study 7 (1978): M upper triangular, 1 on the diagonal and 2
               above, q = -e; unique solution e_n (exponential for Lemke, a P-matrix problem).
fathi          Y. Fathi, Math. Prog. 17 (1979): M_ii = 4(i-1)+1, M_ij = 4(min(i,j)-1)+2, q = -e;
               unique solution e_1.
degenerate_2x2 M = [[2, 1], [1, 2]], q = (-1, -2): unique solution (0, 1) with x1 = w1 = 0.
psd_2x2        M = [[1, 1], [1, 1]], q = (-1, -1): solution set {x >= 0 : x1 + x2 = 1}
               (non-isolated: Newton is singular everywhere on it).
box_lcp_*      Box-constrained LCPs built backwards from a chosen solution: a P-matrix M (hence a
               unique solution), a chosen x* with rows free, single-bounded, doubly bounded and
               fixed, some at a bound with w = 0 (degenerate), and q = w* - M x*.
random_lcp_*   Monotone LCPs, M = A A^T + 0.1 I + (S - S^T)/2 (positive definite, not symmetric),
               q standard normal; reference solution from Lemke's method.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp

INF = np.inf


@dataclass(frozen=True)
class McpProblem:
    """One test problem.

    starts: (label, x0) pairs.  distance(x): distance of x to the known solution set (0 at a
    solution), computed from the published solution(s) or a closed form, never from the solver.
    solution_atol: how close the solver's x must be, from the precision of the published numbers.
    solutions: points of the solution set exact to rounding (empty when only published to a few
    digits).  hard_starts: start labels at which solve_mcp with default options is known not to
    converge, each explained in the module docstring.
    """

    name: str
    fun: Callable[[np.ndarray], np.ndarray]
    jac: Callable[[np.ndarray], np.ndarray]
    lower: np.ndarray
    upper: np.ndarray
    starts: tuple[tuple[str, np.ndarray], ...]
    distance: Callable[[np.ndarray], float]
    solution_atol: float
    solutions: tuple[np.ndarray, ...] = ()
    hard_starts: tuple[str, ...] = ()

    @property
    def n(self) -> int:
        return self.lower.shape[0]


def _points(solutions):
    return tuple(np.asarray(s, dtype=float) for s in solutions)


def _nearest(solutions):
    sols = _points(solutions)
    return lambda x: min(float(np.abs(x - s).max()) for s in sols)


def _starts(*points):
    return tuple((label, np.asarray(p, dtype=float)) for label, p in points)


# MCPLIB's eight starting points of kojshin and josephy
_KOJIMA_STARTS = _starts(("0", [0, 0, 0, 0]), ("1", [1, 1, 1, 1]), ("100", [100, 100, 100, 100]),
                         ("1010", [1, 0, 1, 0]), ("1000", [1, 0, 0, 0]), ("0110", [0, 1, 1, 0]),
                         ("0101", [0, 1, 0, 1]), ("near", [1.25, 0, 0, 0.5]))


def kojima_shindo() -> McpProblem:
    def fun(x):
        x1, x2, x3, x4 = x
        return np.array([3 * x1 * x1 + 2 * x1 * x2 + 2 * x2 * x2 + x3 + 3 * x4 - 6,
                         2 * x1 * x1 + x1 + x2 * x2 + 10 * x3 + 2 * x4 - 2,
                         3 * x1 * x1 + x1 * x2 + 2 * x2 * x2 + 2 * x3 + 9 * x4 - 9,
                         x1 * x1 + 3 * x2 * x2 + 2 * x3 + 3 * x4 - 3])

    def jac(x):
        x1, x2, _, _ = x
        return np.array([[6 * x1 + 2 * x2, 2 * x1 + 4 * x2, 1.0, 3.0],
                         [4 * x1 + 1, 2 * x2, 10.0, 2.0],
                         [6 * x1 + x2, x1 + 4 * x2, 2.0, 9.0],
                         [2 * x1, 6 * x2, 2.0, 3.0]])

    solutions = ([1.0, 0.0, 3.0, 0.0], [np.sqrt(6.0) / 2.0, 0.0, 0.0, 0.5])
    return McpProblem("kojima_shindo", fun, jac, np.zeros(4), np.full(4, INF), _KOJIMA_STARTS,
                      _nearest(solutions), 1e-8, _points(solutions))


def josephy() -> McpProblem:
    def fun(x):
        x1, x2, x3, x4 = x
        return np.array([3 * x1 * x1 + 2 * x1 * x2 + 2 * x2 * x2 + x3 + 3 * x4 - 6,
                         2 * x1 * x1 + x1 + x2 * x2 + 3 * x3 + 2 * x4 - 2,
                         3 * x1 * x1 + x1 * x2 + 2 * x2 * x2 + 2 * x3 + 3 * x4 - 1,
                         x1 * x1 + 3 * x2 * x2 + 2 * x3 + 3 * x4 - 3])

    def jac(x):
        x1, x2, _, _ = x
        return np.array([[6 * x1 + 2 * x2, 2 * x1 + 4 * x2, 1.0, 3.0],
                         [4 * x1 + 1, 2 * x2, 3.0, 2.0],
                         [6 * x1 + x2, x1 + 4 * x2, 2.0, 3.0],
                         [2 * x1, 6 * x2, 2.0, 3.0]])

    solution = ([np.sqrt(6.0) / 2.0, 0.0, 0.0, 0.5],)
    return McpProblem("josephy", fun, jac, np.zeros(4), np.full(4, INF), _KOJIMA_STARTS,
                      _nearest(solution), 1e-8, _points(solution))


def mathiesen() -> McpProblem:
    # unknowns (y, p1, p2, p3); technology a = (1, -1, -1), shares s, endowment b
    s1, s2 = 0.9, 0.1
    b2, b3 = 5.0, 3.0

    def fun(x):
        y, p1, p2, p3 = x
        income = b2 * p2 + b3 * p3
        return np.array([-p1 + p2 + p3,                   # zero profit of the activity
                         y - s1 * income / p1,             # market clearing, good 1
                         b2 - y - s2 * income / p2,        # good 2 (numeraire)
                         b3 - y])                          # good 3 (s3 = 0: no final demand)

    def jac(x):
        y, p1, p2, p3 = x
        income = b2 * p2 + b3 * p3
        return np.array([[0.0, -1.0, 1.0, 1.0],
                         [1.0, s1 * income / p1 ** 2, -s1 * b2 / p1, -s1 * b3 / p1],
                         [-1.0, 0.0, s2 * income / p2 ** 2 - s2 * b2 / p2, -s2 * b3 / p2],
                         [-1.0, 0.0, 0.0, 0.0]])

    lower = np.array([0.0, 0.0, 1.0, 0.0])
    upper = np.array([INF, INF, 1.0, INF])
    starts = _starts(("1", [1, 1, 1, 1]), ("mid", [1, 3, 1, 2]), ("y0", [0, 5, 1, 5]),
                     ("far", [10, 20, 1, 20]))
    solution = ([3.0, 6.0, 1.0, 5.0],)
    return McpProblem("mathiesen", fun, jac, lower, upper, starts, _nearest(solution), 1e-8,
                      _points(solution))


def nash_cournot() -> McpProblem:
    c = np.array([10.0, 8.0, 6.0, 4.0, 2.0])
    L = 5.0
    beta = np.array([1.2, 1.1, 1.0, 0.9, 0.8])
    gamma = 1.1
    scale = 5000.0 ** (1.0 / gamma)

    def fun(q):
        Q = q.sum()
        p = scale * Q ** (-1.0 / gamma)
        dp = -p / (gamma * Q)
        return c + (L * q) ** (1.0 / beta) - p - q * dp

    def jac(q):
        Q = q.sum()
        p = scale * Q ** (-1.0 / gamma)
        dp = -p / (gamma * Q)
        ddp = -(1.0 / gamma + 1.0) * dp / Q
        with np.errstate(divide="ignore"):
            mc = (L / beta) * (L * q) ** (1.0 / beta - 1.0)   # inf at q_i = 0 for beta > 1
        J = -(dp + q[:, None] * ddp) * np.ones((5, 5))
        J[np.diag_indices(5)] += mc - dp
        return J

    starts = _starts(("1", np.ones(5)), ("10", np.full(5, 10.0)), ("50", np.full(5, 50.0)),
                     ("mixed", [1.0, 20.0, 5.0, 0.5, 30.0]))
    published = [15.4293, 12.4986, 9.6635, 7.1651, 5.1326]
    return McpProblem("nash_cournot", fun, jac, np.zeros(5), np.full(5, INF), starts,
                      _nearest((published,)), 1e-4)   # published to 4 decimals


def billups() -> McpProblem:
    def fun(x):
        return np.array([(x[0] - 1.0) ** 2 - 1.01])

    def jac(x):
        return np.array([[2.0 * (x[0] - 1.0)]])

    starts = _starts(("mcplib", [3.0]), ("1.5", [1.5]), ("0", [0.0]))
    solution = ([1.0 + np.sqrt(1.01)],)
    return McpProblem("billups", fun, jac, np.zeros(1), np.full(1, INF), starts,
                      _nearest(solution), 1e-10, _points(solution), hard_starts=("0",))


def nocedal_wright() -> McpProblem:
    # min (x1-1)^2 + (x2-2.5)^2  s.t.  A x + b >= 0;  unknowns (x1, x2, l1, l2, l3)
    A = np.array([[1.0, -2.0], [-1.0, -2.0], [-1.0, 2.0]])
    b = np.array([2.0, 6.0, 2.0])
    target = np.array([1.0, 2.5])
    J = np.zeros((5, 5))
    J[:2, :2] = 2.0 * np.eye(2)
    J[:2, 2:] = -A.T
    J[2:, :2] = A

    def fun(z):
        x, lam = z[:2], z[2:]
        return np.concatenate([2.0 * (x - target) - A.T @ lam, A @ x + b])

    def jac(z):
        return J.copy()

    lower = np.array([-INF, -INF, 0.0, 0.0, 0.0])
    upper = np.full(5, INF)
    starts = _starts(("0", np.zeros(5)), ("2,0", [2, 0, 0, 0, 0]), ("far", [-10, 10, 5, 5, 5]))
    solution = ([1.4, 1.7, 0.8, 0.0, 0.0],)
    return McpProblem("nocedal_wright", fun, jac, lower, upper, starts, _nearest(solution), 1e-9,
                      _points(solution))


def rosenbrock_box() -> McpProblem:
    def fun(x):
        x1, x2 = x
        return np.array([-400.0 * x1 * (x2 - x1 * x1) - 2.0 * (1.0 - x1),
                         200.0 * (x2 - x1 * x1)])

    def jac(x):
        x1, x2 = x
        return np.array([[-400.0 * (x2 - 3.0 * x1 * x1) + 2.0, -400.0 * x1],
                         [-400.0 * x1, 200.0]])

    starts = _starts(("classic", [-1.2, 1.0]), ("0", [0.0, 0.0]), ("corner", [-2.0, 2.0]),
                     ("upper", [0.5, -1.0]))
    solution = ([0.5, 0.25],)
    return McpProblem("rosenbrock_box", fun, jac, np.array([-2.0, -1.0]), np.array([0.5, 2.0]),
                      starts, _nearest(solution), 1e-9, _points(solution), hard_starts=("0",))


def _lcp(name, M, q, lower, upper, starts, solutions, atol, distance=None):
    M = np.asarray(M, dtype=float)
    q = np.asarray(q, dtype=float)

    def fun(x):
        return M @ x + q

    def jac(x):
        return M

    return McpProblem(name, fun, jac, np.asarray(lower, float), np.asarray(upper, float),
                      starts, distance or _nearest(solutions), atol, _points(solutions))


def _lcp_starts(n, rng):
    return _starts(("0", np.zeros(n)), ("1", np.ones(n)), ("10", np.full(n, 10.0)),
                   ("rand", rng.uniform(0.0, 5.0, n)))


def murty(n: int = 8) -> McpProblem:
    M = np.eye(n) + 2.0 * np.triu(np.ones((n, n)), 1)
    solution = np.zeros(n)
    solution[-1] = 1.0
    return _lcp(f"murty_{n}", M, -np.ones(n), np.zeros(n), np.full(n, INF),
                _lcp_starts(n, np.random.default_rng(1)), (solution,), 1e-9)


def fathi(n: int = 8) -> McpProblem:
    i = np.arange(1, n + 1)
    M = 4.0 * (np.minimum.outer(i, i) - 1) + 2.0
    M[np.diag_indices(n)] = 4.0 * (i - 1) + 1.0
    solution = np.zeros(n)
    solution[0] = 1.0
    return _lcp(f"fathi_{n}", M, -np.ones(n), np.zeros(n), np.full(n, INF),
                _lcp_starts(n, np.random.default_rng(2)), (solution,), 1e-9)


def degenerate_2x2() -> McpProblem:
    starts = _starts(("0", [0, 0]), ("1", [1, 1]), ("sol", [0.0, 1.0]), ("far", [10, 0]))
    return _lcp("degenerate_2x2", [[2.0, 1.0], [1.0, 2.0]], [-1.0, -2.0], np.zeros(2),
                np.full(2, INF), starts, ([0.0, 1.0],), 1e-9)


def psd_2x2() -> McpProblem:
    def distance(x):
        return float(max(abs(x[0] + x[1] - 1.0), -x.min(), 0.0))

    starts = _starts(("0", [0, 0]), ("1", [1, 1]), ("far", [10, 0]), ("skew", [3, 0.1]))
    return _lcp("psd_2x2", [[1.0, 1.0], [1.0, 1.0]], [-1.0, -1.0], np.zeros(2), np.full(2, INF),
                starts, ([0.5, 0.5], [1.0, 0.0]), 1e-9, distance)


def _p_matrix(n, rng, skew):
    A = rng.standard_normal((n, n))
    S = rng.standard_normal((n, n))
    return A @ A.T / n + 0.5 * np.eye(n) + skew * (S - S.T) / 2.0


def box_lcp_mixed(seed: int = 3) -> McpProblem:
    """Every kind of row: free, lower, upper, box, fixed; strict and degenerate."""
    rng = np.random.default_rng(seed)
    # (lower, upper, x*, w*) per row
    rows = [(-INF, INF, 0.7, 0.0),      # free
            (0.0, INF, 0.0, 1.3),        # lower, strictly active
            (0.0, INF, 0.0, 0.0),        # lower, degenerate (x = l, w = 0)
            (0.0, INF, 2.0, 0.0),        # lower, inactive
            (-INF, 1.0, 1.0, -0.8),      # upper, strictly active
            (-INF, 1.0, -0.5, 0.0),      # upper, inactive
            (-1.0, 1.0, -1.0, 0.6),      # box at lower
            (-1.0, 1.0, 1.0, -0.9),      # box at upper
            (-1.0, 1.0, 1.0, 0.0),       # box at upper, degenerate
            (-1.0, 1.0, 0.2, 0.0),       # box interior
            (0.5, 0.5, 0.5, 3.0)]        # fixed
    lower, upper, xs, ws = (np.array(c, dtype=float) for c in zip(*rows))
    n = lower.size
    M = _p_matrix(n, rng, 0.5)
    q = ws - M @ xs
    starts = _starts(("0", np.zeros(n)), ("1", np.ones(n)), ("-5", np.full(n, -5.0)),
                     ("rand", rng.uniform(-3.0, 3.0, n)))
    return _lcp("box_lcp_mixed", M, q, lower, upper, starts, (xs,), 1e-9)


def box_lcp_obstacle(n: int = 12) -> McpProblem:
    """A 1-D obstacle problem: tridiagonal M (-1, 2, -1) + 0.1 I, every row in [-0.3, 0.4]."""
    M = 2.1 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)
    t = np.linspace(0.0, 1.0, n)
    xs = np.clip(np.sin(2.0 * np.pi * t), -0.3, 0.4)
    ws = np.zeros(n)
    ws[xs >= 0.4] = -1.0 - t[xs >= 0.4]
    ws[xs <= -0.3] = 0.5 + t[xs <= -0.3]
    q = ws - M @ xs
    rng = np.random.default_rng(4)
    starts = _starts(("0", np.zeros(n)), ("upper", np.full(n, 0.4)), ("lower", np.full(n, -0.3)),
                     ("rand", rng.uniform(-0.3, 0.4, n)))
    return _lcp(f"box_lcp_obstacle_{n}", M, q, np.full(n, -0.3), np.full(n, 0.4), starts,
                (xs,), 1e-9)


def lemke(M: np.ndarray, q: np.ndarray, max_pivots: int = 10_000) -> np.ndarray:
    """Lemke's complementary pivoting (covering vector e) for w = M z + q >= 0, z >= 0, z.w = 0.

    Terminates with a solution for P-matrices; the result is polished by solving
    M_SS z_S = -q_S on the support S it identified.  Raises RuntimeError on ray termination.
    """
    n = q.size
    if (q >= 0).all():
        return np.zeros(n)
    # tableau columns: w (n), z (n), z0, rhs;  w - M z - e z0 = q
    T = np.hstack([np.eye(n), -M, -np.ones((n, 1)), q[:, None]]).astype(float)
    basis = list(range(n))
    z0 = 2 * n

    def pivot(row, col):
        T[row] /= T[row, col]
        others = np.arange(n) != row
        T[others] -= np.outer(T[others, col], T[row])

    row = int(np.argmin(q))
    pivot(row, z0)
    leaving, basis[row] = basis[row], z0
    for _ in range(max_pivots):
        entering = leaving + n if leaving < n else leaving - n
        col = T[:, entering]
        positive = col > 1e-12
        if not positive.any():
            raise RuntimeError("Lemke: ray termination (the LCP may have no solution)")
        ratios = np.full(n, np.inf)
        ratios[positive] = T[positive, -1] / col[positive]
        row = int(np.argmin(ratios))
        pivot(row, entering)
        leaving, basis[row] = basis[row], entering
        if leaving == z0:
            break
    else:
        raise RuntimeError("Lemke: pivot limit reached")
    z = np.zeros(n)
    for r, var in enumerate(basis):
        if n <= var < 2 * n:
            z[var - n] = T[r, -1]
    support = np.flatnonzero(z > 0)
    if support.size:
        z[support] = np.linalg.solve(M[np.ix_(support, support)], -q[support])
    return z


def random_lcp(n: int, seed: int) -> McpProblem:
    rng = np.random.default_rng(seed)
    M = _p_matrix(n, rng, 1.0)
    q = rng.standard_normal(n)
    reference = lemke(M, q)
    return _lcp(f"random_lcp_{n}_s{seed}", M, q, np.zeros(n), np.full(n, INF),
                _lcp_starts(n, rng), (reference,), 1e-8)


def random_monotone_lcp_data(n: int, seed: int, sparse: bool = False, bandwidth: int = 3,
                             skew: float = 0.5):
    """(M, q) with M = A A^T + 0.01 I + skew part; A banded and M a scipy.sparse CSR if sparse."""
    rng = np.random.default_rng(seed)
    if sparse:
        offsets = list(range(-bandwidth, bandwidth + 1))
        A = sp.diags([rng.standard_normal(n - abs(k)) for k in offsets], offsets, format="csr")
        S = sp.diags([rng.standard_normal(n - abs(k)) for k in offsets], offsets, format="csr")
        M = (A @ A.T + 0.01 * sp.identity(n) + skew * (S - S.T)).tocsr()
    else:
        A = rng.standard_normal((n, n)) / np.sqrt(n)
        S = rng.standard_normal((n, n)) / np.sqrt(n)
        M = A @ A.T + 0.01 * np.eye(n) + skew * (S - S.T)
    q = rng.standard_normal(n)
    return M, q


def standard_problems() -> tuple[McpProblem, ...]:
    """The shared table: published problems, constructed box LCPs, Lemke-checked random LCPs."""
    return (kojima_shindo(), josephy(), mathiesen(), nash_cournot(), billups(), nocedal_wright(),
            rosenbrock_box(), murty(8), fathi(8), degenerate_2x2(), psd_2x2(), box_lcp_mixed(),
            box_lcp_obstacle(12), random_lcp(10, 11), random_lcp(20, 12), random_lcp(30, 13))
