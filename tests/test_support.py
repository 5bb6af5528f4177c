"""Support friction of planar bodies (implicit_contact/support.py): closed forms and Jacobian.

A disc of mass M and inertia I lies on a horizontal support (the world's gravity is along -z,
out of its plane) with Coulomb friction mu under its weight N = M g. Backward Euler with the
maximum-dissipation rows gives, step by step, exactly what Coulomb friction predicts:

* sliding: v+ = v - mu g h along -v (constant deceleration mu g) until it would reverse, then 0;
* spinning in place: omega+ = omega - h mu N e_r / I until 0;
* a push F < mu N: no motion at all (static friction -F); F > mu N: acceleration (F - mu N)/M.
"""
import math

import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact import formulation as fm
from implicit_contact.support import SupportFriction, SupportSpec

M, I_ZZ, R = 2.0, 0.3, 0.5
G = 9.81
MU = 0.4
H = 0.01
EXACT = 1e-9          # [m/s, rad/s] closed forms of backward Euler, to solver tolerance
FD_TOL = 1e-6         # Jacobian against central differences (relative to max |J|)


def _world(v0=(0.0, 0.0, 0.0), q0=(0.0, 0.0, 0.0), h=H, with_ground=False):
    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity([0.0, 0.0, -G])
    sk = dart.dynamics.Skeleton("puck")
    joint, body = sk.createPlanarJointAndBodyNodePair()
    joint.setXYPlane()
    body.setName("puck")
    body.setMass(M)
    body.setMomentOfInertia(I_ZZ / 2, I_ZZ / 2, I_ZZ)
    ic.attach(body, ic.shapes.Disc(R), friction=ic.Friction(mu=0.5))
    sk.setPositions(np.asarray(q0, float))
    sk.setVelocities(np.asarray(v0, float))
    world.addSkeleton(sk)
    if with_ground:            # a wall at x = -1: a contact pair next to the support block
        wall = dart.dynamics.Skeleton("wall")
        _, wb = wall.createWeldJointAndBodyNodePair()
        ic.attach(wb, ic.shapes.HalfPlane([1.0, 0.0], -1.0), friction=ic.Friction(mu=0.5))
        world.addSkeleton(wall)
    return world, body, sk


def _stepper(world, body, mu=MU, **kw):
    st = ic.ImplicitContactStepper(world, on_failure="raise")
    st.set_support_friction(body, mu, M * G, **kw)
    return st


def test_sliding_decelerates_at_mu_g_and_stops():
    v0 = np.array([1.0, -0.5])
    world, body, sk = _world(v0=(*v0, 0.0))
    st = _stepper(world, body)            # one point at the centre: no torsion
    speed, direction = np.linalg.norm(v0), v0 / np.linalg.norm(v0)
    x = np.zeros(2)
    for _ in range(40):
        st.step()
        speed = max(0.0, speed - MU * G * H)
        x += H * speed * direction
        v = np.asarray(sk.getVelocities())
        np.testing.assert_allclose(v[:2], speed * direction, atol=EXACT)
        assert abs(v[2]) < EXACT
    assert speed == 0.0                    # it stopped within the 40 steps (v0 / (mu g) = 0.28 s)
    np.testing.assert_allclose(np.asarray(sk.getPositions())[:2], x, atol=EXACT * H * 40)
    # at rest the support carries nothing
    np.testing.assert_allclose(st.support_wrench(body), 0.0, atol=EXACT * M)


def test_spin_down_at_mu_n_e_r_over_inertia():
    e_r = 2 * R / 3                        # uniform pressure on a disc of radius R
    world, body, sk = _world(v0=(0.0, 0.0, 5.0))
    st = _stepper(world, body, torsion_radius=e_r)
    omega = 5.0
    for _ in range(20):
        st.step()
        omega = max(0.0, omega - H * MU * M * G * e_r / I_ZZ)
        v = np.asarray(sk.getVelocities())
        assert abs(v[2] - omega) < EXACT and np.linalg.norm(v[:2]) < EXACT


def test_three_points_give_centroid_and_mean_radius():
    pts = [(0.3 * math.cos(a), 0.3 * math.sin(a) + 0.1) for a in (0.0, 2.1, 4.2)]
    sf = SupportFriction.from_points(MU, 10.0, pts)
    np.testing.assert_allclose(sf.centre, np.mean(pts, axis=0), atol=1e-15)
    assert sf.e_r == pytest.approx(np.mean(np.linalg.norm(np.array(pts) - np.mean(pts, axis=0), axis=1)), rel=1e-14)


@pytest.mark.parametrize("push", [0.5, 1.5])
def test_push_below_and_above_mu_n(push):
    """An external force push * mu N along x: held at rest (static friction equal and opposite)
    below 1, accelerated at (F - mu N) / M above."""
    world, body, sk = _world()
    st = _stepper(world, body)
    F = push * MU * M * G
    v_expected = 0.0
    for _ in range(10):
        body.setExtForce([F, 0.0, 0.0])
        st.step()
        v_expected += H * max(0.0, F - MU * M * G) / M
        v = np.asarray(sk.getVelocities())
        assert abs(v[0] - v_expected) < EXACT and abs(v[1]) < EXACT
    p = st.support_wrench(body)
    assert p[0] == pytest.approx(-min(F, MU * M * G) * H, rel=1e-9)


