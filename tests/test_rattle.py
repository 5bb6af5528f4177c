"""Order 2 (rattle.py): the split stage's rows against central differences, observed orders in
free flight, on a pendulum and on a rocking ellipsoid against exact references, an inelastic
impact, slide-to-roll at 5/7 v0, quasi-rigid layers (Example 3's bounce and core hit, a stiff
layer, friction on a layer), joint springs and dampers, and the fallbacks to order 1."""
import numpy as np
import pytest

import implicit_contact as ic
from comparisons import convergence as cv
from implicit_contact import ncp
from implicit_contact import shapes as shp
from implicit_contact.params import Friction
from implicit_contact.testing import dart_world, ground_box, jacobian_error, random_pair_problem
from scenes import disc_on_quasi_rigid_plane as qr

H = 0.01
EPS_FD = 1e-6
ATOL_FD = 5e-6            # as test_formulation: truncation + round-off of central differences
ORDER_2 = 1.85            # observed order from h to h/2 of a second-order scheme (its asymptote is 2)
ORDER_1_MAX = 1.2         # ... and the most a first-order one shows

SPLIT_CASES = [
    (2, ("planar", "fixed"), shp.Disc(1.0, center=[0.1, 0.2]), shp.HalfPlane([0.0, 1.0], 0.0), True, Friction(0.4)),
    (2, ("planar", "planar"), shp.Ellipse([1.0, 0.5]), shp.Superellipse([0.6, 0.3], 4.0), False, Friction(0.4)),
    (3, ("free", "fixed"), shp.Sphere(0.5, center=[0.1, 0.0, 0.2]), shp.HalfSpace([0, 0, 1], 0.0), True,
     Friction(0.3, 1.0, 0.8, 0.2)),
    (3, ("free", "free"), shp.Ellipsoid([1.0, 0.5, 0.7]), shp.Superquadric([0.5, 0.4, 0.3], 4.0), False,
     Friction(0.3, 1.0, 0.8, 0.2)),
    (3, ("free", "free"), shp.Sphere(0.4), shp.Intersection.box([0.3, 0.2, 0.1]), False, Friction(0.3, 1.0, 1.0, 0.0)),
]


@pytest.mark.parametrize("case", range(len(SPLIT_CASES)))
def test_split_stage_jacobian_matches_central_differences(case):
    """Stage 1's rows (impulse in a fixed frame at l, the mean slip) differentiate like [GI]'s."""
    dim, kinds, piece1, piece2, fixed2, friction = SPLIT_CASES[case]
    frame = np.random.default_rng(50 + case).normal(size=15)
    problem, z = random_pair_problem(dim, kinds, piece1, piece2, friction, np.random.default_rng(case), H, fixed2,
                                     start_frame=frame)
    assert jacobian_error(problem, z, EPS_FD) <= ATOL_FD
    # the frame at l is used: the residual differs from [GI]'s at the same point
    plain, z_plain = random_pair_problem(dim, kinds, piece1, piece2, friction, np.random.default_rng(case), H, fixed2)
    assert np.max(np.abs(problem.fun(z) - plain.fun(z_plain))) > 1e-3


RTOL_CORIOLIS = 1e-12      # round-off of the closed form and of DART's exact central differences


def test_free_body_coriolis_jacobian_matches_darts_central_differences():
    """dart_adapter.free_coriolis_jacobian (closed form from M) against coriolis_jacobian (DART's
    Coriolis forces by central differences, exact for a quadratic up to round-off), on free bodies
    with random masses, inertias, centres of mass off the origin, poses and velocities."""
    import dartpy as dart
    from implicit_contact import dart_adapter as adapter
    rng = np.random.default_rng(7)
    for _ in range(8):
        skel = dart.dynamics.Skeleton("coriolis_probe")
        _, body = skel.createFreeJointAndBodyNodePair()
        A = rng.normal(size=(3, 3))
        body.setInertia(dart.dynamics.Inertia(0.5 + 3.0 * rng.random(), 0.3 * rng.normal(size=3),
                                              A @ A.T + 0.1 * np.eye(3)))
        skel.setPositions(rng.normal(size=6))
        v = 3.0 * rng.normal(size=6)
        skel.setVelocities(v)
        record = adapter.SkeletonRecord(skel, adapter.FREE, 6, -1)
        by_differences = adapter.coriolis_jacobian(record, v)
        closed = adapter.free_coriolis_jacobian(np.asarray(skel.getMassMatrix()), v[:3])
        assert np.max(np.abs(closed - by_differences)) <= RTOL_CORIOLIS * np.max(np.abs(by_differences))
        assert np.max(np.abs(by_differences[:, 3:])) <= RTOL_CORIOLIS * np.max(np.abs(by_differences))


