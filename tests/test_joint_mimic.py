"""Mimic joints as bilateral joint rows of the step's MCP (joint_rows.py; issue 15).

DART's URDF loader marks a <mimic> joint MIMIC, but dartpy does not expose its relation; the
stepper takes it from ic.urdf_mimic_joints(urdf) and holds q_f = m q_l + o at the end of every
step, with the constraint's impulse on both dofs.
"""
import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact.testing import dart_world, urdf_skeleton

H = 1e-3
M_LEADER, M_FOLLOWER = 0.2, 0.1
RELATION_TOL = 1e-12       # |q_f - (m q_l + o)| after a step [m]

GRIPPER = f"""<?xml version="1.0"?>
<robot name="gripper">
  <link name="palm">
    <inertial><mass value="1"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>
  </link>
  <joint name="left" type="prismatic">
    <parent link="palm"/><child link="left_pad"/><origin xyz="-0.1 0 0"/><axis xyz="1 0 0"/>
    <limit lower="-0.05" upper="0.2" effort="100" velocity="1"/>
  </joint>
  <link name="left_pad">
    <inertial><mass value="{M_LEADER}"/><inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial>
    <collision><geometry><sphere radius="0.02"/></geometry></collision>
  </link>
  <joint name="right" type="prismatic">
    <parent link="palm"/><child link="right_pad"/><origin xyz="0.1 0 0"/><axis xyz="1 0 0"/>
    <limit lower="-0.2" upper="0.05" effort="100" velocity="1"/>
    <mimic joint="left" multiplier="-1" offset="0"/>
  </joint>
  <link name="right_pad">
    <inertial><mass value="{M_FOLLOWER}"/><inertia ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial>
    <collision><geometry><sphere radius="0.02"/></geometry></collision>
  </link>
</robot>
"""



@pytest.fixture(params=[1, 2], ids=["order1", "order2"])
def order(request):
    """The test holds for [GI]'s step and for the split step of rattle.py (StepperOptions.order)."""
    return request.param

def _world():
    """The gripper, its palm welded, without gravity."""
    world = dart_world(H, gravity=0.0)
    gripper = urdf_skeleton(GRIPPER)
    world.addSkeleton(gripper)
    return world, gripper


def test_urdf_mimic_relation_is_read_and_required():
    assert ic.urdf_mimic_joints(GRIPPER) == {"right": ("left", -1.0, 0.0)}
    world, gripper = _world()
    assert gripper.getJoint("right").getActuatorType().name == "MIMIC"
    with pytest.raises(ValueError, match="urdf_mimic_joints"):
        ic.ImplicitContactStepper(world)
    with pytest.raises(ValueError, match="not joints of a mobile skeleton"):
        ic.ImplicitContactStepper(world, mimic={**ic.urdf_mimic_joints(GRIPPER), "nowhere": ("left", 1.0, 0.0)})


def test_mimic_pair_moves_as_one_body_under_a_force_on_the_leader(order):
    """A force F on the leader accelerates both pads: with q_f = -q_l their kinetic energy is
    (m_l + m_f) v^2 / 2, so a = F / (m_l + m_f); the follower mirrors the leader at every step and
    the relation's impulse on the follower is m_f times its velocity change."""
    world, gripper = _world()
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order), mimic=ic.urdf_mimic_joints(GRIPPER))
    left, right = gripper.getDof("left").getIndexInSkeleton(), gripper.getDof("right").getIndexInSkeleton()
    F = 2.0
    a = F / (M_LEADER + M_FOLLOWER)
    for n in range(1, 101):
        forces = np.zeros(gripper.getNumDofs())
        forces[left] = F
        gripper.setForces(forces)
        stepper.step()
        q, v = gripper.getPositions(), gripper.getVelocities()
        assert abs(q[right] + q[left]) < RELATION_TOL
        assert v[left] == pytest.approx(a * n * H, rel=1e-9)
        assert stepper.joint_mimic_impulse(gripper)[right] == pytest.approx(-M_FOLLOWER * a * H, rel=1e-9)


def test_mimic_fingers_squeeze_a_ball_symmetrically(order):
    """The leader, pushed closed, squeezes a free ball between the pads: the mimic coupling makes
    the squeeze symmetric, so the ball stays centred and both pads press it equally (the
    follower's push comes from the relation's impulse, not from a force of its own)."""
    world, gripper = _world()
    ball = dart.dynamics.Skeleton("ball")
    _, body = ball.createFreeJointAndBodyNodePair()
    node = body.createShapeNode(dart.dynamics.SphereShape(0.03))
    node.createCollisionAspect()
    body.setMass(0.05)
    body.setMomentOfInertia(*(3 * [0.4 * 0.05 * 0.03 ** 2]))
    world.addSkeleton(ball)
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order), mimic=ic.urdf_mimic_joints(GRIPPER))
    left = gripper.getDof("left").getIndexInSkeleton()
    for _ in range(400):
        forces = np.zeros(gripper.getNumDofs())
        forces[left] = 1.0
        gripper.setForces(forces)
        report = stepper.step()
    touching = [c for c in report.contacts if c.p_n > 0.0]
    assert len(touching) == 2
    assert touching[0].p_n == pytest.approx(touching[1].p_n, rel=1e-9)
    # pads at rest on the ball: each presses with the leader's force shared out, F / 2 per pad
    assert touching[0].p_n / H == pytest.approx(0.5, rel=1e-6)
    assert abs(ball.getPositions()[3]) < 1e-12
