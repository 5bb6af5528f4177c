"""A step that repeats the last one's structure (ImplicitContactStepper._repeat_step) is the same step.

_repeat_step refreshes the last step's problem in place and carries its solution over with
kernels instead of rebuilding it pair by pair through _one_step; the mathematics must be the
same. Each scene is stepped twice, with the repeat path and with it switched off: positions,
velocities and the solver's iteration counts must agree bit for bit at every step, and the
repeat path must have taken most steps (else this test would test nothing). Order 2's step
(_split_step) has its own repeat path for stage 1 (_split_repeat, the same kernel with stage 1's
tables and frames at l), checked the same way on the scenes of its work-precision study.
"""
import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from scenes import disc_on_quasi_rigid_plane as quasi
from scenes import disc_rolling, ellipsoid_rocking
from scenes import sphere_on_two_spheres as spheres
from test_articulated import _pendulum_world
from test_rigid3d import _dart_box, _free_body, _ground, _world
from test_support import _stepper as _support_stepper, _world as _support_world

MIN_REPEATED = 0.5     # fraction of the steps the repeat path must take in these steady scenes


ORDER_2 = ic.StepperOptions(order=2)     # order 2's stage 1 repeats too (ImplicitContactStepper._split_repeat)


def _disc(options=None):
    world = disc_rolling.build_world(0.01)
    return world, ic.ImplicitContactStepper(world, options=options), None


def _spheres(options=None):
    world = spheres.build_world(0.01)
    stepper = ic.ImplicitContactStepper(world, options=options)
    ball = world.getSkeleton("ball").getBodyNode(0)
    for name in ("sphere_r10", "sphere_r9"):
        stepper.set_pair_friction(ball, world.getSkeleton("fixed_spheres").getBodyNode(name), spheres.FRICTION)
    return world, stepper, lambda: spheres.push(world, 0.0)


def _ellipsoid(options=None):
    world = ellipsoid_rocking.build_world(2e-3)
    return world, ic.ImplicitContactStepper(world, options=options), None


def _sliding_box():
    world = _world(2e-3)
    _ground(world, mu=0.3)
    _dart_box(world, [0.4, 0.3, 0.2], 0.3, [0.0, 0.0, 0.1 + 1e-9], velocity=[0.0, 0.0, 0.0, 1.5, 0.0, 0.0])
    return world, ic.ImplicitContactStepper(world), None


def _quasi_rigid():
    world = quasi.build_world(1.0, h=1e-3)
    return world, ic.ImplicitContactStepper(world), None


def _pendulum():
    world, _, _, _ = _pendulum_world(1e-3)
    return world, ic.ImplicitContactStepper(world), None


def _support():
    world, body, _ = _support_world(v0=(0.4, 0.1, 2.0))
    return world, _support_stepper(world, body), None


SCENES = {"disc": (_disc, 150), "spheres": (_spheres, 150), "ellipsoid": (_ellipsoid, 150),
          "sliding box": (_sliding_box, 150), "quasi-rigid disc": (_quasi_rigid, 600),
          "pendulum on an obstacle": (_pendulum, 600), "support friction": (_support, 100),
          "disc, order 2": (lambda: _disc(ORDER_2), 150), "spheres, order 2": (lambda: _spheres(ORDER_2), 150),
          "ellipsoid, order 2": (lambda: _ellipsoid(ORDER_2), 150)}


def _run(make, steps, repeat):
    world, stepper, before = make()
    taken = [0]
    if repeat:
        original = stepper._repeat_step

        def counting(h, t0):
            report = original(h, t0)
            taken[0] += report is not None
            return report
        stepper._repeat_step = counting
    else:
        stepper._repeat_step = lambda h, t0: None
    skeletons = [world.getSkeleton(i) for i in range(world.getNumSkeletons())]
    states, iterations, impulses = [], [], []
    for _ in range(steps):
        if before is not None:
            before()
        report = stepper.step()
        iterations.append(report.iterations)
        impulses.append([(c.p_n, c.p_t, c.p_o, c.p_r, c.slip) for c in report.contacts])
        states.append(np.concatenate([np.r_[s.getPositions(), s.getVelocities()] for s in skeletons]))
    return np.array(states), iterations, taken[0], impulses


@pytest.mark.parametrize("name", list(SCENES))
def test_repeat_path_steps_bit_for_bit_as_the_general_path(name):
    make, steps = SCENES[name]
    fast, it_fast, taken, p_fast = _run(make, steps, repeat=True)
    slow, it_slow, _, p_slow = _run(make, steps, repeat=False)
    assert taken >= MIN_REPEATED * steps, f"the repeat path took {taken} of {steps} steps"
    np.testing.assert_array_equal(fast, slow)
    assert it_fast == it_slow
    assert p_fast == p_slow          # the contact reports (made lazily on the repeat path) too


