"""Enforced joint position limits as joint rows of the step's MCP (joint_rows.py; issue 15).

A limit row holds q_j + h v_j+ on the allowed side at l+1 (geometrically implicit in joint space,
inelastic), is built only when the dof is near its limit, and a limit that a solved step crosses
although its row was left out is added and the step solved again.
"""
import math

import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact.testing import dart_world, revolute_pendulum

G = 9.81
H = 1e-3
M, LENGTH = 1.0, 0.5
BALL_AT_REST = 1e-3        # |v_x| of the ball after the blow [m/s] (its fall tilts the normal)
LIMIT_TOL = 1e-12          # how far past a held limit q may end [rad] (solver tolerance, far below it)



@pytest.fixture(params=[1, 2], ids=["order1", "order2"])
def order(request):
    """The test holds for [GI]'s step and for the split step of rattle.py (StepperOptions.order)."""
    return request.param

def _pendulum(q0, lower=-np.inf, upper=np.inf, bob_radius=None, mass=M):
    """A bob of mass m at LENGTH below a horizontal revolute axis (y) at the origin; positive q
    swings it towards -x."""
    world = dart_world(H, G)
    return world, revolute_pendulum(world, q0, mass, LENGTH, limits=(lower, upper), bob_radius=bob_radius)


def test_pendulum_falls_onto_its_lower_limit_and_rests_with_the_static_impulse(order):
    lower = 0.5
    world, pend = _pendulum(1.0, lower=lower, upper=2.0)
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order))
    q_prev, v_prev = 1.0, 0.0
    rows_seen = False
    for _ in range(1000):
        report = stepper.step()
        q, v = float(pend.getPositions()[0]), float(pend.getVelocities()[0])
        assert q >= lower - LIMIT_TOL
        if report.unknowns:
            rows_seen = True
        else:                     # no row while the limit is out of reach of this step
            assert q_prev - lower > H * abs(v_prev)
        q_prev, v_prev = q, v
    assert rows_seen
    assert q == pytest.approx(lower, abs=LIMIT_TOL)
    assert abs(v) < 1e-12
    # at rest on the stop: its impulse carries gravity's torque, h m g l sin(lower)
    impulse = float(stepper.joint_limit_impulse(pend)[0])
    assert impulse == pytest.approx(H * M * G * LENGTH * math.sin(lower), rel=1e-9)


def test_limit_stop_follows_dart_native():
    """Before the stop the two steppers take the same step (to round-off); DART's constraint
    then holds the limit to its LCP residual, this one to the MCP's tolerance: both rest on it."""
    runs = []
    for native in (True, False):
        world, pend = _pendulum(1.0, lower=0.5, upper=2.0)
        stepper = None if native else ic.ImplicitContactStepper(world)
        q = []
        for _ in range(1000):
            world.step() if native else stepper.step()
            q.append(float(pend.getPositions()[0]))
        runs.append(np.array(q))
    free = runs[0] > 0.5 + 1e-3
    first = int(np.argmin(free))                        # the first step at the stop
    assert first > 100
    assert np.abs(runs[0][:first] - runs[1][:first]).max() < 1e-12
    assert abs(runs[0][-1] - 0.5) < 1e-9 and abs(runs[1][-1] - 0.5) < LIMIT_TOL


def test_struck_pendulum_is_held_by_a_limit_its_first_solve_left_out(order):
    """A hanging pendulum (at rest, 1 mrad from its upper limit: no row) is struck by a ball at
    5 m/s: the first solve swings it past the limit, the limit's row is added and the step solved
    again; the stop holds the bob, so the rigid, inelastic impact leaves the ball at rest along x
    (restitution 0; the step that touches ends with the ball at the held bob, v+ the distance it
    covered, the next one stops it) and the limit's impulse takes the blow."""
    upper = 1e-3
    world, pend = _pendulum(0.0, upper=upper, bob_radius=0.05)
    ball = dart.dynamics.Skeleton("ball")
    _, body = ball.createFreeJointAndBodyNodePair()
    r, m = 0.05, 0.5
    node = body.createShapeNode(dart.dynamics.SphereShape(r))
    node.createCollisionAspect()
    body.setMass(m)
    body.setMomentOfInertia(*(3 * [0.4 * m * r * r]))
    ball.setPositions([0.0, 0.0, 0.0, 0.1 + 0.012, 0.0, -LENGTH])     # 12 mm from the bob
    ball.setVelocities([0.0, 0.0, 0.0, -5.0, 0.0, 0.0])
    world.addSkeleton(ball)
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order))
    struck = None
    for n in range(20):
        report = stepper.step()
        q = float(pend.getPositions()[0])
        assert q <= upper + LIMIT_TOL
        if any(c.p_n > 0.0 for c in report.contacts) and struck is None:
            struck = n
            assert float(stepper.joint_limit_impulse(pend)[0]) < 0.0   # the stop pushes towards -q
            assert q == pytest.approx(upper, abs=LIMIT_TOL)
        if struck is not None and n == struck + 1:
            assert abs(float(ball.getVelocities()[3])) < BALL_AT_REST
    assert struck is not None