ATOL_ORIGIN_JACOBIAN = 1e-14   # DART's world Jacobian of a FREE / PLANAR origin carries round-off (~2e-15)


def test_origin_and_jacobian_of_free_and_planar_bodies_are_darts():
    """dart_adapter.origin_and_jacobian (stage 2's bodies at q+) gives a FREE or PLANAR body's
    origin and world Jacobian in closed form: the origin exactly DART's, the Jacobian DART's to
    round-off, after random poses, velocities and position integrations."""
    import dartpy as dart
    from implicit_contact import dart_adapter as adapter
    rng = np.random.default_rng(11)
    free = dart.dynamics.Skeleton("free_probe")
    _, free_body = free.createFreeJointAndBodyNodePair()
    planar = dart.dynamics.Skeleton("planar_probe")
    joint, planar_body = planar.createPlanarJointAndBodyNodePair()
    joint.setXYPlane()
    origin = np.zeros(3)
    for skel, body, kind, k in ((free, free_body, adapter.FREE, 6), (planar, planar_body, adapter.PLANAR, 3)):
        for _ in range(50):
            skel.setPositions(3.0 * rng.normal(size=k))
            skel.setVelocities(rng.normal(size=k))
            skel.integratePositions(rng.uniform(1e-4, 1e-2))
            rec = _BodyProbe(body, skel, kind)
            p, J = adapter.origin_and_jacobian(rec)
            assert np.array_equal(p, body.getTransform().matrix()[:3, 3])
            assert np.max(np.abs(J - skel.getWorldJacobian(body, origin))) <= ATOL_ORIGIN_JACOBIAN


class _BodyProbe:
    """What origin_and_jacobian reads of a dart_adapter.BodyRecord."""

    def __init__(self, body_node, skeleton, kind):
        self.body_node, self.skeleton, self.kind = body_node, skeleton, kind


RTOL_KICK = 1e-12           # round-off of a 6 x 6 LU solve against numpy's


def test_block_kicks_solve_each_skeleton_block_and_mark_a_singular_one():
    """step_kernels.block_kicks (stage 2's free half kick, rattle.Stage2.start): u + M^-1 b per
    diagonal block, against numpy's dense solve; an exactly singular block gives NaN, which the
    solver reports as NOT_FINITE, instead of an exception mid-step."""
    from implicit_contact import step_kernels
    rng = np.random.default_rng(11)
    A, B = rng.normal(size=(6, 6)), rng.normal(size=(3, 3))
    M = np.zeros((9, 9))
    M[:6, :6], M[6:, 6:] = A @ A.T + np.eye(6), B @ B.T + np.eye(3)
    u, b = rng.normal(size=9), rng.normal(size=9)
    blocks = np.array([[0, 6], [6, 3]], np.int64)
    out = np.zeros(12)
    step_kernels.block_kicks(M, u, b, blocks, out)
    expected = u + np.linalg.solve(M, b)
    assert np.max(np.abs(out[:9] - expected)) <= RTOL_KICK * np.max(np.abs(expected))
    assert np.all(out[9:] == 0.0)              # (the impulse columns are not touched)
    M[6:, 6:] = 0.0
    step_kernels.block_kicks(M, u, b, blocks, out)
    assert np.all(np.isnan(out[6:9])) and np.max(np.abs(out[:6] - expected[:6])) <= RTOL_KICK * np.max(np.abs(expected))


def _observed_order(errors):
    return float(np.log2(errors[0] / errors[1]))


def test_order_2_tumbles_a_free_body_to_second_order():
    """A free asymmetric top (comparisons/convergence.py): body-frame angular velocity after 0.5 s
    against Euler's equations."""
    err = {order: [cv.tumble_error(order, h, 0.5) for h in (4e-3, 2e-3)] for order in (1, 2)}
    assert _observed_order(err[2]) >= ORDER_2
    assert _observed_order(err[1]) <= ORDER_1_MAX
    assert err[2][1] < 0.01 * err[1][1]


def test_order_2_keeps_a_pendulum_energy_to_second_order():
    """A revolute pendulum released at 1 rad: the largest energy error over 1 s."""
    err = [cv.pendulum_energy_error(2, h) for h in (4e-3, 2e-3)]
    assert _observed_order(err) >= ORDER_2
    assert err[1] < 0.01 * cv.pendulum_energy_error(1, 2e-3)


ROCK_ENERGY_RTOL = 1e-4   # issue 14's bound on the rocking energy at h = 2e-3


