"""The unknowns of one step and their index maps: what a step's MCP is made of.

A step's unknown vector z holds, in this order: every involved skeleton's velocities, then per
candidate pair its block (a1, a2, multipliers, p_n, friction, quasi-rigid unknowns), then per
support block its friction unknowns; rows share the indices of the unknowns they pair with.
``build_layout`` allocates z from the pairs' static descriptions (PairSpec); the Layout packs
and unpacks it, so no other code does index arithmetic by hand. Only the rows a pair needs are
allocated: no friction rows at mu = 0 or while a gap is open (``with_friction``), no torsion at
e_r = 0, a coordinate of a point on a fixed half-space dropped, quasi-rigid unknowns only for
quasi-rigid pairs ([GI] Sec. 4.2 counts 11 unknowns for Example 1, 32 for Example 2).
"""
from __future__ import annotations

from dataclasses import dataclass
import math
import weakref

import numpy as np

from .params import Friction
from .shapes import _least_aligned_axis
from .support import allocate as allocate_supports

FREE, PLANAR, FIXED = "free", "planar", "fixed"
ARTICULATED = "articulated"   # a body of a multi-body skeleton (or any other root): see BodyKinematics


@dataclass
class ContactObject:
    """One convex piece (a single function or an intersection) of one body."""
    body: int                  # index into the step's body list
    functions: tuple
    fixed_halfspace: bool      # a fixed body whose piece is one half-space / half-plane
    label: str = ""


@dataclass
class PairSpec:
    """The static description of a candidate pair, as the layout needs it."""
    key: tuple
    obj1: ContactObject
    obj2: ContactObject
    dim: int
    friction: Friction
    with_friction: bool
    k1: int = 0                # eq (28)'s k1 of a pair not in the cone form: 0, its one function
    tangent_axis: np.ndarray | None = None
    impulse_scale: float = 1.0
    objects: tuple = ()        # the stepper's own records of the two pieces, for reports
    compliance: object = None  # an ic.Compliance: a quasi-rigid pair (rows/contact.py, [GI] Sec. 5)
    compliant_side: int = 2    # which body carries the deformed layer
    delta_prev: float = 0.0    # its normal deflection at l
    layer_share: float = 1.0   # the share of the step's layer impulse this solve applies (order 2's
    #                            first stage: 1/2 of the midpoint rule's, rattle.py eq R11)
    patch: bool = False        # friction's e_r is the contact patch's at l (patch.py), per step
    shared: bool = False       # another pair with friction rows joins the same two skeletons (no
    #                            patch torsion then: stepper._share_patches)
    normal_l: np.ndarray | None = None   # the pair's unit normal at l (memory or static seed)
    start_frame: np.ndarray | None = None  # order 2's first stage (rattle.py): n, t, o and the
    #                                        levers a1 - p1, a2 - p2 at l (15,), else None

    @property
    def cone_form(self) -> bool:
        """Whether body 1's normal is normalised by its multipliers' sum (rows/contact.py, eqs
        28n-32n): body 1 an intersection. Then no active function k1 is chosen, and the pair has
        one more unknown, s (its scaled distance); else body 1 is one function (k1 = 0)."""
        return len(self.obj1.functions) > 1


