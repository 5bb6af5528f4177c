"""Coulomb joint friction as joint rows of the step's MCP (rows/dynamics.py; issue 15).

DART's joint friction (joint.setCoulombFriction) bounds a dof's friction impulse by h f and makes
it maximally dissipative: the dof sticks while the impulse it needs is within the bound, else it
slides with the bounded impulse opposite its velocity. Checked against the closed forms of a
spinning wheel and a held pendulum, against DART's own stepper (the same velocity-level scheme
without contact: the same trajectory to round-off), and with contact in the same MCP.
"""
import math

import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact.params import Friction
from implicit_contact.testing import dart_world, ground_box, revolute_pendulum

G = 9.81
# DART's own stepper and this one agree to round-off while the pendulum slips; once its joint
# sticks, DART's boxed LCP leaves it creeping at its solver's residual (measured over 1 s: 6.6e-12
# and 1.6e-11 rad/s for f = 3 and 5, against <= 7e-16 here)
DART_AGREEMENT = 5e-11     # rad, over the 1 s runs
STICK_TOL = 1e-12          # a stuck dof's velocity [rad/s]



@pytest.fixture(params=[1, 2], ids=["order1", "order2"])
def order(request):
    """The test holds for [GI]'s step and for the split step of rattle.py (StepperOptions.order)."""
    return request.param

def _wheel(h, f, w0, inertia):
    """A wheel on a vertical revolute axis: no torque but the joint friction f."""
    world = dart_world(h, G)
    skel = dart.dynamics.Skeleton("wheel")
    joint, body = skel.createRevoluteJointAndBodyNodePair()
    joint.setAxis([0.0, 0.0, 1.0])
    body.setMass(1.0)
    body.setMomentOfInertia(0.1, 0.1, inertia)
    joint.setCoulombFriction(0, f)
    world.addSkeleton(skel)
    skel.setVelocities([w0])
    return world, skel


def _pendulum(h, f, q0, m=1.0, length=0.5, shape=False):
    """A point-like bob of mass m at distance length below a horizontal revolute axis (y)."""
    world = dart_world(h, G)
    return world, revolute_pendulum(world, q0, m, length, friction=f, bob_radius=0.05 if shape else None)


def test_spinning_wheel_decelerates_at_f_over_I_and_stops_for_good(order):
    h, f, w0, inertia = 1e-3, 0.5, 2.0, 0.2
    world, wheel = _wheel(h, f, w0, inertia)
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order))
    t_stop = inertia * w0 / f                          # 0.8 s
    n_stop = int(round(t_stop / h))
    for n in range(1, int(1.5 * n_stop)):
        stepper.step()
        w = float(wheel.getVelocities()[0])
        impulse = float(stepper.joint_friction_impulse(wheel)[0])
        if n < n_stop:                                 # sliding: the bound, opposite the spin
            assert w == pytest.approx(w0 - n * h * f / inertia, abs=1e-12)
            assert impulse == pytest.approx(-h * f, rel=1e-12)
        elif n > n_stop:                               # stopped, and nothing to resist: no impulse
            assert abs(w) < STICK_TOL
            assert abs(impulse) < 1e-12


def test_held_pendulum_sticks_below_the_friction_bound_and_slips_above():
    h, m, length, q0 = 1e-3, 1.0, 0.5, 1.0
    torque = m * G * length * math.sin(q0)             # gravity's torque about the axis
    inertia = m * length ** 2 + 1e-3
    # sticks: f above the gravity torque holds it, with the impulse that balances gravity
    world, pend = _pendulum(h, 1.2 * torque, q0, m, length)
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(200):
        stepper.step()
    assert float(pend.getPositions()[0]) == pytest.approx(q0, abs=1e-12)
    assert abs(float(pend.getVelocities()[0])) < STICK_TOL
    assert float(stepper.joint_friction_impulse(pend)[0]) == pytest.approx(h * torque, rel=1e-9)
    # slips: f below it, the first step's acceleration is (torque - f) / I about the axis
    f = 0.8 * torque
    world, pend = _pendulum(h, f, q0, m, length)
    stepper = ic.ImplicitContactStepper(world)
    stepper.step()
    assert float(pend.getVelocities()[0]) == pytest.approx(-h * (torque - f) / inertia, rel=1e-9)
    assert float(stepper.joint_friction_impulse(pend)[0]) == pytest.approx(h * f, rel=1e-12)


@pytest.mark.parametrize("f", [0.5, 3.0, 5.0])
def test_swinging_pendulum_follows_dart_native(f):
    """No contact: DART's stepper and this one take the same semi-implicit step with the same
    boxed friction, so they agree to round-off over 1000 steps (slipping, then sticking at f = 3,
    held from the start at f = 5 > m g l sin q0 = 4.13 N m)."""
    h = 1e-3
    runs = []
    for native in (True, False):
        world, pend = _pendulum(h, f, 1.0)
        stepper = None if native else ic.ImplicitContactStepper(world)
        q = []
        for _ in range(1000):
            world.step() if native else stepper.step()
            q.append(float(pend.getPositions()[0]))
        runs.append(np.array(q))
    assert np.abs(runs[0] - runs[1]).max() < DART_AGREEMENT
    assert abs(float(pend.getVelocities()[0])) < STICK_TOL or f == 0.5   # f = 0.5 keeps swinging
    if f == 5.0:
        assert np.abs(runs[1] - 1.0).max() < 1e-12


def test_joint_friction_and_contact_in_one_mcp(order):
    """A pendulum bob (r = 0.05) swings into a frictionless ground and comes to rest on it, at
    the angle where it touches (cos q = 0.7): then the moments about the axis balance, the
    contact's p_n l sin q and the joint friction impulse against gravity's h m g l sin q (how
    the rigid problem shares them out is not unique; their sum is), the friction within h f."""
    h, m, length, f = 1e-3, 1.0, 0.5, 0.5
    world, pend = _pendulum(h, f, 1.2, m=m, length=length, shape=True)
    gb = ground_box(world, top=-0.5 + 0.1)              # 0.1 m above the hanging bob's lowest point
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order))
    stepper.set_pair_friction(pend.getBodyNode(0), gb, Friction(mu=0.0))
    touched = False
    for _ in range(1500):
        report = stepper.step()
        touched |= any(c.p_n > 0.0 for c in report.contacts)
        assert all(c.gap > -1e-9 for c in report.contacts)
    assert touched
    q = float(pend.getPositions()[0])
    assert abs(float(pend.getVelocities()[0])) < 1e-9
    assert abs(q) == pytest.approx(math.acos(0.7), abs=1e-7)
    (c,) = [c for c in report.contacts if c.p_n > 0.0]
    impulse = float(stepper.joint_friction_impulse(pend)[0])
    assert abs(impulse) <= h * f * (1 + 1e-12)
    lever = length * math.sin(abs(q))
    assert c.p_n * lever + math.copysign(impulse, q) == pytest.approx(h * m * G * lever, rel=1e-8)
