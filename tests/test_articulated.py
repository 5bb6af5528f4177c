"""Articulated skeletons (issue 6): a revolute pendulum striking a fixed ellipsoid, a URDF arm
pushing a ball against DART's native stepper, refusals, and the Jacobian of an articulated pair."""
import math

import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact import formulation as fm
from implicit_contact.testing import dart_world, ground_box, jacobian_error, random_blocks, random_point, urdf_skeleton
from implicit_contact import shapes as shp
from implicit_contact.closest import closest_points
from implicit_contact.params import Friction

L, R_TIP = 0.5, 0.05


def _iso(T):
    return dart.math.Isometry3(T) if hasattr(dart.math, "Isometry3") else T


def _pendulum_world(h, obstacle=True, q0=1.2, damping=0.0, mu=0.3):
    """A 1-dof revolute pendulum (pivot at z = 1, axis y) with a sphere at its tip, and a fixed
    ellipsoid in the path of the tip (or none)."""
    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity([0.0, 0.0, -9.81])
    skel = dart.dynamics.Skeleton("pendulum")
    joint, body = skel.createRevoluteJointAndBodyNodePair()
    joint.setAxis([0.0, 1.0, 0.0])
    T = np.eye(4)
    T[2, 3] = 1.0
    joint.setTransformFromParentBodyNode(_iso(T))
    joint.setDampingCoefficient(0, damping)
    body.setMass(1.0)
    body.setLocalCOM([0.0, 0.0, -L])
    body.setMomentOfInertia(1e-3, 1e-3, 1e-3)
    ic.attach(body, shp.Sphere(R_TIP, center=[0.0, 0.0, -L]), friction=Friction(mu))
    skel.setPositions([q0])
    world.addSkeleton(skel)
    obst = None
    if obstacle:
        g = dart.dynamics.Skeleton("obstacle")
        wj, obst = g.createWeldJointAndBodyNodePair()
        T = np.eye(4)
        T[:3, 3] = [0.2, 0.0, 0.45]
        wj.setTransformFromParentBodyNode(_iso(T))
        ic.attach(obst, shp.Ellipsoid([0.1, 0.2, 0.15]), friction=Friction(mu))
        world.addSkeleton(g)
    return world, skel, body, obst


def _energy(skel):
    return skel.computeKineticEnergy() + skel.computePotentialEnergy()


def _distance(body, obst):
    T1, T2 = body.getWorldTransform().matrix(), obst.getWorldTransform().matrix()
    res = closest_points(shp.Sphere(R_TIP, center=[0.0, 0.0, -L]), (T1[:3, :3], T1[:3, 3]),
                         shp.Ellipsoid([0.1, 0.2, 0.15]), (T2[:3, :3], T2[:3, 3]))
    return -res.depth if res.overlapping else res.distance


def test_pendulum_strikes_ellipsoid_without_penetration_or_energy_gain():
    h = 2e-3
    world, skel, body, obst = _pendulum_world(h)
    stepper = ic.ImplicitContactStepper(world)
    E0 = _energy(skel)
    E, worst, contact_steps, gain_in_contact, gain_free = E0, math.inf, 0, 0.0, 0.0
    for _ in range(int(round(1.5 / h))):
        report = stepper.step()
        assert report.success
        E1 = _energy(skel)
        worst = min(worst, _distance(body, obst))      # DART's own pose after integratePositions
        if any(c.p_n > 0.0 for c in report.contacts):
            contact_steps += 1
            gain_in_contact = max(gain_in_contact, E1 - E)
        else:
            gain_free = max(gain_free, E1 - E)
        E = E1
    assert contact_steps >= 2                           # it did strike (more than once)
    assert worst >= -1e-6                               # no penetration beyond 1e-6 m
    assert gain_in_contact <= 1e-9                      # contact steps never add energy
    # free flight: DART's semi-implicit Euler oscillates by O(h) (measured 2.4e-4 J per step here)
    assert gain_free < 1e-3
    assert E < E0 - 1.0                                 # inelastic impacts dissipated energy


