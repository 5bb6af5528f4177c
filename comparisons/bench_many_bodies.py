"""Time per step of the implicit stepper with many bodies, and how it grows with the contacts.

Question: what does one step cost with 10, 30 and 100 bodies once they land, and how does the
cost grow with the number of active contacts (the stability study's fit t = a n^b; goal b <= 1.2
and <= 50 ms per step with 100 bodies)? The scene is comparisons.stability's many-body case:
exponent-4 superquadrics dropped in layers into a box of five fixed half-spaces, h = 0.01 s; the
first bodies land at about step 10. Every run steps from the same initial state; each step is
timed (wall and CPU time of this process: the machine is shared, CPU time wanders less) and the
table lists the steps with at least one active contact (p_n > 0). DART's own step of the same
layout with BoxShapes (stability.many_bodies_world, NATIVE) is stepped alternately with the
implicit one, so that the two medians and their ratio come from the same minutes of the machine.

--jacobian dense | sparse forces the Jacobian storage of formulation.StepProblem (default: auto,
sparse from formulation.SPARSE_MIN_UNKNOWNS unknowns); --threshold measures the crossover on
the 10- and 30-body steps (one problem per body count, its Jacobian assembled and J + I
factorised both ways).

History (shared 2-core VM, median CPU ms per landed step, steps 10-15):
    Python rows, dense J:                     158 / 1776 / 18924 ms for 10 / 30 / 100 bodies
    sparse J + splu (superquadric kernel):    165 /  389 /  2627
    far pairs left out of the MCP:             65 /  190 /   915, fit t = 0.0089 s n^1.17
    compiled rows and dense solver (issue 12): 16-28 / 42-44 / 208-229, fit t = 0.004-0.008 s n^0.8-1.0;
        DART's native step of the box layout in the same run: 0.38 / 0.63 / 1.7 ms.
    compiled sparse LU, closest-point blocks eliminated first (block_elimination.py), 2026-12-06:
        17-19 / 29-33 / 136-141 (the commit before, alternated: 17-19 / 31-33 / 138-145).
    lean kernels (no reference counts on their views, _jit.lean_kernel), 2026-12-07:
        15-18 / 23 / 101-112 (the commit before, alternated: 16 / 28 / 121-123).
    static closest points of new pairs in one compiled call (closest._single_run), 2026-12-07:
        14.6 / 21.0-23.6 / 82.6-97.5 (5315530, alternated: 18.5 / 24.2-27.1 / 100.6-119.6).
What remains at 100 bodies (steps 11-15, timed per call): ~2-3 solves per landing step (friction
rows switched on) of ~10 Newton iterations, each iteration two compiled assemblies of F and J (~0.7
ms each for ~175 pairs: the line search's trial and the new iterate) and one Newton step (~1.1 ms:
the closest-point blocks eliminated, ~2200 -> ~880 unknowns, 0.36 ms, and their LU, 0.24 ms), ~85
ms of a 138 ms step; the rest is Python around the solves: the layouts rebuilt while pairs keep
changing (~15 ms a layout and its tables), the seeds of new pairs (their static closest points ~0.1
ms each since 2026-12-07), the checks.

Run: python -m comparisons.bench_many_bodies [--bodies 10 30 100] [--steps 16] [--jacobian auto]
"""
import argparse
import math
import time

import numpy as np

import implicit_contact as ic
from implicit_contact import formulation as fm
from comparisons import stability

H = 0.01
STEPS = 16                 # first landings at about step 10
GOAL_100 = 0.050           # [s] per landed step with 100 bodies (issue 12)


def _world(n):
    build = getattr(stability, "many_bodies_world", None) or getattr(stability, "_many_bodies_world")
    return build(n, H, stability.IMPLICIT)


def run(n: int, steps: int = STEPS, native: bool = True) -> list[dict]:
    """Per step: wall [s], cpu [s], candidate pairs, active contacts, unknowns, Newton iterations
    of the implicit step, and (native) the wall time of DART's own step of the same layout with
    BoxShapes, stepped alternately with it."""
    world = _world(n)
    stepper = ic.ImplicitContactStepper(world)
    twin = stability.many_bodies_world(n, H, stability.NATIVE) if native else None
    out = []
    for k in range(steps):
        t0, c0 = time.perf_counter(), time.process_time()
        report = stepper.step()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        native_wall = math.nan
        if twin is not None:
            t1 = time.perf_counter()
            twin.step()
            native_wall = time.perf_counter() - t1
        out.append({"step": k, "wall": wall, "cpu": cpu, "pairs": len(report.contacts),
                    "contacts": sum(1 for c in report.contacts if c.p_n > 0.0), "unknowns": report.unknowns,
                    "iterations": report.iterations, "substeps": report.substeps, "success": report.success,
                    "native": native_wall})
        if not report.success:
            break
    return out


def fit(records: list[dict], key: str = "cpu"):
    """(a, b) of t = a n^b over the steps with contacts solved at the first attempt, or None."""
    pts = [(r["contacts"], r[key]) for r in records if r["contacts"] > 0 and r["substeps"] == 1]
    if len({c for c, _ in pts}) < 2:
        return None
    x, y = np.log([c for c, _ in pts]), np.log([t for _, t in pts])
    b, log_a = np.polyfit(x, y, 1)
    return math.exp(log_a), b


