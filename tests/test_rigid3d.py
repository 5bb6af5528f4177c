"""3D rigid contact with the implicit stepper: resting, rolling down an incline, drops coming to rest."""
import math

import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic

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
