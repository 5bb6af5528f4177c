"""Malformed input at the public boundary: each is refused with a clear exception (or is a documented
no-op), and the DART world is unchanged after any refused or failed step.

Complements tests/test_stepper_api.py (policies on a first step, zero mass, revolute limits, arrow
shapes, one overlap, a NaN velocity at step time), tests/test_shapes.py (shape constructors) and
tests/test_articulated.py (Coulomb joint friction, servo actuators). What is added here: every
non-finite state entry at construction and at step time with the whole world compared; non-finite
forces and gravity; negative mass and indefinite inertia; shape records that bypass the
constructors; unsupported DART shapes and actuators; empty worlds; parameter objects; and, for
each failure policy, that nothing is lost: positions, velocities, accelerations, joint and external
forces, time, and the stepper's warm start (the next step after a failed one equals, bit for bit,
the step of a twin stepper that never failed, and a fresh stepper to solver tolerance).
"""
import json
import math
import warnings

import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact import ncp
from implicit_contact.dart_adapter import SHAPE_NODE_PREFIX
from scenes import disc_rolling

NAN, INF = float("nan"), float("inf")
H = 0.01
FRESH_ATOL = 1e-9   # [m, m/s] a fresh stepper (no warm start) against the warm one: solver tol 1e-10
                    # on scaled rows, O(1) quantities


# ---------------------------------------------------------------------------------------------
# worlds and the state we compare
# ---------------------------------------------------------------------------------------------
def _world(gravity=(0.0, 0.0, -9.81)):
    world = dart.simulation.World()
    world.setTimeStep(H)
    world.setGravity(list(gravity))
    return world


def _ball(world, name="ball", z=1.0, shape=None, mass=1.0):
    skel = dart.dynamics.Skeleton(name)
    _, body = skel.createFreeJointAndBodyNodePair()
    body.setName(name)
    body.setMass(mass)
    body.setMomentOfInertia(0.1, 0.1, 0.1)
    skel.setPositions([0.0, 0.0, 0.0, 0.0, 0.0, z])
    ic.attach(body, shape if shape is not None else ic.shapes.Sphere(0.5), friction=ic.Friction(mu=0.5))
    world.addSkeleton(skel)
    return skel, body


def _ground(world):
    skel = dart.dynamics.Skeleton("ground")
    _, body = skel.createWeldJointAndBodyNodePair()
    body.setName("ground")
    ic.attach(body, ic.shapes.HalfSpace([0.0, 0.0, 1.0], 0.0), friction=ic.Friction(mu=0.5))
    world.addSkeleton(skel)
    return body


def _resting_and_flying():
    """A ball resting on the ground (a contact step) and one in flight (a free step)."""
    world = _world()
    _ground(world)
    _ball(world, "resting", z=0.5)
    _ball(world, "flying", z=3.0)
    return world


def _state(world):
    """Everything a step may change, per skeleton, and the time (NaN compares equal to NaN)."""
    out = [world.getTime()]
    for s in range(world.getNumSkeletons()):
        sk = world.getSkeleton(s)
        out += [np.array(sk.getPositions()), np.array(sk.getVelocities()), np.array(sk.getAccelerations()),
                np.array(sk.getForces()), np.array(sk.getExternalForces())]
    return out


def _same(a, b):
    return len(a) == len(b) and a[0] == b[0] and all(np.array_equal(x, y, equal_nan=True) for x, y in zip(a[1:], b[1:]))


def _qv(world):
    return [np.r_[world.getSkeleton(s).getPositions(), world.getSkeleton(s).getVelocities()]
            for s in range(world.getNumSkeletons())]


# ---------------------------------------------------------------------------------------------
# non-finite states and forces
# ---------------------------------------------------------------------------------------------
BAD_STATE = [(what, k, value) for what in ("positions", "velocities") for k, value in ((5, NAN), (3, INF), (0, -INF))]