def threshold(bodies=(10, 30), steps=STEPS):
    """Jacobian assembly + one LU, dense vs sparse, on the last step's problem of each run."""
    import scipy.linalg as la
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla
    from implicit_contact import stepper as stepper_mod
    rows = []
    captured = {}
    original = stepper_mod.ImplicitContactStepper._solve

    def capture(self, problem, z0):
        captured["args"] = problem, z0
        return original(self, problem, z0)

    stepper_mod.ImplicitContactStepper._solve = capture
    try:
        for n in bodies:
            run(n, steps, native=False)
            problem, z0 = captured["args"]
            for mode in ("dense", "sparse"):
                p = fm.StepProblem(problem.h, problem.skeletons, problem.bodies, problem.specs, problem.layout,
                                   problem.supports, jacobian=mode)
                best = math.inf
                for _ in range(5):
                    t0 = time.process_time()
                    J = p._assemble(z0, True)[1]
                    # the Newton matrix diag(da) + diag(db) J has J's pattern and a full diagonal
                    # (J itself can be singular at a complementary start): factorise J + I
                    if mode == "dense":
                        la.lu_factor(J + np.eye(J.shape[0]))
                    else:
                        spla.splu((J + sp.identity(J.shape[0], format="csr")).tocsc())
                    best = min(best, time.process_time() - t0)
                rows.append((n, problem.layout.n, mode, best))
    finally:
        stepper_mod.ImplicitContactStepper._solve = original
    return rows


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bodies", type=int, nargs="+", default=[10, 30, 100])
    parser.add_argument("--steps", type=int, default=STEPS)
    parser.add_argument("--jacobian", choices=("auto", "dense", "sparse"), default="auto")
    parser.add_argument("--threshold", action="store_true")
    parser.add_argument("--no-native", action="store_true", help="time the implicit stepper alone")
    args = parser.parse_args(argv)
    if args.threshold:
        print(f"{'bodies':>6s} {'unknowns':>8s} {'jacobian':>8s} {'J + LU [ms]':>11s}")
        for n, nz, mode, t in threshold(steps=args.steps):
            print(f"{n:6d} {nz:8d} {mode:>8s} {1e3 * t:11.1f}")
        return
    if args.jacobian != "auto":
        fm.SPARSE_MIN_UNKNOWNS = 0 if args.jacobian == "sparse" else 10 ** 12
    every = []
    print(f"{'bodies':>6s} {'step':>4s} {'pairs':>5s} {'contacts':>8s} {'unknowns':>8s} {'iter':>4s} "
          f"{'wall ms':>8s} {'cpu ms':>8s} {'native ms':>9s}")
    summary = []
    for n in args.bodies:
        records = run(n, args.steps, native=not args.no_native)
        every += records
        for r in records:
            if r["contacts"] > 0:
                print(f"{n:6d} {r['step']:4d} {r['pairs']:5d} {r['contacts']:8d} {r['unknowns']:8d} "
                      f"{r['iterations']:4d} {1e3 * r['wall']:8.1f} {1e3 * r['cpu']:8.1f} {1e3 * r['native']:9.2f}")
        free = [r["cpu"] for r in records if r["contacts"] == 0 and r["pairs"] > 0]
        landed = [r for r in records if r["contacts"] > 0]
        summary.append((n, np.median(free) if free else math.nan,
                        np.median([r["wall"] for r in landed]) if landed else math.nan,
                        np.median([r["cpu"] for r in landed]) if landed else math.nan,
                        np.median([r["native"] for r in landed]) if landed else math.nan,
                        max((r["contacts"] for r in records), default=0),
                        max((r["unknowns"] for r in records), default=0)))
    print("\nmedians over the steps with contacts (native: DART's step of the same layout with BoxShapes, "
          "stepped alternately)")
    print(f"{'bodies':>6s} {'free fall cpu ms':>16s} {'landed wall ms':>14s} {'landed cpu ms':>13s} "
          f"{'native ms':>9s} {'ratio':>6s} {'contacts':>8s} {'unknowns':>8s}  goal")
    for n, free, wall, cpu, native, contacts, unknowns in summary:
        goal = ""
        if n == 100:
            goal = f"<= {1e3 * GOAL_100:.0f} ms: {'met' if wall <= GOAL_100 else 'NOT met'}"
        print(f"{n:6d} {1e3 * free:16.1f} {1e3 * wall:14.1f} {1e3 * cpu:13.1f} {1e3 * native:9.2f} "
              f"{wall / native:6.0f} {contacts:8d} {unknowns:8d}  {goal}")
    ab = fit(every)
    if ab is not None:
        a, b = ab
        print(f"fit over the steps with contacts: t = {a:.4f} s * n_contacts^{b:.2f} (CPU time; goal b <= 1.2: "
              f"{'met' if b <= 1.2 else 'NOT met'})")


if __name__ == "__main__":
    main()
