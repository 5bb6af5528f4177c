"""A rigid unit disc dropped on a quasi-rigid half-plane ([GI] Sec. 6.3, Example 3, Figs. 7 and 8).

The half-plane y <= 0 has a compliant layer: a frictionless, undamped linear spring (k = 1000 N/m)
over a rigid core at depth delta_max. The disc (m = 1, I = 0.5) is released at rest with its centre
at y = 1.5 and h = 1e-4.

What to look for, against the analytic solution (printed beside the simulation):
  * contact starts at t0 = sqrt(2 * 0.5 / g) = 0.319275 s with speed g t0 = 3.132092 m/s;
  * delta_max = 0.05: the deflection reaches the core at t = 0.335542 s; the core's impulse stops
    the disc (a plastic hit), after which the total energy (kinetic + gravity + spring) is exactly
    m g (1 - 0.05) + k 0.05^2 / 2 = 10.5695 J and the disc bounces on the undamped spring;
  * delta_max = 1: the core is never touched; the deflection peaks at 0.109340 at t = 0.372070 s
    and the disc leaves the layer at t = 0.424865 s.
With the paper's scheme (eq 49, spring at the end of the step) the total energy drifts down by
about h/2 (g^2 t_flight + k^2 A^2 tau) per bounce; the "midpoint" scheme keeps it (see README).

Run: python -m scenes.disc_on_quasi_rigid_plane [--scheme paper|midpoint] [--h 1e-4] [--duration 1] [--animate]
"""
import argparse
import math
from dataclasses import dataclass
from pathlib import Path

import dartpy as dart
import numpy as np

import implicit_contact as ic
from implicit_contact.trajectory import Trajectory, simulate as run

# 1. Parameters (SI units)
RADIUS, MASS, INERTIA = 1.0, 1.0, 0.5
G = 9.81
K = 1000.0                  # [N/m]
Y0 = 1.5                    # release height of the centre [m]
H = 1e-4


# The analytic solution ------------------------------------------------------------------------
T_CONTACT = math.sqrt(2 * (Y0 - RADIUS) / G)          # 0.319275 s
V_CONTACT = G * T_CONTACT                              # 3.132092 m/s
OMEGA = math.sqrt(K / MASS)


def analytic_deflection(t):
    """Deflection of the layer without a core, while in contact (0 before)."""
    tau = np.maximum(np.asarray(t, float) - T_CONTACT, 0.0)
    return (G / OMEGA**2) * (1 - np.cos(OMEGA * tau)) + (V_CONTACT / OMEGA) * np.sin(OMEGA * tau)


def analytic_events(delta_max):
    """Times of: contact, the core hit (nan if none), the peak deflection and its value, release."""
    # delta(tau) = d is solved by bisection on the rising branch (exact to round-off)
    def first_time(d, lo, hi):
        f = lambda t: float(analytic_deflection(t)) - d
        for _ in range(200):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if f(mid) < 0 else (lo, mid)
        return 0.5 * (lo + hi)
    # d delta / d tau = (g/w) sin(w tau) + v0 cos(w tau) = 0
    t_peak = T_CONTACT + (math.pi - math.atan2(V_CONTACT * OMEGA, G)) / OMEGA
    peak = float(analytic_deflection(t_peak))
    t_core = first_time(delta_max, T_CONTACT, t_peak) if delta_max < peak else math.nan
    # release: the deflection returns to zero after the peak
    lo, hi = t_peak, t_peak + math.pi / OMEGA
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if analytic_deflection(mid) > 0 else (lo, mid)
    return {"contact": T_CONTACT, "core": t_core, "peak_time": t_peak, "peak": peak, "release": 0.5 * (lo + hi)}


def core_episode_end(p_core):
    """Index of the last step of the first core hit: a plastic stop takes two steps with
    backward Euler positions (the core's impulse stops the disc at delta_max by the end of a
    step, then cancels the remaining velocity), and the energy "right after the hit" is there."""
    hit = np.nonzero(p_core > 0)[0]
    if len(hit) == 0:
        return None
    k = hit[0]
    while k + 1 < len(p_core) and p_core[k + 1] > 0:
        k += 1
    return k


def energy_after_core_hit(delta_max):
    """Plastic stop on the core: v = 0 at y = r - delta_max; gravity + spring energy."""
    return MASS * G * (RADIUS - delta_max) + 0.5 * K * delta_max**2


# 2. Build the DART world
def build_world(delta_max: float, h: float = H, scheme: str = "paper", damping: float = 0.0, k: float = K):
    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity([0.0, -G, 0.0])
    disc = dart.dynamics.Skeleton("disc")
    joint, body = disc.createPlanarJointAndBodyNodePair()
    joint.setXYPlane()
    body.setName("disc")
    body.setMass(MASS)
    body.setMomentOfInertia(INERTIA / 2, INERTIA / 2, INERTIA)
    ic.attach(body, ic.shapes.Disc(RADIUS))                       # rigid, frictionless
    disc.setPositions([0.0, Y0, 0.0])
    ground = dart.dynamics.Skeleton("ground")
    _, gbody = ground.createWeldJointAndBodyNodePair()
    gbody.setName("ground")
    ic.attach(gbody, ic.shapes.HalfPlane([0.0, 1.0], 0.0),
              compliance=ic.Compliance(k=k, c=damping, delta_max=delta_max, scheme=scheme))
    world.addSkeleton(disc)
    world.addSkeleton(ground)
    return world


