"""The quasi-rigid drop of [GI] Example 3: cost per step, and energy per bounce of both schemes and
of order 2.

Questions:
  * what does a step cost (Newton iterations, wall time) in the two runs of Example 3
    (delta_max = 0.05: the core is hit; delta_max = 1: it is not), h = 1e-4?
  * how much total energy (kinetic + gravity + spring) does one bounce lose with the printed
    scheme (eq 49: spring at the end of the step, backward Euler), with the midpoint variant and
    with StepperOptions(order=2) (rattle.py, R11-R14), at h = 1e-3 and 1e-4? One bounce = from the release at rest to the next apex, where v_y
    changes sign from + to - in flight.
  * what does each do at the hard hit on the rigid core (delta_max = 0.05)? Analytic: a
    plastic stop leaves m g (r - 0.05) + k 0.05^2 / 2 = 10.5695 J.

Run: python -m comparisons.bench_quasi_rigid
"""
import time

import numpy as np

from scenes import disc_on_quasi_rigid_plane as scene


def cost(delta_max, h=1e-4, duration=0.45, order=1):
    t0 = time.perf_counter()
    rec = scene.simulate(delta_max, duration=duration, h=h, order=order)
    wall = time.perf_counter() - t0
    contact = np.array([bool(r.contacts) and r.contacts[0].p_n > 0 for r in rec.traj.reports])
    it = rec.traj.iterations
    sec = rec.traj.step_seconds
    return {"steps": len(it), "contact steps": int(contact.sum()),
            "iterations in contact (mean/max)": f"{it[contact].mean():.2f} / {it[contact].max()}",
            "us per contact step (median)": 1e6 * float(np.median(sec[contact])),
            "us per flight step (median)": 1e6 * float(np.median(sec[~contact])), "wall s": wall}


RUNS = (("paper", 1), ("midpoint", 1), ("paper", 2))   # (scheme, order); order 2 takes its own layer rule


def _label(scheme, order):
    return scheme if order == 1 else "order 2"


def energy_per_bounce(scheme, h, delta_max=1.0, order=1):
    rec = scene.simulate(delta_max, duration=0.8, h=h, scheme=scheme, order=order)
    # the first apex after the bounce: v_y turns from + to - while out of contact
    flying = rec.p_spring == 0
    turn = np.nonzero((rec.vy[:-1] > 0) & (rec.vy[1:] <= 0) & flying[1:])[0]
    k = turn[0] + 1
    return rec.energy[k] - rec.energy[0], rec


def main():
    print("Cost per step, h = 1e-4, scheme 'paper' and order 2")
    for dm, order in ((0.05, 1), (1.0, 1), (0.05, 2), (1.0, 2)):
        c = cost(dm, order=order)
        print(f"  order {order}, delta_max = {dm}: " + ", ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}"
                                                  for k, v in c.items()))
    print("\nTotal energy change over one bounce (release at rest -> next apex), delta_max = 1 [J]")
    print(f"  {'h':>8} " + " ".join(f"{_label(*run):>12}" for run in RUNS))
    for h in (1e-3, 1e-4):
        print(f"  {h:8.0e} " + " ".join(f"{energy_per_bounce(s, h, order=o)[0]:12.3e}" for s, o in RUNS))
    print("\nThe hard hit on the core, delta_max = 0.05, h = 1e-4 (analytic after a plastic stop: "
          f"{scene.energy_after_core_hit(0.05):.4f} J)")
    for scheme, order in RUNS:
        rec = scene.simulate(0.05, duration=0.40, h=1e-4, scheme=scheme, order=order)
        k = scene.core_episode_end(rec.p_core)
        print(f"  {_label(scheme, order):9s} energy after the hit {rec.energy[k]:.4f} J, v_y after it {rec.vy[k]:+.4f} m/s, "
              f"energy at 0.40 s {rec.energy[-1]:.4f} J")


if __name__ == "__main__":
    main()