def test_order_2_rocks_an_ellipsoid_to_second_order_and_keeps_its_energy():
    """The rocking ellipsoid (scenes/ellipsoid_rocking.py) over 0.6 s, against its exact 1-dof
    rolling reference: tilt error second order in h, rocking energy within 1e-4 at h = 2e-3."""
    from scenes import ellipsoid_rocking as er
    errors, energy = [], None
    for h in (4e-3, 2e-3):
        traj = er.simulate(0.6, h, stepper_options=ic.StepperOptions(order=2), on_failure="raise")
        t, q, _, _ = traj.arrays()
        exact, _ = er.exact_rocking(t)
        errors.append(float(np.max(np.abs(er.tilt_angle(q) - exact))))
        energy = er.rocking_energy(traj)
    assert _observed_order(errors) >= ORDER_2
    assert np.max(np.abs(energy - er.exact_energy())) <= ROCK_ENERGY_RTOL * er.exact_energy()


TOL = 1e-6                 # the stepper's default contact tolerance


def test_order_2_impact_is_inelastic_and_does_not_penetrate():
    """A ball falling at 2 m/s onto the ground stops in its normal direction (restitution 0)."""
    h = 0.005
    world = dart_world(h)
    ground_box(world, mu=0.5)
    ball = cv.ball(world, 0.5, 0.1 + 0.004, [0.0, 0.0, -2.0])
    stepper = ic.ImplicitContactStepper(world, on_failure="raise", options=ic.StepperOptions(order=2))
    lowest = np.inf
    for _ in range(40):
        stepper.step()
        lowest = min(lowest, ball.getPositions()[5])
    assert lowest >= 0.1 - TOL
    assert abs(ball.getVelocities()[5]) < 1e-8                 # resting, no bounce
    assert abs(ball.getPositions()[5] - 0.1) <= TOL


def test_order_2_slide_to_roll_ends_at_five_sevenths():
    """A ball sliding without spin at v0 on mu = 0.3 rolls at 5/7 v0 once friction has stopped
    the slip (at t = 2 v0 / (7 mu g) = 0.19 s), then keeps that speed."""
    h, v0 = 0.002, 2.0
    world = dart_world(h)
    ground_box(world, mu=0.3)
    ball = cv.ball(world, 0.3, 0.1, [v0, 0.0, 0.0])
    stepper = ic.ImplicitContactStepper(world, on_failure="raise", options=ic.StepperOptions(order=2))
    for _ in range(150):
        stepper.step()
    v = np.array(ball.getVelocities())
    assert abs(v[3] - 5.0 / 7.0 * v0) < 1e-6
    assert abs(v[1] * 0.1 - v[3]) < 1e-6                          # rolling: omega_y r = v_x


def test_order_must_be_1_or_2():
    with pytest.raises(ValueError, match="order must be 1"):
        ic.StepperOptions(order=3)


# -- quasi-rigid layers (rattle.py, R11-R14) -------------------------------------------------------
SAME_ATOL = 1e-10          # m: the same discretisation on the same state, up to round-off
PLASTIC_V_ATOL = 1e-10     # m/s: the normal velocity left after a plastic hit on the core
ENERGY_ATOL = 1e-9         # J: Example 3's energy (10.6 J) against the plastic stop's, and kept after


def test_order_2_layer_is_the_midpoint_rule_in_a_fixed_frame():
    """A frictionless disc bouncing on Example 3's undamped layer (no core): with the contact frame
    fixed the split step's two half layer impulses (R11) make the implicit midpoint rule, that is
    order 1 with the "midpoint" scheme, step for step, and its energy and peak deflection."""
    h = 1e-3
    two = qr.simulate(1.0, duration=0.45, h=h, scheme="paper", order=2)
    mid = qr.simulate(1.0, duration=0.45, h=h, scheme="midpoint")
    assert np.max(np.abs(two.y - mid.y)) <= SAME_ATOL
    assert np.max(np.abs(two.deflection - mid.deflection)) <= SAME_ATOL
    assert abs(two.energy[-1] - two.energy[0]) < 0.5 * qr.K * (qr.V_CONTACT * h) ** 2
    assert two.deflection.max() == pytest.approx(qr.analytic_events(1.0)["peak"], rel=1e-3)


