"""The lock-piece grasp of [GI] Sec. 6.4 (scenes.gear_grasp) and its study (comparisons.grasp).

Oracles: the printed tooth angles and the 20.75 mm rim (eqs 56-57, NOTES.md's reading: neighbouring
teeth 0.149398 rad apart, the two groups mirror images about -y at +-17.75, +-26.31, +-34.87 deg);
Brost and Christiansen's sweet spot (0, -11) mm, from which a mid-range-friction squeeze ends on the
outer-most teeth with the jaws about 27.5 mm apart (NOTES.md); a squeeze from the far corner
(19, -1) mm grips the rim nearly diametrically, which the friction cone holds (mu_gripper = 0.5 >
tan of the contact angle there), so it fails; the jaws' y and orientation holds stay within 1e-6 of
the part's size.
"""
import csv
import math

import numpy as np
import pytest

from comparisons import grasp
from scenes import gear_grasp as gg

ANGLE_TOL = 1e-6          # [rad] the printed angles have 6 decimals
PRINTED_SPACING = 0.149398  # [rad] theta_{i+1} - theta_i within a group (NOTES.md)
MIRROR_DEG = (17.75, 26.31, 34.87)   # [deg] from -y, NOTES.md (2 decimals)
ON_SURFACE = 1e-12        # [m] |f| of a point constructed on a surface (round-off)
HOLD_TOL = 1e-6 * 2 * gg.R            # [m] the brief: jaw hold error below 1e-6 of the part's size
PAIR_SEPARATION_MM = (27.5, 0.1)      # outer-teeth grasp: separation ~27.5 mm (NOTES.md), +- 0.1 mm
MID = 0.5                 # mid-range friction, inside dVC's "medium" (0.33, 0.66]


def test_union_parts_are_the_disc_and_six_teeth_centred_on_the_rim_at_the_printed_angles():
    part = gg.lock_piece()
    assert len(part.parts) == 7
    disc = part.parts[0]
    assert float(disc.value(np.array([gg.R, 0.0]))) == pytest.approx(0.0, abs=ON_SURFACE)
    for i, th in enumerate(gg.THETAS):
        tooth = part.parts[i + 1]
        c = np.asarray(tooth.center)
        assert np.hypot(*c) == pytest.approx(0.02075, abs=1e-12)
        assert math.atan2(c[1], c[0]) % (2 * math.pi) == pytest.approx(th, abs=ANGLE_TOL)
        # long semi-axis (2.3 mm) along the radius, short (1.1 mm) along the rim
        u = c / np.linalg.norm(c)
        w = np.array([-u[1], u[0]])
        assert float(tooth.value(c + 0.0023 * u)) == pytest.approx(0.0, abs=ON_SURFACE)
        assert float(tooth.value(c + 0.0011 * w)) == pytest.approx(0.0, abs=ON_SURFACE)
    spacing = np.diff(gg.THETAS)
    assert spacing[[0, 1, 3, 4]] == pytest.approx(PRINTED_SPACING, abs=2e-6)


def test_tooth_groups_are_mirror_images_about_minus_y():
    from_minus_y = np.degrees(np.array(gg.THETAS) - 1.5 * math.pi)
    assert sorted(np.round(np.abs(from_minus_y), 2)) == sorted(MIRROR_DEG * 2)
    part = gg.lock_piece()
    rng = np.random.default_rng(0)
    pts = rng.uniform(-0.025, 0.025, (2000, 2))
    mirrored = pts * np.array([-1.0, 1.0])
    inside = np.asarray(part.value(pts)) <= 0
    inside_m = np.asarray(part.value(mirrored)) <= 0
    near = np.abs(np.asarray(part.value(pts))) < 1e-7      # printed angles: 6 decimals
    assert np.all(inside[~near] == inside_m[~near])
    # the outer-most teeth: theta_1 on the left, theta_6 on the right
    assert gg.lock_piece().parts[gg.LEFT_OUTER].center[0] < -0.011
    assert gg.lock_piece().parts[gg.RIGHT_OUTER].center[0] > 0.011


def test_start_opening_clears_the_part_by_the_gap_on_the_nearer_side():
    for x, y in ((0.0, -0.011), (0.019, -0.001), (0.01, -0.019)):
        lo, hi = gg.extent_below(y)
        d = gg.start_opening(x, y)
        assert x + d - hi >= gg.GAP_START - 1e-12 and (x - d) <= lo - gg.GAP_START + 1e-12
        assert min(x + d - hi, lo - (x - d)) == pytest.approx(gg.GAP_START, abs=1e-12)


@pytest.fixture(scope="module")
def sweet():
    return gg.simulate_grasp(0.0, -11.0, MID, MID)


