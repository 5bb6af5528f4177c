"""solve_mcp against complementarity problems whose answers are known independently of it.

The problems (comparisons/mcp_problems.py) carry published solutions, closed-form solution sets,
solutions built in by construction, or Lemke's pivoting result.  The contract tests check what
the stepper relies on: statuses instead of exceptions, ValueError for malformed input only,
NaN never hidden, sparse and dense paths agreeing.
"""
import math

import numpy as np
import pytest
import scipy.sparse as sp

from comparisons.mcp_problems import lemke, standard_problems
from implicit_contact.ncp import McpResult, SolverOptions, Status, newton_min_map, solve_mcp, solve_proximal

MIN_SOLVED_FRACTION = 0.95   # of all (problem, start) pairs, the brief's robustness target
RTOL_FD = 1e-6               # central differences, step 1e-6, relative to max |J| of O(1..1e3)
FD_STEP = 1e-6
ATOL_SPARSE_DENSE = 1e-12    # same iterates up to LU pivoting round-off
ATOL_LEMKE = 1e-9            # Lemke's support polished by one LU solve of a P-matrix block
ATOL_STABLE_FB = 1e-6        # relative, for phi(1, 1e-17) = 1e-17 (cancellation would give 0)
QUADRATIC_MERIT_FACTOR = 10.0  # psi_{k+1} <= K psi_k^2 for O(1) problem data (measured ~0.35)
ATOL_EXACT = 1e-12           # listed exact solutions evaluated in floating point, O(1) data
ATOL_SMALL_LCP = 1e-10       # residual tol 1e-10 times ||M^-1|| = O(1) for the 2x2 examples
RTOL_RECOMPUTE = 1e-12       # the natural residual recomputed here with np.clip

PROBLEMS = standard_problems()
PAIRS = [(p, label, x0) for p in PROBLEMS for label, x0 in p.starts]


@pytest.fixture(scope="module")
def results():
    return {(p.name, label): solve_mcp(p.fun, p.jac, x0, p.lower, p.upper)
            for p, label, x0 in PAIRS}


def _natural_residual(x, F, lower, upper):
    return float(np.max(np.abs(x - np.clip(x - F, lower, upper))))


# ---------------------------------------------------------------- the problem table itself

@pytest.mark.parametrize("problem", PROBLEMS, ids=lambda p: p.name)
def test_problem_jacobian_matches_central_differences(problem):
    for _, x0 in problem.starts[:2]:
        # an interior point near the start: F may be singular on the bounds (nash, mathiesen)
        x = np.clip(x0, problem.lower, problem.upper) + 0.1
        x = np.where(problem.lower == problem.upper, problem.lower, x)
        J = problem.jac(x)
        fd = np.column_stack([(problem.fun(x + FD_STEP * e) - problem.fun(x - FD_STEP * e))
                              / (2 * FD_STEP) for e in np.eye(problem.n)])
        assert np.abs(J - fd).max() <= RTOL_FD * max(1.0, np.abs(J).max())


@pytest.mark.parametrize("problem", PROBLEMS, ids=lambda p: p.name)
def test_listed_solutions_solve_the_problem(problem):
    for x in problem.solutions:
        assert _natural_residual(x, problem.fun(x), problem.lower, problem.upper) <= ATOL_EXACT
        assert problem.distance(x) == 0.0


def test_lemke_oracle_reproduces_murty_and_fathi():
    n = 8
    murty = np.eye(n) + 2.0 * np.triu(np.ones((n, n)), 1)
    np.testing.assert_allclose(lemke(murty, -np.ones(n)), np.eye(n)[-1], atol=ATOL_LEMKE)
    i = np.arange(1, n + 1)
    fathi = 4.0 * (np.minimum.outer(i, i) - 1) + 2.0
    fathi[np.diag_indices(n)] = 4.0 * (i - 1) + 1.0
    np.testing.assert_allclose(lemke(fathi, -np.ones(n)), np.eye(n)[0], atol=ATOL_LEMKE)


# ---------------------------------------------------------------- solving the table

def test_solved_fraction_over_all_problem_start_pairs(results):
    failed = []
    for p, label, _ in PAIRS:
        r = results[p.name, label]
        if not (r.success and p.distance(r.x) <= p.solution_atol):
            failed.append(f"{p.name}/{label}: {r.status.value}, residual {r.residual:.1e}, "
                          f"distance {p.distance(r.x):.1e}")
    fraction = 1.0 - len(failed) / len(PAIRS)
    print(f"\nsolved {len(PAIRS) - len(failed)}/{len(PAIRS)} = {fraction:.1%}; failed: {failed}")
    assert fraction >= MIN_SOLVED_FRACTION, f"solved {fraction:.1%}; failed: {failed}"


def test_every_converged_pair_is_at_the_known_solution(results):
    wrong = [(p.name, label, p.distance(results[p.name, label].x)) for p, label, _ in PAIRS
             if results[p.name, label].success
             and not p.distance(results[p.name, label].x) <= p.solution_atol]
    assert not wrong, f"converged to a point that is not the known solution: {wrong}"


def test_no_failures_outside_the_documented_hard_starts(results):
    surprising = [(p.name, label, results[p.name, label].status.value) for p, label, _ in PAIRS
                  if not results[p.name, label].success and label not in p.hard_starts]
    assert not surprising, surprising


