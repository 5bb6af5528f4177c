"""Example 2 of [GI]: a unit sphere pushed across two fixed spheres (events and friction law)."""
import numpy as np
import pytest

from scenes import sphere_on_two_spheres as scene

MU = scene.FRICTION.mu
EVENT_AGREEMENT = 0.05   # [s] the bound between h = 0.01 and h = 0.001
CONE_TOL = 1e-7          # relative: |p_f| = mu p_n while sliding, up to the solver tolerance


@pytest.fixture(scope="module")
def coarse():
    return scene.simulate(duration=4.5, h=0.01)


def test_events_are_detected_in_order(coarse):
    ev = scene.events(coarse)
    assert all(np.isfinite(list(ev.values()))), ev
    assert 2.0 < ev["contact2_slides"] < ev["contact2_lost"]
    assert ev["contact1_lost"] < ev["contact2_lost"] < 4.5


def test_friction_law_sliding_and_rolling(coarse):
    c1 = scene.contact_series(coarse, "sphere_r10")
    c2 = scene.contact_series(coarse, "sphere_r9")
    on1 = c1.normal > 1e-6
    # contact 1 slides from the start: friction magnitude equals mu times the normal force
    assert on1[:50].all()
    np.testing.assert_allclose(c1.friction[on1], MU * c1.normal[on1], rtol=CONE_TOL)
    # contact 2 rolls at first: zero slip and friction strictly inside the cone
    ev = scene.events(coarse)
    rolling = (c2.t < ev["contact2_slides"] - 0.05) & (c2.normal > 1e-6)
    assert rolling.sum() > 100
    assert np.all(c2.slip[rolling] < scene.ROLL_SLIP)
    assert np.all(c2.friction[rolling] < MU * c2.normal[rolling])
    sliding = (c2.slip > scene.ROLL_SLIP) & (c2.normal > 1e-6)
    np.testing.assert_allclose(c2.friction[sliding], MU * c2.normal[sliding], rtol=CONE_TOL)


def test_event_times_converge_in_h(coarse):
    fine = scene.simulate(duration=4.5, h=0.001)
    a, b = scene.events(coarse), scene.events(fine)
    for name in a:
        assert abs(a[name] - b[name]) <= EVENT_AGREEMENT, (name, a[name], b[name])


def test_start_from_rest_at_small_h_needs_no_retry():
    """Example 2 from rest at h = 1e-3: the first steps (near-zero slip, two contacts) must solve
    without the retry policy. Regression: a restart that started every newly rubbing contact
    sliding made the first step fail at h = 1e-3."""
    traj = scene.simulate(duration=0.02, h=1e-3, on_failure="raise")
    assert all(r.success and r.substeps == 1 for r in traj.reports)
