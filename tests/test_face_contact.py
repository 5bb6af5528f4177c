"""A box on its face against statics and Coulomb's closed forms: the equivalent contact point under
an off-centre load, the tipping force, the incline's stick/slide threshold and sliding
acceleration, and the spin-down of a square face by its patch's torsional friction (no e_r set)."""
import math

import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact.testing import dart_world, ground_box

G = 9.81
STATIC = 1e-9          # [m], [N s] statics from the solver's residual 1e-10 on rows of O(1)
SETTLE = 30            # steps before a resting box is measured (it starts at rest, on its face)


@pytest.fixture(params=[1, 2], ids=["order1", "order2"])
def order(request):
    """Each closed form holds for [GI]'s step and for the split step of rattle.py."""
    return request.param


def _box(world, size, mass, mu, position, rotation=None):
    """A free DART BoxShape body of uniform inertia on the world's ground."""
    skel = dart.dynamics.Skeleton("box")
    _, body = skel.createFreeJointAndBodyNodePair()
    node = body.createShapeNode(dart.dynamics.BoxShape(list(size)))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(mu)
    x, y, z = size
    body.setMass(mass)
    body.setMomentOfInertia(mass * (y * y + z * z) / 12, mass * (x * x + z * z) / 12, mass * (x * x + y * y) / 12)
    world.addSkeleton(skel)
    q = np.zeros(6)
    if rotation is not None:
        q[:3] = rotation
    q[3:] = position
    skel.setPositions(q)
    return skel, body


def test_off_centre_load_puts_the_ecp_at_the_centre_of_pressure(order):
    """A vertical load F at (x0, y0) on the top face of a box resting on its bottom face: the
    contact point is the centre of pressure F (x0, y0) / (m g + F) and p_n = (m g + F) h."""
    h, m, F, x0, y0 = 0.01, 2.0, 30.0, 0.15, -0.08
    size = (0.4, 0.3, 0.1)
    world = dart_world(h)
    ground_box(world, mu=0.5)
    skel, body = _box(world, size, m, 0.5, [0.0, 0.0, size[2] / 2])
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order))
    for _ in range(SETTLE):
        body.setExtForce([0.0, 0.0, -F], [x0, y0, size[2] / 2], False, True)
        report = stepper.step()
    (c,) = [c for c in report.contacts if c.p_n > 0]
    centre = np.array([x0, y0]) * F / (m * G + F)
    np.testing.assert_allclose(c.a1[:2], centre, atol=STATIC)
    assert c.p_n == pytest.approx((m * G + F) * h, abs=STATIC)
    assert np.linalg.norm(skel.getVelocities()) < STATIC


@pytest.mark.parametrize("ratio, tips", [(0.97, False), (1.03, True)])
def test_box_pushed_at_height_tips_over_its_edge_at_the_static_force(ratio, tips, order):
    """A horizontal push F at height z above the ground on a box of width w: it tips about its
    leading edge once F z > m g w / 2 and not below (mu high enough that it never slides)."""
    h, m, mu = 0.005, 1.0, 2.0
    w, depth, H, z = 0.2, 0.3, 0.4, 0.35
    F = ratio * m * G * w / (2.0 * z)
    world = dart_world(h)
    ground_box(world, mu=mu)
    skel, body = _box(world, (w, depth, H), m, mu, [0.0, 0.0, H / 2])
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order))
    for _ in range(80):                                   # 0.4 s
        body.setExtForce([F, 0.0, 0.0], [0.0, 0.0, z - H / 2], False, True)
        stepper.step()
    pitch = skel.getPositions()[1]                         # rotation about y (tipping towards +x)
    T = body.getWorldTransform().matrix()
    corners = np.array(np.meshgrid([-w / 2, w / 2], [-depth / 2, depth / 2], [-H / 2, H / 2])).T.reshape(-1, 3)
    lowest = float(np.min(corners @ T[2, :3] + T[2, 3]))
    assert lowest > -1e-8                                  # it never sinks into the ground
    if tips:
        assert pitch > 0.05                                # turned about its edge
    else:
        assert abs(pitch) < 1e-9 and np.linalg.norm(skel.getVelocities()) < 1e-9