def test_reported_residual_is_the_natural_residual_and_history_is_consistent(results):
    for p, label, _ in PAIRS:
        r = results[p.name, label]
        assert isinstance(r, McpResult)
        F = p.fun(r.x)
        assert r.residual == pytest.approx(_natural_residual(r.x, F, p.lower, p.upper),
                                           rel=RTOL_RECOMPUTE, abs=1e-300)
        assert r.success == (r.residual <= SolverOptions().tol)
        assert len(r.merit_history) == r.iterations + 1 == len(r.steps) + 1
        assert np.all((r.x >= p.lower) & (r.x <= p.upper)), "iterates stay in the box"


def test_kojima_shindo_reaches_both_published_solutions(results):
    problem = PROBLEMS[0]
    reached = {min(range(2), key=lambda k: np.abs(results["kojima_shindo", label].x
                                                  - problem.solutions[k]).max())
               for label, _ in problem.starts if results["kojima_shindo", label].success}
    assert reached == {0, 1}


def test_fast_local_rate_at_the_degenerate_kojima_shindo_solution():
    """x* = (sqrt(6)/2, 0, 0, 1/2) has x3 = F3 = 0; the merit still falls superlinearly."""
    problem = PROBLEMS[0]
    r = solve_mcp(problem.fun, problem.jac, dict(problem.starts)["near"], problem.lower,
                  problem.upper)
    assert r.success and np.abs(r.x - problem.solutions[1]).max() <= problem.solution_atol
    merits = [m for m in r.merit_history if m > 0.0]
    ratios = [b / a for a, b in zip(merits, merits[1:])]
    assert r.iterations <= 5
    assert ratios[-1] <= 1e-6 and ratios[-2] <= 1e-3, ratios


def test_billups_start_at_zero_is_a_reported_stationary_point():
    """MCPLIB billups from x0 = 0: a local minimiser of the merit; the solver says so."""
    problem = next(p for p in PROBLEMS if p.name == "billups")
    r = solve_mcp(problem.fun, problem.jac, [0.0], problem.lower, problem.upper)
    assert r.status is Status.LINE_SEARCH_FAILED and not r.success
    assert r.x[0] == 0.0
    assert r.residual == pytest.approx(0.01, rel=RTOL_RECOMPUTE)   # |min(0, F(0))| = 0.01
    assert "stationary" in r.message


# ---------------------------------------------------------------- contracts

@pytest.mark.parametrize("problem", [p for p in PROBLEMS if p.solutions], ids=lambda p: p.name)
def test_exact_start_converges_in_zero_iterations(problem):
    for x in problem.solutions:
        r = solve_mcp(problem.fun, problem.jac, x, problem.lower, problem.upper)
        assert r.success and r.iterations == 0 and r.nfev == 1 and r.njev == 0
        np.testing.assert_array_equal(r.x, x)


def test_capped_hard_case_returns_a_status():
    problem = next(p for p in PROBLEMS if p.name == "rosenbrock_box")
    r = solve_mcp(problem.fun, problem.jac, dict(problem.starts)["classic"], problem.lower,
                  problem.upper, SolverOptions(max_iterations=1))
    assert r.status is Status.MAX_ITERATIONS and not r.success and r.iterations == 1
    assert r.residual > SolverOptions().tol and "max_iterations" in r.message


def test_zero_iterations_only_evaluates_the_start():
    problem = PROBLEMS[0]
    r = solve_mcp(problem.fun, problem.jac, np.ones(4), problem.lower, problem.upper,
                  SolverOptions(max_iterations=0))
    assert r.status is Status.MAX_ITERATIONS and r.nfev == 1 and r.njev == 0
    assert r.residual == pytest.approx(_natural_residual(np.ones(4), problem.fun(np.ones(4)),
                                                         problem.lower, problem.upper))


def test_start_is_projected_and_not_modified():
    problem = next(p for p in PROBLEMS if p.name == "box_lcp_mixed")
    x0 = np.full(problem.n, -5.0)
    seen = []
    r = solve_mcp(lambda x: seen.append(x.copy()) or problem.fun(x), problem.jac, x0,
                  problem.lower, problem.upper)
    np.testing.assert_array_equal(x0, -5.0)
    np.testing.assert_array_equal(seen[0], np.clip(x0, problem.lower, problem.upper))
    assert r.success


def _lcp(M, q):
    M = np.asarray(M, float)
    q = np.asarray(q, float)
    return (lambda x: M @ x + q), (lambda x: M)


def test_start_on_a_kink_uses_a_generalized_jacobian_and_converges_fast():
    """x0 = (0, 1): row 1 has x1 = 0 and F1 = 0 exactly, the FB kink; solution (0, 4/3)."""
    fun, jac = _lcp([[1.0, 1.0], [1.0, 3.0]], [-1.0, -4.0])
    r = solve_mcp(fun, jac, [0.0, 1.0], 0.0, np.inf)
    assert r.success and r.iterations <= 5 and r.steps == "N" * r.iterations
    np.testing.assert_allclose(r.x, [0.0, 4.0 / 3.0], atol=ATOL_SMALL_LCP)
    m = r.merit_history
    # quadratic rate: Phi_{k+1} <= C Phi_k^2, i.e. psi_{k+1} <= C^2 psi_k^2 / 2 (C ~ 1 here)
    assert m[-1] <= QUADRATIC_MERIT_FACTOR * m[-2] ** 2
    assert m[-2] <= QUADRATIC_MERIT_FACTOR * m[-3] ** 2


