"""Broadphase: world AABBs grown by a motion margin -> candidate pairs (the only module importing coal).

The geometrically implicit step of [GI] solves, for every pair of bodies that may touch during the
step, the closest-point KKT conditions (eqs 15-18) and the gap complementarity
0 <= p_n ⊥ f(a2) >= 0 (eq 19) at the END of the step. A pair needs rows only if the two bodies
can come into contact within the step, so the broadphase has one job: return every pair whose
world axis-aligned bounding boxes, each grown by its own margin, overlap. The margin is the
caller's business (|v| h + tolerance bounds how far a body's surface can move in one step).

Math. Object i has the box B_i = [lo_i - m_i, hi_i + m_i] (componentwise, m_i >= 0). Two boxes
overlap iff on every axis k

    lo_ik - m_i <= hi_jk + m_j   and   lo_jk - m_j <= hi_ik + m_i,

with closed intervals: touching boxes ARE candidates (a resting contact has grown boxes that at
least touch, and dropping it would open the gap the formulation must close).

Unbounded shapes (half-spaces, infinite cylinders) have entries -inf / +inf. coal's managers
also do arithmetic on boxes (SSaP picks its sweep axis from the spread of the box centres, a tree
from volumes), where inf - inf = NaN, so every infinite entry is clamped to +-L with L = 2 max|finite entry| + 1. The clamp is exact for the test above:
each comparison is "a <= b" with a in (finite values) U {-inf} and b in (finite values) U {+inf}
(a box with lo = +inf or hi = -inf is empty and rejected); the map -inf -> -L, +inf -> +L is
monotone and puts -L below and +L above every finite value, so every comparison keeps its truth
value.

Engine and read-back (coal 3.0.3 Python bindings, measured; the tests pin the behaviour):
- coal.SSaPCollisionManager (simple sweep and prune: sort by the box minima along the axis of
  largest spread, sweep, test the other two axes, all comparisons closed). Of coal's managers it
  is the one that is both exact and cheap here. Measured with the oracle of the tests: the
  DynamicAABBTree's full `update()` throws "negative volume" on any zero-volume box (a flat box,
  a point, the padded 2D case below), and its per-object `update(obj)` avoids that but
  rebalances the tree on every call (17 ms at n = 1000, ten times SSaP); SaP and
  DynamicAABBTreeArray return wrong pair sets after their boxes are rewritten, IntervalTree misses
  touching boxes, Naive is exact but O(n^2) in C++.
- one coal.CollisionObject per object, registered one by one (`registerObjects` accepts no
  Python list, nor does `update(objects)`). Its AABB is written directly through the reference
  returned by `getAABB()`; `manager.update()` re-sorts from those boxes and never calls
  `computeAABB()` (which would overwrite them from the geometry), and neither do we.
- Python cannot subclass a collision callback ("This class cannot be instantiated from
  Python"), and `CollisionCallBackCollect.getCollisionPairs()` has no converter to Python
  (TypeError), so that callback only answers `exist(a, b)` one pair at a time: O(n^2) calls.
  Instead the manager is collided with a `CollisionCallBackDefault`, which runs the narrowphase
  on every pair whose boxes overlap and appends one contact per colliding pair to one
  CollisionResult (coal does not clear it between pairs). Every geometry is the same unit sphere
  at the origin (identity transform), so that narrowphase always reports a collision: the
  contacts are exactly the box-overlap pairs. Each geometry carries its object index in its
  otherwise unused `cost_density` field, which `contact.o1` / `contact.o2` give back.
  `num_max_contacts` is set above n(n-1)/2 so the callback never stops early.
Cost per call with every box moving (2 shared cores, VM; the dense numpy interval test
in brackets): n = 2: 13 us (19 us); n = 10: 35 us (21 us); n = 100: 150-250 us (100-120 us);
n = 200: 210-280 us (290-400 us); n = 1000: 1.6-2.1 ms (10 ms). The coal work itself is a few
microseconds; the rest is about 0.5 us per AABB write (two per moving object) and about 1 us per
pair read back, plus ~10 us of input checks. Boxes that did not change since the last call are
not rewritten (static ground, fixtures). Numpy is not faster at n <= 3 (its call overhead is
~20 us), so no short-circuit is taken for tiny n: coal runs for every n >= 2, n < 2 returns [].

2D callers may pass (n, 2) boxes: the third axis is padded with the closed interval [0, 0],
which every other padded box touches, so the 2D overlap test is unchanged (SSaP accepts such flat
boxes; the DynamicAABBTree would not).
"""
from __future__ import annotations