def test_order_2_core_hit_is_plastic_in_one_step():
    """Example 3 with a core at delta_max = 0.05 m: the core's impulse is stage 2's Newton law
    (R12), so the first core step ends at delta_max with no normal velocity and the energy of the
    plastic stop; then the spring lifts the disc off and the energy stays. Order 1's "midpoint"
    scheme bounces off the core (0.25 m/s); its "paper" scheme takes two steps to stop."""
    h = 1e-3
    rec = qr.simulate(0.05, duration=0.36, h=h, order=2)
    hit = np.nonzero(rec.p_core > 0)[0]
    assert len(hit) == 1
    k = hit[0]
    assert abs(rec.t[k] - qr.analytic_events(0.05)["core"]) <= h
    assert rec.deflection[k] == pytest.approx(0.05, abs=1e-9)
    assert abs(rec.vy[k]) <= PLASTIC_V_ATOL
    assert abs(rec.energy[k] - qr.energy_after_core_hit(0.05)) <= ENERGY_ATOL
    assert np.max(np.abs(rec.energy[k:] - rec.energy[k])) <= ENERGY_ATOL
    assert rec.vy[-1] > 0.5                       # lifted off the core
    mid = qr.simulate(0.05, duration=0.36, h=h, scheme="midpoint")
    assert mid.vy[qr.core_episode_end(mid.p_core)] > 0.1


def _ball_on_layer(order, h, k, c, v0=0.0, z=None, mu=0.0, delta_max=np.inf):
    """A 1 kg ball of radius 0.1 m (cv.ball) over a welded half-space z <= 0 with a quasi-rigid
    layer (k, c, delta_max), friction mu on both; (world, ball, stepper)."""
    import dartpy as dart
    world = dart_world(h)
    ground = dart.dynamics.Skeleton("ground")
    _, body = ground.createWeldJointAndBodyNodePair()
    ic.attach(body, shp.HalfSpace([0, 0, 1], 0.0), friction=Friction(mu),
              compliance=ic.Compliance(k=k, c=c, delta_max=delta_max))
    world.addSkeleton(ground)
    ball = cv.ball(world, mu, cv.BALL_R if z is None else z, [v0, 0.0, 0.0])
    return world, ball, ic.ImplicitContactStepper(world, on_failure="raise", options=ic.StepperOptions(order=order))


def test_order_2_rocks_on_a_layer_to_second_order():
    """The rocking ellipsoid on an undamped quasi-rigid layer (k = 1e5 N/m): rolling keeps the
    energy with the layer's k delta^2 / 2; its error is second order under order 2 (the split
    frame of a compliant pair, R1 and R5, with R11) and first order under order 1."""
    err = {order: [cv.layer_rocking_error(order, h) for h in (4e-3, 2e-3)] for order in (1, 2)}
    assert _observed_order(err[2]) >= ORDER_2
    assert _observed_order(err[1]) <= ORDER_1_MAX
    assert err[2][1] < 1e-3 * err[1][1]


STIFF_LAYER_K = 1e8        # N/m, critically damped: h c / (2 m) = 10 at h = 1e-3
STIFF_LAYER_RISE = 2e-4    # m: the lift-off after landing of a converged run (h = 1e-5), 1.7e-4 m, + 15 %


def test_order_2_stiff_layer_does_not_bounce(monkeypatch):
    """A ball dropped 1 cm onto a critically damped layer stiff for the step: with the damper's
    stage-2 half at v+ (R14) it lifts off no more than a converged run (h = 1e-5: 0.17 mm) and
    settles at the static deflection m g / k at rest. With the midpoint rule alone (STIFF_DAMPER
    = inf) the damper rings and the ball bounces off 4 mm high."""
    from implicit_contact import rattle
    c = 2.0 * np.sqrt(STIFF_LAYER_K)

    def heights():
        _, ball, stepper = _ball_on_layer(2, 1e-3, STIFF_LAYER_K, c, z=cv.BALL_R + 0.01, delta_max=0.01)
        z = []
        for _ in range(200):
            report = stepper.step()
            z.append(ball.getPositions()[5])
        return np.array(z), report, ball.getVelocities()[5]
    z, report, vz = heights()
    static = 9.81 / STIFF_LAYER_K
    landed = np.argmax(z < cv.BALL_R)
    assert landed > 0 and z[landed:].max() < cv.BALL_R + STIFF_LAYER_RISE
    assert report.contacts[0].deflection == pytest.approx(static, rel=1e-6)
    assert z[-1] == pytest.approx(cv.BALL_R - static, abs=1e-12)
    assert abs(vz) < 1e-9                                  # at rest: v+ = 0 (R14)
    monkeypatch.setattr(rattle, "STIFF_DAMPER", np.inf)
    z, _, _ = heights()
    assert z[landed:].max() > cv.BALL_R + 1e-3


SLIDE_ATOL = 1e-9          # m: the sliding ball's distance at two steps (order 2's slide is exact)


