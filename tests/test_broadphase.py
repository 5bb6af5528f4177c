"""Broadphase against an independent brute-force oracle.

The oracle is the dense numpy interval test on the grown boxes, with no clamping of infinite
entries (numpy compares +-inf exactly): it checks both coal's tree query and the clamp argument of
implicit_contact.broadphase. Overlap is closed: touching boxes are candidates. Every comparison is
exact (the same floating-point lo - m, hi + m on both sides), so pair lists must be EQUAL.
"""
import numpy as np
import pytest

from implicit_contact.broadphase import Broadphase


def oracle_pairs(lo, hi, margin):
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    margin = np.broadcast_to(np.asarray(margin, float), (len(lo),))
    grown_lo = lo - margin[:, None]
    grown_hi = hi + margin[:, None]
    overlap = np.ones((len(lo), len(lo)), dtype=bool)
    for axis in range(lo.shape[1]):
        overlap &= grown_lo[:, None, axis] <= grown_hi[None, :, axis]
        overlap &= grown_lo[None, :, axis] <= grown_hi[:, None, axis]
    i, j = np.nonzero(np.triu(overlap, 1))
    return list(zip(i.tolist(), j.tolist()))


def random_boxes(rng, n, p_infinite=0.0, grid=False, p_flat=0.0):
    """Boxes in a cube sized so that a few pairs overlap; grid=True puts every coordinate on a
    coarse integer lattice, which makes many boxes touch exactly; p_flat is the probability that
    a box has zero extent along an axis (flat boxes, segments, points)."""
    side = 2.0 * max(n, 1) ** (1 / 3)
    if grid:
        lo = rng.integers(0, int(side) + 2, size=(n, 3)).astype(float)
        hi = lo + rng.integers(0, 3, size=(n, 3))
    else:
        centre = rng.uniform(0.0, side, (n, 3))
        half = rng.uniform(0.05, 0.8, (n, 3))
        lo, hi = centre - half, centre + half
    flat = rng.random((n, 3)) < p_flat
    hi[flat] = lo[flat]
    lo[rng.random((n, 3)) < p_infinite] = -np.inf
    hi[rng.random((n, 3)) < p_infinite] = np.inf
    return lo, hi


@pytest.mark.parametrize("n", [0, 1, 2, 3, 5, 17, 64, 200])
@pytest.mark.parametrize("kind", ["finite", "infinite", "touching", "flat"])
def test_matches_oracle_on_random_boxes(n, kind):
    rng = np.random.default_rng(1000 * n + len(kind))
    broadphase = Broadphase(n)
    for trial in range(3):  # repeated calls exercise the re-sort, not only the first build
        lo, hi = random_boxes(
            rng,
            n,
            p_infinite=0.15 if kind == "infinite" else 0.0,
            grid=kind in ("touching", "flat"),
            p_flat=0.3 if kind == "flat" else 0.0,
        )
        exact_ties = kind in ("touching", "flat") and trial == 0
        margin = 0.0 if exact_ties else rng.uniform(0.0, 0.3, n)
        assert broadphase.candidates(lo, hi, margin) == oracle_pairs(lo, hi, margin)


def test_touching_boxes_are_candidates_and_a_gap_is_not():
    # x-intervals [0, 1], [1, 2], [3, 4]: 0 and 1 touch, 1 and 2 are 1 apart, 0 and 2 are 2 apart.
    lo = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    hi = lo + 1.0
    broadphase = Broadphase(3)
    assert broadphase.candidates(lo, hi, 0.0) == [(0, 1)]
    # A margin of 0.5 each closes the gap of 1 exactly: 1 and 2 touch at x = 2.5.
    assert broadphase.candidates(lo, hi, 0.5) == [(0, 1), (1, 2)]
    # A margin of 1 each closes the gap of 2 exactly: 0 and 2 touch at x = 2.
    assert broadphase.candidates(lo, hi, 1.0) == [(0, 1), (0, 2), (1, 2)]
    assert broadphase.candidates(lo, hi, np.array([1.0, 0.0, 0.9999])) == [(0, 1)]


def test_half_space_and_unbounded_objects():
    # A ground half-space y <= 0 (box unbounded except its top), an everywhere-unbounded object,
    # a ball resting on the ground, a ball far above it.
    lo = np.array([[-np.inf, -np.inf, -np.inf], [-np.inf, -np.inf, -np.inf], [-1, 0, -1], [-1, 5, -1.0]])
    hi = np.array([[np.inf, 0.0, np.inf], [np.inf, np.inf, np.inf], [1, 2, 1], [1, 7, 1.0]])
    broadphase = Broadphase(4)
    assert broadphase.candidates(lo, hi, 0.0) == [(0, 1), (0, 2), (1, 2), (1, 3)]
    # Grown by 5, the high ball reaches down to y = 0 exactly: it touches the ground's top face.
    assert broadphase.candidates(lo, hi, np.array([0.0, 0.0, 0.0, 5.0])) == [
        (0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)
    ]