def test_start_on_an_upper_bound_kink_of_a_box_row():
    """Box [0, 1]^2, x0 = (1, 0.5): x1 = u1 and F1 = 0 (inner-level kink).  M is positive
    definite, so the solution (1, 0) (both rows degenerate) is unique."""
    fun, jac = _lcp([[2.0, 1.0], [1.0, 2.0]], [-2.5, -1.0])
    r = solve_mcp(fun, jac, [1.0, 0.5], 0.0, 1.0)
    assert r.success and r.iterations <= 8 and r.steps == "N" * r.iterations
    np.testing.assert_allclose(r.x, [1.0, 0.0], atol=ATOL_SMALL_LCP)


def test_singular_jacobian_falls_back_to_levenberg_marquardt_without_stalling():
    """Two identical free rows: J singular everywhere, solutions a line.  The damping tied to
    ||Phi|| must reach tol = 1e-12 (a fixed 1e-6 damping stalls around 1e-7)."""
    def fun(x):
        return np.full(2, x[0] + x[1] - 1.0)

    def jac(x):
        return np.ones((2, 2))

    r = solve_mcp(fun, jac, [3.0, -7.0], -np.inf, np.inf, SolverOptions(tol=ATOL_EXACT))
    assert r.success and "L" in r.steps and r.iterations <= 10
    assert abs(r.x.sum() - 1.0) <= ATOL_EXACT


def test_inconsistent_singular_system_returns_a_status():
    fun, jac = _lcp([[1.0, 1.0], [1.0, 1.0]], [-1.0, 1.0])   # x1 + x2 = 1 and = -1: no solution
    r = solve_mcp(fun, jac, [0.3, 0.2], -np.inf, np.inf)
    assert not r.success
    assert r.status in (Status.SINGULAR, Status.LINE_SEARCH_FAILED, Status.MAX_ITERATIONS)


def test_watch_stops_a_stalled_solve_at_its_iteration():
    """SolverOptions.watch: the inconsistent system's merit stays at 1 from its third iteration;
    watched at 6 the solve stops there (MAX_ITERATIONS, the message says it stalled) instead of
    going on to its own stop at 7."""
    fun, jac = _lcp([[1.0, 1.0], [1.0, 1.0]], [-1.0, 1.0])
    unwatched = solve_mcp(fun, jac, [0.3, 0.2], -np.inf, np.inf)
    watched = solve_mcp(fun, jac, [0.3, 0.2], -np.inf, np.inf, SolverOptions(watch=6))
    assert unwatched.iterations > 6
    assert watched.status is Status.MAX_ITERATIONS and watched.iterations == 6 and "stalled" in watched.message
    np.testing.assert_array_equal(watched.merit_history, unwatched.merit_history[:7])


@pytest.mark.parametrize("problem", PROBLEMS, ids=lambda p: p.name)
def test_watch_changes_nothing_but_where_a_stalled_solve_stops(problem):
    """Watched at 5, every start of the problem table is solved exactly as without the watch
    (the same iterations and iterate), or stops at 5 with a best merit over its last
    ncp.STALL_WINDOW iterations above ncp.STALL_GAIN times the best before them."""
    from implicit_contact import ncp
    for label, x0 in problem.starts:
        plain = solve_mcp(problem.fun, problem.jac, x0, problem.lower, problem.upper)
        watched = solve_mcp(problem.fun, problem.jac, x0, problem.lower, problem.upper, SolverOptions(watch=5))
        if watched.iterations == plain.iterations and watched.status is plain.status:
            np.testing.assert_array_equal(watched.x, plain.x)
            continue
        assert watched.status is Status.MAX_ITERATIONS and watched.iterations == 5, label
        h = np.asarray(watched.merit_history)
        assert np.min(h[-ncp.STALL_WINDOW:]) > ncp.STALL_GAIN * np.min(h[:-ncp.STALL_WINDOW]), label
        np.testing.assert_array_equal(h, plain.merit_history[:6])


@pytest.mark.parametrize("problem", PROBLEMS, ids=lambda p: p.name)
def test_stop_hands_over_at_the_first_iterate_it_accepts(problem):
    """solve_mcp's stop: asked at every iterate that is not a solution, before its Newton step,
    with that iterate, F there and its natural residual; True ends the solve there (HANDED_OVER)
    with the iterations, iterate and merit history of the plain solve up to that point. A stop that
    never accepts changes nothing."""
    for label, x0 in problem.starts:
        plain = solve_mcp(problem.fun, problem.jac, x0, problem.lower, problem.upper)
        asked = []

        def never(x, F, residual):
            asked.append((x.copy(), residual))
            np.testing.assert_allclose(residual, _natural_residual(x, F, problem.lower, problem.upper),
                                       rtol=RTOL_RECOMPUTE, atol=0.0)
            return False

        quiet = solve_mcp(problem.fun, problem.jac, x0, problem.lower, problem.upper, stop=never)
        assert quiet.status is plain.status and quiet.iterations == plain.iterations, label
        np.testing.assert_array_equal(quiet.x, plain.x)
        if not asked or plain.iterations < 2:
            continue
        k = len(asked) // 2            # hand over at an iterate half-way
        handed = solve_mcp(problem.fun, problem.jac, x0, problem.lower, problem.upper,
                           stop=lambda x, F, r, seen=[]: seen.append(0) or len(seen) > k)
        assert handed.status is Status.HANDED_OVER and not handed.success, label
        assert handed.iterations == k, label
        np.testing.assert_array_equal(handed.x, asked[k][0])
        assert handed.residual == asked[k][1]
        np.testing.assert_array_equal(handed.merit_history, plain.merit_history[:k + 1])


