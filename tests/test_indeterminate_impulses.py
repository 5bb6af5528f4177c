"""recovery.indeterminate_impulses: redundant contacts (impulses not unique) solved by the proximal
point method on the impulses (ncp.solve_proximal; its own tests are in test_ncp.py), and the torsion
rows such contacts share (stepper._share_patches).

The scene is a table: one rigid body with four box legs, landing flat on a ground box while it
slides and spins. Four parallel leg faces on a plane leave the normal impulses a warp mode
(+ - + -) that no velocity sees, and sticking legs share the body's tangential impulse: the
step's Jacobian is singular in those directions. Each leg is off the others' normal axes, so
their patches give no torsion rows (stepper._share_patches); until they did, four torsion rows
held the one yaw too, and the landing needed more halvings (2 with every recovery, 4 without the
proximal re-solve and the endgame).

The legs land sliding (the table spins at 2 rad/s), and by default a new contact that clearly
slides starts its friction re-solve sliding (recovery._clearly_sliding): that landing stalls next
to a solution, and the proximal re-solve lands it without halving (without it: 2 substeps). The
guards of the endgame land the table as every new contact used to land, from a sticking start
(recovery.SLIDE_RATIO = inf), the start a contact that may stick still gets.
"""
from dataclasses import replace

import numpy as np
import pytest

import dartpy as dart

import implicit_contact as ic
from implicit_contact import ncp, recovery, step_solver
from implicit_contact import stepper as stepper_module
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


def _without(monkeypatch, recovery_function):
    monkeypatch.setattr(recovery, "RECOVERIES", tuple(r for r in recovery.RECOVERIES if r is not recovery_function))


def test_the_proximal_re_solve_lands_the_sliding_table_without_halving(monkeypatch):
    """From the default (sliding) start the landing step stalls next to a solution; the proximal
    re-solve finishes it at h, and without that recovery the step is halved once (measured: 2
    proximal re-solves in the landing). The solver's min-map endgame is left out here: since its
    watchdog (ncp.newton_min_map) it finishes this landing at h on its own, before the recovery
    is asked (the endgame's own test is below)."""
    monkeypatch.setattr(step_solver, "ENDGAME_RESIDUAL", -1.0)
    retries = []
    proximal, original = recovery.indeterminate_impulses, recovery.RECOVERIES

    def counted(*args):
        outcome = proximal(*args)
        retries.append(outcome is recovery.RETRY)
        return outcome

    monkeypatch.setattr(recovery, "RECOVERIES", tuple(counted if r is proximal else r for r in recovery.RECOVERIES))
    reports, _ = _land_and_rest(LANDING + 1)
    assert reports[LANDING].substeps == 1 and any(retries)
    monkeypatch.setattr(recovery, "RECOVERIES", tuple(r for r in original if r is not proximal))
    reports, _ = _land_and_rest(LANDING + 1)
    assert reports[LANDING].substeps == 2


def test_the_compiled_proximal_solve_is_the_python_drivers_bit_for_bit(monkeypatch):
    """step_solver.solve(proximal=True) on a dense problem solves each regularised problem of
    ncp.solve_proximal in one compiled call (step_solver._solve_regularised); it must be the
    Python driver's solve (ncp.solve_mcp on F + W (. - x_k) and J + diag(W)) bit for bit: the
    landing table's proximal re-solves, each repeated both ways from the same start (the min-map
    endgame left out, which finishes the landing without them: previous test)."""
    monkeypatch.setattr(step_solver, "ENDGAME_RESIDUAL", -1.0)
    captured = []
    original = step_solver.solve

    def capture(problem, z0, options, sync=True, proximal=False, stop=None):
        result = original(problem, z0, options, sync, proximal, stop)
        if proximal:
            assert not problem._sparse
            problem._sync()
            python = ncp.solve_proximal(problem.fun, problem.jac, z0, problem.lower, problem.upper,
                                        step_solver.impulse_weights(problem), options)
            compiled = ncp.solve_proximal(
                problem.fun, problem.jac, z0, problem.lower, problem.upper, step_solver.impulse_weights(problem),
                options, inner=lambda c, w, o: step_solver._solve_regularised_once(problem, c, w, c, o))
            captured.append((python, compiled))
        return result
    monkeypatch.setattr(step_solver, "solve", capture)
    _land_and_rest(LANDING + 1)
    assert captured, "the landing should take a proximal re-solve"
    for python, compiled in captured:
        np.testing.assert_array_equal(compiled.x, python.x)
        assert (compiled.status, compiled.iterations, compiled.steps, compiled.nfev, compiled.njev) == \
            (python.status, python.iterations, python.steps, python.nfev, python.njev)
        assert compiled.merit_history == python.merit_history and python.iterations > 0


def test_without_the_proximal_re_solve_or_the_endgame_the_landing_is_halved(monkeypatch, sticking_start):
    """The same scene with indeterminate_impulses left out of the recoveries, and without the
    solver's min-map endgame (step_solver.ENDGAME_RESIDUAL), which lands it without halving on its
    own (next test): the landing step needs 2 substeps (the guard that the next test exercises
    the endgame)."""
    _without(monkeypatch, recovery.indeterminate_impulses)
    monkeypatch.setattr(step_solver, "ENDGAME_RESIDUAL", -1.0)
    reports, _ = _land_and_rest(LANDING + 1)
    assert reports[LANDING].substeps == 2