def test_free_pendulum_matches_dart_and_drifts_first_order():
    drifts = []
    for h in (4e-3, 2e-3):
        world, skel, _, _ = _pendulum_world(h, obstacle=False, damping=0.3 if h == 4e-3 else 0.0)
        native, nskel, _, _ = _pendulum_world(h, obstacle=False, damping=0.3 if h == 4e-3 else 0.0)
        stepper = ic.ImplicitContactStepper(world)
        for _ in range(int(round(0.5 / h))):
            stepper.step()
            native.step()
        # the free step is DART's own (joint damper implicit as in DART)
        np.testing.assert_allclose(skel.getPositions(), nskel.getPositions(), atol=1e-12)
        np.testing.assert_allclose(skel.getVelocities(), nskel.getVelocities(), atol=1e-12)
    for h in (4e-3, 2e-3):
        world, skel, _, _ = _pendulum_world(h, obstacle=False)
        stepper = ic.ImplicitContactStepper(world)
        E0 = _energy(skel)
        worst = 0.0
        for _ in range(int(round(2.0 / h))):
            stepper.step()
            worst = max(worst, abs(_energy(skel) - E0))
        drifts.append(worst)
    ratio = drifts[0] / drifts[1]
    assert 1.6 < ratio < 2.5, drifts                    # first order in h


# -- a URDF arm pushing a ball, implicit against native ---------------------------------------
URDF = """<?xml version="1.0"?>
<robot name="arm">
  <link name="base">
    <inertial><mass value="1.0"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  </link>
  <joint name="shoulder" type="continuous">
    <parent link="base"/><child link="upper"/>
    <origin xyz="0 0 0.08" rpy="0 0 0"/><axis xyz="0 0 1"/>
  </joint>
  <link name="upper">
    <inertial><origin xyz="0.2 0 0"/><mass value="1.0"/>
      <inertia ixx="0.0003" ixy="0" ixz="0" iyy="0.0135" iyz="0" izz="0.0135"/></inertial>
    <collision><origin xyz="0.2 0 0"/><geometry><box size="0.4 0.04 0.04"/></geometry></collision>
  </link>
  <joint name="elbow" type="continuous">
    <parent link="upper"/><child link="fore"/>
    <origin xyz="0.4 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/>
  </joint>
  <link name="fore">
    <inertial><origin xyz="0.15 0 0"/><mass value="0.5"/>
      <inertia ixx="0.0002" ixy="0" ixz="0" iyy="0.004" iyz="0" izz="0.004"/></inertial>
    <collision><origin xyz="0.15 0 0"/><geometry><box size="0.3 0.04 0.04"/></geometry></collision>
  </link>
</robot>
"""


def _arm_world(h, mu=0.5):
    world = dart_world(h)
    arm = urdf_skeleton(URDF)
    arm.setPositions([-0.6, 0.0])
    world.addSkeleton(arm)
    ball = dart.dynamics.Skeleton("ball")
    _, body = ball.createFreeJointAndBodyNodePair()
    r = 0.08
    node = body.createShapeNode(dart.dynamics.SphereShape(r))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(mu)
    body.setMass(0.5)
    inertia = 0.4 * 0.5 * r * r
    body.setMomentOfInertia(inertia, inertia, inertia)
    ball.setPositions([0.0, 0.0, 0.0, 0.55, 0.0, r])
    world.addSkeleton(ball)
    ground_box(world, mu=mu)
    for k in range(arm.getNumBodyNodes()):
        b = arm.getBodyNode(k)
        for s in range(b.getNumShapeNodes()):
            sn = b.getShapeNode(s)
            if sn.hasCollisionAspect():
                (sn.getDynamicsAspect() or sn.createDynamicsAspect()).setFrictionCoeff(mu)
    return world, arm, ball


def _sweep(arm, t, T=1.0):
    """PD joint forces: the shoulder sweeps from -0.6 to 0.8 rad in T, the elbow holds 0."""
    qd = np.array([-0.6 + 1.4 * min(t / T, 1.0), 0.0])
    vd = np.array([1.4 / T if t < T else 0.0, 0.0])
    q, v = np.asarray(arm.getPositions()), np.asarray(arm.getVelocities())
    arm.setForces(np.array([60.0, 20.0]) * (qd - q) + np.array([3.0, 1.0]) * (vd - v))