def test_sparse_jacobian_gives_the_same_answer_as_dense():
    for name in ("kojima_shindo", "box_lcp_mixed", "random_lcp_20_s12", "mathiesen"):
        problem = next(p for p in PROBLEMS if p.name == name)
        for _, x0 in problem.starts:
            dense = solve_mcp(problem.fun, problem.jac, x0, problem.lower, problem.upper)
            sparse = solve_mcp(problem.fun, lambda x: sp.csr_matrix(problem.jac(x)), x0,
                               problem.lower, problem.upper)
            assert sparse.status is dense.status and sparse.iterations == dense.iterations
            np.testing.assert_allclose(sparse.x, dense.x, atol=ATOL_SPARSE_DENSE)


def _full_pattern(J):
    """J as CSR storing every entry, zeros included (a step problem's fixed pattern does)."""
    n = J.shape[0]
    return sp.csr_matrix((J.ravel().copy(), np.tile(np.arange(n), n), np.arange(0, n * n + 1, n)), shape=(n, n))


def test_sparse_jacobian_with_stored_zeros_gives_the_same_iterates_as_dense():
    """Stored zeros are dropped before SuperLU factorises (ncp._nonzeros), which compacts the
    arrays it is given: the Levenberg-Marquardt and gradient steps must still see H itself.
    Singular problems whose Jacobians have zeros (two equal rows beside a decoupled one; the same
    made inconsistent) are solved the same way from a Jacobian that stores all n^2 entries."""
    J0 = np.array([[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 2.0]])
    for c, x0 in (([-1.0, -1.0, 3.0], [3.0, -7.0, 0.5]), ([-1.0, 1.0, 3.0], [0.3, 0.2, -4.0])):
        fun, jac = _lcp(J0, c)
        dense = solve_mcp(fun, jac, x0, -np.inf, np.inf, SolverOptions(tol=ATOL_EXACT))
        sparse = solve_mcp(fun, lambda x: _full_pattern(jac(x)), x0, -np.inf, np.inf, SolverOptions(tol=ATOL_EXACT))
        assert "L" in dense.steps
        assert sparse.status is dense.status and sparse.steps == dense.steps
        np.testing.assert_allclose(sparse.x, dense.x, atol=ATOL_SPARSE_DENSE)


def test_sparse_solve_refuses_a_solution_that_does_not_solve():
    """SuperLU reports only exactly singular matrices; on a numerically singular one it returns a
    finite d far from solving H d = rhs (on example-robot-data's alex_sake even with invalid BLAS
    calls inside). Such a d is no Newton direction: ncp._sparse_solve and the fixed-pattern Newton
    step return None (singular: the solver takes its LM step) unless ||H d - rhs|| <= tol ||rhs||."""
    import scipy.sparse.linalg as spla
    from implicit_contact import ncp
    rng = np.random.default_rng(0)
    n = 6
    A = rng.normal(size=(n, n - 1)) @ rng.normal(size=(n - 1, n))     # rank n - 1 up to round-off
    rhs = rng.normal(size=n)                                         # not in its range
    d = spla.splu(sp.csc_matrix(A)).solve(rhs)
    assert np.isfinite(d).all() and np.linalg.norm(A @ d - rhs) > ncp.SPARSE_SOLVE_TOL * np.linalg.norm(rhs)
    assert ncp._sparse_solve(sp.csr_matrix(A), rhs) is None
    J = _full_pattern(A)
    assert ncp._SparsePattern(J).newton(J, np.zeros(n), np.ones(n), -rhs, np.empty(n)) is None
    well_posed = A + n * np.eye(n)
    J = _full_pattern(well_posed)
    d = ncp._SparsePattern(J).newton(J, np.zeros(n), np.ones(n), -rhs, np.empty(n))
    np.testing.assert_allclose(well_posed @ d, rhs, rtol=0, atol=ATOL_EXACT * np.abs(rhs).max())


def test_sparse_levenberg_marquardt_step_matches_the_dense_one():
    """ncp._sparse_lm solves (H^T H + mu I) d = -g through the quasi-definite system
    [[I, H], [H^T, -mu I]] (no product H^T H; SuperLU's symmetric mode): the same step as
    dense_lm's normal equations, on a random sparse H with a dense block (as a skeleton's rows
    make) and on a rank-deficient H, where mu alone regularises; and its matrix is that system."""
    from implicit_contact.ncp import _sparse_lm, dense_lm
    rng = np.random.default_rng(11)
    n = 60
    H = sp.random(n, n, density=0.05, random_state=3).toarray() + np.eye(n)
    H[:8, :] += rng.normal(size=(8, n))                  # dense rows
    rank_deficient = H.copy()
    rank_deficient[:, 5] = rank_deficient[:, 4]          # two equal columns
    for A, mu in ((H, 1e-6), (rank_deficient, 1e-8)):
        g = A.T @ rng.normal(size=n)
        dense = np.empty(n)
        assert dense_lm(A.copy(), g, mu, dense)
        sparse = _sparse_lm(sp.csr_matrix(A), g, mu)
        assert sparse is not None
        np.testing.assert_allclose(sparse, dense, rtol=RTOL_LM_STEP, atol=RTOL_LM_STEP * np.abs(dense).max())
    from implicit_contact.ncp import _quasi_definite
    K = _quasi_definite(sp.csr_matrix(H), 0.5).toarray()
    np.testing.assert_array_equal(K, np.block([[np.eye(n), H], [H.T, -0.5 * np.eye(n)]]))