def test_order_2_friction_on_a_layer_sees_the_whole_load():
    """A ball sliding at 2 m/s onto a damped layer (k = 1e5 N/m, no core, mu = 0.3): the normal
    load is the layer's alone, known after stage 1, and stage 2's friction acts on it (R13):
    |P_t| = mu P_n while it slides, then it rolls at 5/7 v0. The distance in 0.5 s is the same at
    h = 2e-3 and 5e-4 (order 1's differs by 4e-4: first order)."""
    x = {}
    for order in (1, 2):
        for h in (2e-3, 5e-4):
            _, ball, stepper = _ball_on_layer(order, h, 1e5, 300.0, v0=cv.BALL_V0, mu=cv.BALL_MU)
            for i in range(int(round(0.5 / h))):
                report = stepper.step()
                if order == 2 and i * h < 0.15 and i > 0:     # sliding until 0.194 s
                    (cr,) = report.contacts
                    assert cr.p_spring == cr.p_n and cr.p_core == 0.0 and cr.p_n > 0.0
                    assert np.hypot(cr.p_t, cr.p_o) == pytest.approx(cv.BALL_MU * cr.p_n, rel=1e-9)
            v = np.array(ball.getVelocities())
            assert abs(v[3] - 5.0 / 7.0 * cv.BALL_V0) < 1e-9
            x[order, h] = float(ball.getPositions()[3])
    assert abs(x[2, 2e-3] - x[2, 5e-4]) <= SLIDE_ATOL
    assert abs(x[1, 2e-3] - x[1, 5e-4]) > 1e-4


SPRING_ENERGY_REL = 1e-12     # the implicit midpoint rule keeps a linear oscillator's energy (round-off)


def test_order_2_joint_spring_keeps_its_energy_and_phase():
    """A DART joint spring (no damper, no gravity): under order 2 (rattle.py, R9, the implicit
    midpoint rule) the energy I v^2 / 2 + K q^2 / 2 stays to round-off over 250 steps and the
    angle error is second order; order 1 (DART's implicit spring) loses 15 % in 1 s."""
    energy = {}
    for order in (1, 2):
        q, v, _, _ = cv.spring_hinge_run(order, 4e-3, damping=0.0)
        inertia = 0.25 + 1e-3                                  # m L^2 + the bob's own
        e = 0.5 * inertia * v ** 2 + 0.5 * cv.HINGE_K * q ** 2
        energy[order] = np.max(np.abs(e / (0.5 * cv.HINGE_K * cv.HINGE_Q0 ** 2) - 1.0))
    assert energy[2] <= SPRING_ENERGY_REL
    assert energy[1] >= 0.1
    err = [float(np.max(np.abs(run[0] - run[2]))) for run in
           (cv.spring_hinge_run(2, h, damping=0.0) for h in (4e-3, 2e-3))]
    assert _observed_order(err) >= ORDER_2


def test_order_2_damped_joint_to_second_order():
    """A joint spring and damper: the angle against the exact damped oscillation."""
    err = {order: [cv.damped_joint_error(order, h) for h in (4e-3, 2e-3)] for order in (1, 2)}
    assert _observed_order(err[2]) >= ORDER_2
    assert _observed_order(err[1]) <= ORDER_1_MAX
    assert err[2][1] < 0.01 * err[1][1]


STIFF_D = 2510.0            # [N m s/rad]: h D / (2 I) = 50 at h = 0.01 (I = 0.251 kg m^2)
STIFF_V_REL = 1e-3          # the end velocity against the exact slow creep, relative


def test_order_2_stiff_damper_does_not_ring(monkeypatch):
    """A damper stiff for its dof acts at v+ in stage 2 (rattle.py, R10): the hinge creeps back to
    rest at the exact velocity, every step of one sign. With the midpoint rule alone (R9) the
    velocity is multiplied by (1 - a) / (1 + a) = -0.96 a step: it rings."""
    from implicit_contact import rattle
    q, v, q_exact, v_exact = cv.spring_hinge_run(2, 0.01, damping=STIFF_D, duration=0.2)
    assert np.all(v < 0.0)
    assert np.max(np.abs(v - v_exact)) <= STIFF_V_REL * np.max(np.abs(v_exact))
    assert np.max(np.abs(q - q_exact)) <= 1e-6
    monkeypatch.setattr(rattle, "STIFF_DAMPER", np.inf)
    _, v, _, v_exact = cv.spring_hinge_run(2, 0.01, damping=STIFF_D, duration=0.2)
    assert np.max(np.abs(v - v_exact)) > 0.5 * np.max(np.abs(v_exact))