def _push(native, h=2e-3, T=1.2):
    world, arm, ball = _arm_world(h)
    stepper = None if native else ic.ImplicitContactStepper(world)
    p0 = np.asarray(ball.getPositions())[3:].copy()
    touched = False
    for _ in range(int(round(T / h))):
        _sweep(arm, world.getTime())
        if native:
            world.step()
        else:
            report = stepper.step()
            touched |= any(c.p_n > 0.0 and "ball" in (c.name_a + c.name_b) and "arm" in (c.name_a + c.name_b)
                           for c in report.contacts)
    if not native:
        assert touched
    return np.asarray(ball.getPositions())[3:] - p0, np.asarray(arm.getPositions())


def test_urdf_arm_pushes_ball_like_dart_native():
    d_imp, q_imp = _push(native=False)
    d_nat, q_nat = _push(native=True)
    # both push the ball sideways (+y, the sweep direction) on the ground, by comparable distances
    assert d_imp[1] > 0.3 and d_nat[1] > 0.3
    cos = d_imp[:2] @ d_nat[:2] / (np.linalg.norm(d_imp[:2]) * np.linalg.norm(d_nat[:2]))
    assert cos > 0.98
    assert 0.7 < np.linalg.norm(d_imp[:2]) / np.linalg.norm(d_nat[:2]) < 1.4
    assert abs(d_imp[2]) < 1e-5                        # the ball stays on the ground
    np.testing.assert_allclose(q_imp, q_nat, atol=0.05)


# -- massless links (a URDF's ee_link / tool0) ----------------------------------------------------
TIP_URDF = """<?xml version="1.0"?>
<robot name="tipped">
  <link name="base">
    <inertial><mass value="1.0"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  </link>
  <joint name="hinge" type="continuous">
    <parent link="base"/><child link="arm"/><origin xyz="0 0 0.2"/><axis xyz="0 1 0"/>
  </joint>
  <link name="arm">
    <inertial><origin xyz="0.25 0 0"/><mass value="1.0"/>
      <inertia ixx="1e-4" ixy="0" ixz="0" iyy="0.0209" iyz="0" izz="0.0209"/></inertial>
  </link>
  <joint name="ee_fixed" type="fixed"><parent link="arm"/><child link="ee_link"/><origin xyz="0.5 0 0"/></joint>
  <link name="ee_link">
    <inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>
    <collision><geometry><sphere radius="0.02"/></geometry></collision>
  </link>
  <joint name="tool_fixed" type="fixed"><parent link="ee_link"/><child link="tool0"/><origin xyz="0.01 0 0"/></joint>
  <link name="tool0">
    <inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial>
  </link>
</robot>
"""
REST_FORCE_RTOL = 1e-6


@pytest.mark.parametrize("tip_mass", [0.0, 1e-6])
def test_massless_welded_tip_rests_with_the_static_normal_force(tip_mass):
    """A hinged rod (1 kg, centre of mass at half its 0.5 m length) whose only contact shape is a
    sphere on a massless link welded to its end (as a UR5's ee_link, which DART steps), with a
    massless tool0 beyond it: dropped from horizontal onto a frictionless ground, it rests on the
    tip with the normal force of the statics, N = m g x_com / x_tip = m g / 2 at any angle.
    (Before: the massless link's impulse unit was 0 and the warm start 0/0, a NaN start.) A 1e-6
    kg tip, as robot foot frames weigh, adds its weight at the tip."""
    h, g = 2e-3, 9.81
    world = dart_world(h, g)
    rod = urdf_skeleton(TIP_URDF.replace('<mass value="0"/>', f'<mass value="{tip_mass}"/>', 1))
    assert rod.getBodyNode("ee_link").getMass() == tip_mass and rod.getBodyNode("tool0").getMass() == 0.0
    world.addSkeleton(rod)
    gb = ground_box(world)
    stepper = ic.ImplicitContactStepper(world)
    stepper.set_pair_friction(rod.getBodyNode("ee_link"), gb, Friction(mu=0.0))
    for _ in range(int(round(0.6 / h))):
        report = stepper.step()
    (tip,) = [c for c in report.contacts if "ee_link" in c.name_a + c.name_b]
    sin_rest = (0.2 - 0.02) / 0.5                      # the sphere's centre 0.02 above the ground
    assert math.asin(sin_rest) == pytest.approx(float(rod.getPositions()[0]), abs=1e-6)
    assert abs(float(rod.getVelocities()[0])) < 1e-9
    assert tip.p_n / h == pytest.approx(g * (1.0 / 2 + tip_mass), rel=REST_FORCE_RTOL)   # the tip weighs too
    assert tip.gap > -1e-9


