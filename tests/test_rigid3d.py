"""3D rigid contact with the implicit stepper: resting, rolling down an incline, drops coming to rest."""
import math

import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact import recovery

G = 9.81
PEN_TOL = 1e-8           # [m] allowed penetration: solver tolerance 1e-10 on rows of O(1)
REST_SPEED = 1e-6        # [m/s] a body counts as at rest below this speed


def _world(h, gravity=(0.0, 0.0, -G)):
    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity(list(gravity))
    return world


def _free_body(world, name, mass, inertia_diag, position, rotation=None):
    skel = dart.dynamics.Skeleton(name)
    _, body = skel.createFreeJointAndBodyNodePair()
    body.setName(name)
    body.setMass(mass)
    body.setMomentOfInertia(*inertia_diag)
    rot = np.zeros(3) if rotation is None else np.asarray(rotation, float)
    skel.setPositions(np.r_[rot, position])
    world.addSkeleton(skel)
    return skel, body


def _ground(world, normal=(0.0, 0.0, 1.0), mu=0.5, dart_plane=False):
    skel = dart.dynamics.Skeleton("ground")
    _, body = skel.createWeldJointAndBodyNodePair()
    body.setName("ground")
    if dart_plane:
        node = body.createShapeNode(dart.dynamics.PlaneShape(np.asarray(normal, float), 0.0))
        node.createCollisionAspect()
        node.createDynamicsAspect().setFrictionCoeff(mu)
    else:
        ic.attach(body, ic.shapes.HalfSpace(normal, 0.0), friction=ic.Friction(mu=mu))
    world.addSkeleton(skel)
    return body


def test_sphere_resting_on_a_plane_has_pn_equal_mgh():
    h, m, r = 0.01, 2.0, 0.3
    world = _world(h)
    skel, body = _free_body(world, "ball", m, [0.4 * m * r * r] * 3, [0.0, 0.0, r])
    node = body.createShapeNode(dart.dynamics.SphereShape(r))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(0.5)
    _ground(world, dart_plane=True)
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(50):
        rep = stepper.step()
        (c,) = rep.contacts
        assert c.p_n == pytest.approx(m * G * h, rel=1e-9)
        assert c.gap >= -PEN_TOL
    assert np.allclose(skel.getVelocities(), 0.0, atol=1e-12)
    assert skel.getPositions()[5] == pytest.approx(r, abs=PEN_TOL)


def test_sphere_rolls_down_an_incline_at_five_sevenths_g_sin_theta():
    h, m, r, theta = 0.01, 1.0, 0.5, math.radians(20.0)
    normal = np.array([-math.sin(theta), 0.0, math.cos(theta)])     # plane through the origin
    downhill = np.array([math.cos(theta), 0.0, math.sin(theta)])    # -downhill is down the slope
    world = _world(h)
    skel, body = _free_body(world, "ball", m, [0.4 * m * r * r] * 3, r * normal)
    node = body.createShapeNode(dart.dynamics.SphereShape(r))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(0.6)       # rolling needs mu >= 2/7 tan(theta)
    _ground(world, normal=normal, mu=0.6, dart_plane=True)
    stepper = ic.ImplicitContactStepper(world)
    n = 100
    for _ in range(n):
        rep = stepper.step()
        assert rep.contacts[0].gap >= -PEN_TOL
    v = skel.getVelocities()[3:]
    expected = -(5.0 / 7.0) * G * math.sin(theta) * n * h * downhill
    np.testing.assert_allclose(v, expected, rtol=1e-8, atol=1e-10)
    # rolling: the contact point does not slip
    w = skel.getVelocities()[:3]
    assert np.linalg.norm(v + np.cross(w, -r * normal)) < 1e-9