EVENT_TOL = 0.011          # s: issue 14's 0.01 s, plus round-off in the events' step times


def test_order_2_example_2_events_agree_with_order_1():
    """[GI] Example 2 (two contacts, each closing and opening): the split step's event times
    within 0.01 s of order 1's at the same h."""
    from implicit_contact.trajectory import simulate
    from scenes import sphere_on_two_spheres as s2
    found = {}
    for order in (1, 2):
        world = s2.build_world(s2.H)
        stepper = ic.ImplicitContactStepper(world, on_failure="raise", options=ic.StepperOptions(order=order))
        ball, fixed = world.getSkeleton("ball").getBodyNode(0), world.getSkeleton("fixed_spheres")
        for name in ("sphere_r10", "sphere_r9"):
            stepper.set_pair_friction(ball, fixed.getBodyNode(name), s2.FRICTION)
        found[order] = s2.events(simulate(world, stepper, 5.0, before_step=s2.push))
    assert found[1].keys() == found[2].keys() and len(found[1]) == 3
    for name, t in found[1].items():
        assert abs(found[2][name] - t) <= EVENT_TOL, name


def _random_stage2(rng):
    """Two free bodies (DART's world Jacobian I6) and a fixed one; closed pairs: free/free with
    torsion, free/fixed with friction, free/fixed frictionless, two quasi-rigid pairs with
    friction (a layer's known load and a damper at v+, R12-R14), one with its core closed, one
    open, and a layered patch (its friction point and two vertices)."""
    from implicit_contact import rattle

    def frame():
        n = rng.normal(size=3)
        n /= np.linalg.norm(n)
        t = np.cross(n, rng.normal(size=3))
        t /= np.linalg.norm(t)
        return n, t, np.cross(n, t)

    skeletons = []
    for _ in range(2):
        A = rng.normal(size=(6, 6))
        skeletons.append((A @ A.T + 6 * np.eye(6), rng.normal(size=6), rng.normal(size=6)))
    bodies = [(0, np.eye(6), rng.normal(size=3)), (6, np.eye(6), rng.normal(size=3))]
    pairs = []
    for ends, mu, e_r, load, core_open in (((0, 1), 0.4, 0.05, 0.0, False), ((1, -1), 0.3, 0.0, 0.0, False),
                                           ((0, -1), 0.0, 0.0, 0.0, False), ((1, -1), 0.5, 0.0, 1.3, False),
                                           ((0, -1), 0.6, 0.0, 0.7, True)):
        damp = 0.8 if load else 0.0       # (a stiff layer's damper at v+, R14)
        n, t, o = frame()
        R1 = np.r_[abs(rng.normal()) + 0.2, 0.1 * rng.normal(size=2), 0.1 * rng.normal() if e_r else 0.0]
        pairs.append(rattle.ClosedPair(ends, (rng.normal(size=3), rng.normal(size=3)), n, t, o, 3, mu, 1.0, 0.8,
                                       e_r, 0.05, R1, 0.3, load=load, core_open=core_open, damp=damp,
                                       layered=bool(load)))
    # a layered patch (a quasi-rigid face on a face): its friction point and two vertices
    n, t, o = frame()
    a = rng.normal(size=3)
    pairs.append(rattle.ClosedPair((1, -1), (a, a), n, t, o, 3, 0.5, 1.0, 1.0, 0.0, 0.05,
                                   np.r_[0.0, 0.1 * rng.normal(size=2), 0.0], 0.3, vertices=2, layered=True,
                                   load=0.9, damp=0.4))
    for _ in range(2):
        x = a + 0.1 * np.cross(n, rng.normal(size=3))
        pairs.append(rattle.ClosedPair((1, -1), (x, x), n, t, o, 3, 0.0, 1.0, 1.0, 0.0, 0.05, np.zeros(4), 0.0))
    return rattle.Stage2(skeletons, bodies, pairs), bodies, pairs


