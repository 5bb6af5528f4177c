"""The restarts of a failed solve from static closest points at the poses its iterate implies
(recovery._reseed): centred on the touch patch (recovery.reseed) or the static solver's own points
(recovery.uncentred_reseed), on a box whose bottom face is tilted by micro-radians over the ground.

Tilted by less than the contact tolerance over its face, the box touches the ground at its lowest
corner; the centred seed puts the point under the box's centre, where the closest-point rows are
off (the bottom face's normal is not the ground's), and Newton cannot walk the point to the corner
along a face its rows see as flat (example-robot-data's hyq, on the hull edges of its thighs,
stalled there at every h)."""
from types import SimpleNamespace

import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact import recovery
from implicit_contact.testing import dart_world, ground_box

SIZE = (0.4, 0.3, 0.1)
TILT = (2.0e-6, -1.3e-6, 0.0)     # [rad] rotation vector: the corners' heights differ by < 1e-6 m
POINT = 1e-9                      # [m] the seed's points against the analytic corner
KKT = 1e-12                       # the closest-point rows (15)-(18) at the corner


def _corners(R, p):
    half = 0.5 * np.asarray(SIZE)
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    return (signs * half) @ R.T + p


def _tilted_box_seeds():
    """(lowest corner, {centred: seeded z}, problem, the failed-solve stand-in) from the box's first
    step: the seeds are taken inside the step, from its first solve's problem, with the velocities
    of the iterate set to zero (the end poses are the start poses)."""
    world = dart_world(0.01)
    ground_box(world, mu=0.5)
    skel = dart.dynamics.Skeleton("box")
    _, body = skel.createFreeJointAndBodyNodePair()
    node = body.createShapeNode(dart.dynamics.BoxShape(list(SIZE)))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(0.5)
    body.setMass(2.0)
    world.addSkeleton(skel)
    q = np.zeros(6)
    q[:3] = TILT
    skel.setPositions(q)
    T = body.getWorldTransform()
    R = np.asarray(T.rotation())
    q[3:] = [0.0, 0.0, -_corners(R, np.zeros(3))[:, 2].min()]    # the lowest corner at z = 0
    skel.setPositions(q)
    corner = min(_corners(R, q[3:]), key=lambda c: c[2])
    seen = {}

    def capture(stepper, att, problem, result):
        if not seen:
            x = result.x.copy()
            for cols in problem.layout.v_index:
                x[cols] = 0.0
            seen.update(problem=problem, x=x, att=att,
                        z={c: recovery._reseed(problem, x, att.tol, centred=c) for c in (True, False)})
        return None

    stepper = ic.ImplicitContactStepper(world)
    original = recovery.RECOVERIES
    recovery.RECOVERIES = (capture,) + original
    try:
        stepper.step()
    finally:
        recovery.RECOVERIES = original
    return corner, seen


def _kkt_residual(problem, z, sl):
    """The natural residual of the pair's closest-point rows (15)-(18) at z (scaled rows)."""
    rows = np.concatenate([sl.rows_geo, sl.rows_l1, sl.rows_l2]).astype(int)
    F = problem.fun(z)
    y = np.clip(z[rows] - F[rows], problem.lower[rows], problem.upper[rows])
    return float(np.max(np.abs(z[rows] - y)))


def test_the_uncentred_seed_is_the_lowest_corner_and_solves_the_closest_point_rows():
    corner, seen = _tilted_box_seeds()
    problem = seen["problem"]
    (sl,) = problem.layout.pairs
    z = seen["z"][False]
    np.testing.assert_allclose(z[sl.a1s], corner, atol=POINT)
    np.testing.assert_allclose(z[sl.a2s], corner, atol=POINT)
    assert _kkt_residual(problem, z, sl) <= KKT
    # the centred seed: under the centre, 0.25 m from the corner, its rows off by about the tilt
    zc = seen["z"][True]
    assert np.linalg.norm(zc[sl.a2s] - corner) > 0.2
    assert _kkt_residual(problem, zc, sl) > 0.1 * np.hypot(*TILT[:2])


def test_uncentred_reseed_applies_once_to_a_failed_solve_near_a_solution():
    _, seen = _tilted_box_seeds()
    problem, x = seen["problem"], seen["x"]
    att = SimpleNamespace(uncentred=False, tol=seen["att"].tol, reseeded=None)
    converged = SimpleNamespace(success=True, residual=0.0, x=x)
    far = SimpleNamespace(success=False, residual=10 * recovery.NEAR_SOLUTION, x=x)
    near = SimpleNamespace(success=False, residual=0.5 * recovery.NEAR_SOLUTION, x=x)
    assert recovery.uncentred_reseed(None, att, problem, converged) is None
    assert recovery.uncentred_reseed(None, att, problem, far) is None
    assert att.reseeded is None
    assert recovery.uncentred_reseed(None, att, problem, near) is recovery.RETRY
    np.testing.assert_array_equal(att.reseeded, seen["z"][False])
    att.reseeded = None
    assert recovery.uncentred_reseed(None, att, problem, near) is None     # once a step
    assert att.reseeded is None


def test_the_uncentred_recovery_comes_before_the_proximal_re_solve():
    """Both apply near a solution; the reseed is cheap (one static solve per pair) where the
    proximal re-solves cost two watched solves, and on hyq it was the one that converged."""
    order = recovery.RECOVERIES
    assert order.index(recovery.uncentred_reseed) < order.index(recovery.indeterminate_impulses)
    with pytest.raises(ValueError):
        order.index(None)