RTOL_LM_STEP = 1e-7     # the two factorisations of an LM step (normal equations squares the condition number)


def test_stable_fischer_burmeister_evaluation():
    """One NCP row with x = 1 and F = 1e-17: phi = 2ab / (a + b + r) = 1e-17; the textbook
    a + b - sqrt(a^2 + b^2) rounds to 0 (and the penalty term is (1 - lam) 1e-17)."""
    r = solve_mcp(lambda x: np.array([1e-17]), lambda x: np.zeros((1, 1)), [1.0], 0.0, np.inf,
                  SolverOptions(max_iterations=0))
    assert math.sqrt(2.0 * r.merit_history[0]) == pytest.approx(1e-17, rel=ATOL_STABLE_FB)


# ---------------------------------------------------------------- failures are reported, not hidden

def test_nan_from_fun_at_the_start_gives_not_finite():
    r = solve_mcp(lambda x: np.array([np.nan, 1.0]), lambda x: np.eye(2), [1.0, 1.0], 0.0, np.inf)
    assert r.status is Status.NOT_FINITE and not r.success and np.isnan(r.residual)
    assert np.isnan(r.f[0])


def test_nan_from_fun_during_the_iteration_gives_not_finite_at_the_last_finite_iterate():
    def fun(x):   # defined only for x < 2; the Newton step from 1 lands at 3
        return np.array([x[0] - 3.0]) if x[0] < 2.0 else np.array([np.nan])

    r = solve_mcp(fun, lambda x: np.eye(1), [1.0], -np.inf, np.inf)
    assert r.status is Status.NOT_FINITE and not r.success
    np.testing.assert_array_equal(r.x, [1.0])
    assert r.residual == pytest.approx(2.0)


def test_inf_from_jac_gives_not_finite():
    r = solve_mcp(lambda x: x - 2.0, lambda x: np.full((2, 2), np.inf), [0.0, 0.0], 0.0, np.inf)
    assert r.status is Status.NOT_FINITE and "jac" in r.message


@pytest.mark.parametrize("kwargs, match", [
    (dict(x0=np.zeros((2, 2))), "x0"),
    (dict(x0=np.array([np.nan, 0.0])), "x0 must be finite"),
    (dict(x0=np.array([np.inf, 0.0])), "x0 must be finite"),
    (dict(lower=np.zeros(3)), "lower must be a scalar or have shape"),
    (dict(upper=np.ones((2, 1))), "upper must be a scalar or have shape"),
    (dict(lower=np.array([0.0, 2.0]), upper=np.array([1.0, 1.0])), "lower must be <= upper"),
    (dict(lower=np.array([np.nan, 0.0])), "NaN"),
    (dict(lower=np.array([np.inf, np.inf]), upper=np.inf), "lower must be < \\+inf"),
    (dict(fun=lambda x: np.zeros(3)), "fun\\(x\\) must return an array of shape"),
    (dict(jac=lambda x: np.eye(3)), "jac\\(x\\) must return shape"),
    (dict(jac=lambda x: sp.eye(3, format="csr")), "jac\\(x\\) must return shape"),
    (dict(options="fast"), "options must be a SolverOptions"),
])
def test_malformed_input_raises_value_error(kwargs, match):
    args = dict(fun=lambda x: x - 2.0, jac=lambda x: np.eye(2), x0=np.zeros(2), lower=0.0,
                upper=np.inf)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        solve_mcp(args["fun"], args["jac"], args["x0"], args["lower"], args["upper"],
                  **({"options": args["options"]} if "options" in args else {}))


@pytest.mark.parametrize("kwargs", [dict(tol=0.0), dict(tol=np.nan), dict(max_iterations=-1),
                                    dict(max_iterations=2.5), dict(armijo=0.5),
                                    dict(nonmonotone_memory=0), dict(min_newton_step=2.0),
                                    dict(min_step=1.0), dict(descent_power=2.0),
                                    dict(lm_factor=0.0), dict(fb_lambda=0.0),
                                    dict(fb_lambda=1.5), dict(watch=-1), dict(watch=1.5)])
def test_invalid_options_raise_value_error(kwargs):
    with pytest.raises(ValueError, match="SolverOptions"):
        SolverOptions(**kwargs)


