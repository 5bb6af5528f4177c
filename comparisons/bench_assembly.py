"""Cost of one evaluation of the step residual F (``fun``) and of F with its Jacobian J, per pair.

Question: how many microseconds do ``StepProblem.fun`` and ``StepProblem.jac`` take for one
contact pair? The Newton solver calls them several times per step, so they bound the
stepper's speed (goal: < 60 us for J and < 25 us for F on a 3D sphere pair with friction and
torsion; < 30 / < 15 us on the 2D disc pair; the numbers below are on a shared 2-core VM).
Problems are built the way tests/test_formulation.py builds them (random poses, masses and a
random z with positive multipliers), one pair each:
  * 2D disc (planar) on a fixed half-plane, friction              (Example 1's pair)
  * 3D fixed sphere (body 1) and free sphere, friction + torsion   (Example 2's pairs)
  * 3D free ellipsoid on a free box (an intersection of 6 planes), friction + torsion
Columns: fun = F alone; jac = F and J from scratch (``_assemble(z, True)``); fun+jac = the
solver's pattern, F at a point and then J at the same point (jac then finishes the evaluations
fun left suspended). Times are CPU time of this thread, the best batch over rounds that
interleave cases and modules (the machine is shared: medians wander by 2x under load).

Run: python -m comparisons.bench_assembly [--repeat 16000] [--baseline FILE_OR_GIT_REVISION]
``--baseline`` also times another version of implicit_contact/formulation.py on the same
problems, e.g. ``--baseline 85fccb5`` (the code before the assembly was optimised).
"""
import argparse
import importlib.util
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from implicit_contact import formulation as fm
from implicit_contact.testing import random_pair_problem
from implicit_contact import shapes as shp
from implicit_contact.params import Friction

H = 0.01

# fun, jac, fun+jac (us) of the code before the assembly was optimised (85fccb5), measured with
# --baseline 85fccb5 next to the optimised code (15.3, 44.1, 45.5 / 22.5, 69.5, 71.0 / 36.0,
# 126.2, 128.7); printed when no --baseline is given.
BEFORE = {
    "2D disc / half-plane, friction": (61.9, 144.6, 210.0),
    "3D fixed sphere / free sphere, friction+torsion": (107.2, 228.0, 345.9),
    "3D free ellipsoid / free box, friction+torsion": (168.3, 423.8, 607.4),
}

CASES = {
    "2D disc / half-plane, friction":
        (2, ("planar", "fixed"), shp.Disc(1.0), shp.HalfPlane([0.0, 1.0], 0.0), True, Friction(0.4)),
    "3D fixed sphere / free sphere, friction+torsion":
        (3, ("fixed", "free"), shp.Sphere(10.0), shp.Sphere(1.0), False, Friction(0.2, 1.0, 1.0, 0.3)),
    "3D free ellipsoid / free box, friction+torsion":
        (3, ("free", "free"), shp.Ellipsoid([1.0, 0.5, 0.7]), shp.Intersection.box([0.3, 0.2, 0.1]), False,
         Friction(0.3, 1.0, 0.8, 0.2)),
}


def build(fm, case, seed=0):
    """(problem, z) for one case, as in tests/test_formulation.py."""
    dim, kinds, piece1, piece2, fixed2, friction = case
    return random_pair_problem(dim, kinds, piece1, piece2, friction, np.random.default_rng(seed), H, fixed2, fm)


def _us_per_call(f, calls, batch=10):
    """Per-call CPU time of this thread: the best batch of `batch` calls (as timeit advises)."""
    best = np.inf
    for _ in range(max(calls // batch, 1)):
        t0 = time.thread_time_ns()
        for _ in range(batch):
            f()
        best = min(best, (time.thread_time_ns() - t0) / batch)
    return 1e-3 * best


def _fun_then_jac(problem, z):
    """The solver's pattern: F at a point, then J at the same point (caches cleared first)."""
    problem._key_f = problem._key_j = None
    problem.fun(z)
    problem.jac(z)


def measure(modules, repeat, rounds=8):
    """{module index: {case: (fun us, jac us, fun + jac us)}}; jac is a full _assemble(z, True).
    The machine is shared: thread time leaves out waits for a core, and the minimum over rounds
    that interleave all cases and modules leaves out the stretches slowed down by neighbours
    (medians wander by 2x under load)."""
    problems = [{name: build(mod, case) for name, case in CASES.items()} for mod in modules]
    calls = (lambda p, z: p._assemble(z, False), lambda p, z: p._assemble(z, True), _fun_then_jac)
    for probs in problems:                      # warm-up (caches, first-call work)
        for problem, z in probs.values():
            for _ in range(20):
                for call in calls:
                    call(problem, z)
    best = [{name: [np.inf] * len(calls) for name in CASES} for _ in modules]
    for _ in range(rounds):
        for m, probs in enumerate(problems):
            for name, (problem, z) in probs.items():
                for j, call in enumerate(calls):
                    t = _us_per_call(lambda: call(problem, z), repeat // rounds)
                    best[m][name][j] = min(best[m][name][j], t)
    return [{name: tuple(v) for name, v in b.items()} for b in best]


def _load(path_or_revision):
    """formulation.py from a file or a git revision, loaded inside the package."""
    path = path_or_revision
    if not os.path.exists(path):
        root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
        text = subprocess.run(["git", "show", f"{path_or_revision}:implicit_contact/formulation.py"],
                              cwd=root, check=True, capture_output=True, text=True).stdout
        with tempfile.NamedTemporaryFile("w", suffix=".py", delete=False) as f:
            f.write(text)
        path = f.name
    spec = importlib.util.spec_from_file_location("implicit_contact._formulation_baseline", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod           # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=16000)
    parser.add_argument("--baseline", default=None,
                        help="another formulation.py (a file or a git revision) to time as well")
    args = parser.parse_args(argv)
    mods = [fm] + ([_load(args.baseline)] if args.baseline else [])
    res = measure(mods, args.repeat)
    now, base = res[0], (res[1] if args.baseline else None)
    label = f"{args.baseline}:" if args.baseline else "before:"
    print(f"{'one-pair problem, us per call':48s} {'fun':>7s} {'jac':>7s} {'fun+jac':>8s}   "
          f"{label:>8s} {'fun':>7s} {'jac':>7s} {'fun+jac':>8s}")
    fmt = lambda t: f"{t:7.1f}" if t is not None else f"{'-':>7s}"
    for name, (tf, tj, tfj) in now.items():
        bf, bj, bfj = base[name] if base else BEFORE[name]
        print(f"{name:48s} {tf:7.1f} {tj:7.1f} {tfj:8.1f}   {'':8s} {fmt(bf)} {fmt(bj)} {fmt(bfj):>8s}")
    print("fun: F alone; jac: F and J from scratch (_assemble(z, True)); fun+jac: the solver's "
          "pattern, F at a point then J there")


if __name__ == "__main__":
    main()