@pytest.mark.parametrize("tan_theta, slides", [(0.45, False), (0.7, True)])
def test_block_on_an_incline_sticks_below_mu_and_slides_above_with_coulomb_acceleration(tan_theta, slides, order):
    """Gravity tilted by theta about y over a flat ground box (the incline's frame): a flat block
    with mu = 0.5 stays at rest for tan theta < mu, else slides down with acceleration
    g (sin theta - mu cos theta); a constant acceleration is exact for the first-order scheme."""
    h, m, mu, steps = 0.005, 1.5, 0.5, 60
    theta = math.atan(tan_theta)
    world = dart_world(h)
    world.setGravity([G * math.sin(theta), 0.0, -G * math.cos(theta)])
    ground_box(world, mu=mu)
    skel, _ = _box(world, (0.4, 0.4, 0.05), m, mu, [0.0, 0.0, 0.025])
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order))
    for _ in range(steps):
        stepper.step()
    v = skel.getVelocities()
    if slides:
        a = G * (math.sin(theta) - mu * math.cos(theta))
        assert v[3] == pytest.approx(a * steps * h, rel=1e-9)
        assert abs(v[4]) < 1e-9 and abs(v[5]) < 1e-9 and np.linalg.norm(v[:3]) < 1e-9
    else:
        assert np.linalg.norm(v) < STATIC
        assert np.linalg.norm(skel.getPositions()[3:5]) < STATIC


def test_square_box_spinning_flat_stops_at_the_patch_torsion_closed_form(order):
    """A square face of side a spinning at omega0 on the ground, no e_r given: uniform pressure
    gives the friction moment mu m g a (sqrt 2 + ln(1 + sqrt 2)) / 6, so omega falls linearly and
    the box stops at t = omega0 I_zz / that moment, and not before."""
    h, a, m, mu, w0 = 0.005, 0.4, 2.0, 0.3, 6.0
    world = dart_world(h)
    ground_box(world, mu=mu)
    skel, _ = _box(world, (a, a, 0.1), m, mu, [0.0, 0.0, 0.05])
    skel.setVelocities([0.0, 0.0, w0, 0.0, 0.0, 0.0])
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order))
    moment = mu * m * G * a * (math.sqrt(2.0) + math.log(1.0 + math.sqrt(2.0))) / 6.0
    izz = m * a * a / 6.0
    t_stop = w0 * izz / moment
    omega = []
    for _ in range(int(1.3 * t_stop / h)):
        stepper.step()
        omega.append(skel.getVelocities()[2])
    t = h * np.arange(1, len(omega) + 1)
    spinning = t < t_stop - h
    np.testing.assert_allclose(np.array(omega)[spinning], w0 - moment / izz * t[spinning], rtol=0, atol=1e-9)
    assert np.all(np.abs(np.array(omega)[t >= t_stop]) < 1e-12)
    assert np.linalg.norm(skel.getVelocities()[3:]) < 1e-9   # no drift off the spot


# boxes resting flat and started downwards with spin, whose first step failed after 6 solves at
# every h the retry policy tried before the landing predictor (recovery.face_landing)
SLAPS = {
    "wide box": (1.31196e-3, (0.45027, 0.47032, 0.21101), 5.75815, (2.73075, 2.42763, 1.40930), (1.56110, -1.09137, -5.11594)),
    "tall box": (2.96320e-4, (0.16602, 0.25952, 0.41823), 1.26449, (2.06643, -2.80771, 5.37650), (-0.55961, 0.78929, -2.43458)),
}


@pytest.mark.parametrize("name", list(SLAPS))
def test_box_started_down_flat_with_spin_lands_in_one_step(name, order):
    """A box resting on its face with a downward speed of 2-5 m/s and a spin about a tilted
    axis: the impact is inelastic and the equivalent contact point moves to where the normal
    impulse's moment stops the face's rotation, so the box ends its first step flat, at rest
    along the normal, on the ground, in one solve sequence at the world's h (no substeps), with
    p_n = m (|v_z| + g h), and it never gains energy."""
    h, size, m, w, v = SLAPS[name]
    world = dart_world(h)
    ground_box(world, mu=0.5)
    skel, body = _box(world, size, m, 0.5, [0.0, 0.0, size[2] / 2])
    skel.setVelocities(np.r_[w, v])
    energy = skel.computeKineticEnergy() + skel.computePotentialEnergy()
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order))
    report = stepper.step()
    assert report.success and report.substeps == 1
    vel = skel.getVelocities()
    R = body.getWorldTransform().rotation()
    assert abs(R[2, 2]) == pytest.approx(1.0, abs=1e-12)          # flat: its face on the ground
    assert abs(vel[5]) < STATIC and np.linalg.norm(vel[:2]) < STATIC
    assert skel.getPositions()[5] == pytest.approx(size[2] / 2, abs=STATIC)
    (c,) = [c for c in report.contacts if c.p_n > 0]
    assert c.p_n == pytest.approx(m * (abs(v[2]) + G * h), rel=1e-9)
    assert skel.computeKineticEnergy() + skel.computePotentialEnergy() < energy