@pytest.mark.parametrize("shape, rest_ke", [
    # a superquadric lands and stops; an ellipsoid rolls and rocks on its curved side, which loses
    # energy only through the integrator's damping (rate ~ h omega^2 / 2), so it is "at rest" only
    # to a small fraction of the 2 J it fell through
    (ic.shapes.Superquadric([0.3, 0.2, 0.15], 4.0), 1e-20),
    (ic.shapes.Ellipsoid([0.3, 0.2, 0.1]), 2e-3),
])
def test_dropped_body_comes_to_rest_without_penetration(shape, rest_ke):
    h, m, duration = 0.01, 1.0, 5.0
    world = _world(h)
    skel, body = _free_body(world, "body", m, [1.0, 1.0, 1.0], [0.0, 0.0, 0.3], rotation=[0.3, 0.0, 0.0])
    mp = shape.mass_properties(1.0)
    body.setMomentOfInertia(*np.diag(mp.inertia) * m / mp.mass)
    ic.attach(body, shape, friction=ic.Friction(mu=0.5, e_r=0.02))
    _ground(world)
    stepper = ic.ImplicitContactStepper(world)
    gaps, energy = [], []
    for _ in range(int(duration / h)):
        rep = stepper.step()
        gaps += [c.gap for c in rep.contacts]
        v = skel.getVelocities()
        energy.append(0.5 * v @ skel.getMassMatrix() @ v + m * G * skel.getPositions()[5])
    assert min(gaps) >= -PEN_TOL
    # rigid, perfectly inelastic contact with friction: mechanical energy never grows
    assert np.max(np.diff(energy)) <= 1e-9
    v = skel.getVelocities()
    assert 0.5 * v @ skel.getMassMatrix() @ v < rest_ke
    # lying on its smallest semi-axis
    assert skel.getPositions()[5] == pytest.approx(_smallest_axis(shape), abs=1e-3)


def _smallest_axis(shape):
    lo, hi = shape.aabb(np.eye(3), np.zeros(3))
    return float(np.min(hi))


def _dart_box(world, size, mu, position, rotation=(0.0, 0.0, 0.0), velocity=None):
    skel, body = _free_body(world, "box", 1.0, [1.0, 1.0, 1.0], position, rotation)
    sx, sy, sz = size
    body.setMomentOfInertia((sy**2 + sz**2) / 12, (sx**2 + sz**2) / 12, (sx**2 + sy**2) / 12)
    node = body.createShapeNode(dart.dynamics.BoxShape(np.asarray(size, float)))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(mu)
    if velocity is not None:
        skel.setVelocities(np.asarray(velocity, float))
    return skel


def test_dart_box_slides_to_rest_like_a_block_with_coulomb_friction():
    """A BoxShape (six half-spaces) sliding on its face: one contact point at the centre of
    pressure carries the weight; it decelerates at mu g and stops at v0 / (mu g)."""
    h, mu, v0 = 0.001, 0.3, 0.5
    world = _world(h)
    skel = _dart_box(world, (0.4, 0.3, 0.2), mu, [0.0, 0.0, 0.1], velocity=[0, 0, 0, v0, 0, 0])
    _ground(world, mu=mu, dart_plane=True)
    stepper = ic.ImplicitContactStepper(world)
    t_stop = v0 / (mu * G)
    n = int(1.5 * t_stop / h)
    vx = []
    for _ in range(n):
        rep = stepper.step()
        assert rep.contacts[0].gap >= -PEN_TOL
        vx.append(skel.getVelocities()[3])
    vx = np.array(vx)
    stopped = np.nonzero(vx <= 1e-12)[0][0]
    assert abs((stopped + 1) * h - t_stop) <= h
    assert skel.getPositions()[3] == pytest.approx(v0**2 / (2 * mu * G), abs=v0 * h)
    assert skel.getPositions()[5] == pytest.approx(0.1, abs=PEN_TOL)
    assert np.allclose(skel.getPositions()[:3], 0.0, atol=1e-12)    # it does not tip