def test_stage_2_rows_are_point_velocities_and_their_jacobian_matches_central_differences():
    rng = np.random.default_rng(7)
    stage, bodies, pairs = _random_stage2(rng)
    v = rng.normal(size=stage.nv)
    for cp, G in zip(pairs, stage.G):
        # the oracle: material point velocities v_o + omega x (a - p) of each free end
        vel, omega = np.zeros(3), np.zeros(3)
        for side, sgn in ((0, -1.0), (1, 1.0)):
            b = cp.bodies[side]
            if b >= 0:
                col, _, p = bodies[b]
                w, vo = v[col:col + 3], v[col + 3:col + 6]
                vel += sgn * (vo + np.cross(w, cp.a[side] - p))
                omega += sgn * w
        np.testing.assert_allclose(G @ v, [cp.n @ vel, cp.t @ vel, cp.o @ vel, cp.n @ omega], rtol=0, atol=1e-12)
    x = stage.start() + 0.1 * rng.normal(size=stage.n)
    x[stage.nv:] = np.abs(x[stage.nv:]) + 0.2
    # (R5) against its definition with the pairs' total impulses (a layer's load in P_n, R12)
    P = stage.impulses(x)
    assert P[3][0] == pytest.approx(x[stage.pi[3][0]] + 1.3 - 0.8 * stage.G[3, 0] @ x[:stage.nv], abs=1e-14)
    force = stage.M @ (x[:stage.nv] - stage.u) - stage.hf
    for cp, G, Pc in zip(pairs, stage.G, P):
        dP = (Pc - cp.R1) * (cp.vertices == 0, cp.friction, cp.friction, cp.friction)   # (a frictionless
        #                                       pair: P_n alone; a patch's point: its vertices carry P_n)
        force -= cp.s_p * (G[:3].T @ dP[:3] + cp.e_r * G[3] * dP[3])
    F = stage.fun(x)
    np.testing.assert_allclose(F[:stage.nv], stage.scale * force, rtol=0, atol=1e-12)
    assert F[stage.pi[4][0]] == x[stage.pi[4][0]]          # an open core: no core impulse
    # the layered patch: its vertices' sum less the layer's L - beta w (w: its point's unknown),
    # and each vertex's normal velocity above w
    w, (c1, c2) = x[stage.pi[5][0]], (stage.pi[6][0], stage.pi[7][0])
    assert P[5][0] == pytest.approx(x[c1] + x[c2], abs=1e-14)
    assert F[stage.pi[5][0]] == pytest.approx(x[c1] + x[c2] - (0.9 - 0.4 * w), abs=1e-14)
    for k, c in ((6, c1), (7, c2)):
        assert F[c] == pytest.approx(stage.G[k, 0] @ x[:stage.nv] - w, abs=1e-14)
    J = stage.jac(x)
    J_fd = np.column_stack([(stage.fun(x + EPS_FD * e) - stage.fun(x - EPS_FD * e)) / (2 * EPS_FD)
                            for e in np.eye(stage.n)])
    assert np.max(np.abs(J - J_fd) / np.maximum(1.0, np.abs(J_fd))) <= ATOL_FD


def test_order_2_keeps_an_articulated_skeleton_in_contact_to_second_order():
    """A pendulum hinged at the centre of a ball sliding on frictionless ground
    (comparisons/convergence.py): its energy error is second order in h."""
    err = [cv.cart_energy_error(2, h) for h in (4e-3, 2e-3)]
    assert _observed_order(err) >= ORDER_2
    assert err[1] < 0.01 * cv.cart_energy_error(1, 2e-3)


def test_order_2_lands_a_nearly_flat_superquadric_and_brings_it_to_rest(monkeypatch):
    """A superquadric of exponent 10 dropped tilted (comparisons/stability.py's case): with its
    impulse in the frame at l, stage 1 stalls on the nearly flat face (the undetermined point of
    a face on a face) and the step is solved again with every pair unsplit; it lands without a
    StepFailure and rests on its smallest semi-axis."""
    from comparisons import stability as stab
    monkeypatch.setenv(stab.ORDER_ENV, "2")
    record = stab.shape_case(stab.ShapeCase("superquadric", 10.0, duration=1.5))
    assert record.completed, record.error
    assert record.min_gap >= -stab.PEN_TOL
    rest = next(c for c in record.checks if c.text.startswith("|final height"))
    assert rest.ok, rest.describe()


FALLBACK_ATOL = 1e-12      # m, m/s: the same [GI] step on the same state, up to round-off
FALLBACK_H, FALLBACK_STEPS = 0.002, 40


def _sliding_ball(order):
    """(stepper, positions and velocities after FALLBACK_STEPS) of a ball (r = 0.1 m) sliding
    without spin at 2 m/s on mu = 0.3."""
    world = dart_world(FALLBACK_H)
    ground_box(world, mu=0.3)
    ball = cv.ball(world, 0.3, 0.1, [2.0, 0.0, 0.0])
    stepper = ic.ImplicitContactStepper(world, on_failure="raise", options=ic.StepperOptions(order=order))
    for _ in range(FALLBACK_STEPS):
        stepper.step()
    return stepper, np.concatenate([ball.getPositions(), ball.getVelocities()])