def test_sweet_spot_grasp_succeeds_on_the_outer_teeth_for_mid_range_friction(sweet):
    assert sweet.success, sweet.reason
    assert not sweet.step_failure
    assert sweet.separation_mm == pytest.approx(PAIR_SEPARATION_MM[0], abs=PAIR_SEPARATION_MM[1])
    assert any(gg.RIGHT_OUTER in c.parts for c in sweet.contacts["right"])
    assert any(gg.LEFT_OUTER in c.parts for c in sweet.contacts["left"])
    # the part slid up between the jaws (Brost and Christiansen's explanation of the sweet spot)
    assert sweet.part_mm_rad[1] > 3.0


def test_jaws_hold_y_and_orientation_within_1e6_of_the_part_size(sweet):
    y_err, th_err = sweet.hold_error
    assert y_err < HOLD_TOL
    assert th_err * gg.FINGER_LENGTH < HOLD_TOL     # worst lever: the finger's length


def test_far_corner_grasp_fails_gripping_the_rim():
    out = gg.simulate_grasp(19.0, -1.0, MID, MID)
    assert not out.success
    assert out.reason.startswith("held elsewhere")
    assert all(c.parts == (0,) for side in ("right", "left") for c in out.contacts[side])


def test_success_test_rejects_an_inner_tooth_and_a_weak_hold():
    strong = gg.F_GRIP
    right_ok = gg.JawContact((gg.RIGHT_OUTER,), (13.7, -18.2), strong, 0.86)
    left_ok = gg.JawContact((gg.LEFT_OUTER,), (-13.7, -18.2), strong, -0.86)
    assert gg.classify({"right": (right_ok,), "left": (left_ok,)}) == (True, "held by the outer teeth")
    inner_flank = gg.JawContact((gg.LEFT_OUTER,), (-11.0, -18.2), strong, 0.86)
    assert not gg.classify({"right": (right_ok,), "left": (inner_flank,)})[0]
    rim = gg.JawContact((0,), (-20.0, -5.0), strong, math.nan)
    assert not gg.classify({"right": (right_ok,), "left": (rim,)})[0]
    weak = gg.JawContact((gg.LEFT_OUTER,), (-13.7, -18.2), 0.1 * strong, -0.86)
    assert gg.classify({"right": (right_ok,), "left": (weak,)}) == (False, "not held")


def test_tiny_grid_runs_through_the_process_pool_and_resumes_its_results_file(tmp_path):
    cells = dict(xs=(0, 19), ys=(-1,), trials=1, out=tmp_path, progress=False, plot=False)
    first = grasp.study(max_workers=2, **cells)
    assert first.ran == 2
    path = tmp_path / "grasp_trials.csv"
    with open(path, newline="") as handle:
        rows = list(csv.DictReader(handle))
    assert len(rows) == 2 and tuple(rows[0]) == grasp.TRIAL_FIELDS
    assert {(int(r["x_mm"]), int(r["y_mm"])) for r in rows} == {(0, -1), (19, -1)}
    assert all(r["kind"] in grasp.KINDS for r in rows)
    again = grasp.study(max_workers=2, **cells)
    assert again.ran == 0
    assert len(again.rows) == 2
    with open(path, newline="") as handle:
        assert len(list(csv.DictReader(handle))) == 2
    assert (tmp_path / "grasp_cells.csv").exists() and (tmp_path / "grasp.md").exists()
    # a trial that raised is not a result: the next run retries it and its new row supersedes it
    rows = list(csv.DictReader(open(path, newline="")))
    broken = dict(rows[1], kind="run error", success="0", reason="run error: ModuleNotFoundError: scenes")
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=grasp.TRIAL_FIELDS)
        writer.writeheader()
        writer.writerows([rows[0], broken])
    retried = grasp.study(max_workers=0, **cells)
    assert retried.ran == 1 and len(retried.rows) == 2
    assert all(r["kind"] != "run error" for r in retried.rows)


def test_plan_draws_reproducible_frictions_in_range():
    a = grasp.plan((0, 1), (-11,), trials=3, mu_support=(0.33, 0.66), mu_gripper=(0.66, 0.99))
    b = grasp.plan((0, 1), (-11,), trials=3, mu_support=(0.33, 0.66), mu_gripper=(0.66, 0.99))
    assert a == b and len(a) == 6
    assert all(0.33 <= c.mu_support <= 0.66 and 0.66 <= c.mu_gripper <= 0.99 for c in a)
    assert len({c.seed for c in a}) == 6


def test_summary_finds_the_sweet_spot_and_plateau_of_a_known_map():
    xs, ys = tuple(range(0, 6)), tuple(range(-14, -7))
    rows = []
    for x in xs:
        for y in ys:
            ok = x <= 2 and -13 <= y <= -9
            rows.append({"x_mm": x, "y_mm": y, "trial": 0, "success": int(ok),
                         "kind": "success" if ok else "held elsewhere"})
    s = grasp.summarise(rows, xs, ys)
    assert s["sweet_spot"] == (0, -11)
    assert s["plateau"]["cells"] == 5 * 5
    assert s["plateau"]["x"] == (-2, 2) and s["plateau"]["y"] == (-13, -9)