def test_dart_box_dropped_on_an_edge_lands_flat_with_the_retry_policy():
    """Face-first landings from an edge are the hard case of point contact on flat faces: the
    full step may fail to converge; 'retry' (the default) halves h and the box lands flat."""
    h = 0.01
    world = _world(h)
    skel = _dart_box(world, (0.4, 0.3, 0.2), 0.5, [0.0, 0.0, 0.4], rotation=(0.3, 0.2, 0.0))
    _ground(world, mu=0.5, dart_plane=True)
    stepper = ic.ImplicitContactStepper(world)          # on_failure="retry" by default
    for _ in range(150):
        rep = stepper.step()
        assert rep.success and all(c.gap >= -PEN_TOL for c in rep.contacts)
    R = dart.math.expMapRot(skel.getPositions()[:3]) if hasattr(dart.math, "expMapRot") else None
    z_axis = (R @ [0, 0, 1]) if R is not None else None
    assert skel.getPositions()[5] == pytest.approx(0.1, abs=1e-6)
    if z_axis is not None:
        assert abs(z_axis[2]) == pytest.approx(1.0, abs=1e-6)
    v = skel.getVelocities()
    assert np.linalg.norm(v[3:]) < 1e-6          # at rest but for a free spin about z (e_r = 0)


def _hexagonal_prism(world, apothem, half_length, mu, position, velocity):
    """A prism along y with a regular hexagonal cross-section (8 half-spaces), lying on a face."""
    skel, body = _free_body(world, "prism", 1.0, [0.02, 0.02, 0.02], position)
    angles = np.pi / 2 + np.arange(6) * np.pi / 3          # face normals in the xz plane, one down
    normals = [[math.cos(a), 0.0, math.sin(a)] for a in angles] + [[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]
    offsets = [apothem] * 6 + [half_length] * 2
    ic.attach(body, ic.shapes.Intersection.polytope(normals, offsets), friction=ic.Friction(mu=mu))
    skel.setVelocities(np.asarray(velocity, float))
    return skel, ic.shapes.Intersection.polytope(normals, offsets)


@pytest.mark.parametrize("body", ["dart box", "hexagonal prism"])
def test_body_sliding_off_a_table_edge_tips_over_it(body):
    """Both bodies intersections ([GI] eqs 28-32) with the active surface k1 of body 1 unknown in
    advance. A body slides along a table, reaches its edge, tips over it and falls. Body 1 must be
    the side touching with a face (the falling body's bottom face on the table's edge): the
    stepper swaps the pair's bodies when body 1's k1 goes inactive. Every step succeeds, the two
    never interpenetrate by the independent static closest-point oracle, the body turns about
    the edge while touching it, and ends below the table top."""
    from implicit_contact.closest import closest_points
    h = 0.005
    world = _world(h)
    base = dart.dynamics.Skeleton("table")
    _, top = base.createWeldJointAndBodyNodePair()
    node = top.createShapeNode(dart.dynamics.BoxShape(np.array([1.0, 1.0, 0.2])))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(0.2)
    world.addSkeleton(base)
    if body == "dart box":
        skel = _dart_box(world, (0.4, 0.3, 0.2), 0.2, [0.2, 0.0, 0.2], velocity=[0, 0, 0, 1.2, 0, 0])
        shape = ic.shapes.Intersection.box([0.2, 0.15, 0.1])
    else:
        apothem = 0.1
        skel, shape = _hexagonal_prism(world, apothem, 0.15, 0.2, [0.2, 0.0, 0.1 + apothem], [0, 0, 0, 1.2, 0, 0])
    stepper = ic.ImplicitContactStepper(world)               # default policy: retry
    table = ic.shapes.Intersection.box([0.5, 0.5, 0.1])
    tipped_in_contact = False
    for _ in range(180):
        rep = stepper.step()
        assert rep.success
        T = skel.getBodyNode(0).getWorldTransform().matrix()
        res = closest_points(table, (np.eye(3), np.zeros(3)), shape, (T[:3, :3], T[:3, 3]))
        assert not (res.overlapping and res.depth > PEN_TOL), res.depth
        pitch = math.atan2(T[0, 2], T[2, 2])               # rotation about y
        touching = any(c.p_n > 0.0 for c in rep.contacts)
        tipped_in_contact |= touching and pitch > 0.3
    assert tipped_in_contact                                 # it turned about the edge, touching it
    assert skel.getPositions()[5] < 0.0                      # and fell off (table top at z = 0.1)


@pytest.mark.parametrize("speed, z0, friction", [
    (100.0, 0.6, None),
    # comparisons.stability's impact cases: with friction rows, the failed solves after the
    # rejected far-side solution were re-seeded from the static closest points of a sphere wholly
    # below the plane (its centre, where grad f = 0) and the step raised ZeroDivisionError
    (100.0, 0.55, ic.Friction(mu=0.5)),
    (30.0, 0.55, ic.Friction(mu=0.5)),
])
def test_fast_sphere_does_not_tunnel_through_a_half_space(speed, z0, friction):
    """100 m/s at h = 0.01: the sphere would cross the plane (and its own diameter 10 times) in
    one step. With the half-space's point on its plane, eqs (15)-(19) also admit the sphere's far
    side as a 'closest point' once it is wholly through; the stepper rejects that (l2 <= 0) and the
    contact stops the sphere at the plane."""
    h, r = 0.01, 0.1
    world = _world(h)
    skel, body = _free_body(world, "bullet", 1.0, [0.004] * 3, [0.0, 0.0, z0])
    skel.setVelocities([0, 0, 0, 0, 0, -speed])
    if friction is None:
        ic.attach(body, ic.shapes.Sphere(r))
    else:
        ic.attach(body, ic.shapes.Sphere(r), friction=friction)
    _ground(world)
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(20):
        rep = stepper.step()
        assert skel.getPositions()[5] >= r - PEN_TOL
        assert all(c.gap >= -PEN_TOL for c in rep.contacts)
    assert skel.getVelocities()[5] == pytest.approx(0.0, abs=1e-9)


def test_hexagon_tips_off_a_wedge_and_lands_on_a_face_2d():
    """2D, both bodies intersections: a hexagon (six half-planes) dropped onto the vertex of a
    fixed wedge (a fingertip, [GI] eqs 58-61) first rests its face on the wedge's vertex (body 1:
    the hexagon), tips, rolls over its own vertex down the wedge's face (body 1: the wedge) and
    lands on the ground. Every step succeeds with the default policy, the independent static
    closest-point oracle never finds the hexagon inside the wedge, and it ends lying on a face."""
    from implicit_contact.closest import closest_points
    world = _world(0.005, gravity=(0.0, -G, 0.0))
    skel = dart.dynamics.Skeleton("hexagon")
    joint, body = skel.createPlanarJointAndBodyNodePair()
    joint.setXYPlane()
    body.setMass(1.0)
    body.setMomentOfInertia(0.01, 0.01, 0.01)
    apothem = 0.1
    angles = -np.pi / 2 + np.arange(6) * np.pi / 3
    hexagon = ic.shapes.Intersection.polytope([[math.cos(a), math.sin(a)] for a in angles], [apothem] * 6)
    ic.attach(body, hexagon, friction=ic.Friction(mu=0.5))
    skel.setPositions([0.03, 0.3 + apothem + 1e-3, 0.0])
    world.addSkeleton(skel)
    fixed = dart.dynamics.Skeleton("wedge")
    _, wb = fixed.createWeldJointAndBodyNodePair()
    s2 = math.sqrt(0.5)
    wedge = ic.shapes.Intersection.fingertip((0.0, 0.3), (s2, s2), (-s2, s2))    # vertex up at y = 0.3
    ic.attach(wb, wedge, friction=ic.Friction(mu=0.5))
    ic.attach(wb, ic.shapes.HalfPlane([0.0, 1.0], 0.0), friction=ic.Friction(mu=0.5))
    world.addSkeleton(fixed)
    stepper = ic.ImplicitContactStepper(world)
    on_wedge_face = False
    for _ in range(600):
        rep = stepper.step()
        assert rep.success
        q = skel.getPositions()
        R = np.array([[math.cos(q[2]), -math.sin(q[2])], [math.sin(q[2]), math.cos(q[2])]])
        res = closest_points(wedge, (np.eye(2), np.zeros(2)), hexagon, (R, q[:2]))
        assert not (res.overlapping and res.depth > PEN_TOL), res.depth
        on_wedge_face |= any(c.p_n > 0.0 and c.a1[1] < 0.29 and "wedge" in c.name_a + c.name_b
                             for c in rep.contacts)           # touching below the wedge's vertex
    assert on_wedge_face
    q = skel.getPositions()
    assert q[1] == pytest.approx(apothem, abs=2e-3)           # on the ground, lying on a face
    assert abs(math.remainder(q[2], np.pi / 3)) < 0.05


def _ball_landing_step(vx, slide_ratio, monkeypatch):
    """One step (h = 0.01) of a ball of radius 0.1 m, 1 mm over the ground falling at 1 m/s with
    horizontal speed vx, mu = 0.5: (the pairs _clearly_sliding started sliding, the ball's
    velocities after the step)."""
    monkeypatch.setattr(recovery, "SLIDE_RATIO", slide_ratio)
    h, m, r = 0.01, 1.0, 0.1
    world = _world(h)
    skel, body = _free_body(world, "ball", m, [0.4 * m * r * r] * 3, [0.0, 0.0, r + 1e-3])
    skel.setVelocities([0.0, 0.0, 0.0, vx, 0.0, -1.0])
    node = body.createShapeNode(dart.dynamics.SphereShape(r))
    node.createCollisionAspect()
    node.createDynamicsAspect().setFrictionCoeff(0.5)
    _ground(world, dart_plane=True)
    started = []
    rows = recovery.friction_rows

    def recorded(stepper, att, problem, result):
        outcome = rows(stepper, att, problem, result)
        if outcome is recovery.RETRY and att.added:
            started.append(list(att.sliding))
        return outcome

    monkeypatch.setattr(recovery, "RECOVERIES", tuple(recorded if f is rows else f for f in recovery.RECOVERIES))
    report = ic.ImplicitContactStepper(world).step()
    assert report.success and report.substeps == 1
    return started, skel.getVelocities()


@pytest.mark.parametrize("vx, slides", [(0.0, False), (0.05, False), (2.0, False), (8.0, True)])
def test_a_new_contact_starts_its_friction_re_solve_sliding_only_when_it_clearly_slides(vx, slides, monkeypatch):
    """recovery._clearly_sliding: a ball landing at 1 m/s (p_n = m dv_n, dv_n ~ 1 m/s) with
    horizontal speed 8 m/s slips more than SLIDE_RATIO (10) times what friction at the cone's edge
    takes from it in the step (mu dv_n = 0.5 m/s): its friction re-solve starts sliding. Dropped
    straight, at 5 cm/s or at 2 m/s (it slides too: rolling would need 2/7 of 2 m/s, but the ratio
    is 4) it starts sticking. Either start reaches the same step (the start is not a decision):
    the ball slides on at vx - mu dv_n with omega_y = 5/2 mu dv_n / r, or rolls."""
    started, v = _ball_landing_step(vx, recovery.SLIDE_RATIO, monkeypatch)
    assert started == [[0] if slides else []]
    _, v_stick_start = _ball_landing_step(vx, math.inf, monkeypatch)
    np.testing.assert_allclose(v, v_stick_start, atol=1e-9)
    dv_n = 1.0 + G * 0.01 - 1e-3 / 0.01           # p_n / m: stop the fall (gap 1 mm closed in the step)
    if vx > 3.5 * 0.5 * dv_n:                       # 1 + m r^2 / I = 3.5: friction cannot make it roll
        assert v[3] == pytest.approx(vx - 0.5 * dv_n, rel=1e-6)
        assert v[1] == pytest.approx(2.5 * 0.5 * dv_n / 0.1, rel=1e-6)
    else:
        assert v[3] == pytest.approx(v[1] * 0.1, abs=1e-9)       # rolls: v_x = omega_y r