def _set_entry(skel, what, k, value):
    x = np.array(skel.getPositions() if what == "positions" else skel.getVelocities())
    x[k] = value
    (skel.setPositions if what == "positions" else skel.setVelocities)(x)


@pytest.mark.parametrize("what, k, value", BAD_STATE)
def test_non_finite_state_is_refused_at_construction(what, k, value):
    world = _resting_and_flying()
    _set_entry(world.getSkeleton("flying"), what, k, value)
    with pytest.raises(ValueError, match="skeleton 'flying' has non-finite positions or velocities"):
        ic.ImplicitContactStepper(world)


@pytest.mark.parametrize("policy", ["raise", "warn", "retry"])
@pytest.mark.parametrize("what, k, value", BAD_STATE)
def test_non_finite_state_is_refused_at_step_whatever_the_policy_and_no_skeleton_moves(what, k, value, policy):
    world = _resting_and_flying()
    stepper = ic.ImplicitContactStepper(world, on_failure=policy)
    stepper.step()
    _set_entry(world.getSkeleton("flying"), what, k, value)
    before = _state(world)
    with pytest.raises(ValueError, match="non-finite"):
        stepper.step()
    assert _same(before, _state(world))


@pytest.mark.parametrize("value", [NAN, INF])
def test_non_finite_external_force_is_dropped_by_dart_so_the_step_is_unaffected(value):
    """Documented no-op at DART's boundary: BodyNode::addExtForce ignores a NaN/Inf force (with a
    warning), so the stepper never sees it; the step equals that of a twin world without it."""
    world, twin = _resting_and_flying(), _resting_and_flying()
    stepper, twin_stepper = ic.ImplicitContactStepper(world), ic.ImplicitContactStepper(twin)
    for name in ("resting", "flying"):
        world.getSkeleton(name).getBodyNode(0).addExtForce([value, 0.0, 0.0])
        assert np.all(np.isfinite(world.getSkeleton(name).getExternalForces()))
    stepper.step()
    twin_stepper.step()
    assert all(np.array_equal(a, b) for a, b in zip(_qv(world), _qv(twin)))


def _nan_joint_force(world):
    world.getSkeleton("resting").setForces([0.0, 0.0, 0.0, NAN, 0.0, 0.0])


def _nan_gravity(world):
    world.setGravity([0.0, 0.0, NAN])


@pytest.mark.parametrize("poison", [_nan_joint_force, _nan_gravity], ids=["joint force", "gravity"])
def test_non_finite_joint_force_or_gravity_raises_and_leaves_the_world_unchanged(poison):
    """DART accepts NaN generalized forces and gravity; the stepper must not step with them."""
    world = _resting_and_flying()
    stepper = ic.ImplicitContactStepper(world, on_failure="warn")
    stepper.step()
    poison(world)
    before = _state(world)
    with pytest.raises(ValueError):
        stepper.step()
    assert _same(before, _state(world))


@pytest.mark.parametrize("poison", [_nan_joint_force, _nan_gravity], ids=["joint force", "gravity"])
def test_non_finite_joint_force_or_gravity_is_named_in_the_error(poison):
    world = _resting_and_flying()
    stepper = ic.ImplicitContactStepper(world)
    poison(world)
    with pytest.raises(ValueError, match=r"non-finite (forces|gravity)"):
        stepper.step()


# ---------------------------------------------------------------------------------------------
# masses, shapes, joints the stepper refuses when it is built
# ---------------------------------------------------------------------------------------------
def test_negative_mass_and_indefinite_inertia_are_refused():
    world = _world()
    _, body = _ball(world)
    body.setMass(-2.0)                         # DART warns and keeps it
    with pytest.raises(ValueError, match="has mass -2.0: masses must be positive and finite"):
        ic.ImplicitContactStepper(world)
    for moments in ((0.0, 0.0, 0.0), (-1.0, 1.0, 1.0)):
        world = _world()
        _, body = _ball(world)
        body.setMomentOfInertia(*moments)
        with pytest.raises(ValueError, match="rotational inertia that is not positive definite"):
            ic.ImplicitContactStepper(world)