def test_order_2_falls_back_to_order_1_when_stage_1_fails(monkeypatch):
    """A split step whose first stage fails (DART still at l) is taken as [GI]'s step: with
    stage 1 made to fail on every step with contact, a ball sliding to rolling under order 2
    follows order 1's trajectory, every step counted in order1_steps; without the fallback the
    first step raises StepFailure."""

    _, reference = _sliding_ball(1)
    real_stage1 = ic.ImplicitContactStepper._stage1

    def failing_stage1(self, state, pairs, joints, t0):
        if not pairs:
            return real_stage1(self, state, pairs, joints, t0)
        return None, ic.StepReport(False, 0, np.inf, "MAX_ITERATIONS", (), t0, 1, "stage 1 made to fail", 0)

    monkeypatch.setattr(ic.ImplicitContactStepper, "_stage1", failing_stage1)
    stepper, fallen_back = _sliding_ball(2)
    assert stepper.order1_steps == FALLBACK_STEPS
    np.testing.assert_allclose(fallen_back, reference, rtol=0.0, atol=FALLBACK_ATOL)
    assert fallen_back[9] - 0.1 * fallen_back[7] > 0.1     # still sliding at 0.08 s: friction rows active

    monkeypatch.setattr(ic.ImplicitContactStepper, "_order1_step", lambda self, h, keep, failed: failed)
    with pytest.raises(ic.StepFailure):
        _sliding_ball(2)


ONE_STEP_ATOL = 1e-9       # m, rad, m/s: one order-1 step among order-2 steps, against its predicted shift


def test_order_2_falls_back_to_order_1_when_stage_2_fails(monkeypatch):
    """A split step whose second stage fails (DART at q+ by then) is taken as [GI]'s step from
    l: with stage 2 made to fail on every step with contact, a ball sliding to rolling under
    order 2 follows order 1's trajectory, every step counted; without the fallback the first
    step raises StepFailure; a stage 2 of the repeat path (_split_repeat) that fails once costs
    one order-1 step."""
    from implicit_contact import rattle

    _, reference = _sliding_ball(1)
    solves = []

    def failed(self):
        x = self.start()
        return ncp.McpResult(x, np.zeros_like(x), ncp.Status.MAX_ITERATIONS, 50, 1.0, (), "stage 2 made to fail",
                             "", 0, 0)

    def failing_stage2(self, options, converged_at=None, budget=None):
        solves.append(1)
        return failed(self)

    real_solve, real_repeat = rattle.Stage2.solve, ic.ImplicitContactStepper._split_repeat
    _, order2 = _sliding_ball(2)
    repeated = []

    def failing_once(self, options, converged_at=None, budget=None):
        solves.append(1)
        if len(solves) == 10:
            return failed(self)
        return real_solve(self, options, converged_at, budget)

    def split_repeat(self, h, t0):
        report = real_repeat(self, h, t0)
        repeated.append((len(solves), report is not None))
        return report

    monkeypatch.setattr(rattle.Stage2, "solve", failing_once)
    monkeypatch.setattr(ic.ImplicitContactStepper, "_split_repeat", split_repeat)
    stepper, once = _sliding_ball(2)
    assert (10, True) in repeated and stepper.order1_steps == 1      # the 10th stage 2 was the repeat path's
    # that one step moved the positions with its end velocity, order 2's with the mean: under the
    # sliding ball's constant accelerations (-mu g along x, spin-up 5 mu g / (2 r) about y) the
    # runs differ by h^2 a / 2 in those coordinates and in nothing else
    shift = np.zeros(12)
    h = FALLBACK_H
    shift[1], shift[3] = 0.5 * h * h * 5.0 * 0.3 * cv.G / (2.0 * 0.1), -0.5 * h * h * 0.3 * cv.G
    np.testing.assert_allclose(once - order2, shift, rtol=0.0, atol=ONE_STEP_ATOL)
    monkeypatch.setattr(ic.ImplicitContactStepper, "_split_repeat", real_repeat)
    solves.clear()

    monkeypatch.setattr(rattle.Stage2, "solve", failing_stage2)
    stepper, fallen_back = _sliding_ball(2)
    assert len(solves) == FALLBACK_STEPS and stepper.order1_steps == FALLBACK_STEPS
    np.testing.assert_allclose(fallen_back, reference, rtol=0.0, atol=FALLBACK_ATOL)
    assert fallen_back[9] - 0.1 * fallen_back[7] > 0.1     # still sliding at 0.08 s: friction rows active

    monkeypatch.setattr(ic.ImplicitContactStepper, "_order1_step", lambda self, h, keep, failed: failed)
    with pytest.raises(ic.StepFailure, match="second stage"):
        _sliding_ball(2)
