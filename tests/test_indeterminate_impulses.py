"""recovery.indeterminate_impulses: redundant contacts (impulses not unique) solved by the proximal
point method on the impulses (ncp.solve_proximal; its own tests are in test_ncp.py).

The scene is a table: one rigid body with four box legs, landing flat on a ground box while it
slides and spins. Four parallel leg faces on a plane leave the normal impulses a warp mode
(+ - + -) that no velocity sees, and sticking legs share the body's tangential and torsional
impulse: the step's Jacobian is singular in those directions.

The legs land sliding (the table spins at 2 rad/s), and by default a new contact that clearly
slides starts its friction re-solve sliding (recovery._clearly_sliding): that landing then takes
2 substeps with or without this recovery (measured). The guards below land the table as every
new contact used to land, from a sticking start (recovery.SLIDE_RATIO = inf), the start a contact
that may stick still gets; their landing stalls next to a solution and needs this recovery.
"""
import numpy as np
import pytest

import dartpy as dart

import implicit_contact as ic
from implicit_contact import ncp, recovery, step_solver
from implicit_contact.testing import dart_world, ground_box

H = 1e-3
MASS = 5.0
LEGS = [(x, y) for x in (-0.27, 0.27) for y in (-0.17, 0.17)]
LANDING = 4          # the step in which the legs land (they start 2 mm over the ground at 0.5 m/s)
REST_TOL = 1e-6      # [m/s, rad/s] resting velocities
WEIGHT_RTOL = 1e-6   # summed normal impulse of a resting step against m g h


def _table_world(mu):
    world = dart_world(H)
    table = dart.dynamics.Skeleton("table")
    _, body = table.createFreeJointAndBodyNodePair()

    def box(size, position):
        node = body.createShapeNode(dart.dynamics.BoxShape(list(size)))
        T = dart.math.Isometry3()
        T.set_translation(list(position))
        node.setRelativeTransform(T)
        node.createCollisionAspect()
        node.createDynamicsAspect().setFrictionCoeff(mu)

    box((0.6, 0.4, 0.03), (0.0, 0.0, 0.3))
    for x, y in LEGS:
        box((0.03, 0.03, 0.3), (x, y, 0.135))          # leg bottoms at z = -0.015 in the body
    body.setMass(MASS)
    body.setMomentOfInertia(0.1, 0.2, 0.25)
    world.addSkeleton(table)
    ground_box(world, mu=mu)
    table.setPositions([0.0, 0.0, 0.0, 0.0, 0.0, 0.017])
    table.setVelocities([0.0, 0.0, 2.0, 0.3, 0.2, -0.5])   # spinning at 2 rad/s, sliding, falling
    return world, table


def _land_and_rest(steps):
    world, table = _table_world(mu=1.0)
    stepper = ic.ImplicitContactStepper(world)
    reports = [stepper.step() for _ in range(steps)]
    return reports, table


@pytest.fixture
def sticking_start(monkeypatch):
    """Every new contact's friction re-solve starts sticking (see the module's docstring)."""
    monkeypatch.setattr(recovery, "SLIDE_RATIO", np.inf)


@pytest.mark.parametrize("slide_ratio", [recovery.SLIDE_RATIO, np.inf])
def test_four_legged_table_lands_with_fewer_halvings_and_rests_on_its_weight(monkeypatch, slide_ratio):
    """From the sticking start (SLIDE_RATIO = inf), with the proximal re-solve the landing step
    needs 2 substeps (measured: its frictionless solve at h / 2 stalled at natural residual 4e-5
    with p_n = (21, 0, 0, 24) on the legs, and converged in 2 proximal steps); without it, 4. The table then rests: zero velocities, and the
    legs' normal impulses sum to m g h in every resting step (however they share it). The same
    holds with the default sliding start."""
    monkeypatch.setattr(recovery, "SLIDE_RATIO", slide_ratio)
    reports, table = _land_and_rest(60)
    assert all(r.success for r in reports)
    assert reports[LANDING].substeps <= 2
    assert max(r.substeps for r in reports) <= 2
    np.testing.assert_allclose(table.getVelocities(), 0.0, atol=REST_TOL)
    last = reports[-1]
    legs = [c for c in last.contacts if c.p_n > 0.0]
    assert len(legs) >= 3
    assert sum(c.p_n for c in last.contacts) == pytest.approx(MASS * 9.81 * H, rel=WEIGHT_RTOL)


def test_without_the_proximal_re_solve_the_landing_is_halved_twice(monkeypatch, sticking_start):
    """The same scene with indeterminate_impulses left out of the recoveries, and without the
    solver's min-map endgame (step_solver.ENDGAME_RESIDUAL), which lands it with 2 substeps on its
    own (next test): the landing step needs 4 substeps (the guard that the test above exercises
    this recovery)."""
    monkeypatch.setattr(recovery, "RECOVERIES",
                        tuple(r for r in recovery.RECOVERIES if r is not recovery.indeterminate_impulses))
    monkeypatch.setattr(step_solver, "ENDGAME_RESIDUAL", -1.0)
    reports, _ = _land_and_rest(LANDING + 1)
    assert reports[LANDING].substeps == 4


def test_the_min_map_endgame_alone_lands_the_table_with_one_halving(monkeypatch, sticking_start):
    """Without indeterminate_impulses, the solves that stall next to a solution (natural residual
    <= step_solver.ENDGAME_RESIDUAL, J singular along the warp mode and the shared torsions) are
    finished by ncp.newton_min_map's least-norm steps: the landing needs 2 substeps, not 4, and
    the table rests on its weight as above (measured: 7 of 10 endgames converged)."""
    monkeypatch.setattr(recovery, "RECOVERIES",
                        tuple(r for r in recovery.RECOVERIES if r is not recovery.indeterminate_impulses))
    calls = []
    endgame = ncp.newton_min_map

    def counted(*args, **kwargs):
        result = endgame(*args, **kwargs)
        calls.append(result.success)
        return result

    monkeypatch.setattr(ncp, "newton_min_map", counted)
    reports, table = _land_and_rest(60)
    assert all(r.success for r in reports)
    assert reports[LANDING].substeps == 2 and max(r.substeps for r in reports) <= 2
    assert any(calls)
    np.testing.assert_allclose(table.getVelocities(), 0.0, atol=REST_TOL)
    assert sum(c.p_n for c in reports[-1].contacts) == pytest.approx(MASS * 9.81 * H, rel=WEIGHT_RTOL)