def test_dart_refuses_bad_sizes_and_masses_itself_so_they_never_reach_the_stepper():
    """Documented no-op at DART's boundary: setRadius(0), a zero box side, a negative ellipsoid
    diameter and setMass(NaN) are ignored by DART (it keeps the previous value and warns)."""
    assert dart.dynamics.SphereShape(0.0).getRadius() == 1.0
    assert dart.dynamics.SphereShape(-1.0).getRadius() == 1.0
    assert np.array_equal(dart.dynamics.BoxShape([1.0, 0.0, 1.0]).getSize(), [1.0, 1.0, 1.0])
    assert np.array_equal(dart.dynamics.EllipsoidShape([1.0, -1.0, 1.0]).getDiameters(), [1.0, 1.0, 1.0])
    world = _world()
    _, body = _ball(world)
    body.setMass(NAN)
    assert body.getMass() == 1.0
    ic.ImplicitContactStepper(world)


@pytest.mark.parametrize("record, match", [
    ({"type": "Sphere", "radius": 0.0}, "radius must be a positive finite length"),
    ({"type": "Sphere", "radius": -1.0}, "radius must be a positive finite length"),
    ({"type": "Ellipsoid", "semi_axes": [1.0, 0.0, 1.0]}, "semi_axes must be 3 positive finite lengths"),
    ({"type": "Superquadric", "semi_axes": [1.0, 1.0, 1.0], "exponent": 1.5}, "exponent must be a finite number >= 2"),
    ({"type": "Superquadric", "semi_axes": [1.0, 1.0, 1.0], "exponent": [2.0, 4.0]}, "not C\\^2 on the z axis"),
    ({"type": "Torus", "radius": 1.0}, "unknown shape type"),
])
def test_shape_records_that_bypass_the_constructors_are_refused_when_the_stepper_is_built(record, match):
    """attach() stores the shape as JSON in a ShapeNode name; an edited or foreign record is parsed by
    the shape constructors again, so it cannot smuggle a zero size or an exponent < 2 in."""
    world = _world()
    _, body = _ball(world)
    node = body.getShapeNode(0)
    stored = json.loads(node.getName()[len(SHAPE_NODE_PREFIX):])
    stored["shape"] = record
    node.setName(SHAPE_NODE_PREFIX + json.dumps(stored))
    with pytest.raises(ValueError, match=match):
        ic.ImplicitContactStepper(world)


def test_attach_refuses_what_is_not_an_implicit_shape_or_parameter_object():
    world = _world()
    _, body = _ball(world)
    with pytest.raises(ValueError, match="needs an implicit_contact.shapes shape"):
        ic.attach(body, dart.dynamics.SphereShape(1.0))
    with pytest.raises(ValueError, match="friction must be an ic.Friction"):
        ic.attach(body, ic.shapes.Sphere(1.0), friction={"mu": 0.5})
    with pytest.raises(ValueError, match="compliance must be an ic.Compliance"):
        ic.attach(body, ic.shapes.Sphere(1.0), compliance=ic.Friction(mu=0.5))
    assert body.getNumShapeNodes() == 1       # nothing was attached by the refused calls


def _dart_shape_world(shape, planar=False):
    world = _world()
    skel = dart.dynamics.Skeleton("body")
    if planar:
        joint, body = skel.createPlanarJointAndBodyNodePair()
        joint.setXYPlane()
    else:
        _, body = skel.createFreeJointAndBodyNodePair()
    body.setMass(1.0)
    body.setMomentOfInertia(0.1, 0.1, 0.1)
    node = body.createShapeNode(shape)
    node.createCollisionAspect()
    world.addSkeleton(skel)
    return world


def _mesh_shape():
    from comparisons import dart_native
    world, disc = dart_native.build_ngon_world(8)
    return disc.getBodyNode(0).getShapeNode(0).getShape()