def test_sliding_and_spinning_follow_the_ellipsoid():
    """Sliding and spinning at once: the wrench lies on the limit ellipsoid and opposes
    (u, e_r^2 omega) ([GI] eq 7 with a known normal impulse)."""
    e_r = 0.2
    world, body, sk = _world(v0=(1.0, 0.0, 4.0))
    st = _stepper(world, body, torsion_radius=e_r)
    st.step()
    v = np.asarray(sk.getVelocities())
    p = st.support_wrench(body)
    P = MU * M * G * H
    y = np.array([p[0], p[1], p[2] / e_r]) / P
    assert np.linalg.norm(y) == pytest.approx(1.0, abs=1e-9)
    slip = np.array([v[0], v[1], e_r * v[2]])
    np.testing.assert_allclose(y, -slip / np.linalg.norm(slip), atol=1e-9)
    # and the dynamics: M dv = p
    np.testing.assert_allclose([M * (v[0] - 1.0), M * v[1], I_ZZ * (v[2] - 4.0)], p, atol=1e-9)


def test_off_centre_support_turns_a_sliding_body():
    """Friction at an off-centre point c exerts a moment r x p about the body origin."""
    world, body, sk = _world(v0=(1.0, 0.0, 0.0))
    st = _stepper(world, body, points=[(0.0, 0.2)])
    st.step()
    p = st.support_wrench(body)
    assert p[0] < 0.0 and p[2] == pytest.approx(-0.2 * p[0] + 0.0 * p[1], rel=1e-9)
    assert np.asarray(sk.getVelocities())[2] > 0.0       # the drag at +y turns it counter-clockwise


def test_jacobian_matches_differences():
    """The StepProblem's Jacobian with a support block (and a contact pair) by central differences."""
    from implicit_contact.support import SupportSpec as _S
    world, body, sk = _world(v0=(-0.8, 0.3, 2.0), q0=(-0.5 + 1e-3, 0.0, 0.4), with_ground=True)
    st = ic.ImplicitContactStepper(world, on_failure="raise")
    st.set_support_friction(body, MU, M * G, points=[(0.1, 0.0), (-0.1, 0.1), (0.0, -0.2)])
    captured = {}
    original = st._solve

    def spy(problem, z0, *args, **kwargs):
        captured.setdefault("problem", problem)
        captured.setdefault("z0", z0)
        return original(problem, z0, *args, **kwargs)
    st._solve = spy
    st.step()
    problem = captured["problem"]
    assert len(problem.supports) == 1 and isinstance(problem.supports[0], _S)
    assert problem.layout.pairs, "the wall pair must be in the problem"
    rng = np.random.default_rng(3)
    z = captured["z0"] + 0.05 * rng.standard_normal(problem.layout.n)
    ss = problem.layout.supports[0]
    z[ss.sigma] = 0.7
    J = problem.jac(z)
    J = J.toarray() if hasattr(J, "toarray") else np.asarray(J)
    eps = 1e-7
    Jfd = np.empty_like(J)
    for i in range(problem.layout.n):
        e = np.zeros(problem.layout.n)
        e[i] = eps
        Jfd[:, i] = (problem.fun(z + e) - problem.fun(z - e)) / (2 * eps)
    rows = np.r_[problem.layout.v_index[0], np.arange(ss.y.start, ss.sigma + 1)]
    err = np.max(np.abs(J[rows] - Jfd[rows])) / np.max(np.abs(J))
    assert err < FD_TOL


def test_bad_support_input():
    world, body, sk = _world()
    st = ic.ImplicitContactStepper(world)
    for kw in ({"mu": -0.1, "normal_force": 1.0}, {"mu": math.nan, "normal_force": 1.0},
               {"mu": 0.3, "normal_force": 0.0}, {"mu": 0.3, "normal_force": math.inf}):
        with pytest.raises(ValueError):
            st.set_support_friction(body, **kw)
    with pytest.raises(ValueError):
        st.set_support_friction(body, 0.3, 1.0, points=[(math.nan, 0.0)])
    with pytest.raises(ValueError):
        st.set_support_friction(body, 0.3, 1.0, points=np.zeros((0, 2)))
    # a 3D free body cannot have a 2.5D support
    w3 = dart.simulation.World()
    sk3 = dart.dynamics.Skeleton("ball")
    _, b3 = sk3.createFreeJointAndBodyNodePair()
    ic.attach(b3, ic.shapes.Sphere(0.1))
    w3.addSkeleton(sk3)
    with pytest.raises(ValueError, match="PlanarJoint"):
        ic.ImplicitContactStepper(w3).set_support_friction(b3, 0.3, 1.0)


def test_mu_zero_removes_the_support():
    world, body, sk = _world(v0=(1.0, 0.0, 0.0))
    st = _stepper(world, body)
    st.set_support_friction(body, 0.0, M * G)
    st.step()
    assert np.asarray(sk.getVelocities())[0] == pytest.approx(1.0, abs=1e-15)
