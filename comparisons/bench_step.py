"""Time per step of the implicit stepper against DART's native world.step(), measured in one run.

Question: what does one geometrically implicit step cost, next to DART's own collision + LCP
step on the same scenes?
  * rolling disc (Example 1, h = 0.01): implicit disc vs DART's 1000-gon prism with FCL (the
    configuration of the paper's Fig. 1); goal: implicit <= 0.5 x native.
  * sphere on two spheres (Example 2, h = 0.01): implicit vs DART with SphereShapes; goal: <= 1 ms.
Times are medians over the steps of a run (the first steps, with JIT-like warm-ups of numpy and
dartpy caches, are excluded); the machine is shared, so repeat it and expect up to 2x spread.

Run: python -m comparisons.bench_step [--steps 300]
"""
import argparse
import time

import numpy as np

import implicit_contact as ic
from comparisons import dart_native
from scenes import disc_rolling, sphere_on_two_spheres as spheres

WARMUP = 10


def _median_step(step, n, before=None, world=None):
    times = []
    for k in range(n + WARMUP):
        if before is not None:
            before(world, 0.0)
        t0 = time.perf_counter()
        step()
        if k >= WARMUP:
            times.append(time.perf_counter() - t0)
    return float(np.median(times)), times


def measure(steps: int = 300) -> dict:
    out = {}
    world = disc_rolling.build_world(0.01)
    stepper = ic.ImplicitContactStepper(world)
    out["disc implicit"], _ = _median_step(stepper.step, steps)
    world, _ = dart_native.build_ngon_world(1000, h=0.01, detector="fcl")
    out["disc native 1000-gon FCL"], _ = _median_step(world.step, steps)
    world = spheres.build_world(0.01)
    stepper = ic.ImplicitContactStepper(world)
    ball = world.getSkeleton("ball").getBodyNode(0)
    for name in ("sphere_r10", "sphere_r9"):
        stepper.set_pair_friction(ball, world.getSkeleton("fixed_spheres").getBodyNode(name), spheres.FRICTION)
    out["spheres implicit"], _ = _median_step(stepper.step, min(steps, 300), spheres.push, world)
    world = spheres.build_world(0.01)
    out["spheres native (SphereShapes)"], _ = _median_step(world.step, min(steps, 300), spheres.push, world)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=300)
    args = parser.parse_args(argv)
    m = measure(args.steps)
    print(f"{'configuration':34s} {'median us/step':>15s}")
    for name, t in m.items():
        print(f"{name:34s} {1e6 * t:15.1f}")
    print(f"disc: implicit / native 1000-gon FCL = {m['disc implicit'] / m['disc native 1000-gon FCL']:.2f} "
          "(goal <= 0.5)")
    print(f"spheres: implicit = {1e3 * m['spheres implicit']:.2f} ms per step (goal <= 1 ms); "
          f"implicit / native = {m['spheres implicit'] / m['spheres native (SphereShapes)']:.1f}")


if __name__ == "__main__":
    main()