# 3. Step it
@dataclass
class Record:
    """Per step: the trajectory and the contact's spring and core impulses [N s], deflection [m],
    and total energy [J] (kinetic + gravity + spring)."""
    traj: Trajectory
    t: np.ndarray
    y: np.ndarray
    vy: np.ndarray
    p_spring: np.ndarray
    p_core: np.ndarray
    deflection: np.ndarray
    energy: np.ndarray


def simulate(delta_max: float, duration: float = 1.0, h: float = H, scheme: str = "paper",
             damping: float = 0.0, k: float = K, order: int = 1) -> Record:
    """order: StepperOptions.order (2: the split step, whose layer takes the midpoint rule
    whatever the scheme, implicit_contact/rattle.py)."""
    world = build_world(delta_max, h, scheme, damping, k)
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order))
    traj = run(world, stepper, duration)
    t, q, v, ke = traj.arrays()
    ps, pc, dn = [0.0], [0.0], [0.0]
    for rep in traj.reports:
        c = rep.contacts[0] if rep.contacts else None
        ps.append(c.p_spring if c else 0.0)
        pc.append(c.p_core if c else 0.0)
        dn.append(c.deflection if c else 0.0)
    dn = np.array(dn)
    energy = ke + MASS * G * q[:, 1] + 0.5 * k * dn**2
    return Record(traj, t, q[:, 1], v[:, 1], np.array(ps), np.array(pc), dn, energy)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--h", type=float, default=H)
    parser.add_argument("--duration", type=float, default=1.0)
    parser.add_argument("--scheme", choices=ic.params.SCHEMES, default="paper")
    parser.add_argument("--animate", action="store_true", help="also write scenes/out/<name>.gif")
    args = parser.parse_args(argv)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = Path(__file__).resolve().parent / "out"
    out.mkdir(exist_ok=True)
    for delta_max, fig_name in ((0.05, "Fig. 7"), (1.0, "Fig. 8")):
        rec = simulate(delta_max, args.duration, args.h, args.scheme)
        ev = analytic_events(delta_max)
        on = np.nonzero(rec.p_spring > 0)[0]
        hit = np.nonzero(rec.p_core > 0)[0]
        print(f"delta_max = {delta_max}  ({fig_name}, scheme {args.scheme}, h = {args.h})")
        print(f"  contact starts      {rec.t[on[0]]:.6f} s   analytic {ev['contact']:.6f}")
        if len(hit):
            k_end = core_episode_end(rec.p_core)
            print(f"  core hit            {rec.t[hit[0]]:.6f} s   analytic {ev['core']:.6f}")
            print(f"  energy after hit    {rec.energy[k_end]:.6f} J   analytic {energy_after_core_hit(delta_max):.6f}")
        else:
            first = on[np.nonzero(np.diff(on) > 1)[0][0]] if np.any(np.diff(on) > 1) else on[-1]
            print(f"  no core impulse; peak deflection {rec.deflection.max():.6f}   analytic {ev['peak']:.6f}")
            print(f"  contact ends        {rec.t[first]:.6f} s   analytic {ev['release']:.6f}")
        print(f"  total energy drift over the run: {rec.energy[-1] - rec.energy[0]:+.3e} J "
              f"(after any core hit: {rec.energy[-1] - rec.energy[hit[0]] if len(hit) else float('nan'):+.3e} J)")
        fig, ax = plt.subplots(2, 3, figsize=(12, 6))
        ax[0, 0].plot(rec.t, rec.p_spring, label="spring impulse")
        ax[0, 0].plot(rec.t, rec.p_core, label="core impulse")
        ax[0, 0].set(xlabel="time [s]", ylabel="impulse [N s]", title="(a) normal impulses")
        ax[0, 0].legend()
        ax[0, 1].plot(rec.t, K * rec.deflection)
        ax[0, 1].set(xlabel="time [s]", ylabel="spring force [N]", title="(b) spring force k delta")
        ax[0, 2].plot(rec.t, rec.y)
        ax[0, 2].set(xlabel="time [s]", ylabel="y [m]", title="(c) disc centre height")
        ax[1, 0].plot(rec.t, rec.vy)
        ax[1, 0].set(xlabel="time [s]", ylabel="v_y [m/s]", title="(d) velocity")
        ax[1, 1].plot(rec.t, rec.energy)
        ax[1, 1].set(xlabel="time [s]", ylabel="energy [J]", title="(e) total energy (with spring)")
        ax[1, 2].plot(rec.t, rec.deflection, label="simulated")
        ax[1, 2].plot(rec.t, np.where(rec.t < ev["release"], analytic_deflection(rec.t), 0.0), "--",
                      label="analytic (no core, first contact)")
        ax[1, 2].set(xlabel="time [s]", ylabel="deflection [m]", title="deflection")
        ax[1, 2].legend(fontsize=8)
        fig.suptitle(f"Disc on a quasi-rigid half-plane, delta_max = {delta_max} ({fig_name}), scheme {args.scheme}")
        fig.tight_layout()
        path = out / f"quasi_rigid_dmax{delta_max:g}_{args.scheme}.png"
        fig.savefig(path, dpi=110)
        print(f"  wrote {path}")
        if args.animate:
            from implicit_contact import animate as an
            gif = an.animate(rec.traj, [an.Disc(RADIUS), an.HalfPlane((0.0, 1.0), 0.0)],
                             out / f"quasi_rigid_dmax{delta_max:g}_{args.scheme}.gif",
                             stride=max(1, int(round(0.01 / args.h))))
            print(f"  wrote {gif}")


if __name__ == "__main__":
    main()