@dataclass
class PairSlots:
    """Column indices of one pair's unknowns and row indices of its rows in z / F."""
    a1: np.ndarray
    a2: np.ndarray
    l1: np.ndarray
    l2: np.ndarray
    p_n: int
    p_t: np.ndarray            # (d-1,) friction unknowns, empty if no friction
    p_r: int                   # -1 if no torsion
    sigma: int                 # -1 if no friction
    rows_geo: np.ndarray       # 2d rows: (15) then (16)
    rows_l1: np.ndarray        # complementarity rows of bounded l1 (aligned with l1 unknowns)
    rows_l2: np.ndarray
    row_n: int
    rows_fric: np.ndarray      # (d-1) + torsion rows, then sigma row = sigma
    dbar: int = -1             # quasi-rigid pairs: algebraic offset, deflection, core impulse
    dn: int = -1               # (each row shares its unknown's index: (35), spring, core)
    p_nr: int = -1
    s: int = -1                # cone-form pairs (PairSpec.cone_form): scaled distance; its row is
    #                            sum_i l1_i = 1 (29n)

    def __post_init__(self):
        # the same blocks as slices (every block is contiguous), for fast reads and writes
        self.a1s, self.a2s = _as_slice(self.a1), _as_slice(self.a2)
        self.l1s, self.l2s, self.p_ts = _as_slice(self.l1), _as_slice(self.l2), _as_slice(self.p_t)
        self.rows_l1s, self.rows_l2s = _as_slice(self.rows_l1), _as_slice(self.rows_l2)
        self.l1_bounded = np.arange(len(self.rows_l1))   # which functions have complementarity rows
        self.l2_bounded = np.arange(len(self.rows_l2))
        # the pair's rigid unknowns (each row shares its unknown's index): points, s, multipliers,
        # p_n, friction; not a quasi-rigid layer's dbar, dn, p_nr
        self.columns = np.concatenate([self.a1, self.a2, [self.s] if self.s >= 0 else [], self.l1, self.l2,
                                       [self.p_n], self.rows_fric]).astype(np.int64)

    _ARRAYS = ("a1", "a2", "l1", "l2", "p_t", "rows_geo", "rows_l1", "rows_l2", "rows_fric", "columns")

    def moved(self, base: int) -> "PairSlots":
        """These slots with every index moved by base (build_layout's per-kind templates); the
        same as allocating the block at column base, without __post_init__'s work: the index
        arrays are read-only views of one moved copy of this template's. Kept per (template,
        base) in _MOVED: layouts that differ only after a pair's block give it the same slots
        (measured: 73 % of a 27-superquadric box's blocks and 38 % of 100 superquadrics' come
        again within their runs), and a block's making was ~20 us of Python."""
        key = (id(self), base)
        kept = _MOVED.get(key)
        if kept is not None:
            return kept
        if len(_MOVED) > MOVED_KEPT:
            _MOVED.clear()
        out = _MOVED[key] = self._moved(base)
        return out

    def _moved(self, base: int) -> "PairSlots":
        flat = self.__dict__.get("_flat")
        if flat is None:
            parts = [getattr(self, name) for name in PairSlots._ARRAYS]
            ends = np.cumsum([len(x) for x in parts]).tolist()
            flat = self.__dict__["_flat"] = (np.concatenate(parts).astype(np.int64),
                                             list(zip([0] + ends[:-1], ends)))
        values, bounds = flat
        moved = values + base
        moved.flags.writeable = False
        out = object.__new__(PairSlots)
        out.template = self
        out.a1, out.a2, out.l1, out.l2, out.p_t, out.rows_geo, out.rows_l1, out.rows_l2, out.rows_fric, out.columns = (
            moved[a:b] for a, b in bounds)
        out.p_n, out.row_n = self.p_n + base, self.row_n + base
        out.p_r, out.sigma, out.dbar, out.dn, out.p_nr, out.s = (
            _moved_index(at, base) for at in (self.p_r, self.sigma, self.dbar, self.dn, self.p_nr, self.s))
        out.a1s, out.a2s, out.l1s, out.l2s = (_moved_slice(self.a1s, base), _moved_slice(self.a2s, base),
                                              _moved_slice(self.l1s, base), _moved_slice(self.l2s, base))
        out.p_ts, out.rows_l1s, out.rows_l2s = (_moved_slice(self.p_ts, base), _moved_slice(self.rows_l1s, base),
                                                _moved_slice(self.rows_l2s, base))
        out.l1_bounded, out.l2_bounded = self.l1_bounded, self.l2_bounded
        return out


