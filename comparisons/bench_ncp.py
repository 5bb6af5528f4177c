"""How fast and how reliably does solve_mcp solve standard MCPs and monotone LCPs?

Question: on the published test problems (comparisons/mcp_problems.py, several starts each) and on
random monotone LCPs (M = A A^T + 0.01 I + skew part; dense n = 10, 50, 200 and banded sparse
n = 2000), what status, how many iterations and what time per solve does solve_mcp reach, and
what does one call cost beyond the user's fun / jac (the stepper calls it every time step)?

A solve counts as solved when the status is CONVERGED and x is within the problem's tolerance of
the independently known solution (published, by construction, or Lemke's pivoting for dense LCPs
with n <= 200); the large sparse LCPs have no oracle and are checked by the natural residual.

Run: python -m comparisons.bench_ncp      (about a minute on one core)
"""
from __future__ import annotations

import statistics
import time

import numpy as np

from comparisons.mcp_problems import lemke, random_monotone_lcp_data, standard_problems
from implicit_contact.ncp import SolverOptions, solve_mcp

MIN_REPEATS = 5          # timing: at least this many solves ...
MIN_TIMING_SECONDS = 0.05  # ... and at least this long per row; the median is reported
ATOL_LEMKE = 1e-8        # agreement with Lemke's solution (P-matrix: unique solution)


def _time(solve):
    times = []
    start = time.perf_counter()
    while len(times) < MIN_REPEATS or time.perf_counter() - start < MIN_TIMING_SECONDS:
        t0 = time.perf_counter()
        solve()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _row(problem, start, result, seconds, solved):
    return (f"{problem:<22} {start:<8} {result.status.value:<19} {result.iterations:>4} "
            f"{result.nfev:>5} {result.residual:>9.1e} {seconds * 1e3:>10.3f}  "
            f"{'yes' if solved else 'NO'}")


HEADER = (f"{'problem':<22} {'start':<8} {'status':<19} {'iter':>4} {'nfev':>5} "
          f"{'residual':>9} {'ms/solve':>10}  solved")


def standard_set():
    rows, solved = [], []
    for p in standard_problems():
        for label, x0 in p.starts:
            result = solve_mcp(p.fun, p.jac, x0, p.lower, p.upper)
            ok = result.success and p.distance(result.x) <= p.solution_atol
            seconds = _time(lambda: solve_mcp(p.fun, p.jac, x0, p.lower, p.upper))
            rows.append(_row(p.name, label, result, seconds, ok))
            solved.append(ok)
    return rows, solved


def random_lcps():
    rows, solved = [], []
    cases = [(n, seed, False) for n in (10, 50, 200) for seed in (1, 2, 3)]
    cases += [(2000, seed, True) for seed in (1, 2)]
    for n, seed, sparse in cases:
        M, q = random_monotone_lcp_data(n, seed, sparse=sparse)

        def fun(x, M=M, q=q):
            return M @ x + q

        def jac(x, M=M):
            return M

        x0 = np.zeros(n)
        result = solve_mcp(fun, jac, x0, 0.0, np.inf)
        if sparse:
            ok = result.success
        else:
            ok = result.success and np.abs(result.x - lemke(M, q)).max() <= ATOL_LEMKE
        seconds = _time(lambda: solve_mcp(fun, jac, x0, 0.0, np.inf))
        name = f"lcp_{'sparse' if sparse else 'dense'}_{n}_s{seed}"
        rows.append(_row(name, "0", result, seconds, ok))
        solved.append(ok)
    return rows, solved


def overhead():
    """Per-call cost beyond fun / jac on n = 11: at the solution, and per iteration."""
    n = 11
    M, q = random_monotone_lcp_data(n, 5)
    lines = []
    for kind, lo, hi in (("NCP rows", np.zeros(n), np.full(n, np.inf)),
                         ("3 free + 5 NCP + 3 box rows",
                          np.r_[np.full(3, -np.inf), np.zeros(8)],
                          np.r_[np.full(8, np.inf), np.ones(3)])):
        def fun(x):
            return M @ x + q

        def jac(x):
            return M

        options = SolverOptions()
        solution = solve_mcp(fun, jac, np.zeros(n), lo, hi, options)
        x_star = solution.x

        def best(call, number=200, repeat=15):
            runs = []
            for _ in range(repeat):
                t0 = time.perf_counter()
                for _ in range(number):
                    call()
                runs.append((time.perf_counter() - t0) / number)
            return min(runs)

        at_solution = best(lambda: solve_mcp(fun, jac, x_star, lo, hi, options))
        cold = solve_mcp(fun, jac, np.zeros(n), lo, hi, options)
        total = best(lambda: solve_mcp(fun, jac, np.zeros(n), lo, hi, options), number=50)
        user = best(lambda: fun(x_star), number=2000) * cold.nfev + \
            best(lambda: jac(x_star), number=2000) * cold.njev
        per_iteration = (total - user - at_solution) / cold.iterations
        lines.append(f"n = 11, {kind}: start at the solution {at_solution * 1e6:.1f} us "
                     f"({solution.status.value} there: 0 iterations); from x0 = 0 "
                     f"{cold.iterations} iterations, {total * 1e6:.0f} us, "
                     f"{per_iteration * 1e6:.1f} us per iteration beyond fun/jac")
    return lines


def main():
    print(__doc__.split("\n\n")[1])
    print()
    print(HEADER)
    rows, solved = standard_set()
    print("\n".join(rows))
    print()
    print(HEADER)
    lcp_rows, lcp_solved = random_lcps()
    print("\n".join(lcp_rows))
    print()
    print("\n".join(overhead()))
    total = solved + lcp_solved
    print(f"\nsolved fraction: {sum(total)}/{len(total)} = {sum(total) / len(total):.1%} "
          f"(standard set {sum(solved)}/{len(solved)}, random LCPs {sum(lcp_solved)}/"
          f"{len(lcp_solved)})")


if __name__ == "__main__":
    main()
