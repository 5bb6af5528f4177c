"""Candidate pairs that cannot touch within a step are left out of the MCP (StepperOptions.skip_far_pairs).

The filter must change nothing but the cost: a step's solution with and without it is the same to
round-off, and a pair left out on the free-flight prediction that the solved velocities could close
(a body knocked towards a wall by an impact) is put back and the step solved again.
"""
import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from comparisons import stability

SAME = 1e-12          # [m, rad] the runs with and without the filter agree to round-off
PEN_TOL = 1e-8        # [m]


def _positions(world):
    return np.concatenate([world.getSkeleton(i).getPositions() for i in range(world.getNumSkeletons())])


def test_bodies_landing_in_a_box_move_the_same_with_fewer_pairs():
    runs = {}
    for skip in (False, True):
        world = stability.many_bodies_world(10, 0.01, stability.IMPLICIT)
        stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(skip_far_pairs=skip))
        pairs, states = 0, []
        for _ in range(14):                       # the first landings are at about step 10
            report = stepper.step()
            pairs += len(report.contacts)
            states.append(_positions(world))
        runs[skip] = (pairs, np.array(states), sum(c.p_n > 0 for c in report.contacts))
    (pairs_all, q_all, active), (pairs_near, q_near, active_near) = runs[False], runs[True]
    assert active >= 1 and active_near == active
    assert np.max(np.abs(q_all - q_near)) < SAME
    assert pairs_near < 0.8 * pairs_all           # the filter left out a fifth of the pairs or more


def _sphere(world, name, x, vx, radius=0.1):
    skel = dart.dynamics.Skeleton(name)
    _, body = skel.createFreeJointAndBodyNodePair()
    body.setName(name)
    body.setMass(1.0)
    body.setMomentOfInertia(0.004, 0.004, 0.004)
    ic.attach(body, ic.shapes.Sphere(radius), friction=ic.Friction(mu=0.0))
    skel.setPositions([0.0, 0.0, 0.0, x, 0.0, 0.0])
    skel.setVelocities([0.0, 0.0, 0.0, vx, 0.0, 0.0])
    world.addSkeleton(skel)
    return skel


@pytest.mark.parametrize("skip", [False, True])
def test_a_ball_knocked_into_a_wall_stops_at_it(skip):
    """Ball A rests 1 cm from a wall; ball C arrives at 10 m/s and, within one step, knocks A 4 cm.
    The candidates came from free flight (A at rest: the pair A / wall was not among them); the
    solved step is checked against the broadphase at its end poses, and the step is solved again
    with the pair. Before that check A ended 3 cm inside the wall and bounced out of it."""
    world = dart.simulation.World()
    world.setTimeStep(0.01)
    world.setGravity([0.0, 0.0, 0.0])
    wall = dart.dynamics.Skeleton("wall")
    _, wb = wall.createWeldJointAndBodyNodePair()
    ic.attach(wb, ic.shapes.HalfSpace([-1.0, 0.0, 0.0], 0.0), friction=ic.Friction(mu=0.0))   # solid x >= 0
    world.addSkeleton(wall)
    a = _sphere(world, "a", -0.11, 0.0)
    c = _sphere(world, "c", -0.43, 10.0)
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(skip_far_pairs=skip))
    resolves = []
    original = stepper._one_step

    def spy(h, keep=frozenset()):
        resolves.append(bool(keep))
        return original(h, keep)
    stepper._one_step = spy
    for _ in range(6):
        report = stepper.step()
        assert report.success
        xa, xc = a.getPositions()[3], c.getPositions()[3]
        assert xa <= -0.1 + PEN_TOL and xc <= xa - 0.2 + PEN_TOL
    assert a.getPositions()[3] == pytest.approx(-0.1, abs=PEN_TOL)      # A stopped at the wall
    assert c.getPositions()[3] == pytest.approx(-0.3, abs=PEN_TOL)      # and C against A
    assert abs(a.getVelocities()[3]) < 1e-9 and abs(c.getVelocities()[3]) < 1e-9
    assert any(resolves)                          # the check put the pair A / wall in
