"""Observed orders in h of order 1 ([GI]) and order 2 (implicit_contact/rattle.py).

Each case is one smooth phase with an exact reference, measured at h = 4e-3, 2e-3, 1e-3, 5e-4:

* tumble:   a free asymmetric top without gravity (inertia 0.1, 0.2, 0.35 kg m^2, spun near its
            unstable middle axis); error of the body-frame angular velocity after 1 s against
            Euler's equations (DOP853, rtol 1e-13).
* pendulum: a revolute pendulum (1 kg at 0.5 m) released at 1 rad; largest energy error in 1 s.
* cart:     a pendulum (0.5 kg at 0.5 m, released at 0.8 rad) hinged at the centre of a 1 kg
            ball (r = 0.1 m) that slides on frictionless ground: an articulated skeleton in
            persistent contact; largest energy error in 1 s (its exact energy is constant).
* rocking:  scenes/ellipsoid_rocking.py (rolling without slip); largest tilt error in 1 s against
            its exact 1-dof reference, and the rocking energy's largest relative error.
* slide:    a ball (r = 0.1 m) sliding without spin at 2 m/s on mu = 0.3; error of its position
            at 0.15 s, inside the sliding phase (x = v0 t - mu g t^2 / 2).
* damped joint: the pendulum without gravity, held by a DART joint spring (10 N m/rad) and
            damper (0.05 N m s/rad), released at 0.3 rad; largest angle error in 1 s against the
            exact damped oscillation.
* example 2: [GI] Example 2 (scenes/sphere_on_two_spheres.py) over 4 s; largest error of its two
            contact-loss times against an order-2 run at h = EXAMPLE2_REF_H. The events are read
            at step times, so their error is O(h) for either order: printed, not a smooth phase.

The order printed between two step sizes is log2(e(h) / e(h/2)). The figure goes to
comparisons/out/convergence.png.

Run: python -m comparisons.convergence [--quick]   (--quick: h = 4e-3, 2e-3 only)
"""
from __future__ import annotations

import argparse
from pathlib import Path
import time

import numpy as np
from scipy.integrate import solve_ivp

import implicit_contact as ic
from implicit_contact.testing import dart_world, ground_box, revolute_pendulum

STEPS = (4e-3, 2e-3, 1e-3, 5e-4)
EXAMPLE2_REF_H = 2.5e-4                 # [s] the reference run of Example 2's events
OUT = Path(__file__).resolve().parent / "out"

INERTIA = np.array([0.1, 0.2, 0.35])    # [kg m^2], the top's principal moments
OMEGA0 = np.array([0.3, 4.0, 0.5])      # [rad/s] body frame, near the unstable middle axis
BALL_R, BALL_MU, BALL_V0 = 0.1, 0.3, 2.0
G = 9.81
HINGE_K, HINGE_D, HINGE_Q0 = 10.0, 0.05, 0.3     # [N m/rad], [N m s/rad], [rad]: the spring hinge


def _stepper(world, order):
    return ic.ImplicitContactStepper(world, on_failure="raise", options=ic.StepperOptions(order=order))


def tumble_error(order: int, h: float, duration: float = 1.0) -> float:
    """max |omega_body(T) - exact| [rad/s] of the free top after duration."""
    import dartpy as dart
    world = dart_world(h, 0.0)
    skel = dart.dynamics.Skeleton("top")
    _, body = skel.createFreeJointAndBodyNodePair()
    body.setMass(2.0)
    body.setMomentOfInertia(*INERTIA, 0.0, 0.0, 0.0)
    world.addSkeleton(skel)
    skel.setVelocities(np.r_[OMEGA0, 1.0, 0.0, 0.0])
    stepper = _stepper(world, order)
    for _ in range(int(round(duration / h))):
        stepper.step()
    R = body.getWorldTransform().rotation()
    I = INERTIA
    rhs = lambda _, w: [(I[1] - I[2]) * w[1] * w[2] / I[0], (I[2] - I[0]) * w[2] * w[0] / I[1],
                        (I[0] - I[1]) * w[0] * w[1] / I[2]]
    exact = solve_ivp(rhs, (0.0, duration), OMEGA0, method="DOP853", rtol=1e-13, atol=1e-14).y[:, -1]
    return float(np.max(np.abs(R.T @ np.array(skel.getVelocities())[:3] - exact)))


def _energy_error(world, skel, order: int, duration: float) -> float:
    """Largest |E(t) - E(0)| [J] of one skeleton stepped for duration."""
    stepper = _stepper(world, order)
    energy = lambda: skel.computeKineticEnergy() + skel.computePotentialEnergy()
    e0, worst = energy(), 0.0
    for _ in range(int(round(duration / world.getTimeStep()))):
        stepper.step()
        worst = max(worst, abs(energy() - e0))
    return worst


def pendulum_energy_error(order: int, h: float, duration: float = 1.0) -> float:
    """Largest |E(t) - E(0)| [J] of the pendulum over duration."""
    world = dart_world(h)
    return _energy_error(world, revolute_pendulum(world, 1.0), order, duration)


