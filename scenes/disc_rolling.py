"""Unit disc rolling on the ground ([GI] Sec. 1 and 6.1, Example 1, Fig. 1).

What to look for: the disc is an implicit curve, f = (|x - c|^2 - 1)/2, so its kinetic energy
stays 6.75 J to round-off while it rolls (a polygonal disc in DART's own stepper loses it: see
``python -m comparisons.energy_loss``). The normal impulse while rolling is m g h, and a disc
started sliding (v = [-3, 0, 0]) stops slipping at t* = |v0| / (3 mu g) = 0.2548 s and then rolls
with v_x = -2, omega = 2.

Run: python -m scenes.disc_rolling [--slide] [--h 0.01] [--duration 5] [--animate]
"""
import argparse
from pathlib import Path

import dartpy as dart
import numpy as np

import implicit_contact as ic
from implicit_contact.trajectory import Trajectory, simulate as run

# 1. Parameters (SI units)
RADIUS = 1.0          # [m]
MASS = 1.0            # [kg]
INERTIA = 0.5         # [kg m^2] about the disc axis, m r^2 / 2
MU = 0.4              # Coulomb friction, disc and ground
G = 9.81              # [m/s^2], along -y
Q0 = (0.0, 1.0, 0.0)  # [x, y, theta]
V0 = (-3.0, 0.0, 3.0)  # [v_x, v_y, omega]: rolling without slip (v_x = -omega r)
H = 0.01              # time step [s]


# 2. Build the DART world
def build_world(h: float = H, q0=Q0, v0=V0, mu: float = MU) -> dart.simulation.World:
    """A PlanarJoint disc (XY plane, gravity -y) on a fixed ground, with implicit shapes."""
    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity([0.0, -G, 0.0])

    disc = dart.dynamics.Skeleton("disc")
    joint, body = disc.createPlanarJointAndBodyNodePair()
    joint.setXYPlane()
    body.setName("disc")
    body.setMass(MASS)
    body.setMomentOfInertia(INERTIA / 2, INERTIA / 2, INERTIA)  # thin disc; only Izz matters in 2D
    ic.attach(body, ic.shapes.Disc(RADIUS), friction=ic.Friction(mu=mu))
    disc.setPositions(np.asarray(q0, float))
    disc.setVelocities(np.asarray(v0, float))

    ground = dart.dynamics.Skeleton("ground")
    _, gbody = ground.createWeldJointAndBodyNodePair()
    gbody.setName("ground")
    ic.attach(gbody, ic.shapes.HalfPlane([0.0, 1.0], 0.0), friction=ic.Friction(mu=mu))

    world.addSkeleton(disc)
    world.addSkeleton(ground)
    return world


# 3. Step it
def simulate(duration: float = 5.0, h: float = H, v0=V0, q0=Q0, mu: float = MU,
             stepper_options=None) -> Trajectory:
    world = build_world(h, q0, v0, mu)
    stepper = ic.ImplicitContactStepper(world, options=stepper_options)
    return run(world, stepper, duration)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--h", type=float, default=H)
    parser.add_argument("--duration", type=float, default=5.0)
    parser.add_argument("--slide", action="store_true", help="start sliding: v0 = [-3, 0, 0]")
    parser.add_argument("--animate", action="store_true", help="also write scenes/out/<name>.gif")
    args = parser.parse_args(argv)
    v0 = (-3.0, 0.0, 0.0) if args.slide else V0
    traj = simulate(args.duration, args.h, v0)
    t, q, v, ke = traj.arrays()

    # 4. Check what mechanics predicts: a small printed table
    print(f"{'t [s]':>8} {'x [m]':>10} {'v_x [m/s]':>10} {'omega':>8} {'KE [J]':>12} {'p_n [N s]':>11}")
    for k in np.linspace(0, len(t) - 1, 11).astype(int):
        rep = traj.reports[k - 1] if k > 0 else None
        pn = rep.contacts[0].p_n if rep is not None and rep.contacts else float("nan")
        print(f"{t[k]:8.3f} {q[k, 0]:10.4f} {v[k, 0]:10.5f} {v[k, 2]:8.4f} {ke[k]:12.9f} {pn:11.6f}")
    print(f"relative KE change over {args.duration} s: {(ke[-1] - ke[0]) / ke[0]:.3e}; "
          f"median step {1e6 * np.median(traj.step_seconds):.0f} us, "
          f"mean Newton iterations {traj.iterations.mean():.2f}")

    # 5. Plot
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = Path(__file__).resolve().parent / "out"
    out.mkdir(exist_ok=True)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(t, ke, label="implicit disc")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("kinetic energy [J]")
    ax.set_title("Does the rolling disc keep its kinetic energy?")
    ax.legend()
    fig.tight_layout()
    name = "disc_sliding" if args.slide else "disc_rolling"
    path = out / f"{name}.png"
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")
    if args.animate:
        from implicit_contact import animate as an
        gif = an.animate(traj, [an.Disc(RADIUS), an.HalfPlane((0.0, 1.0), 0.0)], out / f"{name}.gif",
                         stride=max(1, len(t) // 150), follow=0, window=(6.0, 3.0),
                         title="Disc on the ground (implicit stepper)")
        print(f"wrote {gif}")


if __name__ == "__main__":
    main()
