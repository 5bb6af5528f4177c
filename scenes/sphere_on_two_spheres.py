"""A unit sphere pushed across two fixed spheres ([GI] Sec. 6.2, Example 2, Figs. 4 and 5).

What to look for: contact 1 (with the radius-10 sphere) slides from the start, its friction
magnitude equal to mu times the normal force; contact 2 (radius-9 sphere) rolls, its friction
below mu times the normal force and its slip zero, until it turns to sliding; then both contacts
are lost. The paper reports about 3.0 s (contact 2 starts sliding), 3.2 s (contact 1 lost) and
3.6 s (contact 2 lost), all captured with a fixed time step.

The spheres are DART SphereShapes with collision aspects, so the same world also runs with DART's
own stepper. Torsional friction e_r = 0.3 is the implicit stepper's (DART has none).

Run: python -m scenes.sphere_on_two_spheres [--h 0.01] [--duration 5] [--animate]
"""
import argparse
from dataclasses import dataclass
from pathlib import Path

import dartpy as dart
import numpy as np

import implicit_contact as ic
from implicit_contact.trajectory import Trajectory, simulate as run

# 1. Parameters (SI units)
BIG = (10.0, (0.0, 0.0, 0.0))          # contact 1: radius, centre
SMALL = (9.0, (0.0, 11.4, 0.0))        # contact 2
RADIUS, MASS = 1.0, 1.0                # the moving unit sphere
INERTIA = 0.4 * MASS * RADIUS**2       # solid sphere
Q0 = (0.0, 6.62105263157895, 8.78417110772903)
FORCE = (1.0, 2.6, -9.81)              # applied at the centre every step; gravity is off
FRICTION = ic.Friction(mu=0.2, e_t=1.0, e_o=1.0, e_r=0.3)
H = 0.01


# 2. Build the DART world
def build_world(h: float = H):
    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity([0.0, 0.0, 0.0])

    fixed = dart.dynamics.Skeleton("fixed_spheres")
    _, big = fixed.createWeldJointAndBodyNodePair()
    big.setName("sphere_r10")
    _add_sphere(big, BIG[0], BIG[1])
    _, small = fixed.createWeldJointAndBodyNodePair(big)
    small.setName("sphere_r9")
    _add_sphere(small, SMALL[0], SMALL[1])

    ball = dart.dynamics.Skeleton("ball")
    _, body = ball.createFreeJointAndBodyNodePair()
    body.setName("ball")
    body.setMass(MASS)
    body.setMomentOfInertia(INERTIA, INERTIA, INERTIA)
    _add_sphere(body, RADIUS, (0.0, 0.0, 0.0))
    ball.setPositions(np.r_[0.0, 0.0, 0.0, Q0])

    world.addSkeleton(fixed)
    world.addSkeleton(ball)
    return world


def _add_sphere(body, radius, center):
    node = body.createShapeNode(dart.dynamics.SphereShape(radius))
    T = np.eye(4)
    T[:3, 3] = center
    node.setRelativeTransform(dart.math.Isometry3(T) if hasattr(dart.math, "Isometry3") else T)
    node.createVisualAspect()
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(FRICTION.mu)


def push(world, t):
    """The applied force of Example 2 (DART clears external forces after every step)."""
    world.getSkeleton("ball").getBodyNode(0).addExtForce(np.asarray(FORCE, float))


# 3. Step it
def simulate(duration: float = 5.0, h: float = H, on_failure: str = "raise", stepper_options=None) -> Trajectory:
    world = build_world(h)
    stepper = ic.ImplicitContactStepper(world, on_failure=on_failure, options=stepper_options)
    ball = world.getSkeleton("ball").getBodyNode(0)
    fixed = world.getSkeleton("fixed_spheres")
    for name in ("sphere_r10", "sphere_r9"):
        stepper.set_pair_friction(ball, fixed.getBodyNode(name), FRICTION)
    return run(world, stepper, duration, before_step=push)


@dataclass
class ContactSeries:
    """Per step: normal force [N]; friction magnitude [N] in the norm of the friction ellipsoid,
    sqrt((f_t/e_t)^2 + (f_o/e_o)^2 + (m_r/e_r)^2), which the elliptic law ([GI] eq 5) bounds by
    mu times the normal force and which equals it while sliding; the tangential force alone [N]
    (smaller while the contact also resists spin); slip speed [m/s]."""
    t: np.ndarray
    normal: np.ndarray
    friction: np.ndarray
    tangential: np.ndarray
    slip: np.ndarray