# -- refusals -----------------------------------------------------------------------------------
def test_enforced_joint_limits_outside_or_on_rotations_are_refused():
    # (enforced limits on q + h v coordinates are supported since issue 15: tests/test_joint_limits.py)
    world, skel, _, _ = _pendulum_world(1e-3, q0=1.2)
    joint = skel.getJoint(0)
    joint.setPositionLowerLimit(0, -0.5)
    joint.setPositionUpperLimit(0, 0.5)
    joint.setLimitEnforcement(True)
    with pytest.raises(ValueError, match="outside its enforced limits"):
        ic.ImplicitContactStepper(world)
    world = dart.simulation.World()
    ball = dart.dynamics.Skeleton("ball_jointed")
    bj, body = ball.createBallJointAndBodyNodePair()
    body.setMass(1.0)
    ic.attach(body, shp.Sphere(0.1, center=[0.0, 0.0, -0.5]))
    bj.setLimitEnforcement(True)
    world.addSkeleton(ball)
    with pytest.raises(ValueError, match="BallJoint's rotation does not"):
        ic.ImplicitContactStepper(world)


def test_constraint_joints_are_refused():
    # (Coulomb joint friction is supported since issue 15: tests/test_joint_friction.py)
    world, skel, _, _ = _pendulum_world(1e-3)
    skel.getJoint(0).setActuatorType(dart.dynamics.ActuatorType.SERVO)
    with pytest.raises(ValueError, match="SERVO"):
        ic.ImplicitContactStepper(world)


# -- the Jacobian of an articulated pair ----------------------------------------------------------
H = 0.01
EPS_FD = 1e-6


def _articulated(rng, col, ndof):
    R, p = fm.so3_exp(rng.normal(size=3)), rng.normal(size=3)
    J = rng.normal(size=(6, ndof))
    return fm.BodyKinematics(fm.ARTICULATED, 3, R, p, None, H, np.arange(col, col + ndof), 1.0, J)


def _problem(kinds, piece1, piece2, friction, rng, reduced=(False, False)):
    bodies, nv, col = [], [], 0
    for kind in kinds:
        if kind == "articulated":
            bodies.append(_articulated(rng, col, 4))
            nv.append(4)
            col += 4
        elif kind == "free":
            R, p = fm.so3_exp(rng.normal(size=3)), rng.normal(size=3)
            bodies.append(fm.BodyKinematics(fm.FREE, 3, R, p, None, H, np.arange(col, col + 6), 1.0))
            nv.append(6)
            col += 6
        else:
            bodies.append(fm.BodyKinematics(fm.FIXED, 3, fm.so3_exp(np.array([0.0, 0.0, 0.3])),
                                            np.array([0.1, 0.2, 0.3]), None, H, None))
    o1 = fm.ContactObject(0, tuple(piece1.functions), reduced[0])
    o2 = fm.ContactObject(1, tuple(piece2.functions), reduced[1])
    spec = fm.PairSpec(("a", "b"), o1, o2, 3, friction, friction.active, 0, np.array([1.0, 0.0, 0.0]), 0.05)
    layout = fm.build_layout(nv, [spec])
    blocks = random_blocks(bodies, rng)
    return fm.StepProblem(H, blocks, bodies, [spec], layout), layout