# build_layout's moved blocks, per (id of a template in _PAIR_TEMPLATES, which are never freed,
# and base column); emptied when it holds more than MOVED_KEPT
_MOVED = {}
MOVED_KEPT = 50_000


def _moved_index(at, base):
    return at + base if at >= 0 else -1      # -1: the block has no such unknown


def _moved_slice(sl, base):
    return slice(sl.start + base, sl.stop + base) if sl.stop > sl.start else sl


@dataclass
class Layout:
    """Packs and unpacks the unknown vector z of one step; no other code does index arithmetic."""
    n: int
    v_index: list              # per skeleton: column indices of its velocities
    pairs: list                # PairSlots per pair
    lower: np.ndarray
    upper: np.ndarray
    supports: tuple = ()       # support.SupportSlots per support block (after all pairs)
    joint_index: list = None   # per skeleton: columns of its joint rows (after the supports)


def _position_rows(layout: Layout):
    """The position-level rows (15), (17)-(19) of all pairs (scaled by 1/h), kept with the layout."""
    rows = layout.__dict__.get("_position_rows")
    if rows is None:
        parts = [np.zeros(0, int)]
        for sl in layout.pairs:
            parts += [sl.rows_geo[: len(sl.rows_geo) // 2], sl.rows_l1, sl.rows_l2, [sl.row_n]]
            parts += [[r] for r in (sl.dbar, sl.p_nr) if r >= 0]     # (35) and the core: lengths
        rows = layout.__dict__["_position_rows"] = np.concatenate(parts).astype(int)
    return rows


def closest_point_blocks(layout: Layout):
    """Per pair its closest-point unknowns a1, a2, l1, l2 and s ([GI] eqs 15-18; the cone form's
    28n-32n) as groups (bptr, bidx) for ncp.solve_mcp's blocks: a pair's closest-point rows read
    its own group and its bodies' velocities only, so in the Newton matrix the groups are coupled
    only through the other unknowns (block_elimination.py). Kept with the layout."""
    blocks = layout.__dict__.get("_closest_point_blocks")
    if blocks is None:
        groups = [np.concatenate([sl.a1, sl.a2, sl.l1, sl.l2, [sl.s] if sl.s >= 0 else []]).astype(np.int64)
                  for sl in layout.pairs]
        groups = [g for g in groups if len(g)]
        bptr = np.zeros(len(groups) + 1, np.int64)
        bptr[1:] = np.cumsum([len(g) for g in groups])
        bidx = np.concatenate(groups) if groups else np.zeros(0, np.int64)
        blocks = layout.__dict__["_closest_point_blocks"] = (bptr, bidx)
    return blocks


_REDUCED_CACHE = weakref.WeakKeyDictionary()


def _reduced_point(obj: ContactObject, kin):
    """For a fixed half-space: a = a0 + T s (a0 on the plane, T orthonormal tangents), world frame.
    Cached per plane function and body pose (the ground is the same every step)."""
    fn = obj.functions[0]
    key = (kin.dim, np.asarray(kin.R0, float).tobytes(), np.asarray(kin.p0, float).tobytes())
    try:
        per_fn = _REDUCED_CACHE.setdefault(fn, {})
    except TypeError:            # not weak-referenceable
        return _reduced_point_uncached(obj, kin)
    hit = per_fn.get(key)
    if hit is None:
        if len(per_fn) > 16:
            per_fn.clear()
        hit = per_fn[key] = _reduced_point_uncached(obj, kin)
    return hit


def _reduced_point_uncached(obj: ContactObject, kin):
    dim = kin.dim
    n_b, offset = obj.functions[0].plane()            # body frame
    R, p = kin.R0[:dim, :dim], kin.p0[:dim]
    n = R @ np.asarray(n_b, float)
    a0 = (float(offset) + float(n @ p)) * n
    if dim == 2:
        T = np.array([[-n[1]], [n[0]]])
    else:
        T = _tangent_basis(n, _least_aligned_axis(n))[1:].T
    return a0, T


def _tangent_basis(n, e):
    u = e - (e @ n) * n
    t = u / np.linalg.norm(u)
    return np.array([n, t, np.cross(n, t)])


def build_layout(nv_per_skeleton: list, specs: list, supports: tuple = (), joint_bounds: tuple = ()) -> Layout:
    """Allocate z: velocities first, then each pair's unknowns, then the support blocks'
    (support.SupportSpec), then per skeleton its joint rows (joint_bounds: per skeleton, None or
    the (lower, upper) arrays of its rows' unknowns, rows/dynamics.py); rows follow the same order.
    A pair's block is its kind's (_pair_template) moved to its first column."""
    # the skeletons' velocities first: per skeleton a read-only view of one range of columns
    ends = np.cumsum(np.asarray(nv_per_skeleton, np.int64)).tolist()
    col = ends[-1] if ends else 0
    columns = np.arange(col)
    columns.flags.writeable = False
    v_index = [columns[end - nv:end] for nv, end in zip(nv_per_skeleton, ends)]
    lower, upper = [np.full(col, -np.inf)], [np.full(col, np.inf)]
    slots = []
    for spec in specs:
        template, lo, hi = _pair_template(spec)
        slots.append(template.moved(col))
        lower.append(lo)
        upper.append(hi)
        col += len(lo)
    rest_lower, rest_upper = [], []
    support_slots, col = allocate_supports(col, supports, rest_lower, rest_upper)
    joint_index = []
    for s in range(len(nv_per_skeleton)):
        bounds = joint_bounds[s] if s < len(joint_bounds) else None
        nj = 0 if bounds is None else len(bounds[0])
        joint_index.append(np.arange(col, col + nj))
        if nj:
            rest_lower += [float(x) for x in bounds[0]]
            rest_upper += [float(x) for x in bounds[1]]
            col += nj
    lower.append(np.array(rest_lower, float))
    upper.append(np.array(rest_upper, float))
    return Layout(col, v_index, slots, np.concatenate(lower), np.concatenate(upper), tuple(support_slots),
                  joint_index)


_PAIR_TEMPLATES = {}


def _pair_template(spec):
    """(PairSlots of the pair's block at column 0, its unknowns' lower and upper bounds), kept per
    kind of block: what build_layout allocates depends on these alone."""
    comp = spec.compliance
    key = (spec.dim, len(spec.obj1.functions), len(spec.obj2.functions), bool(spec.obj1.fixed_halfspace),
           bool(spec.obj2.fixed_halfspace), spec.cone_form, bool(spec.with_friction),
           bool(spec.with_friction and spec.dim == 3 and spec.friction.torsion),
           None if comp is None else math.isfinite(comp.delta_max))
    held = _PAIR_TEMPLATES.get(key)
    if held is None:
        lower, upper = [], []
        template = _allocate_pair(spec, 0, lower, upper)
        for name in PairSlots._ARRAYS + ("l1_bounded", "l2_bounded"):
            getattr(template, name).flags.writeable = False
        held = _PAIR_TEMPLATES[key] = (template, np.array(lower, float), np.array(upper, float))
    return held


def _allocate_pair(spec, col, lower, upper):
    """One pair's PairSlots from column col; its unknowns' bounds appended to lower and upper."""
    d = spec.dim
    n1, n2 = len(spec.obj1.functions), len(spec.obj2.functions)
    red1, red2 = spec.obj1.fixed_halfspace, spec.obj2.fixed_halfspace
    na1 = d - 1 if red1 else d
    na2 = d - 1 if red2 else d
    base = col
    a1 = np.arange(col, col + na1); col += na1
    a2 = np.arange(col, col + na2); col += na2
    # multipliers made free by a reduced side come next, so that the 2d geometric rows
    # pair with exactly the free unknowns a1, a2 and those multipliers.
    free_l1 = red1
    free_l2 = red2
    geo_free = na1 + na2 + int(free_l1) + int(free_l2)
    if geo_free != 2 * d:
        raise AssertionError("geometric rows and free unknowns do not balance")
    l1 = np.arange(col, col + n1) if free_l1 else None
    if free_l1:
        col += n1
    l2 = np.arange(col, col + n2) if free_l2 else None
    if free_l2:
        col += n2
    rows_geo = np.arange(base, base + 2 * d)
    lower += [-np.inf] * geo_free
    upper += [np.inf] * geo_free
    s_col = -1
    if spec.cone_form:
        s_col = col; col += 1
        lower.append(-np.inf); upper.append(np.inf)
    rows_l1 = np.arange(0)
    rows_l2 = np.arange(0)
    if not free_l1:
        l1 = np.arange(col, col + n1); rows_l1 = l1.copy(); col += n1
        lower += [0.0] * n1; upper += [np.inf] * n1
    if not free_l2:
        l2 = np.arange(col, col + n2); rows_l2 = l2.copy(); col += n2
        lower += [0.0] * n2; upper += [np.inf] * n2
    p_n = col; col += 1
    lower.append(0.0); upper.append(np.inf)
    p_t = np.arange(0)
    p_r = sigma = -1
    rows_fric = np.arange(0)
    if spec.with_friction:
        p_t = np.arange(col, col + d - 1); col += d - 1
        lower += [-np.inf] * (d - 1); upper += [np.inf] * (d - 1)
        if d == 3 and spec.friction.torsion:
            p_r = col; col += 1
            lower.append(-np.inf); upper.append(np.inf)
        sigma = col; col += 1
        lower.append(0.0); upper.append(np.inf)
        rows_fric = np.arange(p_t[0], col)
    dbar = dn = p_nr = -1
    if spec.compliance is not None:
        dbar, dn = col, col + 1
        col += 2
        lower += [-np.inf, -np.inf]; upper += [np.inf, np.inf]
        if math.isfinite(spec.compliance.delta_max):
            p_nr = col; col += 1
            lower.append(0.0); upper.append(np.inf)
    return PairSlots(a1, a2, l1, l2, p_n, p_t, p_r, sigma, rows_geo, rows_l1, rows_l2, p_n, rows_fric, dbar, dn,
                     p_nr, s_col)


@dataclass
class SkeletonBlock:
    """Newton-Euler data of one skeleton at l: M v+ = M v + h force + sum J^T P."""
    M: np.ndarray
    v: np.ndarray
    force: np.ndarray
    body: int                  # its contact body in StepProblem.bodies
    joints: "JointRows | None" = None


@dataclass
class JointRows:
    """A skeleton's joint rows at l (rows/dynamics.py): F_r = G[r] . v+ + c[r] complementary to
    lower[r] <= lambda_r <= upper[r]; unit[r] lambda_r is the generalized impulse along G[r]."""
    G: np.ndarray              # (n_j, k)
    c: np.ndarray              # (n_j,)
    unit: np.ndarray           # (n_j,)
    lower: np.ndarray          # (n_j,)
    upper: np.ndarray          # (n_j,)
    keys: tuple = ()           # what each row is, e.g. ("friction", dof) (joint_rows.py)


@dataclass
class PairState:
    """A pair's unknowns unpacked (impulses in physical units)."""
    a1: np.ndarray
    a2: np.ndarray
    l1: np.ndarray
    l2: np.ndarray
    p_n: float
    p_t: np.ndarray
    p_r: float
    sigma: float
    normal: np.ndarray
    tangents: np.ndarray
    gap: float


def _as_slice(index):
    """A contiguous index array as a slice (layouts only allocate contiguous blocks)."""
    if len(index) == 0:
        return slice(0, 0)
    return slice(int(index[0]), int(index[-1]) + 1)