def _slap(name, options, on_failure="retry"):
    """The world of test_box_started_down_flat_with_spin_lands_in_one_step and its stepper."""
    h, size, m, w, v = SLAPS[name]
    world = dart_world(h)
    ground_box(world, mu=0.5)
    skel, _ = _box(world, size, m, 0.5, [0.0, 0.0, size[2] / 2])
    skel.setVelocities(np.r_[w, v])
    return world, skel, ic.ImplicitContactStepper(world, on_failure=on_failure, options=options)


BUDGET = 3     # Newton iterations: fewer than the slap's landing step takes (it takes tens)


@pytest.mark.parametrize("on_failure", ["retry", "raise", "warn"])
def test_a_step_that_spends_its_iteration_budget_fails_at_once_with_the_world_unchanged(on_failure, order):
    """The wide box's landing slap needs more Newton iterations than BUDGET: with
    max_step_iterations = BUDGET the step fails after at most BUDGET + 1 (one polishing step)
    iterations, without halving (substeps 1), and the world is exactly as before (q, v, time);
    with the default budget the same step lands, having spent more than BUDGET."""
    _, _, free = _slap("wide box", ic.StepperOptions(order=order))
    landed = free.step()
    assert landed.success and landed.spent > BUDGET + 1 and landed.spent >= landed.iterations

    world, skel, stepper = _slap("wide box", ic.StepperOptions(order=order, max_step_iterations=BUDGET), on_failure)
    before = (skel.getPositions().copy(), skel.getVelocities().copy(), world.getTime())
    if on_failure == "warn":
        with pytest.warns(RuntimeWarning, match="max_step_iterations"):
            report = stepper.step()
    else:
        with pytest.raises(ic.StepFailure, match="max_step_iterations") as info:
            stepper.step()
        report = info.value.report
    assert not report.success and report.status == "BUDGET_EXHAUSTED"
    assert report.substeps == 1 and report.spent <= BUDGET + 1
    np.testing.assert_array_equal(skel.getPositions(), before[0])
    np.testing.assert_array_equal(skel.getVelocities(), before[1])
    assert world.getTime() == before[2]
    assert stepper.order1_steps == 0


def test_a_step_past_its_wall_time_budget_fails_before_its_next_solve(order):
    """max_step_seconds = 1e-9 s has passed before the first solve: the step fails having spent
    no Newton iteration, the world unchanged, and a stepper without the limit then lands it."""
    world, skel, stepper = _slap("wide box", ic.StepperOptions(order=order, max_step_seconds=1e-9), "raise")
    before = (skel.getPositions().copy(), skel.getVelocities().copy())
    with pytest.raises(ic.StepFailure, match="max_step_seconds") as info:
        stepper.step()
    assert info.value.report.spent == 0
    np.testing.assert_array_equal(skel.getPositions(), before[0])
    np.testing.assert_array_equal(skel.getVelocities(), before[1])
    assert ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=order)).step().success


def test_a_budget_that_is_not_reached_changes_nothing(order):
    """The slap and 20 steps of resting after it with max_step_iterations = None and with the
    default budget: the same trajectory bit for bit."""
    runs = []
    for limit in (None, ic.StepperOptions().max_step_iterations):
        _, skel, stepper = _slap("tall box", ic.StepperOptions(order=order, max_step_iterations=limit))
        for _ in range(20):
            stepper.step()
        runs.append(np.r_[skel.getPositions(), skel.getVelocities()])
    np.testing.assert_array_equal(runs[0], runs[1])


@pytest.mark.parametrize("field, value", [("max_step_iterations", 0), ("max_step_iterations", 2.5),
                                          ("max_step_seconds", 0.0), ("max_step_seconds", math.inf)])
def test_a_budget_that_is_not_a_budget_is_refused(field, value):
    with pytest.raises(ValueError, match=field):
        ic.StepperOptions(**{field: value})