def test_shorten_nonfinite_halves_a_step_into_undefined_rows_and_converges():
    """F = x^3 - 1, defined for x < 2 only: from x = 0.1 the Newton step lands at 33.4. By default
    the solver stops there (NOT_FINITE, the last finite iterate); with shorten_nonfinite the trial
    point counts as an infinite merit, the step is shortened and the root x = 1 is found."""
    def fun(x):
        return np.array([x[0] ** 3 - 1.0]) if x[0] < 2.0 else np.array([np.nan])

    def jac(x):
        return np.array([[3.0 * x[0] ** 2]])

    stopped = solve_mcp(fun, jac, [0.1], -np.inf, np.inf)
    assert stopped.status is Status.NOT_FINITE and stopped.x[0] == 0.1
    shortened = solve_mcp(fun, jac, [0.1], -np.inf, np.inf, SolverOptions(shorten_nonfinite=True))
    assert shortened.success and shortened.x[0] == pytest.approx(1.0, abs=1e-10)
    with pytest.raises(ValueError, match="shorten_nonfinite"):
        SolverOptions(shorten_nonfinite=1)


# the stepper's descent test (stepper.DEFAULT_SOLVER): the tests below take O(1) steps on residuals of 1e-6
PROXIMAL_OPTIONS = SolverOptions(tol=1e-10, max_iterations=50, descent_rho=1e-24)


def test_proximal_steps_contract_by_w_over_s_plus_w():
    """F(x) = s (x - 2), one free row, weight w: proximal step k solves s (x - 2) + w_k (x - x_k) = 0
    exactly (one Newton iteration), w_k = min(w, r_k) with r_k = s |x_k - 2| the natural residual
    at x_k, so the error shrinks by w_k / (s + w_k): by half while r_k >= w, then quadratically.
    With s = w = 1e-6 from x = 1 the errors are 1/2, 1/6, 1/42, 1/1806, 3.1e-7: five steps to
    a residual <= 1e-10, where a fixed w would take 14 (2^-13 = 1.2e-4 > 1e-4)."""
    s, w = 1e-6, 1e-6

    def fun(x):
        return s * (x - 2.0)

    def jac(x):
        return np.array([[s]])

    errors = [1.0]
    while s * errors[-1] > PROXIMAL_OPTIONS.tol:
        wk = min(w, s * errors[-1])
        errors.append(errors[-1] * wk / (s + wk))
    assert len(errors) - 1 == 5 and errors[4] == pytest.approx(1.0 / 1806.0)
    r = solve_proximal(fun, jac, [1.0], -np.inf, np.inf, [w], PROXIMAL_OPTIONS)
    assert r.success and "in 5 proximal steps" in r.message
    assert r.iterations == 5 and r.steps == "N" * 5
    assert r.x[0] == pytest.approx(2.0 - errors[-1], abs=1e-12)
    assert r.residual == pytest.approx(s * errors[-1], rel=1e-6)


def _table(c):
    """A table of mass m on four legs at (+-a, +-b), resting (v = 0 is the answer): unknowns
    v = (vz, wx, wy) (free rows M v - B^T p - f) and the legs' impulses p >= 0 (rows B v). Any
    p = mgh/4 (1, 1, 1, 1) + t (1, -1, 1, -1) with p >= 0 solves it (the warp mode is B's null
    vector). The start: free-fall velocities and impulses mgh/4 + c times the warp mode."""
    m, g, h, a, b = 2.0, 9.81, 1e-2, 0.3, 0.2
    legs = np.array([[a, b], [-a, b], [-a, -b], [a, -b]])
    B = np.column_stack([np.ones(4), legs[:, 1], -legs[:, 0]])
    M = np.diag([m, 0.1, 0.2])
    f = np.array([-m * g * h, 0.0, 0.0])
    warp = np.array([1.0, -1.0, 1.0, -1.0])
    assert np.allclose(B.T @ warp, 0.0)

    def fun(z):
        return np.concatenate([M @ z[:3] - B.T @ z[3:] - f, B @ z[:3]])

    def jac(z):
        J = np.zeros((7, 7))
        J[:3, :3], J[:3, 3:], J[3:, :3] = M, -B.T, B
        return J

    p_rest = m * g * h / 4.0
    z0 = np.concatenate([np.linalg.solve(M, f), p_rest + c * warp])
    lo = np.r_[np.full(3, -np.inf), np.zeros(4)]
    return fun, jac, z0, lo, p_rest, warp


def test_proximal_solution_keeps_the_starts_share_of_a_non_unique_impulse():
    """The regularised rows' component along B's null vector n reads w (p - p_k) . n = 0 (F does
    not move along n), so every proximal step keeps the start's warp share: the answer is
    mgh/4 (1, 1, 1, 1) + c n exactly, for any c that keeps p > 0."""
    for c in (0.0, 0.01, -0.02):
        fun, jac, z0, lo, p_rest, warp = _table(c)
        weight = np.r_[np.zeros(3), np.full(4, 1e-6)]
        r = solve_proximal(fun, jac, z0, lo, np.inf, weight, PROXIMAL_OPTIONS)
        assert r.success
        np.testing.assert_allclose(r.x[:3], 0.0, atol=1e-10)
        np.testing.assert_allclose(r.x[3:], p_rest + c * warp, atol=1e-9)


def test_proximal_solve_of_a_problem_without_solution_stops_with_the_true_residual():
    """An inconsistent system (x1 + x2 = 1 and = -1) has no solution, but each regularised one does:
    every proximal step moves x along (1, -1) by 1 / w and leaves the unregularised residual at 1.
    The solve stops when the iterations run out and reports that residual, not the inner one."""
    fun, jac = _lcp([[1.0, 1.0], [1.0, 1.0]], [-1.0, 1.0])
    r = solve_proximal(fun, jac, [0.3, 0.2], -np.inf, np.inf, [1e-6, 1e-6], PROXIMAL_OPTIONS)
    assert r.status is Status.MAX_ITERATIONS and r.message.startswith("Stopped after")
    assert r.iterations == PROXIMAL_OPTIONS.max_iterations
    assert r.residual == pytest.approx(1.0) and np.abs(r.x).max() > 1e6