@pytest.mark.parametrize("make, planar, match", [
    (lambda: dart.dynamics.CapsuleShape(0.5, 1.0), False, "CapsuleShape is not supported by the implicit stepper"),
    (lambda: dart.dynamics.ConeShape(0.5, 1.0), False, "ConeShape is not supported by the implicit stepper"),
    (_mesh_shape, True, "MeshShape is not supported on a planar body"),   # (3D: its hull, tests/test_meshes.py)
    (lambda: dart.dynamics.PlaneShape([0.0, 0.0, 0.0], 0.0), False, "normal must be a non-zero vector"),
], ids=["capsule", "cone", "mesh on planar", "plane without normal"])
def test_unsupported_dart_collision_shapes_are_refused(make, planar, match):
    with pytest.raises(ValueError, match=match):
        ic.ImplicitContactStepper(_dart_shape_world(make(), planar))


# (MIMIC without its relation is refused with its own sentence since issue 15: tests/test_joint_mimic.py)
@pytest.mark.parametrize("actuator", ["VELOCITY", "ACCELERATION", "LOCKED"])
def test_constraint_actuators_are_refused(actuator):
    world = _world()
    skel = dart.dynamics.Skeleton("arm")
    joint, body = skel.createRevoluteJointAndBodyNodePair()
    body.setMass(1.0)
    ic.attach(body, ic.shapes.Sphere(0.1, center=[0.5, 0.0, 0.0]))
    joint.setActuatorType(getattr(dart.dynamics.ActuatorType, actuator))
    world.addSkeleton(skel)
    with pytest.raises(ValueError, match=f"actuator type {actuator}: the implicit stepper supports FORCE and PASSIVE"):
        ic.ImplicitContactStepper(world)


@pytest.mark.parametrize("shape, x, overlapping", [
    (ic.shapes.Sphere(0.5), 0.9, True),
    (ic.shapes.Superquadric([0.5, 0.4, 0.3], 4.0), 0.95, True),
    (ic.shapes.Sphere(0.5), 1.0, False),                # touching exactly is allowed
])
def test_bodies_overlapping_at_the_start_are_refused_and_touching_ones_are_not(shape, x, overlapping):
    world = _world(gravity=(0.0, 0.0, 0.0))
    a, _ = _ball(world, "a", z=0.0, shape=shape)
    b, _ = _ball(world, "b", z=0.0, shape=shape)
    b.setPositions([0.0, 0.0, 0.0, x, 0.0, 0.0])
    if overlapping:
        with pytest.raises(ValueError, match="interpenetrate by about .* at the start"):
            ic.ImplicitContactStepper(world)
        # the check is documented as optional: then the stepper is built
        ic.ImplicitContactStepper(world, options=ic.StepperOptions(check_penetration_at_start=False))
    else:
        assert ic.ImplicitContactStepper(world).step().success


@pytest.mark.parametrize("fixed_ground", [False, True], ids=["empty world", "only fixed bodies"])
def test_world_without_mobile_implicit_bodies_only_advances_time(fixed_ground):
    world = _world()
    if fixed_ground:
        _ground(world)
    stepper = ic.ImplicitContactStepper(world)
    for k in range(3):
        report = stepper.step()
        assert report.success and report.contacts == () and report.status == "NO_CONTACT"
    assert world.getTime() == pytest.approx(3 * H, abs=1e-15)


# ---------------------------------------------------------------------------------------------
# parameter objects
# ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, match", [
    (dict(mu=NAN), "Friction.mu must be a finite number"),
    (dict(mu=INF), "Friction.mu must be a finite number"),
    (dict(mu="0.4"), "Friction.mu must be a finite number"),
    (dict(mu=0.4, e_t=0.0), "e_t and e_o must be > 0"),
    (dict(mu=0.4, e_o=-1.0), "e_t and e_o must be > 0"),
    (dict(mu=0.4, e_r=-0.1), "e_r must be >= 0"),
    (dict(mu=0.4, e_r=NAN), "Friction.e_r must be a finite number"),
])
def test_bad_friction_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ic.Friction(**kwargs)


