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

Run: python -m scenes.gripper_squeeze [--h 0.002] [--squeeze 10] [--duration 1.5]
"""
import argparse
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


# 4. Run
def run(h=H, duration=1.5, squeeze=F_SQUEEZE, verbose=True):
    world, gripper, obj = build_world(h)
    stepper = ic.ImplicitContactStepper(world)
    rows = []
    t0 = time.perf_counter()
    n = int(round(duration / h))
    for k in range(n):
        control(gripper, world.getTime(), squeeze)
        report = stepper.step()
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
    return rows, wall


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--h", type=float, default=H)
    ap.add_argument("--squeeze", type=float, default=F_SQUEEZE)
    ap.add_argument("--duration", type=float, default=T_SQUEEZE + T_LIFT + 0.4)
    args = ap.parse_args(argv)
    run(args.h, args.duration, args.squeeze)


if __name__ == "__main__":
    main()
