"""The stepper's boundary: clear errors at construction, transactional steps, failure policies."""
import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact import ncp
from scenes import disc_rolling


def _state(world):
    out = [world.getTime()]
    for s in range(world.getNumSkeletons()):
        sk = world.getSkeleton(s)
        out += [np.array(sk.getPositions()), np.array(sk.getVelocities())]
    return out


def _same(a, b):
    return a[0] == b[0] and all(np.array_equal(x, y) for x, y in zip(a[1:], b[1:]))


def _free_ball(world, shape=None, mass=1.0, z=1.0):
    skel = dart.dynamics.Skeleton(f"ball{world.getNumSkeletons()}")
    _, body = skel.createFreeJointAndBodyNodePair()
    body.setMass(mass)
    body.setMomentOfInertia(0.1, 0.1, 0.1)
    skel.setPositions([0, 0, 0, 0, 0, z])
    ic.attach(body, shape or ic.shapes.Sphere(0.5))
    world.addSkeleton(skel)
    return skel, body


def _ground3d(world):
    g = dart.dynamics.Skeleton("ground")
    _, body = g.createWeldJointAndBodyNodePair()
    ic.attach(body, ic.shapes.HalfSpace([0, 0, 1], 0.0))
    world.addSkeleton(g)


def test_bad_time_step_never_reaches_the_stepper():
    """DART itself ignores h <= 0 (it warns and keeps its step), so the stepper sees a valid h;
    its own check (ValueError) guards the same boundary for other World implementations."""
    world = disc_rolling.build_world(0.01)
    world.setTimeStep(0.0)
    world.setTimeStep(-1.0)
    assert world.getTimeStep() == 0.01
    assert ic.ImplicitContactStepper(world).step().success


def test_two_d_shape_on_a_free_body_is_refused():
    world = dart.simulation.World()
    _free_ball(world, ic.shapes.Disc(0.5))
    with pytest.raises(ValueError, match="FreeJoint and needs 3D shapes"):
        ic.ImplicitContactStepper(world)


def test_three_d_shape_on_a_planar_body_is_refused():
    world = dart.simulation.World()
    skel = dart.dynamics.Skeleton("p")
    joint, body = skel.createPlanarJointAndBodyNodePair()
    joint.setXYPlane()
    ic.attach(body, ic.shapes.Sphere(0.5))
    world.addSkeleton(skel)
    with pytest.raises(ValueError, match="PlanarJoint and needs 2D shapes"):
        ic.ImplicitContactStepper(world)


def test_non_positive_mass_is_refused():
    world = dart.simulation.World()
    skel, body = _free_ball(world)
    body.setMass(0.0)
    with pytest.raises(ValueError, match="mass"):
        ic.ImplicitContactStepper(world)


def test_unsupported_joint_and_mesh_are_refused():
    world = dart.simulation.World()
    skel = dart.dynamics.Skeleton("arm")
    j0, b0 = skel.createBallJointAndBodyNodePair()
    j0.setLimitEnforcement(True)     # ball joints are supported (issue 6); limits on their rotation are not
    b0.setMass(1.0)
    ic.attach(b0, ic.shapes.Sphere(0.1))
    world.addSkeleton(skel)
    with pytest.raises(ValueError, match="BallJoint"):
        ic.ImplicitContactStepper(world)
    world = dart.simulation.World()
    skel, body = _free_ball(world)
    node = body.createShapeNode(dart.dynamics.ArrowShape([0, 0, 0], [0, 0, 1]) if hasattr(dart.dynamics, "ArrowShape")
                                else dart.dynamics.LineSegmentShape([0, 0, 0], [0, 0, 1], 1.0))
    node.createCollisionAspect()
    with pytest.raises(ValueError, match="attach an implicit surface"):
        ic.ImplicitContactStepper(world)


def test_overlapping_bodies_at_start_are_refused():
    world = dart.simulation.World()
    _free_ball(world, z=0.3)          # radius 0.5 at height 0.3: 0.2 into the ground
    _ground3d(world)
    with pytest.raises(ValueError, match="interpenetrate"):
        ic.ImplicitContactStepper(world)