from collections.abc import Callable

import coal
import numpy as np

# Beyond this magnitude the clamp bound 2 max|x| + 1 of unbounded boxes could overflow (and a
# margin could turn a finite box infinite); AABBs in metres never come near it.
_MAX_FINITE_COORDINATE = 1e150
# Up to this many objects every box is rewritten each call: cheaper than testing which changed.
_WRITE_ALL_UP_TO = 8


class Broadphase:
    """Candidate pairs of n objects from their world AABBs grown by motion margins.

    Objects are indexed 0..n-1 and registered with coal once, at construction; each call to
    `candidates` writes the current boxes and queries the tree.
    """

    def __init__(self, n_objects: int):
        if isinstance(n_objects, bool) or not isinstance(n_objects, (int, np.integer)) or n_objects < 0:
            raise ValueError(f"n_objects must be a non-negative integer, got {n_objects!r}")
        self.n_objects = int(n_objects)
        self._manager = coal.SSaPCollisionManager()
        self._objects = []
        self._aabbs = []
        for index in range(self.n_objects):
            geometry = coal.Sphere(1.0)
            geometry.cost_density = float(index)  # the tag read back from each contact
            obj = coal.CollisionObject(geometry)
            # coal's Python binding cannot take a list of objects: register one by one.
            self._manager.registerObject(obj)
            self._objects.append(obj)
            self._aabbs.append(obj.getAABB())  # a reference into obj: writes go through
        self._callback = coal.CollisionCallBackDefault()
        self._callback.data.request.enable_contact = False  # only the yes/no per pair is used
        self._callback.data.request.num_max_contacts = self.n_objects * (self.n_objects - 1) // 2 + 1
        self._last_lo = None  # the boxes written into coal by the last call
        self._last_hi = None

    def candidates(
        self,
        lo: np.ndarray,
        hi: np.ndarray,
        margin: np.ndarray | float = 0.0,
        allowed: Callable[[int, int], bool] | None = None,
    ) -> list[tuple[int, int]]:
        """Sorted pairs (i, j), i < j, whose boxes [lo - margin, hi + margin] overlap (closed).

        lo, hi: (n, 3) or (n, 2) world AABB corners [m]; entries may be -inf (lo) / +inf (hi)
            for unbounded shapes; lo <= hi.
        margin: scalar or (n,) per-object growth [m], finite and >= 0.
        allowed: optional filter allowed(i, j) -> bool called with i < j (e.g. to skip pairs of
            one rigid body or of two fixed bodies); pairs it rejects are dropped.
        """
        grown_lo, grown_hi = self._grown(lo, hi, margin)
        if allowed is not None and not callable(allowed):
            raise ValueError("allowed must be None or a callable allowed(i, j) -> bool")
        if self.n_objects < 2:
            return []
        self._write_boxes(grown_lo, grown_hi)
        # collide() starts with callback.init(), which clears the previous call's contacts.
        self._manager.collide(self._callback)
        result = self._callback.data.result
        pairs = []
        for k in range(result.numContacts()):
            contact = result.getContact(k)
            i = int(contact.o1.cost_density)
            j = int(contact.o2.cost_density)
            pairs.append((i, j) if i < j else (j, i))
        pairs.sort()
        if allowed is not None:
            pairs = [pair for pair in pairs if allowed(*pair)]
        return pairs

    def _write_boxes(self, grown_lo: np.ndarray, grown_hi: np.ndarray) -> None:
        """Write the rows that changed since the last call into coal and re-sort the manager."""
        # Static bodies (ground, fixtures) keep their boxes: skipping their two writes (~0.5 us
        # each) pays once the vectorised change test (~4 us) is cheaper than writing every row.
        if self._last_lo is None or self.n_objects <= _WRITE_ALL_UP_TO:
            changed = range(self.n_objects)
        else:
            differs = grown_lo != self._last_lo
            differs |= grown_hi != self._last_hi
            changed = np.flatnonzero(differs.any(axis=1)).tolist()
        aabbs = self._aabbs
        for k in changed:
            aabbs[k].min_ = grown_lo[k]
            aabbs[k].max_ = grown_hi[k]
        self._last_lo, self._last_hi = grown_lo, grown_hi
        self._manager.update()

    def _grown(self, lo, hi, margin) -> tuple[np.ndarray, np.ndarray]:
        """Validated boxes grown by their margins, infinite entries clamped, C order, (n, 3)."""
        n = self.n_objects
        lo = np.asarray(lo, dtype=float)
        hi = np.asarray(hi, dtype=float)
        if lo.shape != hi.shape or lo.ndim != 2 or lo.shape[0] != n or lo.shape[1] not in (2, 3):
            raise ValueError(
                f"lo and hi must both have shape ({n}, 3) or ({n}, 2), got {lo.shape} and {hi.shape}"
            )
        with np.errstate(invalid="ignore"):  # inf - inf = NaN is wanted: the check below rejects it
            extent = hi - lo
        # One reduction checks everything: NaN propagates, lo > hi gives a negative extent,
        # and lo = +inf or hi = -inf gives NaN (inf - inf) or -inf.
        if n and not np.minimum.reduce(extent, axis=None) >= 0.0:
            raise ValueError(
                "every box needs lo <= hi, no NaN, lo < +inf and hi > -inf (use -inf / +inf only "
                "for the unbounded sides of a shape)"
            )
        unbounded = bool(n) and np.maximum.reduce(extent, axis=None) == np.inf
        if isinstance(margin, (int, float)) and not isinstance(margin, bool):
            if not (0.0 <= margin <= _MAX_FINITE_COORDINATE):
                raise ValueError(f"margin must be finite, >= 0 and at most {_MAX_FINITE_COORDINATE:g}, got {margin}")
            grow = float(margin)
        else:
            grow = np.asarray(margin, dtype=float)
            if grow.shape != (n,):
                raise ValueError(f"margin must be a scalar or have shape ({n},), got shape {grow.shape}")
            if n and not (np.minimum.reduce(grow) >= 0.0 and np.maximum.reduce(grow) <= _MAX_FINITE_COORDINATE):
                raise ValueError(f"margin must be finite, >= 0 and at most {_MAX_FINITE_COORDINATE:g}")
            grow = grow[:, None]
        if lo.shape[1] == 2:
            pad = np.zeros((n, 1))
            lo = np.hstack([lo, pad])
            hi = np.hstack([hi, pad])
        # Fresh C-ordered arrays: each row is a contiguous 3-vector for coal's Eigen converter,
        # and the caller's arrays are never aliased by the cached last boxes.
        grown_lo = np.subtract(lo, grow, order="C")
        grown_hi = np.add(hi, grow, order="C")
        if unbounded:
            return _clamped(grown_lo, grown_hi)
        return grown_lo, grown_hi


def _clamped(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Replace -inf / +inf by -L / +L, L beyond every finite entry (exact for overlap tests)."""
    finite_lo = np.isfinite(lo)
    finite_hi = np.isfinite(hi)
    largest = max(
        np.abs(lo[finite_lo]).max(initial=0.0),
        np.abs(hi[finite_hi]).max(initial=0.0),
    )
    if largest > _MAX_FINITE_COORDINATE:
        raise ValueError(
            f"with unbounded boxes present, finite box coordinates must be at most "
            f"{_MAX_FINITE_COORDINATE:g} in magnitude, got {largest:g}"
        )
    bound = 2.0 * largest + 1.0
    return np.where(finite_lo, lo, -bound), np.where(finite_hi, hi, bound)