@pytest.mark.parametrize("kwargs, match", [
    (dict(k=0.0), "k must be positive"),
    (dict(k=-1e4), "k must be positive"),
    (dict(k=NAN), "k must be finite"),
    (dict(k=INF), "k must be finite"),
    (dict(k=1e4, c=-1.0), "c must be >= 0"),
    (dict(k=1e4, c=NAN), "c must be finite"),
    (dict(k=1e4, delta_max=0.0), "delta_max must be a positive length"),
    (dict(k=1e4, delta_max=-0.01), "delta_max must be a positive length"),
    (dict(k=1e4, delta_max=NAN), "delta_max must be a positive length"),
    (dict(k=1e4, scheme="euler"), "scheme must be one of"),
    (dict(k=np.diag([1e4, 1e4, 1e4])), "only the normal entry"),
    (dict(k=np.eye(2)), "scalar or a 3x3 matrix"),
])
def test_bad_compliance_is_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ic.Compliance(**kwargs)


def test_layers_with_different_schemes_cannot_be_paired():
    with pytest.raises(ValueError, match="same scheme"):
        ic.Compliance.series(ic.Compliance(1e4, scheme="paper"), ic.Compliance(1e4, scheme="midpoint"))


@pytest.mark.parametrize("kwargs, match", [
    (dict(contact_tolerance=0.0), "contact_tolerance"),
    (dict(contact_tolerance=NAN), "contact_tolerance"),
    (dict(contact_tolerance=INF), "contact_tolerance"),
    (dict(max_halvings=-1), "max_halvings"),
    (dict(max_halvings=13), "max_halvings"),
    (dict(max_halvings=2.0), "max_halvings"),
    (dict(retry_iterations_factor=0), "retry_iterations_factor"),
    (dict(retry_iterations_factor=1.5), "retry_iterations_factor"),
])
def test_bad_stepper_options_are_refused(kwargs, match):
    with pytest.raises(ValueError, match=match):
        ic.StepperOptions(**kwargs)


def test_pair_settings_refuse_bad_objects_and_bodies_without_shapes():
    world = _resting_and_flying()
    stepper = ic.ImplicitContactStepper(world)
    a = world.getSkeleton("resting").getBodyNode(0)
    b = world.getSkeleton("flying").getBodyNode(0)
    with pytest.raises(ValueError, match="friction must be an ic.Friction"):
        stepper.set_pair_friction(a, b, 0.5)
    with pytest.raises(ValueError, match="compliance must be an ic.Compliance"):
        stepper.set_pair_compliance(a, b, ic.Friction(mu=0.5))
    bare = dart.dynamics.Skeleton("bare")
    _, node = bare.createFreeJointAndBodyNodePair()
    with pytest.raises(ValueError, match="carries no contact shape"):
        stepper.set_pair_friction(a, node, ic.Friction(mu=0.5))


# ---------------------------------------------------------------------------------------------
# forced solver failures: each policy does what it says and loses nothing
# ---------------------------------------------------------------------------------------------
# No Newton iteration at all (0 evaluates the start only), also on retried substeps: every contact
# step of the sliding disc fails, a free step does not need the solver.
CRIPPLED = ic.StepperOptions(solver=ncp.SolverOptions(tol=1e-10, max_iterations=0, descent_rho=1e-24),
                             max_halvings=2, retry_iterations_factor=1)
FORCE = np.array([0.7, -0.4, 0.0])   # [N] applied to the disc before the failed step; must survive it


def _sliding_disc():
    """The [GI] disc started sliding (v = [-3, 0, 0]): each step needs Newton iterations."""
    world = disc_rolling.build_world(H, v0=(-3.0, 0.0, 0.0))
    world.getSkeleton("disc").setForces([0.0, 0.0, 0.05])       # a joint torque, kept by a failed step
    return world