def test_non_finite_state_is_refused_and_world_untouched():
    world = disc_rolling.build_world()
    stepper = ic.ImplicitContactStepper(world)
    world.getSkeleton("disc").setVelocities([np.nan, 0.0, 0.0])
    before = _state(world)
    with pytest.raises(ValueError, match="non-finite"):
        stepper.step()
    after = _state(world)
    assert after[0] == before[0] and np.array_equal(after[1], before[1])


def test_world_with_no_implicit_bodies_steps_freely():
    """Documented no-op for contact: every skeleton takes the free semi-implicit Euler step."""
    world = dart.simulation.World()
    world.setTimeStep(0.01)
    skel = dart.dynamics.Skeleton("free")
    _, body = skel.createFreeJointAndBodyNodePair()
    world.addSkeleton(skel)
    native = world.clone()
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(10):
        rep = stepper.step()
        native.step()
        assert rep.success and rep.contacts == ()
    np.testing.assert_allclose(skel.getPositions(), native.getSkeleton(0).getPositions(), rtol=0, atol=1e-14)
    np.testing.assert_allclose(skel.getVelocities(), native.getSkeleton(0).getVelocities(), rtol=0, atol=1e-14)


def _hard_world():
    """A sliding disc: its first contact step needs several Newton iterations."""
    return disc_rolling.build_world(0.01, v0=(-3.0, 0.0, 0.0))


def _crippled(policy):
    # no Newton iteration at all (0 evaluates the start only), also on retried substeps
    options = ic.StepperOptions(solver=ncp.SolverOptions(tol=1e-10, max_iterations=0, descent_rho=1e-24),
                                max_halvings=2, retry_iterations_factor=1)
    world = _hard_world()
    return world, ic.ImplicitContactStepper(world, on_failure=policy, options=options)


def test_failure_raise_leaves_world_exactly_as_before():
    world, stepper = _crippled("raise")
    before = _state(world)
    with pytest.raises(ic.StepFailure, match=r"NCP failed at t = 0 s .*disc.*ground.*MAX_ITERATIONS"):
        stepper.step()
    assert _same(before, _state(world))


def test_failure_warn_warns_reports_and_keeps_the_world():
    world, stepper = _crippled("warn")
    before = _state(world)
    with pytest.warns(RuntimeWarning, match="NCP failed"):
        rep = stepper.step()
    assert not rep.success and rep.status == "MAX_ITERATIONS"
    assert _same(before, _state(world))


def test_failure_retry_raises_after_its_bounded_halvings_and_keeps_the_world():
    world, stepper = _crippled("retry")
    before = _state(world)
    with pytest.raises(ic.StepFailure, match="Retried with up to 4 substeps"):
        stepper.step()
    assert _same(before, _state(world))


@pytest.mark.parametrize("drop_pairs", [True, False], ids=["pairs-dropped", "pairs-kept"])
def test_a_step_whose_recoveries_outlast_its_solves(monkeypatch, drop_pairs):
    """recovery.out_of_solves: a recovery asks for another solve after every one of the step's
    MAX_SOLVES solves (each converges). If it also drops the attempt's pairs on the last one, as
    release_idle did on icub at t = 0.927 s (comparisons.real_models), where the failure report
    then raised IndexError, the step fails naming a pair of the problem actually solved and the
    world is unchanged (before the fix the step returned a success). If the pairs stay, the last
    converged solve is the step's answer (friction rows cycling on and off, icub_reduced)."""
    from implicit_contact import recovery
    world = dart.simulation.World()
    world.setTimeStep(0.01)
    _ground3d(world)
    _free_ball(world, z=0.5)                 # resting on the ground: a converged contact step
    stepper = ic.ImplicitContactStepper(world, on_failure="raise")
    calls = []

    def greedy(stepper_, att, problem, result):
        calls.append(result.success)
        if drop_pairs and att.index == recovery.MAX_SOLVES - 1:
            att.specs, att.pairs = [], []
        return recovery.RETRY

    monkeypatch.setattr(recovery, "RECOVERIES", (greedy,) + recovery.RECOVERIES)
    before = _state(world)
    if drop_pairs:
        with pytest.raises(ic.StepFailure, match=r"ball.*ground|ground.*ball") as info:
            stepper.step()
        assert f"more than {recovery.MAX_SOLVES} solves" in str(info.value)
        assert _same(before, _state(world))
    else:
        report = stepper.step()
        assert report.success and len(report.contacts) == 1
        # the ball stays on the ground (its contact's gap within the tolerance)
        assert abs(report.contacts[0].gap) <= ic.StepperOptions().contact_tolerance
    assert len(calls) == recovery.MAX_SOLVES and all(calls)     # every solve had converged


