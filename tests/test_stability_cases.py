"""Regressions from comparisons.stability: cases of the stability matrix that once raised."""
import time

import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact import stepper as stepper_module

PEN_TOL = 1e-6             # [m] the stepper's default contact tolerance


def test_seed_of_flat_lying_superquadrics_side_by_side_is_finite():
    """Two exponent-4 superquadrics lying flat 3.8 cm apart, the second tilted by 6e-10 rad
    (poses from the 10-bodies case at t = 0.86 s): their equators are coplanar to round-off, the
    surfaces have zero curvature there and the static KKT solve stalls above its tolerance.
    The seed of the new pair was NaN and the step raised in nnls; it must be finite and right."""
    shape = ic.shapes.Superquadric([0.1, 0.08, 0.06], 4.0)
    pose1 = (np.array([[0.9456573256978044, 0.32516491562602007, -1.7917986887438426e-26],
                       [-0.32516491562602007, 0.9456573256978044, -1.359813705551827e-26],
                       [1.252263847353469e-26, 1.8685478616835672e-26, 1.0]]),
             np.array([0.018480633520426854, 0.031791859248340056, 0.06]))
    pose2 = (np.array([[-0.12120540664161639, 0.9926274474347566, 3.443226851826329e-10],
                       [-0.9926274474347566, -0.12120540664161639, -6.149793812683319e-10],
                       [-5.687116423798959e-10, -4.1632297406955595e-10, 1.0]]),
             np.array([0.23450218176705181, -0.02875358290200169, 0.060000000000062434]))
    res = stepper_module._closest_seed(shape, pose1, shape, pose2)
    assert np.all(np.isfinite(res.a1)) and np.all(np.isfinite(res.a2)) and np.all(np.isfinite(res.normal))
    # both points on their surfaces, at the distance a brute-force search of the equators finds
    for a, (R, p) in ((res.a1, pose1), (res.a2, pose2)):
        assert abs(shape.value(R.T @ (a - p))) < 1e-9
    theta = np.linspace(0.0, 2 * np.pi, 1501)
    ring = np.stack([0.1 * np.sign(np.cos(theta)) * np.abs(np.cos(theta)) ** 0.5,
                     0.08 * np.sign(np.sin(theta)) * np.abs(np.sin(theta)) ** 0.5, 0 * theta], axis=1)
    w1, w2 = ring @ pose1[0].T + pose1[1], ring @ pose2[0].T + pose2[1]
    brute = np.min(np.linalg.norm(w1[:, None, :] - w2[None, :, :], axis=2))
    assert res.distance == pytest.approx(brute, abs=1e-5)          # grid spacing ~4e-4 m, error ~1e-7 m


def test_ten_bodies_dropped_into_a_box_get_through_the_first_wall_contacts():
    """comparisons.stability's 10 bodies: at t = 0.17 s a body falling at 1.2 m/s brushes a wall
    (tiny p_n). Its friction rows, started sticking, stalled Newton at every h down to h/16
    (StepFailure). Started sliding, as the frictionless solution's slip says, it converged at h
    (measured then). One halving is allowed: the trajectory, hence which step is hard, moves with
    any change of the formulation; the test checks that the landing gets through."""
    from comparisons.stability import IMPLICIT, many_bodies_world

    world = many_bodies_world(10, 0.01, IMPLICIT)
    stepper = ic.ImplicitContactStepper(world, options=ic.StepperOptions(max_halvings=1))
    start = time.perf_counter()
    for _ in range(19):
        report = stepper.step()
        assert all(c.gap >= -PEN_TOL for c in report.contacts)
    assert time.perf_counter() - start < 60.0      # a stalled solve takes minutes


def _ten_bodies(steps, watch, monkeypatch, warm_watch=0, seed=0, handover=True):
    """comparisons.stability's 10 bodies (initial rotations drawn with seed) for `steps` steps with
    recovery.SLIDING_WATCH = watch and recovery.WARM_WATCH = warm_watch, and without the row
    switch handover (recovery.row_switch_test) if handover is False: (Newton iterations spent
    over all solves, every skeleton's end positions, solves ended early by the watch under test:
    the re-solves after friction rows if warm_watch is 0, else the first solves)."""
    from comparisons.stability import IMPLICIT, many_bodies_world
    from implicit_contact import recovery

    monkeypatch.setattr(recovery, "SLIDING_WATCH", watch)
    monkeypatch.setattr(recovery, "WARM_WATCH", warm_watch)
    if not handover:
        monkeypatch.setattr(recovery, "HANDOVER_RESIDUAL", 0.0)
    ended = []
    watched = recovery.watched_solve

    def counting(stepper, att, problem, z0):
        result = watched(stepper, att, problem, z0)
        if warm_watch == 0 and att.added and not result.success and result.iterations == watch:
            ended.append(result)
        if warm_watch > 0 and att.index == 0 and not result.success and result.iterations == warm_watch:
            ended.append(result)
        return result

    monkeypatch.setattr(recovery, "watched_solve", counting)
    world = many_bodies_world(10, 0.01, IMPLICIT, seed=seed)
    stepper = ic.ImplicitContactStepper(world)
    spent = sum(stepper.step().spent for _ in range(steps))
    q = np.concatenate([np.asarray(world.getSkeleton(i).getPositions()) for i in range(world.getNumSkeletons())])
    return spent, q, len(ended)


SAME_END = 1e-9      # [m, rad] the same MCP answers, reached along other solves: round-off apart