def contact_series(traj: Trajectory, body_name: str) -> ContactSeries:
    f_ = FRICTION
    t, n, f, ft, s = [], [], [], [], []
    for k, rep in enumerate(traj.reports):
        h = traj.times[k + 1] - traj.times[k]
        c = next((c for c in rep.contacts if body_name in (c.name_a + c.name_b)), None)
        t.append(traj.times[k + 1])
        n.append(c.p_n / h if c else 0.0)
        f.append(np.sqrt((c.p_t / f_.e_t) ** 2 + (c.p_o / f_.e_o) ** 2 + (c.p_r / f_.e_r) ** 2) / h if c else 0.0)
        ft.append(np.hypot(c.p_t, c.p_o) / h if c else 0.0)
        s.append(c.slip if (c and c.p_n > 0) else 0.0)
    return ContactSeries(np.array(t), np.array(n), np.array(f), np.array(ft), np.array(s))


ROLL_SLIP = 1e-6    # [m/s] tangential slip below which a contact counts as rolling
FORCE_ZERO = 1e-8   # [N] normal forces below this are numerical zeros: the solver's tolerance on
                    # scaled impulses (1e-10 h m g / h) is ~1e-9 N here


def events(traj: Trajectory) -> dict:
    """Event times: each contact lost (last step with a normal force) and contact 2 starting to slide."""
    c1, c2 = contact_series(traj, "sphere_r10"), contact_series(traj, "sphere_r9")
    out = {}
    for name, c in (("contact1_lost", c1), ("contact2_lost", c2)):
        on = np.nonzero(c.normal > FORCE_ZERO)[0]
        out[name] = float(c.t[on[-1]]) if len(on) else float("nan")
    sliding = np.nonzero((c2.normal > FORCE_ZERO) & (c2.slip > ROLL_SLIP))[0]
    out["contact2_slides"] = float(c2.t[sliding[0]]) if len(sliding) else float("nan")
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--h", type=float, default=H)
    parser.add_argument("--duration", type=float, default=5.0)
    parser.add_argument("--animate", action="store_true", help="also write scenes/out/sphere_on_two_spheres.gif")
    args = parser.parse_args(argv)
    traj = simulate(args.duration, args.h)
    t, q, v, ke = traj.arrays()
    ev = events(traj)
    # 4. Check what mechanics predicts: a small printed table
    print("event                      t [s]   ([GI]: about)")
    print(f"contact 2 starts sliding {ev['contact2_slides']:7.3f}   (3.0)")
    print(f"contact 1 lost           {ev['contact1_lost']:7.3f}   (3.2)")
    print(f"contact 2 lost           {ev['contact2_lost']:7.3f}   (3.6)")
    print(f"median step {1e6 * np.median(traj.step_seconds):.0f} us, mean Newton iterations "
          f"{traj.iterations.mean():.2f}, max {traj.iterations.max()}")
    # 5. Plot (Figs 4b and 5)
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = Path(__file__).resolve().parent / "out"
    out.mkdir(exist_ok=True)
    fig, axes = plt.subplots(2, 2, figsize=(10, 6.5))
    labels = ["wx", "wy", "wz", "vx", "vy", "vz"]
    for k in range(6):
        axes[0, 0].plot(t, v[:, k], label=labels[k])
    axes[0, 0].set(xlabel="time [s]", ylabel="velocity [m/s, rad/s]", title="Ball velocities (Fig. 4b)")
    axes[0, 0].legend(ncol=3, fontsize=8)
    for ax, name, title in ((axes[0, 1], "sphere_r10", "Contact 1"), (axes[1, 0], "sphere_r9", "Contact 2")):
        c = contact_series(traj, name)
        ax.plot(c.t, c.normal, label="normal force")
        ax.plot(c.t, c.friction, label="friction (ellipsoid norm, with torsion)")
        ax.plot(c.t, c.tangential, ":", label="|tangential friction force|")
        ax.plot(c.t, FRICTION.mu * c.normal, "--", label="mu x normal force")
        ax.set(xlabel="time [s]", ylabel="force [N]", title=f"{title}: friction against mu x normal (Fig. 5a)")
        ax.legend(fontsize=8)
        axes[1, 1].plot(c.t, c.slip, label=title)
    axes[1, 1].set(xlabel="time [s]", ylabel="slip speed [m/s]", title="Slip speed (Fig. 5b)")
    axes[1, 1].legend()
    fig.tight_layout()
    path = out / "sphere_on_two_spheres.png"
    fig.savefig(path, dpi=120)
    print(f"wrote {path}")
    if args.animate:
        from implicit_contact import animate as an
        bodies = [an.Sphere(RADIUS, q_index=0), an.Sphere(BIG[0], center=BIG[1]), an.Sphere(SMALL[0], center=SMALL[1])]
        gif = an.animate(traj, bodies, out / "sphere_on_two_spheres.gif", plane="yz", stride=max(1, len(t) // 150),
                         follow=0, window=(8.0, 6.0), title="Sphere pushed across two spheres, y-z view")
        print(f"wrote {gif}")


if __name__ == "__main__":
    main()