def test_retry_takes_substeps_that_add_up_to_h():
    """With a solver that fails on the full step but not on halves, retry advances by exactly h."""
    world = disc_rolling.build_world(0.01)
    stepper = ic.ImplicitContactStepper(world, on_failure="retry")
    calls = []
    original = stepper._one_step

    def flaky(h):
        calls.append(h)
        if h == 0.01:
            return ic.StepReport(False, 1, 1.0, "MAX_ITERATIONS", (), world.getTime(), 1, "forced failure")
        return original(h)

    stepper._one_step = flaky
    reference = disc_rolling.build_world(0.005)
    ref_stepper = ic.ImplicitContactStepper(reference)
    rep = stepper.step()
    ref_stepper.step()
    ref_stepper.step()
    assert rep.success and rep.substeps == 2 and calls == [0.01, 0.005, 0.005]
    assert world.getTime() == pytest.approx(0.01, abs=1e-15)
    np.testing.assert_allclose(world.getSkeleton("disc").getPositions(),
                               reference.getSkeleton("disc").getPositions(), rtol=0, atol=1e-14)


def test_invalid_policy_and_options():
    world = disc_rolling.build_world()
    with pytest.raises(ValueError, match="on_failure"):
        ic.ImplicitContactStepper(world, on_failure="ignore")
    with pytest.raises(ValueError, match="contact_tolerance"):
        ic.StepperOptions(contact_tolerance=-1.0)
    with pytest.raises(ValueError, match="mu"):
        ic.Friction(mu=-0.1)


def test_steppers_on_equal_records_share_one_shape_and_step_alike():
    """attach() records are parsed into one shape object per record (dart_adapter._shape_of_record:
    an intersection's analysis is paid once per process). Sharing is safe only if stepping never
    changes a shape: a second world built after the first has been stepped through a tilted
    landing must take the bit-identical trajectory."""
    from implicit_contact import dart_adapter

    def world_with_box():
        world = dart.simulation.World()
        world.setTimeStep(2e-3)
        _ground3d(world)
        box = ic.shapes.Intersection([ic.shapes.HalfSpace(n, 0.1) for n in
                                      ([1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1])])
        skel, body = _free_ball(world, shape=box, z=0.12)
        skel.setPositions([0.3, 0.2, 0.0, 0.0, 0.0, 0.2])
        skel.setVelocities([1.0, -2.0, 3.0, 0.5, 0.0, -1.0])
        return world, body

    w1, b1 = world_with_box()
    w2, b2 = world_with_box()
    s1 = ic.ImplicitContactStepper(w1)
    states1, touching = [_state(w1)], 0
    for _ in range(60):
        touching += any(c.p_n > 0.0 for c in s1.step().contacts)
        states1.append(_state(w1))
    s2 = ic.ImplicitContactStepper(w2)
    shape1 = dart_adapter._shapes_of(b1, planar=False)[0].shape
    assert dart_adapter._shapes_of(b2, planar=False)[0].shape is shape1
    states2 = [_state(w2)]
    for _ in range(60):
        s2.step()
        states2.append(_state(w2))
    assert touching >= 10                 # it landed: contact steps were taken
    assert all(_same(a, b) for a, b in zip(states1, states2))