def test_infinite_boxes_with_far_finite_coordinates():
    # The clamp bound must exceed every finite coordinate, also huge ones.
    lo = np.array([[-np.inf, 0.0, 0.0], [1e12, 0.0, 0.0], [-1e12 - 1.0, 0.0, 0.0]])
    hi = np.array([[-1e12, 1.0, 1.0], [1e12 + 1.0, 1.0, 1.0], [-1e12 - 0.5, 1.0, 1.0]])
    assert Broadphase(3).candidates(lo, hi, 0.0) == oracle_pairs(lo, hi, 0.0) == [(0, 2)]


def test_only_changed_boxes_are_rewritten_but_results_follow_every_change():
    # n above the write-all threshold: most boxes stay, a few jump far; the answer must track them.
    rng = np.random.default_rng(7)
    n = 50
    lo, hi = random_boxes(rng, n)
    broadphase = Broadphase(n)
    assert broadphase.candidates(lo, hi, 0.1) == oracle_pairs(lo, hi, 0.1)
    for _ in range(5):
        moved = rng.choice(n, size=3, replace=False)
        shift = rng.uniform(-3.0, 3.0, (3, 3))
        lo, hi = lo.copy(), hi.copy()
        lo[moved] += shift
        hi[moved] += shift
        assert broadphase.candidates(lo, hi, 0.1) == oracle_pairs(lo, hi, 0.1)


def test_all_pairs_overlapping_are_all_returned():
    # n(n-1)/2 pairs: the callback must not stop at its contact limit.
    n = 60
    lo = np.zeros((n, 3))
    hi = np.ones((n, 3))
    pairs = Broadphase(n).candidates(lo, hi, 0.0)
    assert pairs == [(i, j) for i in range(n) for j in range(i + 1, n)]


def test_two_dimensional_boxes():
    rng = np.random.default_rng(3)
    lo3, hi3 = random_boxes(rng, 40)
    lo, hi = lo3[:, :2], hi3[:, :2]
    assert Broadphase(40).candidates(lo, hi, 0.05) == oracle_pairs(lo, hi, 0.05)


def test_allowed_filters_pairs_and_inputs_are_not_modified():
    rng = np.random.default_rng(5)
    lo, hi = random_boxes(rng, 30)
    lo[0] = -np.inf
    lo_copy, hi_copy = lo.copy(), hi.copy()
    broadphase = Broadphase(30)
    everything = broadphase.candidates(lo, hi, 0.2)
    odd_sum = broadphase.candidates(lo, hi, 0.2, allowed=lambda i, j: (i + j) % 2 == 1)
    assert odd_sum == [pair for pair in everything if sum(pair) % 2 == 1]
    assert all(i < j for i, j in everything) and everything == sorted(set(everything))
    np.testing.assert_array_equal(lo, lo_copy)
    np.testing.assert_array_equal(hi, hi_copy)


@pytest.mark.parametrize(
    "lo, hi, margin",
    [
        ([[0, 0, 0], [0, 0, 0]], [[1, 1, 1]], 0.0),  # wrong shape
        ([[0, 0, 0], [0, 0, np.nan]], [[1, 1, 1], [1, 1, 1]], 0.0),  # NaN
        ([[0, 0, 0], [2, 0, 0]], [[1, 1, 1], [1, 1, 1]], 0.0),  # lo > hi
        ([[0, 0, 0], [np.inf, 0, 0]], [[1, 1, 1], [np.inf, 1, 1]], 0.0),  # empty: lo = +inf
        ([[0, 0, 0], [-np.inf, 0, 0]], [[1, 1, 1], [-np.inf, 1, 1]], 0.0),  # empty: hi = -inf
        ([[0, 0, 0], [1, 0, 0]], [[1, 1, 1], [2, 1, 1]], -0.1),  # negative margin
        ([[0, 0, 0], [1, 0, 0]], [[1, 1, 1], [2, 1, 1]], np.inf),  # infinite margin
        ([[0, 0, 0], [1, 0, 0]], [[1, 1, 1], [2, 1, 1]], [0.1, np.nan]),  # NaN margin
        ([[0, 0, 0], [1, 0, 0]], [[1, 1, 1], [2, 1, 1]], [0.1, 0.1, 0.1]),  # margin shape
    ],
)
def test_bad_input_raises_value_error(lo, hi, margin):
    with pytest.raises(ValueError):
        Broadphase(2).candidates(np.array(lo, float), np.array(hi, float), margin)


def test_bad_constructor_and_filter_raise_value_error():
    with pytest.raises(ValueError):
        Broadphase(-1)
    with pytest.raises(ValueError):
        Broadphase(2.5)
    with pytest.raises(ValueError):
        Broadphase(2).candidates(np.zeros((2, 3)), np.ones((2, 3)), 0.0, allowed=3)