def cart_pendulum(h: float, q0: float = 0.8):
    """(world, skeleton): the pendulum hinged at the centre of a ball on frictionless ground."""
    import dartpy as dart
    world = dart_world(h)
    ground_box(world, mu=0.0)
    skel = dart.dynamics.Skeleton("cart")
    cart = _ball_body(skel, 0.0)
    joint, bob = skel.createRevoluteJointAndBodyNodePair(cart)
    joint.setAxis([0.0, 1.0, 0.0])
    bob.setMass(0.5)
    bob.setMomentOfInertia(1e-3, 1e-3, 1e-3)
    T = dart.math.Isometry3()
    T.set_translation([0.0, 0.0, 0.5])
    joint.setTransformFromChildBodyNode(T)
    world.addSkeleton(skel)
    skel.setPositions([0.0, 0.0, 0.0, 0.0, 0.0, BALL_R, q0])
    return world, skel


def cart_energy_error(order: int, h: float, duration: float = 1.0) -> float:
    """Largest |E(t) - E(0)| [J] of the cart pendulum over duration."""
    return _energy_error(*cart_pendulum(h), order, duration)


def example2_events(order: int, h: float) -> dict:
    """The contact events of [GI] Example 2 (scenes.sphere_on_two_spheres.events) [s]."""
    from scenes import sphere_on_two_spheres as s2
    traj = s2.simulate(4.0, h, on_failure="retry", stepper_options=ic.StepperOptions(order=order))
    return s2.events(traj)


_EXAMPLE2_REF = {}


def example2_event_error(order: int, h: float) -> float:
    """max |t - t_ref| [s] of Example 2's two contact-loss times, t_ref from order 2 at EXAMPLE2_REF_H."""
    if not _EXAMPLE2_REF:
        _EXAMPLE2_REF.update(example2_events(2, EXAMPLE2_REF_H))
    found = example2_events(order, h)
    return max(abs(found[k] - _EXAMPLE2_REF[k]) for k in ("contact1_lost", "contact2_lost"))


def rocking_errors(order: int, h: float, duration: float = 1.0) -> tuple[float, float]:
    """(largest tilt error [rad], largest relative rocking-energy error) of the rocking ellipsoid."""
    from scenes import ellipsoid_rocking as er
    traj = er.simulate(duration, h, stepper_options=ic.StepperOptions(order=order), on_failure="raise")
    t, q, _, _ = traj.arrays()
    exact, _ = er.exact_rocking(t)
    e0 = er.exact_energy()
    return (float(np.max(np.abs(er.tilt_angle(q) - exact))),
            float(np.max(np.abs(er.rocking_energy(traj) - e0)) / e0))


LAYER_K = 1e5   # [N/m]: the undamped quasi-rigid layer under the rocking ellipsoid


def layer_rocking_error(order: int, h: float, duration: float = 1.0, k: float = LAYER_K) -> float:
    """Largest |E(t) - E(0)| over the rocking energy of the rocking ellipsoid on an undamped
    quasi-rigid layer of stiffness k over the ground (stepper.set_pair_compliance; E: kinetic +
    gravity + the layer's k delta^2 / 2, which rolling without slip keeps). The ellipsoid starts
    at its static deflection m g / k (check_penetration_at_start off), so the layer does not
    ring at the start."""
    from scenes import ellipsoid_rocking as er
    world = er.build_world(h)
    skel = world.getSkeleton("ellipsoid")
    q = np.array(skel.getPositions())
    q[5] -= er.MASS * G / k
    skel.setPositions(q)
    stepper = ic.ImplicitContactStepper(world, on_failure="raise",
                                        options=ic.StepperOptions(order=order, check_penetration_at_start=False))
    stepper.set_pair_compliance(skel.getBodyNode(0), world.getSkeleton("ground").getBodyNode(0), ic.Compliance(k=k))
    energy = []
    for _ in range(int(round(duration / h))):
        stepper.step()
        q, v = skel.getPositions(), skel.getVelocities()
        energy.append(0.5 * v @ skel.getMassMatrix() @ v + er.MASS * G * (q[5] - er.SEMI_AXES[2]) + stepper.spring_energy())
    energy = np.array(energy)
    return float(np.max(np.abs(energy - energy[0])) / er.exact_energy())


def _ball_body(skel, mu: float):
    """The root of skel: a FreeJoint body, a 1 kg solid ball of radius BALL_R (DART SphereShape
    with collision, friction mu)."""
    import dartpy as dart
    _, body = skel.createFreeJointAndBodyNodePair()
    body.setMass(1.0)
    body.setMomentOfInertia(*([0.4 * BALL_R ** 2] * 3), 0.0, 0.0, 0.0)
    node = body.createShapeNode(dart.dynamics.SphereShape(BALL_R))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(mu)
    return body


def ball(world, mu: float, z: float, v):
    """A 1 kg solid ball of radius BALL_R (DART SphereShape, friction mu) at height z, velocity v."""
    import dartpy as dart
    skel = dart.dynamics.Skeleton("ball")
    _ball_body(skel, mu)
    world.addSkeleton(skel)
    skel.setPositions([0.0, 0.0, 0.0, 0.0, 0.0, z])
    skel.setVelocities(np.r_[0.0, 0.0, 0.0, v])
    return skel