def test_the_min_map_endgame_alone_lands_the_table_without_halving(monkeypatch, sticking_start):
    """Without indeterminate_impulses, the solves that stall next to a solution (natural residual
    <= step_solver.ENDGAME_RESIDUAL, J singular along the warp mode and the shared tangential
    impulses) are finished by ncp.newton_min_map's least-norm steps: the landing needs no halving,
    and the table rests on its weight as above (measured where this was written: 4 of 5 endgames
    converged; on an AMD EPYC, 2026-12-07, both endgames stopped at 5e-10 and 7e-9 > tol and the
    landing was halved, until the endgame's watchdog: now its one endgame converges in 3 steps,
    one of them the watchdog's, NWN)."""
    _without(monkeypatch, recovery.indeterminate_impulses)
    calls = []
    endgame = ncp.newton_min_map

    def counted(*args, **kwargs):
        result = endgame(*args, **kwargs)
        calls.append(result.success)
        return result

    monkeypatch.setattr(ncp, "newton_min_map", counted)
    reports, table = _land_and_rest(60)
    assert all(r.success for r in reports)
    assert max(r.substeps for r in reports) == 1
    assert any(calls)
    np.testing.assert_allclose(table.getVelocities(), 0.0, atol=REST_TOL)
    assert sum(c.p_n for c in reports[-1].contacts) == pytest.approx(MASS * 9.81 * H, rel=WEIGHT_RTOL)


# -- shared torsion (stepper._share_patches) --------------------------------------------------------
LEG_SIDE = 0.03      # [m] the legs' square feet
DECEL_MARGIN = 1e-9  # [rad/s^2] round-off on the bounds of the table's spin-down


def test_the_table_spinning_on_its_legs_stops_by_their_lever_arms_without_torsion_rows():
    """The table resting on its four legs, spinning at omega0 about its vertical axis through the
    centre of the legs (mu = 0.3): each leg's friction mu m g / 4 acts on a lever arm between
    r - a / sqrt(2) and r + a / sqrt(2) (r the leg centres' distance from the axis, a the feet's
    side: where in its face a leg's contact point lies is not determined by a rigid table), so
    in every step the spin falls at mu m g d / I_zz with d in that range, and the table stops
    before omega0 I_zz / (mu m g (r - a / sqrt(2))). No leg carries a torsion impulse: each is
    off the others' normal axes."""
    mu, w0 = 0.3, 2.0
    world, table = _table_world(mu=mu)
    table.setPositions([0.0, 0.0, 0.0, 0.0, 0.0, 0.015])          # the feet on the ground
    table.setVelocities([0.0, 0.0, w0, 0.0, 0.0, 0.0])
    stepper = ic.ImplicitContactStepper(world)
    r = float(np.hypot(*LEGS[0]))
    izz = 0.25
    fastest = mu * MASS * 9.81 * (r + LEG_SIDE / np.sqrt(2.0)) / izz
    slowest = mu * MASS * 9.81 * (r - LEG_SIDE / np.sqrt(2.0)) / izz
    t_stop = w0 / slowest
    omega, torsion = [w0], []
    for _ in range(int(1.2 * t_stop / H)):
        report = stepper.step()
        omega.append(table.getVelocities()[2])
        torsion.extend(c.p_r for c in report.contacts)
    omega = np.array(omega)
    spinning = omega[1:] > fastest * H                               # steps that end spinning
    decel = -np.diff(omega)[spinning] / H
    assert spinning.sum() > 50
    assert np.all(decel >= slowest - DECEL_MARGIN) and np.all(decel <= fastest + DECEL_MARGIN)
    assert np.all(np.abs(omega[int(np.ceil(t_stop / H)) + 1:]) < 1e-9)
    assert torsion and all(p == 0.0 for p in torsion)


def _pinch_world(mu=0.8):
    """A box (0.5 kg, 10 cm) pinched between two 2 cm finger pads on a fixed base, each pad on a
    prismatic joint along x; the pads' axis passes PINCH_OFFSET from the box's centre, so gravity
    turns the box about it unless the pads' torsional friction holds it."""
    world = dart_world(H)
    gripper = dart.dynamics.Skeleton("gripper")
    _, base = gripper.createWeldJointAndBodyNodePair()
    for side in (-1.0, 1.0):
        props = dart.dynamics.PrismaticJointProperties()
        props.mAxis = [1.0, 0.0, 0.0]
        joint, pad = gripper.createPrismaticJointAndBodyNodePair(base, props)
        T = dart.math.Isometry3()
        T.set_translation([side * 0.06, PINCH_OFFSET, 0.0])
        joint.setTransformFromParentBodyNode(T)
        node = pad.createShapeNode(dart.dynamics.BoxShape([0.02, 0.02, 0.02]))
        node.createCollisionAspect()
        node.createDynamicsAspect().setFrictionCoeff(mu)
        pad.setMass(0.1)
    world.addSkeleton(gripper)
    box = dart.dynamics.Skeleton("object")
    _, body = box.createFreeJointAndBodyNodePair()
    node = body.createShapeNode(dart.dynamics.BoxShape([0.1, 0.1, 0.1]))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(mu)
    body.setMass(0.5)
    body.setMomentOfInertia(0.5 * 0.02 / 12, 0.5 * 0.02 / 12, 0.5 * 0.02 / 12)
    world.addSkeleton(box)
    return world, gripper, box