ART_CASES = [
    (("articulated", "fixed"), shp.Sphere(0.3, center=[0.1, 0.0, 0.2]), shp.Ellipsoid([0.4, 0.3, 0.2]),
     Friction(0.3, 1.0, 0.8, 0.2)),
    (("articulated", "free"), shp.Ellipsoid([0.3, 0.2, 0.25]), shp.Intersection.box([0.3, 0.2, 0.1]),
     Friction(0.4)),
    (("free", "articulated"), shp.Sphere(0.2), shp.Superquadric([0.5, 0.4, 0.3], 4.0), Friction(0.3, 1.0, 1.0, 0.1)),
    (("articulated", "articulated"), shp.Ellipsoid([0.3, 0.2, 0.25]), shp.Sphere(0.3), Friction(0.0)),
]


@pytest.mark.parametrize("case", range(len(ART_CASES)))
def test_articulated_pair_jacobian_matches_central_differences(case):
    kinds, piece1, piece2, friction = ART_CASES[case]
    rng = np.random.default_rng(10 + case)
    problem, layout = _problem(kinds, piece1, piece2, friction, rng)
    assert jacobian_error(problem, random_point(layout, rng), EPS_FD) < 5e-6


EQUIV_CASES = [
    (("free", "free"), shp.Ellipsoid([0.3, 0.2, 0.25]), shp.Intersection.box([0.3, 0.2, 0.1]), (False, False)),
    (("free", "fixed"), shp.Sphere(0.3, center=[0.1, 0.0, 0.0]), shp.HalfSpace([0.0, 0.0, 1.0], 0.0), (False, True)),
    (("fixed", "free"), shp.HalfSpace([0.0, 0.0, 1.0], 0.0), shp.Intersection.box([0.3, 0.2, 0.1]), (True, False)),
]


@pytest.mark.parametrize("case", range(len(EQUIV_CASES)))
def test_articulated_body_with_identity_jacobian_is_a_free_body(case):
    """An ARTICULATED body whose Jacobian is I6 is a free body: same F and J on pairs with friction
    and torsion (reduced half-spaces too)."""
    kinds, piece1, piece2, reduced = EQUIV_CASES[case]
    friction = Friction(0.3, 1.0, 0.8, 0.2)
    fast, layout = _problem(kinds, piece1, piece2, friction, np.random.default_rng(3), reduced=reduced)
    z = random_point(layout, np.random.default_rng(4))
    art, _ = _problem(kinds, piece1, piece2, friction, np.random.default_rng(3), reduced=reduced)
    for b in art.bodies:
        if b.kind == fm.FREE:
            b.kind, b.jacobian = fm.ARTICULATED, np.eye(6)
    art = fm.StepProblem(H, art.skeletons, art.bodies, art.specs, art.layout)
    np.testing.assert_allclose(art.fun(z), fast.fun(z), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(art.jac(z), fast.jac(z), rtol=1e-10, atol=1e-10)


def test_gripper_scene_lifts_when_squeezed_enough():
    from scenes import gripper_squeeze as scene
    rows, _, series = scene.run(h=0.004, duration=scene.T_SQUEEZE + scene.T_LIFT + 0.1, verbose=False)
    # the plotted series: commanded finger forces, each pad's normal = the squeeze, friction in the cone
    last = series[-1]
    assert last[3] == scene.F_SQUEEZE and last[4] == -scene.F_SQUEEZE
    np.testing.assert_allclose(last[[5, 7]], scene.F_SQUEEZE, rtol=1e-6)
    assert np.all(series[:, [6, 8]] <= scene.MU * series[:, [5, 7]] * (1 + 1e-6) + 1e-9)
    t, palm, rise, pads, fn, ft, _ = rows[-1]
    assert pads == 2 and abs(fn - scene.F_SQUEEZE) < 1e-6        # each pad carries the squeeze
    assert rise > 0.9 * scene.LIFT and abs(palm - rise) < 1e-3   # lifted with the palm, no slip
    assert ft <= scene.MU * fn