def test_a_repeated_step_takes_no_snapshot_and_a_failed_one_is_charged_to_the_step(monkeypatch):
    """ImplicitContactStepper._quick_repeat: a step that repeats the last one's structure writes
    DART only after its solve succeeded, so step() takes no snapshot for it (the rolling disc:
    one snapshot, at its first step, in 150). When the repeat fails after its solve (the rocking
    ellipsoid's, told to), step() takes the step the general way and the failed solve's Newton
    iterations count in report.spent, as any failed attempt's do."""
    from implicit_contact import dart_adapter, stepper as stepper_module

    snapshots = []
    original = dart_adapter.snapshot

    def counting(*args, **kwargs):
        snapshots.append(1)
        return original(*args, **kwargs)

    monkeypatch.setattr(stepper_module.adapter, "snapshot", counting)
    world, stepper, _ = _disc()
    for _ in range(150):
        stepper.step()
    assert len(snapshots) == 1

    world, stepper, _ = _ellipsoid()       # (the disc's repeated solves take 0 iterations)
    for _ in range(5):
        stepper.step()
    repeat = stepper._repeat_step

    def solved_then_refused(h, t0):
        report = repeat(h, t0)
        assert report is not None                   # (it did solve: the disc repeats)
        return None
    stepper._repeat_step = solved_then_refused
    report = stepper.step()
    assert stepper._repeat_spent > 0
    assert report.spent == stepper._repeat_spent + report.iterations


def test_a_body_is_read_as_dart_places_it():
    """dart_adapter.read_body gives each body's world transform as the joints place it
    (composed here from their inputs): a welded ground placed off the origin (its joint's
    transform), a free body at exponential coordinates r and position p ([exp(r), p]), and the
    child of a revolute joint about y on it (the free body's transform times the joint's offset
    times the rotation by q about y)."""
    from implicit_contact import dart_adapter
    import dartpy as dart

    def pose(r, p):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = dart.math.expMapRot(np.asarray(r, float)), p
        return T

    world = _world(1e-3)
    ground = _ground(world)
    T_ground = pose([0.3, -0.2, 0.5], [0.1, -0.4, 0.25])
    ground.getParentJoint().setTransformFromParentBodyNode(dart.math.Isometry3(T_ground))
    r, p = [0.4, 1.1, -0.3], [0.3, 0.1, 0.7]
    box = _dart_box(world, [0.4, 0.3, 0.2], 0.3, p, rotation=r)
    joint, child = box.createRevoluteJointAndBodyNodePair(box.getBodyNode(0))
    joint.setAxis([0.0, 1.0, 0.0])
    T_offset = pose([0.0, 0.0, 0.7], [0.2, 0.0, 0.1])
    joint.setTransformFromParentBodyNode(dart.math.Isometry3(T_offset))
    q = 0.9
    box.setPosition(6, q)
    expected = {"ground": T_ground, "box": pose(r, p), "child": pose(r, p) @ T_offset @ pose([0.0, q, 0.0], [0, 0, 0])}
    for name, body in (("ground", ground), ("box", box.getBodyNode(0)), ("child", child)):
        record = type("Record", (), {"body_node": body})
        out = np.empty((4, 4))
        dart_adapter.read_body(record, out)
        np.testing.assert_allclose(out, expected[name], rtol=0, atol=1e-14, err_msg=name)


def test_a_step_on_the_repeat_path_sees_a_fixed_body_the_user_moved():
    """A box resting on a welded ground takes the repeat path; the user then lowers the ground by
    2 mm through its joint between two steps. The next step must see it: the box falls freely,
    v_z = -g h and no contact pushes (a stale ground would hold it where it was). The repeat
    refused it before solving anything, so it charges nothing to the step (until 2026-12-07 a
    refused repeat charged the last step's count again to the budget and report.spent)."""
    h = 2e-3
    world = _world(h)
    ground = _ground(world, mu=0.3)
    box = _dart_box(world, [0.4, 0.3, 0.2], 0.3, [0.0, 0.0, 0.1 + 1e-9])
    stepper = ic.ImplicitContactStepper(world)
    taken = []
    original = stepper._repeat_step
    stepper._repeat_step = lambda h, t0: (lambda r: (taken.append(r is not None), r)[1])(original(h, t0))
    for _ in range(20):
        report = stepper.step()
    assert taken[-1] and any(c.p_n > 0.0 for c in report.contacts), "the box should rest, on the repeat path"
    T = ground.getParentJoint().getTransformFromParentBodyNode()
    T.set_translation(T.translation() + [0.0, 0.0, -2e-3])
    ground.getParentJoint().setTransformFromParentBodyNode(T)
    report = stepper.step()
    assert stepper._repeat_spent is None
    assert all(c.p_n == 0.0 for c in report.contacts)
    np.testing.assert_allclose(box.getVelocities()[3:], [0.0, 0.0, -9.81 * h], atol=1e-9)