def test_proximal_solve_ends_with_an_inner_failure():
    """A NaN at the start stops the first inner solve (NOT_FINITE); the proximal solve says which."""
    def fun(x):
        return np.array([np.nan])

    r = solve_proximal(fun, lambda x: np.ones((1, 1)), [0.0], -np.inf, np.inf, [1e-6], PROXIMAL_OPTIONS)
    assert r.status is Status.NOT_FINITE and r.message.startswith("Proximal step 1 failed: fun returned NaN")


@pytest.mark.parametrize("weight, max_outer, match", [([-1e-6], 5, "weight"), ([np.nan], 5, "weight"),
                                                      ([1e-6, 1e-6], 5, "weight"), ([1e-6], 0, "max_outer")])
def test_proximal_malformed_input_raises_value_error(weight, max_outer, match):
    fun, jac = _lcp([[1.0]], [-1.0])
    with pytest.raises(ValueError, match=match):
        solve_proximal(fun, jac, [0.0], 0.0, np.inf, weight, PROXIMAL_OPTIONS, max_outer=max_outer)


# -- the endgame: Newton on the min-map with least-norm steps (newton_min_map) ----------------------
ENDGAME_TOL = 1e-12
QUADRATIC_RESIDUAL_FACTOR = 10.0   # r_{k+1} <= K r_k^2 for O(1) data (Gauss-Newton on a circle: ~1)


def test_min_map_newton_keeps_the_starts_share_of_a_non_unique_impulse():
    """On the four-legged table (impulses unique only up to the warp mode n, J singular) the
    active piece is linear and consistent: one least-norm step solves it, and a least-norm step
    has no component along J's null vector, so the answer keeps the start's warp share c."""
    for c in (0.0, 0.01, -0.02):
        fun, jac, z0, lo, p_rest, warp = _table(c)
        r = newton_min_map(fun, jac, z0, lo, np.inf, ENDGAME_TOL)
        assert r.success and r.steps == "N" and r.iterations == 1
        np.testing.assert_allclose(r.x[:3], 0.0, atol=ENDGAME_TOL)
        np.testing.assert_allclose(r.x[3:], p_rest + c * warp, atol=ENDGAME_TOL)
        assert r.residual == pytest.approx(_natural_residual(r.x, fun(r.x), lo, np.inf), rel=RTOL_RECOMPUTE)


def test_min_map_newton_converges_quadratically_onto_a_curve_of_solutions():
    """F = (|x|^2 - 1, 2 (|x|^2 - 1)): a rank-one Jacobian everywhere and the unit circle as
    solution set (not isolated, so Newton's matrix is singular at every iterate). The least-norm
    step is Gauss-Newton's on a consistent underdetermined system: quadratic, onto the circle
    along the radius (the start's angle kept)."""
    def fun(x):
        e = x @ x - 1.0
        return np.array([e, 2.0 * e])

    def jac(x):
        return np.array([2.0 * x, 4.0 * x])

    x0 = np.array([1.2, 0.5])
    r = newton_min_map(fun, jac, x0, -np.inf, np.inf, ENDGAME_TOL)
    assert r.success and r.iterations <= 6
    assert np.linalg.norm(r.x) == pytest.approx(1.0, abs=ENDGAME_TOL)
    assert math.atan2(r.x[1], r.x[0]) == pytest.approx(math.atan2(0.5, 1.2), abs=1e-12)
    errors = [e for e in r.merit_history if e > 1e-10]
    assert len(errors) >= 3
    for a, b in zip(errors, errors[1:]):
        assert b <= QUADRATIC_RESIDUAL_FACTOR * a * a


def test_min_map_newton_puts_rows_on_their_bounds():
    """x in [0, 1]^3, F = M x + q with the solution x = (1, 0, 0.5): row 0 at its upper bound
    (F_0 = -1.5 <= 0), row 1 at its lower bound (F_1 = 1 >= 0), row 2 free (F_2 = 0). From a
    start near it the min-map picks that piece and lands on the solution in one step."""
    M = np.array([[2.0, 0.0, 1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 2.0]])
    q = np.array([-4.0, 1.0, -2.0])
    fun, jac = _lcp(M, q)
    x_star = np.array([1.0, 0.0, 0.5])
    F_star = fun(x_star)
    assert F_star[0] < 0 and F_star[1] > 0 and F_star[2] == 0.0
    r = newton_min_map(fun, jac, x_star + np.array([-1e-3, 2e-3, 1e-3]), 0.0, 1.0, ENDGAME_TOL)
    assert r.success and r.iterations == 1
    np.testing.assert_allclose(r.x, x_star, atol=ENDGAME_TOL)


