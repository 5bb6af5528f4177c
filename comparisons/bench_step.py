"""Time per step of the implicit stepper against DART's native world.step(), interleaved in one run.

Question: what does one geometrically implicit step cost, next to DART's own collision + LCP
step on the same scene? Each scene is built twice, once for each stepper, and the two are
stepped alternately (one implicit step, one native step, ...), so that the machine's drifts in
speed hit both alike; the figures are the medians of the per-step wall times and their ratio.

    scene                                             native configuration            goal (ratio)
    rolling disc, h = 0.01 ([GI] Example 1)           1000-gon prism, FCL             <= 0.5
    sphere on two spheres, h = 0.01 (Example 2)       SphereShapes                    <= 20
    rocking ellipsoid on a plane, h = 2e-3            EllipsoidShape, FCL             <= 20
    27 exponent-4 superquadrics dropped into a        the same layout with BoxShapes  <= 30
      walled box, h = 0.01, steps with contact

The first steps of each run (warm-up: caches, the first coal queries) are left out; on the
superquadric box only the steps in which the implicit step has an active contact count (the
bodies land at about step 10), and the native step of the same index is its partner.

Run: python -m comparisons.bench_step [--steps 400] [--repeat 1] [--order 2]   (StepperOptions.order)
"""
import argparse
import time

import numpy as np

import implicit_contact as ic
from comparisons import dart_native, stability
from scenes import disc_rolling, ellipsoid_rocking
from scenes import sphere_on_two_spheres as spheres

WARMUP = 20
GOALS = {"rolling disc": 0.5, "sphere on two spheres": 20.0, "rocking ellipsoid": 20.0,
         "27 superquadrics in a box": 30.0}


def _disc(options):
    world = disc_rolling.build_world(0.01)
    native, _ = dart_native.build_ngon_world(1000, h=0.01, detector="fcl")
    return ic.ImplicitContactStepper(world, options=options), world, native, None, "DART 1000-gon prism, FCL"


def _spheres(options):
    world = spheres.build_world(0.01)
    stepper = ic.ImplicitContactStepper(world, options=options)
    ball = world.getSkeleton("ball").getBodyNode(0)
    for name in ("sphere_r10", "sphere_r9"):
        stepper.set_pair_friction(ball, world.getSkeleton("fixed_spheres").getBodyNode(name), spheres.FRICTION)
    native = spheres.build_world(0.01)
    before = (lambda: spheres.push(world, 0.0), lambda: spheres.push(native, 0.0))
    return stepper, world, native, before, "DART SphereShapes"


def _ellipsoid(options):
    world = ellipsoid_rocking.build_world(2e-3)
    native = ellipsoid_rocking.build_world(2e-3)
    native.setCollisionDetector(dart_native.make_detector("fcl"))
    return ic.ImplicitContactStepper(world, options=options), world, native, None, "DART EllipsoidShape, FCL"


def _superquadrics(options):
    world = stability.many_bodies_world(27, 0.01, stability.IMPLICIT)
    native = stability.many_bodies_world(27, 0.01, stability.NATIVE)
    return ic.ImplicitContactStepper(world, options=options), world, native, None, "DART BoxShapes, FCL"


SCENES = {"rolling disc": (_disc, None), "sphere on two spheres": (_spheres, None),
          "rocking ellipsoid": (_ellipsoid, None), "27 superquadrics in a box": (_superquadrics, 60)}


def measure(name: str, steps: int, order: int = 1) -> dict:
    """Interleaved per-step wall times of one scene: {implicit, native: median [s], ratio, steps,
    configuration}."""
    make, fixed_steps = SCENES[name]
    stepper, world, native, before, configuration = make(ic.StepperOptions(order=order))
    n = fixed_steps or steps
    ti, tn, contact = [], [], []
    for k in range(n + (0 if fixed_steps else WARMUP)):
        if before is not None:
            before[0]()
        t0 = time.perf_counter()
        report = stepper.step()
        t1 = time.perf_counter()
        if before is not None:
            before[1]()
        t2 = time.perf_counter()
        native.step()
        t3 = time.perf_counter()
        if fixed_steps or k >= WARMUP:
            ti.append(t1 - t0)
            tn.append(t3 - t2)
            contact.append(any(c.p_n > 0.0 for c in report.contacts) if fixed_steps else True)
    keep = np.asarray(contact, bool)
    ti, tn = np.asarray(ti)[keep], np.asarray(tn)[keep]
    mi, mn = float(np.median(ti)), float(np.median(tn))
    return {"implicit": mi, "native": mn, "ratio": mi / mn, "steps": int(keep.sum()), "configuration": configuration}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--repeat", type=int, default=1, help="runs of every scene (each printed)")
    parser.add_argument("--scenes", nargs="+", default=list(SCENES), choices=list(SCENES))
    parser.add_argument("--order", type=int, choices=(1, 2), default=1, help="the implicit stepper's order")
    args = parser.parse_args(argv)
    print(f"{'scene':28s} {'native configuration':26s} {'steps':>5s} {'implicit us':>12s} {'native us':>10s} "
          f"{'ratio':>7s} {'goal':>6s}")
    for _ in range(args.repeat):
        for name in args.scenes:
            m = measure(name, args.steps, args.order)
            goal = GOALS[name]
            print(f"{name:28s} {m['configuration']:26s} {m['steps']:5d} {1e6 * m['implicit']:12.1f} "
                  f"{1e6 * m['native']:10.1f} {m['ratio']:7.2f} {goal:6.1f} {'met' if m['ratio'] <= goal else 'NOT met'}")


if __name__ == "__main__":
    main()
