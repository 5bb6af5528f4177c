"""A parallel gripper squeezes a rounded cube (a superquadric) with two force-controlled prismatic
fingers and lifts it off the ground: an articulated skeleton on the implicit stepper.

What to look for: the gripper is one DART skeleton of three bodies: a palm on a vertical
PrismaticJoint (the lift, PD-controlled by a joint force with gravity compensation) and two
fingers on horizontal PrismaticJoints, each pushed towards the object by a constant joint force
F_SQUEEZE. Their pads are ellipsoids (point contacts with torsional friction e_r). The object, a
superquadric |x/a|^4 + |y/a|^4 + |z/a|^4 <= 1 of mass M_OBJ, rests on the ground. Mechanics says:

* while squeezed and lifted, each pad carries a normal force F_SQUEEZE and a vertical friction
  force (M_OBJ (g + a_lift)) / 2, which the cone allows as long as that is <= MU F_SQUEEZE:
  the object rises with the palm without slipping (relative slide of the object in the pads ~ 0);
* with the squeeze below M_OBJ g / (2 MU) (``--squeeze`` small) the pads slide and the object
  stays on the ground.

The bodies of one skeleton do not collide with each other (DART's default), the fingers are
independent force-controlled dofs, and every pair involving a finger runs on the generic path of
the formulation (kind ARTICULATED).

Run: python -m scenes.gripper_squeeze [--h 0.002] [--squeeze 10] [--duration 1.5] [--plot]
(--plot: scenes/out/gripper_squeeze.png, the held grasp next to one squeezed below the threshold:
finger forces, object and palm heights, and each pad's friction force against mu times its
normal force.)
"""
import argparse
from pathlib import Path
import time

import dartpy as dart
import numpy as np

import implicit_contact as ic

# 1. Parameters (SI units)
A_OBJ = 0.04                  # [m] half-size of the rounded cube
EXPONENT = 4.0                # superquadric exponent
M_OBJ = 0.2                   # [kg]
PAD = (0.01, 0.03, 0.03)      # [m] semi-axes of the ellipsoidal finger pads
M_FINGER, M_PALM = 0.1, 0.5   # [kg]
MU = 0.8                      # pad-object friction
E_R = 0.01                    # [m] torsional friction length of the pads
F_SQUEEZE = 10.0              # [N] joint force on each finger
G = 9.81
LIFT = 0.1                    # [m] lift height
T_SQUEEZE, T_LIFT = 0.3, 0.8  # [s] squeeze before lifting; duration of the lift
KP, KD = 400.0, 40.0          # lift PD gains [N/m], [N s/m]
H = 0.002


def _iso(T):
    return dart.math.Isometry3(T) if hasattr(dart.math, "Isometry3") else T


# 2. Build the DART world
def build_world(h=H, mu=MU):
    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity([0.0, 0.0, -G])

    gripper = dart.dynamics.Skeleton("gripper")
    lift, palm = gripper.createPrismaticJointAndBodyNodePair()
    lift.setAxis([0.0, 0.0, 1.0])
    T = np.eye(4)
    T[2, 3] = A_OBJ                              # palm frame at the object's centre height
    lift.setTransformFromParentBodyNode(_iso(T))
    palm.setMass(M_PALM)
    for side, x0 in (("left", -(A_OBJ + PAD[0] + 0.01)), ("right", A_OBJ + PAD[0] + 0.01)):
        joint, finger = gripper.createPrismaticJointAndBodyNodePair(palm)
        joint.setName(side)
        finger.setName(side + "_finger")
        joint.setAxis([1.0, 0.0, 0.0])
        T = np.eye(4)
        T[0, 3] = x0
        joint.setTransformFromParentBodyNode(_iso(T))
        finger.setMass(M_FINGER)
        finger.setMomentOfInertia(1e-4, 1e-4, 1e-4)
        ic.attach(finger, ic.shapes.Ellipsoid(PAD), friction=ic.Friction(mu, e_r=E_R))
    world.addSkeleton(gripper)

    obj = dart.dynamics.Skeleton("object")
    _, body = obj.createFreeJointAndBodyNodePair()
    body.setName("cube")
    inertia = M_OBJ * (2 * A_OBJ) ** 2 / 6.0
    body.setMass(M_OBJ)
    body.setMomentOfInertia(inertia, inertia, inertia)
    ic.attach(body, ic.shapes.Superquadric([A_OBJ] * 3, EXPONENT), friction=ic.Friction(mu, e_r=E_R))
    obj.setPositions([0.0, 0.0, 0.0, 0.0, 0.0, A_OBJ])
    world.addSkeleton(obj)

    ground = dart.dynamics.Skeleton("ground")
    _, gb = ground.createWeldJointAndBodyNodePair()
    ic.attach(gb, ic.shapes.HalfSpace([0.0, 0.0, 1.0], 0.0), friction=ic.Friction(0.5))
    world.addSkeleton(ground)
    return world, gripper, obj


# 3. Controller: squeeze by joint forces, lift by PD with gravity compensation
def control(gripper, t, squeeze=F_SQUEEZE):
    s = min(max((t - T_SQUEEZE) / T_LIFT, 0.0), 1.0)
    z_d = LIFT * (3 * s * s - 2 * s ** 3)                      # smooth step
    v_d = LIFT * (6 * s - 6 * s * s) / T_LIFT if 0.0 < s < 1.0 else 0.0
    z, v = gripper.getPositions()[0], gripper.getVelocities()[0]
    f_lift = (M_PALM + 2 * M_FINGER + M_OBJ) * G + KP * (z_d - z) + KD * (v_d - v)
    gripper.setForces([f_lift, squeeze, -squeeze])
    return f_lift, squeeze, -squeeze