def slide_error(order: int, h: float, duration: float = 0.15) -> float:
    """|x(T) - (v0 T - mu g T^2 / 2)| [m] of the sliding ball, T inside the sliding phase."""
    world = dart_world(h)
    ground_box(world, mu=BALL_MU)
    skel = ball(world, BALL_MU, BALL_R, [BALL_V0, 0.0, 0.0])
    stepper = _stepper(world, order)
    n = int(round(duration / h))
    for _ in range(n):
        stepper.step()
    T = n * h
    return abs(float(skel.getPositions()[3]) - (BALL_V0 * T - 0.5 * BALL_MU * G * T * T))


def spring_hinge(h: float, stiffness: float, damping: float, q0: float = HINGE_Q0):
    """(world, skeleton): the pendulum of pendulum_energy_error without gravity, held by a joint
    spring (rest position 0) and damper, released at q0."""
    world = dart_world(h, 0.0)
    skel = revolute_pendulum(world, q0)
    joint = skel.getJoint(0)
    joint.setSpringStiffness(0, stiffness)
    joint.setDampingCoefficient(0, damping)
    return world, skel


def spring_hinge_run(order: int, h: float, stiffness: float = HINGE_K, damping: float = HINGE_D,
                     duration: float = 1.0):
    """(q, v, exact q, exact v) at every step of the spring hinge over duration; the exact
    solution of I q'' + D q' + K q = 0 by the matrix exponential."""
    from scipy.linalg import expm
    world, skel = spring_hinge(h, stiffness, damping)
    stepper = _stepper(world, order)
    inertia = float(skel.getMassMatrix()[0, 0])
    n = int(round(duration / h))
    out = np.empty((n, 2))
    for i in range(n):
        stepper.step()
        out[i] = skel.getPositions()[0], skel.getVelocities()[0]
    A = np.array([[0.0, 1.0], [-stiffness / inertia, -damping / inertia]])
    step = expm(A * h)
    exact, x = np.empty((n, 2)), np.array([HINGE_Q0, 0.0])
    for i in range(n):
        x = step @ x
        exact[i] = x
    return out[:, 0], out[:, 1], exact[:, 0], exact[:, 1]


def damped_joint_error(order: int, h: float, duration: float = 1.0) -> float:
    """Largest |q(t) - exact| [rad] of the spring hinge over duration."""
    q, _, q_exact, _ = spring_hinge_run(order, h, duration=duration)
    return float(np.max(np.abs(q - q_exact)))


CASES = {
    "tumble": (lambda o, h: tumble_error(o, h), "omega error [rad/s]"),
    "pendulum": (lambda o, h: pendulum_energy_error(o, h), "energy error [J]"),
    "cart": (lambda o, h: cart_energy_error(o, h), "energy error [J]"),
    "rocking": (lambda o, h: rocking_errors(o, h)[0], "tilt error [rad]"),
    "rocking energy": (lambda o, h: rocking_errors(o, h)[1], "relative energy error"),
    "slide": (lambda o, h: slide_error(o, h), "position error [m]"),
    "damped joint": (lambda o, h: damped_joint_error(o, h), "angle error [rad]"),
    "layer rocking": (lambda o, h: layer_rocking_error(o, h), "relative energy error"),
    "example 2": (lambda o, h: example2_event_error(o, h), "event time error [s]"),
}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="h = 4e-3 and 2e-3 only")
    args = parser.parse_args(argv)
    steps = STEPS[:2] if args.quick else STEPS
    results = {}
    print(f"{'case':16s} order  " + "  ".join(f"h={h:<8g}" for h in steps) + "   observed orders      wall")
    for name, (fn, unit) in CASES.items():
        for order in (1, 2):
            t0 = time.perf_counter()
            errs = [fn(order, h) for h in steps]
            wall = time.perf_counter() - t0
            results[(name, order)] = errs
            orders = [np.log2(a / b) if a > 0 and b > 0 else float("nan") for a, b in zip(errs, errs[1:])]
            print(f"{name:16s} {order:5d}  " + "  ".join(f"{e:<10.3e}" for e in errs) + "   "
                  + " ".join(f"{x:5.2f}" for x in orders) + f"   {wall:6.1f} s")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        return results
    fig, axes = plt.subplots(1, len(CASES), figsize=(4 * len(CASES), 3.6))
    for ax, (name, (_, unit)) in zip(axes, CASES.items()):
        for order, style in ((1, "o-"), (2, "s-")):
            ax.loglog(steps, results[(name, order)], style, label=f"order {order}")
        ax.set_title(name)
        ax.set_xlabel("h [s]")
        ax.set_ylabel(unit)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.tight_layout()
    OUT.mkdir(exist_ok=True)
    fig.savefig(OUT / "convergence.png", dpi=110)
    print(f"figure: {OUT / 'convergence.png'}")
    return results


if __name__ == "__main__":
    main()
