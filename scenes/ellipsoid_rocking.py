"""An ellipsoid rocking on its flattest side on a plane, rolling without slip.

What to look for: a solid ellipsoid (semi-axes 0.7, 1.0, 0.5 m along its body x, y, z) lies on
its flattest side (the short axis vertical: radius of curvature b^2 / c = 2 m at the bottom of the
y-z section, well above the centre of mass, so the rest is stable), tilted by 0.2 rad about x and
let go. It rocks about x in the y-z plane, rolling without slip. The ground does no work on a
body that rolls without slip on a smooth convex surface, so the exact motion keeps its mechanical
energy and rocks with a constant amplitude; a first-order time-stepper loses amplitude, O(h). The
implicit stepper (positions at the end of the step) loses 15 % of the rocking energy in 3 s at
h = 0.002 s, DART's own stepper with FCL 0.6 % (python -m comparisons.work_precision).

Exact reference (``exact_rocking``). By symmetry the motion stays in the y-z plane: one degree of
freedom, the tilt theta (rotation about x). For an ellipse with semi-axes b (horizontal at rest)
and c (vertical) the height of the centre above the contact point is the support function

    s(theta) = sqrt(b^2 sin^2 theta + c^2 cos^2 theta),

and the contact point lies s'(theta) to the side of the centre, so the centre moves about the
contact point (the instantaneous centre of rotation) with speed theta' sqrt(s^2 + s'^2):

    T = J(theta) theta'^2 / 2,   J = I_x + m (s^2 + s'^2),    V = m g s(theta),
    J theta'' + J'(theta) theta'^2 / 2 + m g s'(theta) = 0,

    s' = (b^2 - c^2) sin(2 theta) / (2 s),   s'' = ((b^2 - c^2) cos(2 theta) - s'^2) / s.

scipy's DOP853 integrates it to 1e-12 relative (its energy drifts by ~3e-12 J over 5 s). Small
oscillations: omega^2 = m g (b^2/c - c) / (I_x + m c^2) = 29.4 rad^2/s^2, period 1.16 s; at
0.2 rad the period is 1.258 s, and rolling needs |friction| / normal force <= 0.28.

DART world (``build_world``): the ellipsoid is a DART EllipsoidShape and the ground a PlaneShape,
both with collision and dynamics aspects (friction MU), so DART's own stepper runs the same world
(pick its detector with world.setCollisionDetector); the implicit stepper maps both shapes itself
(EllipsoidShape -> ellipsoid, PlaneShape -> half-space). Sleeping is off: near the end of a
rocking swing the ellipsoid is almost at rest and DART must not freeze it.

Run: python -m scenes.ellipsoid_rocking [--h 0.002] [--duration 3] [--animate]
"""
import argparse
from pathlib import Path

import dartpy as dart
import numpy as np
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

import implicit_contact as ic
from implicit_contact.trajectory import Trajectory, simulate as run

# 1. Parameters (SI units)
SEMI_AXES = (0.7, 1.0, 0.5)   # [m] along body x, y, z; rocks about x, so b = 1.0, c = 0.5
MASS = 1.0                    # [kg]
INERTIA = MASS / 5.0 * np.array([SEMI_AXES[1] ** 2 + SEMI_AXES[2] ** 2,     # solid ellipsoid [kg m^2]
                                 SEMI_AXES[0] ** 2 + SEMI_AXES[2] ** 2,
                                 SEMI_AXES[0] ** 2 + SEMI_AXES[1] ** 2])
MU = 1.0                      # Coulomb friction, ellipsoid and ground: rolling needs 0.28
G = 9.81                      # [m/s^2], along -z
TILT0 = 0.2                   # [rad] initial tilt about x, released at rest
H = 0.002                     # time step [s]
EXACT_RTOL = 1e-12            # DOP853 tolerance of the reference (relative; atol 1e-14)