# 4. Run
def run(h=H, duration=1.5, squeeze=F_SQUEEZE, verbose=True):
    world, gripper, obj = build_world(h)
    stepper = ic.ImplicitContactStepper(world)
    rows, series = [], []
    t0 = time.perf_counter()
    n = int(round(duration / h))
    for k in range(n):
        command = control(gripper, world.getTime(), squeeze)
        report = stepper.step()
        pad_forces = []                      # (normal, friction) per pad [N]
        for side in ("left", "right"):
            c = next((c for c in report.contacts if side + "_finger" in c.name_a + c.name_b), None)
            pad_forces += [0.0, 0.0] if c is None else [c.p_n / h, np.hypot(c.p_t, c.p_o) / h]
        series.append([world.getTime(), gripper.getPositions()[0], obj.getPositions()[5] - A_OBJ,
                       *command[1:], *pad_forces])
        if k % max(1, n // 10) == 0 or k == n - 1:
            pads = [c for c in report.contacts if "finger" in c.name_a + c.name_b and c.p_n > 0]
            fn = sum(c.p_n for c in pads) / h / max(len(pads), 1)
            ft = sum(np.hypot(c.p_t, c.p_o) for c in pads) / h / max(len(pads), 1)
            rows.append((world.getTime(), gripper.getPositions()[0], obj.getPositions()[5] - A_OBJ,
                         len(pads), fn, ft, report.iterations))
    wall = (time.perf_counter() - t0) / n
    if verbose:
        print(f"gripper squeeze: F = {squeeze} N per finger, mu = {MU}, object {M_OBJ} kg; "
              f"no slip needs F >= M g / (2 mu) = {M_OBJ * G / (2 * MU):.3f} N (at rest)")
        print("   t [s]   palm z [m]   object rise [m]   pads   normal [N]   friction [N]   iters")
        for t, zp, zo, npads, fn, ft, it in rows:
            print(f"  {t:6.3f}   {zp:10.5f}   {zo:15.5f}   {npads:4d}   {fn:10.4f}   {ft:12.4f}   {it:5d}")
        t, zp, zo = rows[-1][:3]
        verdict = "held (no slip)" if abs(zp - zo) < 1e-3 and zo > 0.5 * LIFT else "not lifted (the pads slid)"
        print(f"  palm rose {zp:.4f} m, object {zo:.4f} m: {verdict}")
        print(f"  wall time per step: {1e3 * wall:.2f} ms")
    return rows, wall, np.array(series)


def plot(runs, path, mu=MU):
    """runs: [(squeeze [N], series from run())]; one column per run."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, len(runs), figsize=(5.2 * len(runs), 8.0), sharex=True, squeeze=False,
                             layout="constrained")
    for col, (squeeze, S) in enumerate(runs):
        t = S[:, 0]
        ax = axes[0, col]
        ax.plot(t, S[:, 3], label="right joint force (command)")
        ax.plot(t, -S[:, 4], "--", label="-(left joint force)")
        ax.plot(t, S[:, 5], ":", label="left pad normal")
        ax.plot(t, S[:, 7], "-.", label="right pad normal")
        ax.set_ylim(-0.1 * squeeze, 2.0 * squeeze)     # the landing's impulse peak is cut off
        ax.set_ylabel("force [N]")
        ax.set_title(f"squeeze {squeeze:g} N per finger "
                     f"({'above' if squeeze >= M_OBJ * G / (2 * mu) else 'below'} M g / (2 mu) = "
                     f"{M_OBJ * G / (2 * mu):.2f} N)")
        ax.legend(fontsize=7)
        ax = axes[1, col]
        ax.plot(t, S[:, 1], label="palm (lift joint)")
        ax.plot(t, S[:, 2], "--", label="object rise")
        ax.set_ylabel("height [m]")
        ax.legend(fontsize=7)
        ax = axes[2, col]
        for j, side in ((5, "left"), (7, "right")):
            ax.plot(t, S[:, j + 1], label=f"{side} pad friction")
            ax.plot(t, mu * S[:, j], ":", label=f"mu x {side} normal")
        ax.axhline(M_OBJ * G / 2, color="grey", lw=0.8, label="M g / 2 (weight per pad)")
        ax.set_ylim(-0.05 * mu * squeeze, 1.5 * mu * squeeze)
        ax.set_ylabel("force [N]")
        ax.set_xlabel("t [s]")
        ax.legend(fontsize=7)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--h", type=float, default=H)
    ap.add_argument("--squeeze", type=float, default=F_SQUEEZE)
    ap.add_argument("--duration", type=float, default=T_SQUEEZE + T_LIFT + 0.4)
    ap.add_argument("--plot", action="store_true",
                    help="write scenes/out/gripper_squeeze.png (this squeeze and 1 N, below the threshold)")
    args = ap.parse_args(argv)
    _, _, series = run(args.h, args.duration, args.squeeze)
    if args.plot:
        weak = 1.0 if args.squeeze != 1.0 else 0.5
        _, _, slipping = run(args.h, args.duration, weak, verbose=False)
        path = Path(__file__).resolve().parent / "out" / "gripper_squeeze.png"
        plot([(args.squeeze, series), (weak, slipping)], path)
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