PINCH_OFFSET = 0.03  # [m]
SQUEEZE = 20.0       # [N] on each pad


@pytest.mark.parametrize("lever", [None, 0.0], ids=["default", "any-shared-contact"])
def test_a_pinch_keeps_its_pads_torsion(monkeypatch, lever):
    """Two pads pinching a box touch it on one axis: neither one's tangential friction can hold a
    spin about that axis, so both keep their patch torsion (their contacts are within
    SHARE_LEVER torsion radii of each other's axis), and the box hangs still against the moment
    m g PINCH_OFFSET of its weight. Dropping the torsion of every pair that shares its two
    skeletons with another (lever 0) lets it turn about the pinch axis: the check can fail."""
    if lever is not None:
        monkeypatch.setattr(stepper_module, "SHARE_LEVER", lever)
    world, gripper, box = _pinch_world()
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(300):
        gripper.setForces([SQUEEZE, -SQUEEZE])
        report = stepper.step()
    turned = float(np.linalg.norm(box.getPositions()[:3]))
    if lever is None:
        assert turned < 1e-9 and np.linalg.norm(box.getPositions()[3:]) < 1e-9
        assert len(report.contacts) == 2 and all(c.p_r != 0.0 for c in report.contacts)
    else:
        assert turned > 0.1


# -- friction left on a pair without normal impulse (recovery.stray_friction) --------------------------
NO_FRICTION = 1e-12  # [scaled impulse] round-off on a zero friction impulse
SAME_STEP = 1e-7     # [m/s, rad/s] two solutions of the step within the solver's tol (1e-10 on scaled rows)
def test_stray_friction_restarts_a_pair_without_normal_impulse_at_zero_friction_and_its_slip(monkeypatch):
    """A ball resting on the ground (friction rows from its last step) is kicked up and sideways:
    its step's solution has p_n = 0 for the pair. From that solution with a friction impulse put
    back on the pair at sigma = 0 (what a stalled re-solve left on example-robot-data's
    anymal-kinova foot, recovery.stray_friction's case), the pair is stuck sliding with no normal
    impulse; the recovery restarts it at p_t = 0 with sigma at its slip |v_t|, from where the
    solve converges to the same step (p_t = 0)."""
    world = dart_world(H)
    ground_box(world, mu=1.0)
    ball = dart.dynamics.Skeleton("ball")
    _, body = ball.createFreeJointAndBodyNodePair()
    node = body.createShapeNode(dart.dynamics.SphereShape(0.1))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(1.0)
    body.setMass(1.0)
    world.addSkeleton(ball)
    ball.setPositions([0.0, 0.0, 0.0, 0.0, 0.0, 0.1])
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(5):
        stepper.step()
    ball.setVelocities([0.0, 0.0, 0.0, 0.4, 0.0, 1.0])      # off the ground, sliding along x
    seen = []
    rows = recovery.friction_rows

    def capture(stepper_, att, problem, result):
        if not seen and result.success:
            seen.append((att, problem, result))
        return rows(stepper_, att, problem, result)

    monkeypatch.setattr(recovery, "RECOVERIES", tuple(capture if r is rows else r for r in recovery.RECOVERIES))
    stepper.step()
    att, problem, result = seen[0]
    sl = problem.layout.pairs[0]
    assert sl.sigma >= 0 and result.x[sl.p_n] == 0.0            # rows from the last step, no impulse now
    stray = result.x.copy()
    stray[sl.p_t], stray[sl.sigma] = [0.3, -0.2], 0.0
    failed = replace(result, x=stray, status=ncp.Status.MAX_ITERATIONS)
    assert recovery.stray_friction(stepper, att, problem, failed) is recovery.RETRY
    start = att.reseeded
    slip = problem.unpack_pair(stray, 0).tangents @ problem.relative_velocity(stray, 0)
    np.testing.assert_array_equal(start[sl.p_t], 0.0)
    assert start[sl.sigma] == pytest.approx(np.linalg.norm(slip), rel=1e-12) and start[sl.sigma] > 0.3
    solved = step_solver.solve(problem, start, stepper.options.solver)
    assert solved.success
    np.testing.assert_allclose(solved.x[sl.p_t], 0.0, atol=NO_FRICTION)
    v = problem.layout.v_index[0]
    np.testing.assert_allclose(solved.x[v], result.x[v], rtol=0, atol=SAME_STEP)
    assert recovery.stray_friction(stepper, att, problem, failed) is None     # once per pairs and rows