def test_watched_resolve_hands_a_stalled_sticking_start_to_restart_sliding_sooner(monkeypatch):
    """recovery.watched_solve. In the first 0.4 s of the 10 bodies dropped with seed 17, a
    re-solve after friction rows were added (started sticking) stalls in the FB valley until
    restart_sliding starts it sliding. Watched after 15 iterations it ends there: the same
    trajectory (restart_sliding then finds the same answers) for fewer Newton iterations (798
    against 915, measured when the new pairs' static closest points were batched,
    closest.closest_points_batch); without the watch (0) none ends early. The seeds of that batch
    equal the per-pair seeds to round-off, and the runs of seed 4, the guard before, then part
    (1956 against 997 iterations, 1.9 cm apart at 0.4 s; seeds 10, 15, 17, 23, 26 and 28 of 0-28
    show the stall, each with the same ends). With seed 4 before: 1028 against 1645, measured at
    the commit that compiled closest._single_run. Until then the guard was seed 0's run, below;
    with the static closest points of new pairs compiled (the same seeds to round-off, another path of a chaotic scene) seed 0 meets no
    such stall in 100 steps (seeds 1, 2, 3, 5, 6 none in 40). On seed 0, before: 856 against 874
    at 0.4 s. The gain is small and not monotone in time: at 0.2 s the totals were 487 against 478
    (the last step's watched re-solve would have converged at 22 iterations; stopped at 15, its
    restart costs 143 against 91). Before the sparse Levenberg-Marquardt step was given H itself
    (ncp._SparsePattern scrambled it from ea35695 to d609407), the 0.2 s totals were 401 against 443.
    Measured with the first solve unwatched (recovery.WARM_WATCH = 0, as here): at 0.4 s 720
    against 735 since 6db71ce; with the first solve watched (the default since then) 573 against
    569: on this scene the warm watch ends those stalls sooner (the next test). Both runs without
    the row switch handover (recovery.row_switch_test): it takes rows off at the iterate where a
    gap is clearly open, and the watched and unwatched runs reach that iterate along other solves,
    so the set it takes off can differ by a pair on the threshold (measured with it: the runs part
    at t = 0.33 s and end 1.9 cm apart; 1761 and 1446 Newton iterations)."""
    spent_off, q_off, ended_off = _ten_bodies(40, 0, monkeypatch, seed=17, handover=False)
    spent_on, q_on, ended_on = _ten_bodies(40, 15, monkeypatch, seed=17, handover=False)
    assert ended_off == 0 and ended_on >= 1
    assert np.max(np.abs(q_on - q_off)) <= SAME_END
    assert spent_on < spent_off


def test_a_stalled_warm_solve_hands_over_at_the_watch(monkeypatch):
    """recovery.watched_solve's first-solve watch: in the 10 bodies' first 0.4 s, warm solves that
    stall are ended at WARM_WATCH = 20 iterations instead of running to the limit of 50, and the
    recoveries (cold_start, friction_rows, ...) find the same answers: the same end positions
    (round-off apart) for fewer Newton iterations. Measured: 533 against 563 unwatched. (The
    figure was 573 against 720, and this test asked for 10 % fewer, until 2026-12-07: a repeat
    the kernel refused before its solve charged the last step's iterations again to
    report.spent, and after a stalled solve of 50 iterations those phantom charges were
    large; with the same trajectories, the runs at 47fd4f3 counted 536 against 702.)"""
    spent_off, q_off, ended_off = _ten_bodies(40, 15, monkeypatch, warm_watch=0)
    spent_on, q_on, ended_on = _ten_bodies(40, 15, monkeypatch, warm_watch=20)
    assert ended_on >= 1
    assert np.max(np.abs(q_on - q_off)) <= SAME_END
    assert spent_on < spent_off


def test_a_solve_whose_rows_will_switch_is_handed_over_with_the_switches_of_its_end(monkeypatch):
    """recovery.row_switch_test: in the 10 bodies' first 0.4 s (seed 4, a sparse step problem), a
    solve is ended once its natural residual is below HANDOVER_RESIDUAL and a pair clearly
    switches friction rows, and friction_rows switches those pairs. Each handed-over solve, run
    to its end from the same start without the handover, converges with the same switches
    (rows/checks: ON for each pair handed on, OFF for each handed off) after more iterations
    (measured: 9 handovers, 84 iterations against 124 run to the end). The same attempt with an
    articulated skeleton taking part gets no stop test (recovery.row_switch_test says why)."""
    from dataclasses import replace

    from comparisons.stability import IMPLICIT, many_bodies_world
    from implicit_contact import ncp, recovery
    from implicit_contact.rows import checks as rk

    events, tests = [], []
    friction_rows = recovery.friction_rows

    def checked(stepper, att, problem, result):
        if result.status is ncp.Status.HANDED_OVER:
            on, off = att.handover
            full = stepper._solve(problem, att.z0)         # (no stop test: to its end)
            flags = problem.checks(full.x, att.tol, att.solver_tol, recovery.TOUCH)
            events.append((full.success, [bool(flags[k] & rk.ON) for k in on],
                           [bool(flags[k] & rk.OFF) for k in off], result.iterations, full.iterations))
            index, att.index = att.index, 0
            tests.append((recovery.row_switch_test(att, problem) is not None,
                          recovery.row_switch_test(replace(att, articulated=True), problem) is None))
            att.index = index
            outcome = friction_rows(stepper, att, problem, result)
            assert outcome is recovery.RETRY
            assert all(att.specs[k].with_friction for k in on) and not any(att.specs[k].with_friction for k in off)
            return outcome
        return friction_rows(stepper, att, problem, result)

    monkeypatch.setattr(recovery, "RECOVERIES", (checked,) + recovery.RECOVERIES[1:])
    world = many_bodies_world(10, 0.01, IMPLICIT, seed=4)
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(40):
        stepper.step()
    assert len(events) >= 3
    assert all(free and articulated for free, articulated in tests)
    for converged, on, off, handed, full in events:
        assert converged and all(on) and all(off) and on + off
        assert handed < full