# 2. Build the DART world
def build_world(h: float = H, tilt0: float = TILT0, mu: float = MU) -> dart.simulation.World:
    """The ellipsoid (FreeJoint) tilted by tilt0 about x, touching the plane z = 0, at rest.

    DART primitives only, with collision aspects: DART's own stepper (any detector) and the
    implicit stepper run this same world."""
    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity([0.0, 0.0, -G])
    sleeping = world.getDeactivationOptions()
    sleeping.mEnabled = False
    world.setDeactivationOptions(sleeping)

    body_skel = dart.dynamics.Skeleton("ellipsoid")
    _, body = body_skel.createFreeJointAndBodyNodePair()
    body.setName("ellipsoid")
    body.setInertia(dart.dynamics.Inertia(MASS, np.zeros(3), np.diag(INERTIA)))
    _add_contact_shape(body, dart.dynamics.EllipsoidShape(2.0 * np.asarray(SEMI_AXES)), mu)  # diameters
    # FreeJoint positions: [rotation vector; origin position], world frame
    body_skel.setPositions(np.r_[tilt0, 0.0, 0.0, 0.0, 0.0, support_height(tilt0)])

    ground = dart.dynamics.Skeleton("ground")
    _, gbody = ground.createWeldJointAndBodyNodePair()
    gbody.setName("ground")
    _add_contact_shape(gbody, dart.dynamics.PlaneShape(np.array([0.0, 0.0, 1.0]), 0.0), mu)

    world.addSkeleton(body_skel)
    world.addSkeleton(ground)
    return world


def _add_contact_shape(body, shape, mu: float):
    node = body.createShapeNode(shape)
    node.createVisualAspect()
    node.createCollisionAspect()
    dynamics = node.createDynamicsAspect()
    dynamics.setFrictionCoeff(mu)
    dynamics.setRestitutionCoeff(0.0)
    return node


# 3. Step it
def simulate(duration: float = 3.0, h: float = H, tilt0: float = TILT0, mu: float = MU,
             stepper_options=None, on_failure: str = "retry") -> Trajectory:
    world = build_world(h, tilt0, mu)
    stepper = ic.ImplicitContactStepper(world, on_failure=on_failure, options=stepper_options)
    return run(world, stepper, duration)


# 4. What mechanics predicts
def support_height(theta):
    """s(theta) [m]: height of the centre above the ground when tilted by theta (module docstring)."""
    b, c = SEMI_AXES[1], SEMI_AXES[2]
    return np.sqrt((b * np.sin(theta)) ** 2 + (c * np.cos(theta)) ** 2)


def _rocking_rhs(_, y):
    theta, rate = y
    b, c = SEMI_AXES[1], SEMI_AXES[2]
    s = support_height(theta)
    ds = (b * b - c * c) * np.sin(2.0 * theta) / (2.0 * s)
    dds = ((b * b - c * c) * np.cos(2.0 * theta) - ds * ds) / s
    J = INERTIA[0] + MASS * (s * s + ds * ds)
    dJ = 2.0 * MASS * (s * ds + ds * dds)
    return [rate, -(0.5 * dJ * rate * rate + MASS * G * ds) / J]


def exact_rocking(times, tilt0: float = TILT0) -> tuple[np.ndarray, np.ndarray]:
    """(theta [rad], theta' [rad/s]) of the exact rolling-without-slip motion at the given times [s]."""
    times = np.asarray(times, float)
    if times.ndim != 1 or times.size == 0 or np.any(times < 0) or not np.all(np.isfinite(times)):
        raise ValueError("times must be a non-empty 1D array of finite times >= 0 [s]")
    t_end = max(float(times.max()), 1e-9)
    sol = solve_ivp(_rocking_rhs, (0.0, t_end), [tilt0, 0.0], method="DOP853", rtol=EXACT_RTOL,
                    atol=1e-14, dense_output=True)
    if not sol.success:
        raise ArithmeticError(f"the rocking reference did not integrate: {sol.message}")
    theta, rate = sol.sol(times)
    return theta, rate


def exact_energy(tilt0: float = TILT0) -> float:
    """Rocking energy [J] of the exact motion, kinetic + m g (z - c) (zero at rest on the flat
    side): m g (s(tilt0) - c), 0.28 J here, which it keeps."""
    return MASS * G * float(support_height(tilt0) - SEMI_AXES[2])