def test_min_map_newton_does_not_claim_a_system_without_solution():
    """x1 + x2 = 1 and x1 + x2 = -1: the least-squares step cannot lower the residual (1 at
    best); the endgame says so and reports the true residual, never CONVERGED."""
    fun, jac = _lcp([[1.0, 1.0], [1.0, 1.0]], [-1.0, 1.0])
    r = newton_min_map(fun, jac, [0.3, 0.2], -np.inf, np.inf, ENDGAME_TOL)
    assert r.status is Status.LINE_SEARCH_FAILED and not r.success
    assert r.residual == pytest.approx(_natural_residual(r.x, fun(r.x), -np.inf, np.inf), rel=RTOL_RECOMPUTE)
    assert r.residual >= 1.0 - 1e-12


WATCHDOG_K = 1e4            # the steep row's weight: every shorter step of the first Newton step fails


def _steep(trap=False):
    """F = (K (x2 - x1^2), 1 - x1), solution (1, 1). From (-9, 81) Newton's step (10, -180)
    raises ||F||_inf from 10 to 1e6 at full length and to 244 at 1/64 (the curvature K d1^2 t^2
    beats the linear decrease), but the full step puts x1 = 1 and the next step is exact. trap:
    F2 + 1000 where x1 > 0.5, so no step from there comes back below 10."""
    def fun(x):
        return np.array([WATCHDOG_K * (x[1] - x[0] ** 2), 1.0 - x[0] + (1e3 if trap and x[0] > 0.5 else 0.0)])

    def jac(x):
        return np.array([[-2.0 * WATCHDOG_K * x[0], WATCHDOG_K], [-1.0, 0.0]])
    return fun, jac, np.array([-9.0, 81.0])


def test_min_map_newton_watchdog_takes_a_refused_full_step_that_the_next_step_redeems(monkeypatch):
    """No length of the first step lowers ||r||; the watchdog's full step (W) does not either,
    but the Newton step after it (N) lands on the solution (to round-off, which one more N
    removes). Without the watchdog the endgame
    stops at its start."""
    from implicit_contact import ncp
    fun, jac, x0 = _steep()
    r = newton_min_map(fun, jac, x0, -np.inf, np.inf, ENDGAME_TOL)
    assert r.success and r.steps[:2] == "WN" and r.iterations <= 3      # (a last N for round-off: K = 1e4)
    np.testing.assert_allclose(r.x, [1.0, 1.0], atol=ENDGAME_TOL)
    assert r.merit_history[0] == 10.0 and r.merit_history[1] == pytest.approx(1e6)
    monkeypatch.setattr(ncp, "ENDGAME_WATCHDOG", 0)
    r = newton_min_map(fun, jac, x0, -np.inf, np.inf, ENDGAME_TOL)
    assert r.status is Status.LINE_SEARCH_FAILED and r.steps == "" and np.array_equal(r.x, x0)


def test_min_map_newton_watchdog_that_does_not_redeem_returns_to_the_iterate_before_it():
    """With the trap no step after the watchdog's comes below the residual before it: the
    endgame returns that iterate (the start), its residual and no steps, LINE_SEARCH_FAILED."""
    fun, jac, x0 = _steep(trap=True)
    r = newton_min_map(fun, jac, x0, -np.inf, np.inf, ENDGAME_TOL)
    assert r.status is Status.LINE_SEARCH_FAILED and not r.success
    assert np.array_equal(r.x, x0) and r.residual == 10.0 and r.steps == "" and r.merit_history == (10.0,)
    assert r.nfev > 5                  # (the watchdog's steps were evaluated)


def test_min_map_newton_reports_nan_as_not_finite():
    r = newton_min_map(lambda x: np.array([np.nan]), lambda x: np.ones((1, 1)), [0.0], -np.inf, np.inf, 1e-10)
    assert r.status is Status.NOT_FINITE and not r.success
    def fun(x):
        return np.array([x[0] - 1.0])
    r = newton_min_map(fun, lambda x: np.array([[np.inf]]), [0.0], -np.inf, np.inf, 1e-10)
    assert r.status is Status.NOT_FINITE and r.x[0] == 0.0


def test_sparse_newton_matrix_is_diag_da_plus_diag_db_j_and_its_transposed_product():
    """ncp.sparse_newton_matrix on a CSR pattern with stored zeros, against scipy's products."""
    from implicit_contact import ncp
    rng = np.random.default_rng(11)
    n = 30
    J = (sp.random(n, n, density=0.15, random_state=rng, format="csr") + sp.eye(n, format="csr")).tocsr()
    J.sort_indices()
    J.data[::5] = 0.0                                  # stored zeros stay stored
    da, db, Phi = rng.uniform(0.0, 1.0, n), rng.uniform(-1.0, 1.0, n), rng.standard_normal(n)
    db[::4] = 0.0                                      # rows without J: H's row is its diagonal
    rows = np.repeat(np.arange(n), np.diff(J.indptr))
    diag = np.flatnonzero(J.indices == rows)
    data, g = np.empty(J.nnz), np.empty(n)
    nonzero = ncp.sparse_newton_matrix(J.indptr.astype(np.int64), J.indices.astype(np.int64), J.data, da, db, diag,
                                       Phi, data, g)
    H = (sp.diags(da) + sp.diags(db) @ J).toarray()
    np.testing.assert_allclose(sp.csr_matrix((data, J.indices, J.indptr), shape=(n, n)).toarray(), H, rtol=0, atol=1e-15)
    np.testing.assert_allclose(g, H.T @ Phi, rtol=1e-14, atol=1e-14)
    assert nonzero == np.count_nonzero(data) == np.count_nonzero(H)
