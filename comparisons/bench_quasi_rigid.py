"""The quasi-rigid drop of [GI] Example 3: cost per step, and energy per bounce of both schemes.

Questions:
  * what does a step cost (Newton iterations, wall time) in the two runs of Example 3
    (delta_max = 0.05: the core is hit; delta_max = 1: it is not), h = 1e-4?
  * how much total energy (kinetic + gravity + spring) does one bounce lose with the printed
    scheme (eq 49: spring at the end of the step, backward Euler) and with the midpoint variant,
    at h = 1e-3 and 1e-4? One bounce = from the release at rest to the next apex, where v_y
    changes sign from + to - in flight.
  * what does each scheme do at the hard hit on the rigid core (delta_max = 0.05)? Analytic: a
    plastic stop leaves m g (r - 0.05) + k 0.05^2 / 2 = 10.5695 J.

Run: python -m comparisons.bench_quasi_rigid
"""
import time

import numpy as np

from scenes import disc_on_quasi_rigid_plane as scene


def cost(delta_max, h=1e-4, duration=0.45):
    t0 = time.perf_counter()
    rec = scene.simulate(delta_max, duration=duration, h=h)
    wall = time.perf_counter() - t0
    contact = np.array([bool(r.contacts) and r.contacts[0].p_n > 0 for r in rec.traj.reports])
    it = rec.traj.iterations
    sec = rec.traj.step_seconds
    return {"steps": len(it), "contact steps": int(contact.sum()),
            "iterations in contact (mean/max)": f"{it[contact].mean():.2f} / {it[contact].max()}",
            "us per contact step (median)": 1e6 * float(np.median(sec[contact])),
            "us per flight step (median)": 1e6 * float(np.median(sec[~contact])), "wall s": wall}


def energy_per_bounce(scheme, h, delta_max=1.0):
    rec = scene.simulate(delta_max, duration=0.8, h=h, scheme=scheme)
    # the first apex after the bounce: v_y turns from + to - while out of contact
    flying = rec.p_spring == 0
    turn = np.nonzero((rec.vy[:-1] > 0) & (rec.vy[1:] <= 0) & flying[1:])[0]
    k = turn[0] + 1
    return rec.energy[k] - rec.energy[0], rec


def main():
    print("Cost per step, h = 1e-4, scheme 'paper'")
    for dm in (0.05, 1.0):
        c = cost(dm)
        print(f"  delta_max = {dm}: " + ", ".join(f"{k} {v:.1f}" if isinstance(v, float) else f"{k} {v}"
                                                  for k, v in c.items()))
    print("\nTotal energy change over one bounce (release at rest -> next apex), delta_max = 1 [J]")
    print(f"  {'h':>8} {'paper':>12} {'midpoint':>12}")
    for h in (1e-3, 1e-4):
        paper, _ = energy_per_bounce("paper", h)
        mid, _ = energy_per_bounce("midpoint", h)
        print(f"  {h:8.0e} {paper:12.3e} {mid:12.3e}")
    print("\nThe hard hit on the core, delta_max = 0.05, h = 1e-4 (analytic after a plastic stop: "
          f"{scene.energy_after_core_hit(0.05):.4f} J)")
    for scheme in ("paper", "midpoint"):
        rec = scene.simulate(0.05, duration=0.40, h=1e-4, scheme=scheme)
        k = scene.core_episode_end(rec.p_core)
        print(f"  {scheme:9s} energy after the hit {rec.energy[k]:.4f} J, v_y after it {rec.vy[k]:+.4f} m/s, "
              f"energy at 0.40 s {rec.energy[-1]:.4f} J")


if __name__ == "__main__":
    main()
