"""Time per step of the implicit stepper with many bodies, and how it grows with the contacts.

Question: what does one step cost with 10, 30 and 100 bodies once they land, and how does the
cost grow with the number of active contacts (the stability study's fit t = a n^b; goal b <= 1.2
and <= 50 ms per step with 100 bodies)? The scene is comparisons.stability's many-body case:
exponent-4 superquadrics dropped in layers into a box of five fixed half-spaces, h = 0.01 s; the
first bodies land at about step 10. Every run steps from the same initial state; each step is
timed (wall and CPU time of this process: the machine is shared, CPU time wanders less) and the
table lists the steps with at least one active contact (p_n > 0).

--jacobian dense | sparse forces the Jacobian storage of formulation.StepProblem (default: auto,
sparse from formulation.SPARSE_MIN_UNKNOWNS unknowns); --threshold measures the crossover on
the 10- and 30-body steps (one problem per body count, its Jacobian factorised both ways).

Measured (shared 2-core VM, steps 10-15, median CPU ms per step with contacts; the runs take
the same Newton paths, contacts and unknowns both ways):
    bodies  contacts  unknowns   dense J + dense LU   sparse J + splu, superquadric kernel
        10       4-9   283-349                  158                  165 (dense below 250 unknowns)
        30      5-17   748-869                 1776                  389
       100     17-67  2737-3333               18924                 2627   (free fall: 1770 -> 359)
    fit t = a n_contacts^b: before 0.0096 s n^1.88, after 0.0212 s n^1.18 (CPU time).
Then pairs that cannot close within the step left out of the MCP (StepperOptions.skip_far_pairs;
same trajectories): 100 bodies ~175 instead of ~290 pairs per landing step; median CPU ms per
landed step 65 / 190 / 915 for 10 / 30 / 100 bodies (free fall 11 / 25 / 79), fit
t = 0.0089 s n^1.17.
What remains is Python per pair: ~175 pairs x ~30 Newton iterations per step (two solves: the
stepper re-solves after switching friction rows on) x ~0.2 ms per pair and iteration.

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


def _world(n):
    build = getattr(stability, "many_bodies_world", None) or getattr(stability, "_many_bodies_world")
    return build(n, H, stability.IMPLICIT)


def run(n: int, steps: int = STEPS) -> list[dict]:
    """Per step: wall [s], cpu [s], candidate pairs, active contacts, unknowns, Newton iterations."""
    world = _world(n)
    stepper = ic.ImplicitContactStepper(world)
    out = []
    for k in range(steps):
        t0, c0 = time.perf_counter(), time.process_time()
        report = stepper.step()
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        out.append({"step": k, "wall": wall, "cpu": cpu, "pairs": len(report.contacts),
                    "contacts": sum(1 for c in report.contacts if c.p_n > 0.0), "unknowns": report.unknowns,
                    "iterations": report.iterations, "substeps": report.substeps, "success": report.success})
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
            run(n, steps)
            problem, z0 = captured["args"]
            for mode in ("dense", "sparse"):
                p = fm.StepProblem(problem.h, problem.skeletons, problem.bodies, problem.specs, problem.layout,
                                   problem.supports, jacobian=mode)
                best = math.inf
                for _ in range(5):
                    t0 = time.process_time()
                    J = p._assemble(z0, True)[1]
                    if mode == "dense":
                        la.lu_factor(J)
                    else:
                        spla.splu(J.tocsc())
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
          f"{'wall ms':>8s} {'cpu ms':>8s}")
    summary = []
    for n in args.bodies:
        records = run(n, args.steps)
        every += records
        for r in records:
            if r["contacts"] > 0:
                print(f"{n:6d} {r['step']:4d} {r['pairs']:5d} {r['contacts']:8d} {r['unknowns']:8d} "
                      f"{r['iterations']:4d} {1e3 * r['wall']:8.1f} {1e3 * r['cpu']:8.1f}")
        free = [r["cpu"] for r in records if r["contacts"] == 0 and r["pairs"] > 0]
        landed = [r for r in records if r["contacts"] > 0]
        summary.append((n, np.median(free) if free else math.nan,
                        np.median([r["cpu"] for r in landed]) if landed else math.nan,
                        max((r["contacts"] for r in records), default=0),
                        max((r["unknowns"] for r in records), default=0)))
    print(f"\n{'bodies':>6s} {'free fall cpu ms':>16s} {'landed cpu ms':>13s} {'contacts':>8s} {'unknowns':>8s}")
    for n, free, landed, contacts, unknowns in summary:
        print(f"{n:6d} {1e3 * free:16.1f} {1e3 * landed:13.1f} {contacts:8d} {unknowns:8d}")
    ab = fit(every)
    if ab is not None:
        a, b = ab
        print(f"fit over the steps with contacts: t = {a:.4f} s * n_contacts^{b:.2f} (CPU time; goal b <= 1.2)")


if __name__ == "__main__":
    main()
