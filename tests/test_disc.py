"""Example 1 of [GI]: the rolling disc and the slide-to-roll transition (closed forms)."""
import numpy as np
import pytest

from scenes import disc_rolling as scene

G, MU, MASS = scene.G, scene.MU, scene.MASS
KE_REL_TOL = 1e-9        # the bound on the relative kinetic-energy change over 5 s
PEN_TOL = 1e-9           # [m] penetration allowed: solver tolerance 1e-10 on scaled rows
PN_REL_TOL = 1e-9        # p_n = m g h while rolling, relative


@pytest.mark.parametrize("h", [0.01, 0.001])
def test_rolling_disc_keeps_its_kinetic_energy(h):
    traj = scene.simulate(duration=5.0, h=h)
    t, q, v, ke = traj.arrays()
    assert ke[0] == pytest.approx(6.75, rel=1e-15)
    assert np.max(np.abs(ke - ke[0])) / ke[0] <= KE_REL_TOL
    # rolling without slip: x follows v_x t exactly, and the contact never opens
    assert q[-1, 0] == pytest.approx(-3.0 * t[-1], rel=1e-8)
    assert np.all(np.abs(q[:, 1] - scene.RADIUS) <= PEN_TOL)
    for rep in traj.reports:
        (c,) = rep.contacts
        assert c.gap >= -PEN_TOL
        assert c.p_n == pytest.approx(MASS * G * h, rel=PN_REL_TOL)
        assert abs(c.p_t) <= 1e-12


def test_slide_to_roll_transition_time_and_final_velocity():
    h = 0.001
    traj = scene.simulate(duration=0.6, h=h, v0=(-3.0, 0.0, 0.0))
    t, q, v, ke = traj.arrays()
    t_star = 3.0 / (3 * MU * G)          # |v0| / (3 mu g) = 0.2548 s
    slip = v[:, 0] + v[:, 2] * scene.RADIUS   # contact-point velocity
    rolling = np.nonzero(np.abs(slip) < 1e-9)[0]
    t_roll = t[rolling[0]]
    assert abs(t_roll - t_star) <= h
    # while sliding the friction impulse is mu p_n and decelerates at mu g
    for k in range(int(0.8 * t_star / h)):
        c = traj.reports[k].contacts[0]
        assert abs(c.p_t) == pytest.approx(MU * c.p_n, rel=1e-9)
    after = t > t_star + 2 * h
    assert np.allclose(v[after, 0], -2.0, atol=1e-9)
    assert np.allclose(v[after, 2], 2.0, atol=1e-9)