def test_the_repeated_steps_report_is_a_step_report_like_any_other():
    """stepper._made_report (the repeated step's StepReport, made without the dataclass's
    __init__) is equal to the one StepReport(...) makes, frozen and printed the same; the rolling
    disc's repeated step returns one with every field set."""
    import dataclasses

    from implicit_contact import stepper as stepper_module

    fields = (True, 3, 1e-12, "CONVERGED", (), 0.25, 1, "Converged in 3 iterations.", 11, 3)
    made = stepper_module._made_report(*fields)
    assert made == ic.StepReport(*fields) and repr(made) == repr(ic.StepReport(*fields))
    with pytest.raises(dataclasses.FrozenInstanceError):
        made.iterations = 4
    world, stepper, _ = _disc()
    for _ in range(5):
        report = stepper.step()
    assert isinstance(report, ic.StepReport) and report.success and report.status == "CONVERGED"
    assert report.spent == report.iterations and report.unknowns > 0
    assert report.time == pytest.approx(world.getTime()) and report.message.startswith("Converged in ")


def test_order_2_reports_read_later_are_the_ones_read_at_once():
    """Order 2's reports carry stage 2's total impulses and slip (stepper._split_contacts), made
    when first read from a copy of what they need of stage 2, whose arrays the next step
    refreshes in place (rattle.Stage2.refresh). On the rocking ellipsoid (every step a repeat
    step, the same stage 2 refreshed): reports read after 40 more steps equal those read at once,
    and stage 2's impulses are not stage 1's (which the reports would hold without them)."""
    def fields(report):
        return [(c.p_n, c.p_t, c.p_o, c.p_r, c.slip, c.gap, tuple(c.a1)) for c in report.contacts]

    def run(read_at_once):
        world, stepper, _ = _ellipsoid(ORDER_2)
        kept, stage2 = [], []
        for _ in range(40):
            report = stepper.step()
            kept.append(fields(report) if read_at_once else report)
            stage2.append(stepper._stage2_kept)
        return ([fields(r) for r in kept] if not read_at_once else kept), stage2

    at_once, stage2 = run(True)
    later, _ = run(False)
    assert all(len(r) == 1 and r[0][0] > 0.0 for r in at_once), "the ellipsoid should rest on the plane"
    assert len({id(s) for s in stage2[5:]}) == 1, "stage 2 should be refreshed in place step after step"
    assert later == at_once
    assert len({r[0][0] for r in at_once}) > 1 and len({r[0][4] for r in at_once}) > 1


def test_a_general_steps_reports_read_later_are_the_ones_read_at_once():
    """The general step's contact reports are made when first read (stepper._LazyContacts, since
    _solution); its problem is cached and refreshed by the steps after it, with their own specs.
    A spinning sliding ball with torsional friction whose e_r changes every step (the same rows,
    so the same cached problem, another spec list): its reports, read after 12 more steps, must
    equal those read as each step returned, and p_r must follow each step's own e_r."""
    def run(read_at_once):
        world = _world(0.01)
        skel, body = _free_body(world, "ball", 2.0, [0.072] * 3, [0.0, 0.0, 0.3])
        node = body.createShapeNode(dart.dynamics.SphereShape(0.3))
        node.createCollisionAspect()
        node.createDynamicsAspect().setFrictionCoeff(0.5)
        skel.setVelocities([0.0, 0.0, 8.0, 1.0, 0.0, 0.0])
        ground = _ground(world)
        stepper = ic.ImplicitContactStepper(world)
        stepper._repeat_step = lambda h, t0: None          # every step a general step
        kept, general = [], []
        for k in range(12):
            stepper.set_pair_friction(body, ground, ic.Friction(mu=0.5, e_r=0.01 * (1 + k % 3)))
            report = stepper.step()
            general.append(isinstance(report.contacts, stepper_module._LazyContacts))
            kept.append([(c.p_n, c.p_t, c.p_o, c.p_r, c.sigma, c.slip, c.gap, tuple(c.a1), tuple(c.normal))
                         for c in report.contacts] if read_at_once else report)
        if not read_at_once:
            kept = [[(c.p_n, c.p_t, c.p_o, c.p_r, c.sigma, c.slip, c.gap, tuple(c.a1), tuple(c.normal))
                     for c in report.contacts] for report in kept]
        return kept, general

    from implicit_contact import stepper as stepper_module
    at_once, general = run(True)
    later, _ = run(False)
    assert all(general), "the general step's reports should be made lazily"
    assert all(len(r) == 1 and r[0][0] > 0.0 for r in at_once[2:]), "the ball should touch from the third step on"
    assert later == at_once
    torsion = [r[0][3] for r in at_once[2:]]
    assert len({abs(p) for p in torsion}) > 1 and all(p != 0.0 for p in torsion)