def tilt_angle(q) -> np.ndarray:
    """Tilt about world x [rad] of the ellipsoid from FreeJoint positions q (rows [rotvec, origin])."""
    q = np.atleast_2d(np.asarray(q, float))
    R = Rotation.from_rotvec(q[:, :3]).as_matrix()
    return np.arctan2(R[:, 2, 1], R[:, 2, 2])


def rocking_energy(traj: Trajectory) -> np.ndarray:
    """Kinetic + potential energy [J] along a trajectory, the potential m g (z - c) zero at rest."""
    _, q, _, ke = traj.arrays()
    return ke + MASS * G * (q[:, 5] - SEMI_AXES[2])


def animation_bodies():
    """The scene for implicit_contact.animate, projected on the y-z plane."""
    from implicit_contact import animate as an
    return [an.Ellipsoid(SEMI_AXES, q_index=0), an.HalfPlane((0.0, 1.0), 0.0)]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--h", type=float, default=H)
    parser.add_argument("--duration", type=float, default=3.0)
    parser.add_argument("--animate", action="store_true", help="also write scenes/out/ellipsoid_rocking.gif")
    args = parser.parse_args(argv)
    traj = simulate(args.duration, args.h)
    t, q, v, ke = traj.arrays()
    tilt = tilt_angle(q)
    exact, _ = exact_rocking(t)
    energy = rocking_energy(traj)
    e0 = exact_energy()

    # A small printed table: tilt against the exact rocking, energy, friction used
    print(f"rocking energy E = kinetic + m g (z - c), exact E0 = {e0:.4f} J")
    print(f"{'t [s]':>7} {'tilt [rad]':>11} {'exact':>9} {'E [J]':>9} {'E / E0':>8}")
    for k in np.linspace(0, len(t) - 1, 11).astype(int):
        print(f"{t[k]:7.3f} {tilt[k]:11.5f} {exact[k]:9.5f} {energy[k]:9.5f} {energy[k] / e0:8.5f}")
    ratios = [np.hypot(c.p_t, c.p_o) / c.p_n for r in traj.reports for c in r.contacts if c.p_n > 1e-12]
    out_of_plane = np.max(np.abs(q[:, 1:3]))
    print(f"max |tilt - exact| = {np.max(np.abs(tilt - exact)):.3e} rad at h = {args.h:g} s (first order "
          f"in h); energy lost by {t[-1]:g} s: {100 * (1 - energy[-1] / e0):.2f} %; largest friction / "
          f"normal impulse {max(ratios, default=0):.3f} (mu = {MU}); out-of-plane rotation "
          f"{out_of_plane:.1e} rad; median step {1e6 * np.median(traj.step_seconds):.0f} us")

    # 5. Plot
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    out = Path(__file__).resolve().parent / "out"
    out.mkdir(exist_ok=True)
    fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True)
    fine = np.linspace(0.0, t[-1], 1000)
    ax1.plot(fine, exact_rocking(fine)[0], "k--", lw=1.0, label="exact (rolling without slip, energy kept)")
    ax1.plot(t, tilt, label=f"implicit stepper, h = {args.h:g} s")
    ax1.set(ylabel="tilt about x [rad]", title="Does the rocking ellipsoid keep its amplitude and energy?")
    ax1.legend(fontsize=8)
    ax2.axhline(e0, color="k", ls="--", lw=1.0, label="exact")
    ax2.plot(t, energy, label="implicit: kinetic + potential")
    ax2.set(xlabel="time [s]", ylabel="rocking energy [J]\n(potential zero at rest)")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    path = out / "ellipsoid_rocking.png"
    fig.savefig(path, dpi=120)
    plt.close(fig)
    print(f"wrote {path}")
    if args.animate:
        from implicit_contact.animate import animate
        gif = animate(traj, animation_bodies(), out / "ellipsoid_rocking.gif", plane="yz",
                      stride=max(1, len(t) // 150), title="Ellipsoid rocking (implicit stepper)")
        print(f"wrote {gif}")


if __name__ == "__main__":
    main()