def _twins(policy, warm_steps=5):
    """Two identical worlds and steppers with the same history of warm_steps steps."""
    pair = []
    for _ in range(2):
        world = _sliding_disc()
        stepper = ic.ImplicitContactStepper(world, on_failure=policy)
        for _ in range(warm_steps):
            stepper.step()
            world.getSkeleton("disc").setForces([0.0, 0.0, 0.05])
        world.getSkeleton("disc").getBodyNode(0).addExtForce(FORCE)
        pair.append((world, stepper))
    return pair


def _fail_once(stepper, policy):
    """One step with the crippled solver under the given policy; returns the failed report."""
    normal = stepper.options
    stepper.options = CRIPPLED
    try:
        if policy == "warn":
            with pytest.warns(RuntimeWarning, match="NCP failed at t = .* The world is unchanged") as caught:
                report = stepper.step()
            assert len(caught) == 1
            return report
        with pytest.raises(ic.StepFailure) as failure:
            stepper.step()
        return failure.value.report
    finally:
        stepper.options = normal


@pytest.mark.parametrize("policy", ["raise", "warn", "retry"])
def test_a_failed_step_loses_nothing_and_the_next_step_equals_a_twin_that_never_failed(policy):
    (world, stepper), (twin, twin_stepper) = _twins(policy)
    before = _state(world)
    report = _fail_once(stepper, policy)
    assert not report.success and report.status == "MAX_ITERATIONS" and "disc" in report.message
    # positions, velocities, accelerations, joint torque, the applied external force, time
    assert _same(before, _state(world))
    np.testing.assert_array_equal(world.getSkeleton("disc").getExternalForces(),
                                  twin.getSkeleton("disc").getExternalForces())
    # the warm start was restored too: the next step is the twin's, bit for bit
    ours, theirs = stepper.step(), twin_stepper.step()
    assert ours.success and theirs.success and ours.iterations == theirs.iterations
    assert all(np.array_equal(a, b) for a, b in zip(_qv(world), _qv(twin)))
    assert world.getTime() == twin.getTime()
    assert [c.p_n for c in ours.contacts] == [c.p_n for c in theirs.contacts]


def test_the_step_after_a_failure_matches_a_fresh_stepper_from_the_same_state():
    (world, stepper), _ = _twins("raise")
    fresh_world = _sliding_disc()
    fresh_skel, skel = fresh_world.getSkeleton("disc"), world.getSkeleton("disc")
    fresh_skel.setPositions(skel.getPositions())
    fresh_skel.setVelocities(skel.getVelocities())
    fresh_world.setTime(world.getTime())
    fresh_skel.getBodyNode(0).addExtForce(FORCE)
    fresh = ic.ImplicitContactStepper(fresh_world)
    _fail_once(stepper, "raise")
    assert stepper.step().success and fresh.step().success
    np.testing.assert_allclose(skel.getPositions(), fresh_skel.getPositions(), rtol=0, atol=FRESH_ATOL)
    np.testing.assert_allclose(skel.getVelocities(), fresh_skel.getVelocities(), rtol=0, atol=FRESH_ATOL)


def test_raise_and_warn_try_once_and_retry_halves_h_exactly_max_halvings_times():
    for policy, expected in (("raise", [H]), ("warn", [H]), ("retry", [H, H / 2, H / 4])):
        (world, stepper), _ = _twins(policy, warm_steps=1)
        calls = []
        original = stepper._one_step

        def recording(h, original=original, calls=calls):
            calls.append(h)
            return original(h)

        stepper._one_step = recording
        report = _fail_once(stepper, policy)
        # each substep sequence stops at its first failed substep
        assert calls == expected, policy
        assert report.time == world.getTime()


def test_step_failure_message_names_time_pair_status_and_what_to_try():
    (world, stepper), _ = _twins("raise", warm_steps=2)
    with pytest.raises(ic.StepFailure) as failure:
        stepper.options = CRIPPLED
        stepper.step()
    text = str(failure.value)
    assert f"t = {world.getTime():.6g} s" in text
    assert "disc" in text and "ground" in text and "MAX_ITERATIONS" in text
    assert "The world is unchanged" in text
    assert not math.isnan(failure.value.report.residual)
