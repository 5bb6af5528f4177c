r"""One time step of [GI] as a mixed complementarity problem: its tables, F(z) and dF/dz.

The equations live in ``implicit_contact/rows`` (one module per part of the paper, compiled);
the unknowns and their index maps in ``layout.py``. This module turns a step's description
(skeleton blocks, body kinematics, pair specs, support blocks and their layout) into the flat
tables the row kernels read, and evaluates them: ``StepProblem.fun`` and ``jac`` for
``ncp.solve_mcp``, and the same tables for the compiled step solver (step_solver.py).

Body kinematics ([GI] eq 21, second line; rows/bodies.py): a moving body's pose at l+1 is
q^{l+1} = q^l (+) h v^{l+1}, written exactly as DART integrates:

* FREE (dartpy 6.20, v = [omega; v_o] in the world frame): R+ = exp(h [omega]x) R, p+ = p + h v_o.
* PLANAR in XY (v = [v_x, v_y, omega]): theta+ = theta + h omega, p+ = p + h [v_x, v_y].
* ARTICULATED (a body of a multi-body skeleton, or of any other root; v = its skeleton's
  velocities, shared by all its bodies): the body moves rigidly with its twist through DART's
  world Jacobian of its origin at l, J = [A_w; A_v] (6 x ndof, angular rows first):
  omega = A_w v, R+ = exp(h [omega]x) R, p+ = p + h A_v v. Exact for a free body (a FREE body
  is this with J = I6); for a chain it differs from DART's joint-space update q+ = q (+) h v
  (which the stepper uses to write back) by O(h^2 |v|^2).

Scaling. Impulses are unknowns in units of s_p = m max(h g_ref, IMPULSE_SPEED) (a pair's weight
impulse, at least m * 1 cm/s: stepper._pair_spec), the Newton-Euler rows are divided by diag(M)
and the position-level rows ((15), (17)-(19), (35), (55)) by h, so that they read as velocities; the friction rows are in velocity units by
construction: a natural-residual tolerance then means about the same on every row.

Jacobian storage. Below SPARSE_MIN_UNKNOWNS unknowns (``jacobian="auto"``) J is a dense (n, n)
array; from there on a scipy.sparse CSR matrix with a pattern fixed per problem: a many-body
problem has thousands of unknowns but each pair touches about 30 of them.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass
import math

import numpy as np
import scipy.sparse as _sparse

from . import bundles

# the layout's names are formulation's too (callers build a step with fm.PairSpec, fm.build_layout, ...)
from .layout import (ARTICULATED, FIXED, FREE, PLANAR, ContactObject, Layout, PairSlots, PairSpec,  # noqa: F401
                     JointRows, PairState, SkeletonBlock, _as_slice, _least_aligned_axis, _position_rows,
                     _reduced_point, _tangent_basis, build_layout)
from .rows import bodies as rb
from .rows import contact as rc
from .rows import dynamics as rd
from .rows import support as rs
from .rows import checks as rk
from .rows import tables as rt
from .rows.assemble import assemble, sparse_pattern

SPARSE_MIN_UNKNOWNS = 250   # measured crossover of the dense and the sparse J + LU (comparisons/bench_many_bodies.py)

_KIND_CODE = {FIXED: rb.FIXED, FREE: rb.MOVING, ARTICULATED: rb.MOVING, PLANAR: rb.PLANAR}
_I6 = np.eye(6)


# ---------------------------------------------------------------------------------------------
# bodies at l+1
# ---------------------------------------------------------------------------------------------
def so3_exp(phi) -> np.ndarray:
    """exp([phi]x) (Rodrigues, rows/bodies.py)."""
    phi = np.asarray(phi, float)
    th2 = float(phi @ phi)
    a, b, _ = rb.so3_coefficients(th2)
    out = np.empty((3, 3))
    rb.i_plus_k(phi, th2, a, b, out)
    return out


def so3_left_jacobian(phi) -> np.ndarray:
    """J_l(phi), the left Jacobian of SO(3) (rows/bodies.py)."""
    phi = np.asarray(phi, float)
    th2 = float(phi @ phi)
    _, b, c = rb.so3_coefficients(th2)
    out = np.empty((3, 3))
    rb.i_plus_k(phi, th2, b, c, out)
    return out


@dataclass
class Pose:
    """A body's pose at l+1 in the pair's dimension d: R (d, d), p (d,); omega (3,) world
    (2D: (0, 0, omega_z))."""
    R: np.ndarray
    p: np.ndarray
    omega: np.ndarray


@dataclass
class BodyKinematics:
    kind: str
    dim: int
    R0: np.ndarray             # 3x3 at l
    p0: np.ndarray             # 3 at l
    q0: np.ndarray | None      # planar: [x, y, theta]
    h: float
    vindex: np.ndarray | None  # columns of its velocity unknowns in z (None for fixed)
    mass: float = math.inf
    jacobian: np.ndarray | None = None   # ARTICULATED: DART's world Jacobian of the body origin at l
    #                                      (6 x ndof of its skeleton, angular rows first)

    @property
    def ndof(self) -> int:
        return 0 if self.vindex is None else len(self.vindex)

    def tables(self, vcol: int = 0):
        """(body_i row, body_f row, its [A_w; A_v] rows or None) of rows/bodies.py."""
        d = self.dim
        R = np.eye(3)
        p = np.zeros(3)
        theta = 0.0
        jac = None
        R0, p0 = np.asarray(self.R0, float), np.asarray(self.p0, float)
        if self.kind == PLANAR:
            q0 = np.asarray(self.q0, float)
            p[:2], theta = q0[:2], float(q0[2])
        elif d == 2:                      # a fixed 2D body: its pose in the plane z = 0
            R[:2, :2], p[:2] = R0[:2, :2], p0[:2]
        else:
            R, p = R0, p0
        if self.kind == FREE:
            jac = _I6
        elif self.kind == ARTICULATED:
            jac = np.asarray(self.jacobian, float)
            if jac.shape != (6, self.ndof):
                raise ValueError(f"an articulated body needs a 6 x {self.ndof} Jacobian, got {jac.shape}")
        bi = np.array([_KIND_CODE[self.kind], vcol, self.ndof, 0, int(self.kind == ARTICULATED)], np.int64)
        bf = np.zeros(rb.NBF)
        bf[rb.B_R0:rb.B_R0 + 9] = np.asarray(R, float).ravel()
        bf[rb.B_P0:rb.B_P0 + 3] = p
        bf[rb.B_THETA0] = theta
        bf[rb.B_H] = self.h
        return bi, bf, jac

    def pose(self, v) -> Pose:
        """The pose at l+1 for the velocities v (rows/bodies.py)."""
        bi, bf, jac = self.tables(0)
        k = self.ndof
        R = np.zeros((1, 3, 3))
        p, w, vo = np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3))
        T = np.zeros((1, 12, max(k, 1)))
        z = np.zeros(max(k, 1))
        z[:k] = np.asarray(v, float)[:k]
        flat = np.zeros(0) if jac is None else np.ascontiguousarray(jac).ravel()
        rb.body_states(bi[None, :], bf[None, :], flat, z, R, p, w, vo, T, np.zeros(12))
        d = self.dim
        return Pose(R[0, :d, :d].copy(), p[0, :d].copy(), w[0].copy())


def eval_functions(funcs, pose: Pose, a):
    """Values (m,) and world gradients (m, d) of body functions at the world point a."""
    xi = pose.R.T @ (np.asarray(a, float) - pose.p)
    f = np.empty(len(funcs))
    G = np.empty((len(funcs), len(a)))
    for i, fn in enumerate(funcs):
        f[i], g = fn.value_gradient(xi)
        G[i] = pose.R @ g
    return f, G


# ---------------------------------------------------------------------------------------------
# the step problem
# ---------------------------------------------------------------------------------------------
def _function_rows(fn) -> np.ndarray:
    try:
        return fn.kernel_params
    except AttributeError:
        raise ValueError(f"{type(fn).__name__} is not one of implicit_contact.shapes' functions: the "
                         "step's compiled rows evaluate Sphere, Ellipsoid, Superquadric, HalfSpace, "
                         "InfiniteCylinder and their 2D forms (and intersections and unions of them)") from None


@dataclass
class _Tables:
    """The flat tables of one step problem (rows/*.py name their columns)."""
    body_i: np.ndarray
    body_f: np.ndarray
    body_jac: np.ndarray
    fpar: np.ndarray
    sk_i: np.ndarray
    sk_M: np.ndarray
    v0: np.ndarray
    hforce: np.ndarray
    pair_i: np.ndarray
    pair_f: np.ndarray
    sup_i: np.ndarray
    sup_f: np.ndarray
    loc_idx: np.ndarray
    loc_off: np.ndarray
    scale: np.ndarray
    kmax: int
    lmax: int
    sup_body: np.ndarray       # support blocks: their body, centre of pressure (body frame), e_r, mu N
    sup_c: np.ndarray
    sup_er: np.ndarray
    sup_mun: np.ndarray
    body_dim: np.ndarray


class StepProblem:
    """F(z) and dF/dz of one geometrically implicit step, for ``ncp.solve_mcp``.

    ``fun`` evaluates the rows only; ``jac`` evaluates both and caches them for the last z, so
    F is bitwise the same either way (one kernel, rows/assemble.py). The pairs' spec.k1 and
    spec.tangent_axis are read at every evaluation (the stepper sets them after building the
    problem, from its warm start)."""

    def __init__(self, h: float, skeletons: list, bodies: list, specs: list, layout: Layout,
                 supports: tuple = (), jacobian: str = "auto", source=None):
        if jacobian not in ("auto", "dense", "sparse"):
            raise ValueError(f"jacobian must be 'auto', 'dense' or 'sparse', got {jacobian!r}")
        self._sparse = jacobian == "sparse" or (jacobian == "auto" and layout.n >= SPARSE_MIN_UNKNOWNS)
        if len(tuple(supports)) != len(layout.supports):
            raise ValueError("the layout's support blocks and the problem's supports differ")
        self.layout = layout
        self.lower, self.upper = layout.lower, layout.upper
        self.tables = self._build_structure(bodies, specs, tuple(supports), skeletons)
        self._pattern = None
        self._rep = np.zeros((len(specs), rc.NREP))
        t = self.tables
        nb = len(bodies)
        wsize = max([12] + [rc.workspace_size(int(p[rc.P_M1]), int(p[rc.P_M2]), int(p[rc.P_NBLK])) for p in t.pair_i])
        self._work = (np.zeros((nb, 3, 3)), np.zeros((nb, 3)), np.zeros((nb, 3)), np.zeros((nb, 3)),
                      np.zeros((nb, 12, t.kmax)), np.zeros(t.lmax), np.zeros((t.lmax, t.lmax)), np.zeros(wsize))
        self.refresh(h, skeletons, bodies, specs, supports, source)

    # -- the tables ---------------------------------------------------------------------------
    def _build_structure(self, bodies, specs, supports, skeletons) -> _Tables:
        """The tables' parts fixed by the layout: kinds, columns, functions, local indices."""
        layout = self.layout
        n = layout.n
        nb = len(bodies)
        body_i = np.zeros((nb, rb.NBI), np.int64)
        at = 0
        for b, kin in enumerate(bodies):
            vcol = int(kin.vindex[0]) if kin.vindex is not None and len(kin.vindex) else 0
            body_i[b] = [_KIND_CODE[kin.kind], vcol, kin.ndof, at, int(kin.kind == ARTICULATED)]
            if kin.kind in (FREE, ARTICULATED):
                at += 6 * kin.ndof
        body_jac = np.zeros(max(at, 1))
        for b, kin in enumerate(bodies):
            if kin.kind == FREE:
                body_jac[body_i[b, rb.B_JAC]:body_i[b, rb.B_JAC] + 36] = _I6.ravel()
        kmax = max([1] + [kin.ndof for kin in bodies])
        # functions: each contact object's functions contiguous
        rows, offsets = [], {}

        def functions_of(obj):
            key = id(obj.functions)
            at = offsets.get(key)
            if at is None:
                at = offsets[key] = (len(rows), len(obj.functions))
                rows.extend(_function_rows(fn) for fn in obj.functions)
            return at

        pair_rows = []
        for spec, sl in zip(specs, layout.pairs):
            kin1, kin2 = bodies[spec.obj1.body], bodies[spec.obj2.body]
            if spec.obj1.body == spec.obj2.body and kin1.vindex is not None:
                raise ValueError("a pair needs two different bodies")
            f1, m1 = functions_of(spec.obj1)
            f2, m2 = functions_of(spec.obj2)
            c0 = int(sl.rows_geo[0])
            template = getattr(sl, "template", None)
            has_sigma, has_pr, block, s_rel = (_block_entries(sl, c0) if template is None else
                                               _block_entries(template, 0))
            pair_rows.append([spec.dim, spec.obj1.body, spec.obj2.body, f1, m1, f2, m2,
                              int(spec.obj1.fixed_halfspace), int(spec.obj2.fixed_halfspace), spec.k1,
                              has_sigma, has_pr, _layer_scheme(spec), spec.compliant_side, c0, *block,
                              kin1.ndof, kin2.ndof, int(spec.start_frame is not None), s_rel])
        pair_i = np.array(pair_rows, np.int64).reshape(len(specs), rc.NPI)
        fpar = np.array(rows) if rows else np.zeros((1, 25))
        sk_i = np.zeros((len(skeletons), rd.NKI), np.int64)
        off = 0
        for s, vidx in enumerate(layout.v_index):
            k = len(vidx)
            jidx = layout.joint_index[s]
            nj = len(jidx)
            if nj != (0 if skeletons[s].joints is None else len(skeletons[s].joints.c)):
                raise ValueError("the layout's joint rows and the skeleton's differ")
            sk_i[s] = [int(vidx[0]) if k else 0, k, off, int(jidx[0]) if nj else 0, nj]
            off += rd.table_size(k, nj)
        sup_i = np.zeros((len(supports), rs.NSI), np.int64)
        sup_body = np.zeros(len(supports), np.int64)
        sup_c, sup_er, sup_mun = np.zeros((len(supports), 2)), np.zeros(len(supports)), np.zeros(len(supports))
        for s, (sp, ss) in enumerate(zip(supports, layout.supports)):
            kin = bodies[sp.body]
            if kin.kind != PLANAR or kin.vindex is None:
                raise ValueError("support friction needs a moving planar body")
            sup_i[s] = [int(kin.vindex[0]), ss.y.start, 3 if sp.friction.torsion else 2, ss.sigma]
            sup_body[s] = sp.body
            sup_c[s], sup_er[s] = sp.friction.centre, sp.friction.e_r
            sup_mun[s] = sp.friction.mu * sp.friction.normal_force
        self._pos_rows = np.asarray(_position_rows(layout), np.int64)
        # plans' local indices: skeletons, pairs, supports
        locs = [np.concatenate([np.arange(sk_i[s, 0], sk_i[s, 0] + sk_i[s, 1]), layout.joint_index[s]]).astype(np.int64)
                for s in range(len(sk_i))]
        for k, spec in enumerate(specs):
            parts = [bodies[o.body].vindex for o in (spec.obj1, spec.obj2) if bodies[o.body].vindex is not None]
            parts.append(np.arange(pair_i[k, rc.P_C0], pair_i[k, rc.P_C0] + pair_i[k, rc.P_NBLK]))
            locs.append(np.concatenate(parts))
        for s in range(len(sup_i)):
            vcol, ycol, ny, _ = sup_i[s]
            locs.append(np.r_[np.arange(vcol, vcol + 3), np.arange(ycol, ycol + ny + 1)])
        loc_off = np.cumsum([0] + [len(x) for x in locs]).astype(np.int64)
        loc_idx = (np.concatenate(locs) if locs else np.zeros(0)).astype(np.int64)
        lmax = max([1] + [len(x) for x in locs])
        return _Tables(body_i, np.zeros((nb, rb.NBF)), body_jac, fpar, sk_i, np.zeros(max(off, 1)), np.zeros(n),
                       np.zeros(n), pair_i, np.zeros((len(specs), rc.NPF)), sup_i,
                       np.zeros((len(supports), rs.NSF)), loc_idx, loc_off, np.ones(n), kmax, lmax,
                       sup_body, sup_c, sup_er, sup_mun, np.array([kin.dim for kin in bodies], np.int64))

    def refresh(self, h, skeletons, bodies, specs, supports=(), source=None):
        """Fill the tables' values for a step at l on the structure built for this layout (the
        same bodies, skeletons and pairs, in order): body poses, Jacobians, mass matrices and
        forces by rows/tables.fill_state from ``source`` (the stepper's world buffers: src,
        R_src, p_src, th_src, J_src, J_at, h_body, sk_src, src_voff, src_moff, V_src, MB_src,
        FB_src), or, when source is None, from the bodies' and skeletons' own arrays; the pairs'
        parameters from their specs."""
        t = self.tables
        layout = self.layout
        if len(bodies) != len(t.body_i) or len(specs) != len(t.pair_i) or len(skeletons) != len(t.sk_i):
            raise ValueError("refresh needs the bodies, skeletons and pairs the problem was built for")
        self.h = h
        self.skeletons, self.bodies, self.specs = skeletons, bodies, specs
        # the pairs as this refresh saw them (the stepper's recoveries edit its spec list later)
        self.keys = tuple(spec.key for spec in specs)
        self.supports = tuple(supports)
        self._vslice = [_as_slice(b.vindex) if b.vindex is not None else None for b in bodies]
        if source is None:
            source = _source_of(bodies, skeletons)
        rt.fill_state(*source, h, t.body_dim, t.body_i, t.body_f, t.body_jac, t.sk_i, t.sk_M, t.v0, t.hforce,
                      t.scale, self._pos_rows, t.sup_body, t.sup_c, t.sup_er, t.sup_mun, t.sup_f)
        for s, block in enumerate(skeletons):
            if block.joints is not None:
                k, off = int(t.sk_i[s, rd.K_NV]), int(t.sk_i[s, rd.K_MOFF])
                jr = block.joints
                table = t.sk_M[off + k * k:off + rd.table_size(k, len(jr.c))].reshape(len(jr.c), k + 2)
                table[:, :k], table[:, k], table[:, k + 1] = jr.G, jr.c, jr.unit
        self._reduced = []
        for k, spec in enumerate(specs):
            r1 = _reduced_point(spec.obj1, bodies[spec.obj1.body]) if spec.obj1.fixed_halfspace else None
            r2 = _reduced_point(spec.obj2, bodies[spec.obj2.body]) if spec.obj2.fixed_halfspace else None
            self._reduced.append((r1, r2))
            pf = t.pair_f[k]
            d = spec.dim
            fr = spec.friction
            pf[rc.Q_SP], pf[rc.Q_MU], pf[rc.Q_ET], pf[rc.Q_EO], pf[rc.Q_ER] = (
                spec.impulse_scale, fr.mu, fr.e_t, fr.e_o, fr.e_r)
            for red, a0_at, T_at in ((r1, rc.Q_A01, rc.Q_T1), (r2, rc.Q_A02, rc.Q_T2)):
                T = np.zeros((3, 3))
                pf[a0_at:a0_at + 3] = 0.0
                if red is None:
                    T[:d, :d] = _EYE[d]
                else:
                    pf[a0_at:a0_at + d] = red[0]
                    T[:d, :d - 1] = red[1]
                pf[T_at:T_at + 9] = T.ravel()
            comp = spec.compliance
            if comp is not None:
                pf[rc.Q_K], pf[rc.Q_C], pf[rc.Q_DMAX] = comp.k_n, spec.layer_share * comp.c_n, comp.delta_max
                pf[rc.Q_DPREV] = spec.delta_prev
            pf[rc.Q_H] = spec.layer_share * h         # (eq 49's h and c: a share of the step's layer impulse)
            split = spec.start_frame is not None
            t.pair_i[k, rc.P_SPLIT] = int(split)
            pf[rc.Q_N0:rc.NPF] = spec.start_frame if split else 0.0
        self._synced = [(None, None)] * len(specs)
        self._invalidate()

    def fill(self, h, source):
        """refresh's state part alone (rows/tables.fill_state from the world buffers), for a step
        whose pairs' parameters are already in the tables (the stepper's _repeat_step)."""
        t = self.tables
        self.h = h
        rt.fill_state(*source, h, t.body_dim, t.body_i, t.body_f, t.body_jac, t.sk_i, t.sk_M, t.v0, t.hforce,
                      t.scale, self._pos_rows, t.sup_body, t.sup_c, t.sup_er, t.sup_mun, t.sup_f)
        self._invalidate()

    @property
    def bundle(self):
        """The tables, bounds, reports and evaluation workspace as one bundles.Tables."""
        b = self.__dict__.get("_bundle")
        if b is None:
            t = self.tables
            R, p, w, vo, T, FL, JL, ws = self._work
            fields = {name: getattr(t, name) for name in bundles.TABLE_FIELDS if hasattr(t, name)}
            fields.update(pos_rows=self._pos_rows, lower=self.lower, upper=self.upper, rep=self._rep, st_R=R,
                          st_p=p, st_w=w, st_vo=vo, st_T=T, FL=FL, JL=JL, ws=ws)
            b = self.__dict__["_bundle"] = bundles.tables(**fields)
        return b

    def _invalidate(self):
        """Forget every evaluation (the tables changed)."""
        self._key_f = self._key_j = None
        self._F = self._J = None
        self._rep_at = None
        self._reports_np = None
        if self._pattern is not None:
            self._pattern = self._pattern[:4] + (self.tables.scale[self._pattern_rows],)

    def _sync(self):
        """Copy the pairs' k1 and tangent axis into the tables (the stepper may set them late)."""
        t = self.tables
        for k, spec in enumerate(self.specs):
            k1, axis = spec.k1, spec.tangent_axis
            if self._synced[k][0] is k1 and self._synced[k][1] is axis:
                continue
            if not 0 <= k1 < len(spec.obj1.functions):
                raise ValueError(f"k1 = {k1} is not a function of body 1 ({len(spec.obj1.functions)})")
            t.pair_i[k, rc.P_K1] = k1
            if spec.dim == 3 and axis is not None:
                t.pair_f[k, rc.Q_AXIS:rc.Q_AXIS + 3] = axis
            self._synced[k] = (k1, axis)
            self._key_f = self._key_j = None

    def _sparse_pattern(self):
        """The CSR pattern of every plan's local block (fixed while the layout is): (slots: the data
        position of each local entry, slot offsets per plan, indices, indptr, the row scale of
        each stored entry); rows/assemble.sparse_pattern."""
        t = self.tables
        n = self.layout.n
        sizes = np.diff(t.loc_off)
        slot_off = np.zeros(len(sizes) + 1, np.int64)
        np.cumsum(sizes * sizes, out=slot_off[1:])
        slots, indices = np.empty(slot_off[-1], np.int64), np.empty(slot_off[-1], np.int64)
        indptr = np.empty(n + 1, np.int64)
        nnz = sparse_pattern(n, t.loc_idx, t.loc_off, slot_off, slots, indptr, indices)
        entry_rows = np.repeat(np.arange(n, dtype=np.int64), np.diff(indptr))
        self._pattern_rows = entry_rows
        # (scipy keeps a CSR matrix's indices in int32 when they fit, and checks their range on
        # every construction unless they already are: 40 -> 18 us a Jacobian at 700 unknowns)
        index = np.int32 if max(n, nnz) < np.iinfo(np.int32).max else np.int64
        self._pattern = (slots, slot_off, indices[:nnz].astype(index), indptr.astype(index), t.scale[entry_rows])
        # each Jacobian is a shallow copy of this matrix with its own data: scipy's constructor
        # checks the arrays every time (~20 us bare, 98 us a Jacobian in the 27-superquadric
        # steps, 5 % of them); the copies share indices and indptr, which nothing writes
        self._csr_template = _sparse.csr_matrix((np.zeros(nnz), self._pattern[2], self._pattern[3]), shape=(n, n))
        return self._pattern

    # -- unknown vector helpers ---------------------------------------------------------------
    def body_velocity(self, z, body_index):
        sl = self._vslice[body_index]
        return z[sl] if sl is not None else _EMPTY

    def end_poses(self, z, spec) -> list:
        """[Pose of body 1, Pose of body 2] of a pair spec at the end of the step z implies."""
        return [self.bodies[o.body].pose(self.body_velocity(z, o.body)) for o in (spec.obj1, spec.obj2)]

    def points(self, z, k):
        """World closest points a1, a2 of pair k and their Jacobians wrt their unknowns."""
        sl = self.layout.pairs[k]
        r1, r2 = self._reduced[k]
        d = self.specs[k].dim
        if r1 is None:
            a1, T1 = z[sl.a1s], _EYE[d]
        else:
            a1, T1 = r1[0] + r1[1] @ z[sl.a1s], r1[1]
        if r2 is None:
            a2, T2 = z[sl.a2s], _EYE[d]
        else:
            a2, T2 = r2[0] + r2[1] @ z[sl.a2s], r2[1]
        return a1, T1, a2, T2

    def pack_points(self, z, k, a1, a2):
        sl = self.layout.pairs[k]
        r1, r2 = self._reduced[k]
        z[sl.a1s] = a1 if r1 is None else r1[1].T @ (a1 - r1[0])
        z[sl.a2s] = a2 if r2 is None else r2[1].T @ (a2 - r2[0])

    # -- evaluation -----------------------------------------------------------------------------
    def fun(self, z):
        self._sync()
        return self.fun_synced(z)

    def jac(self, z):
        self._sync()
        return self.jac_synced(z)

    def fun_synced(self, z):
        """fun without reading the specs' k1 and tangent axes first: for a solver's iterations,
        after one _sync (a loop over the pairs, 15 us an evaluation at 50 pairs)."""
        if self._key_f is None or not np.array_equal(z, self._key_f):
            self._F, _ = self._evaluate(z, False)
            self._key_f = z.copy()
        return self._F

    def jac_synced(self, z):
        """jac after one _sync (fun_synced)."""
        if self._key_j is None or not np.array_equal(z, self._key_j):
            F, J = self._evaluate(z, True)
            self._F, self._key_f = F, z.copy()
            self._J, self._key_j = J, z.copy()
        return self._J

    def _assemble(self, z, need_jac):
        """(F, J or None, per pair (a1, a2, normal, tangents, gap, v_rel) as arrays), uncached."""
        self._sync()
        F, J = self._evaluate(np.asarray(z, float), need_jac)
        return F, J, self._pairs_at

    def _evaluate(self, z, need_jac):
        t = self.tables
        n = self.layout.n
        z = np.ascontiguousarray(z, dtype=float)
        F = np.empty(n)
        sparse = bool(need_jac and self._sparse)
        if sparse:
            slots, slot_off, indices, indptr, dscale = self._pattern or self._sparse_pattern()
            data = np.empty(len(indices))
            J = _EMPTY2
        else:
            slots, slot_off, dscale, data = _EMPTY_I, np.zeros(len(t.loc_off), np.int64), _EMPTY, _EMPTY
            J = np.empty((n, n)) if need_jac else _EMPTY2
        R, p, w, vo, T, FL, JL, ws = self._work
        assemble(t.body_i, t.body_f, t.body_jac, t.fpar, t.sk_i, t.sk_M, t.v0, t.hforce, t.pair_i, t.pair_f,
                 t.sup_i, t.sup_f, t.loc_idx, t.loc_off, slots, slot_off, t.scale, dscale, z, F, J, data,
                 self._rep, R, p, w, vo, T, FL, JL, ws, need_jac, sparse)
        self._rep_at, self._reports_np = z.copy(), None
        if not need_jac:
            return F, None
        if sparse:
            J = copy.copy(self._csr_template)
            J.data = data
            return F, J
        return F, J

    @property
    def _pairs_at(self):
        """Per pair (a1, a2, normal, tangents, gap, v_rel) at the last evaluated z, as arrays."""
        if self._reports_np is None:
            out = []
            for k, spec in enumerate(self.specs):
                d, r = spec.dim, self._rep[k]
                tang = np.array([r[rc.R_T:rc.R_T + d], r[rc.R_O:rc.R_O + d]][: d - 1])
                out.append((r[rc.R_A1:rc.R_A1 + d].copy(), r[rc.R_A2:rc.R_A2 + d].copy(),
                            r[rc.R_N:rc.R_N + d].copy(), tang, float(r[rc.R_GAP]),
                            r[rc.R_VREL:rc.R_VREL + d].copy()))
            self._reports_np = out
        return self._reports_np

    def _evaluated_at(self, z):
        if self._rep_at is None or (z is not self._rep_at and not np.array_equal(z, self._rep_at)):
            self._sync()
            self._evaluate(z, False)

    # -- reading the solution --------------------------------------------------------------------
    def unpack_pair(self, z, k) -> PairState:
        spec, sl = self.specs[k], self.layout.pairs[k]
        self._evaluated_at(z)
        a1, a2, nhat, tang, gap, _ = self._pairs_at[k]
        s_p = spec.impulse_scale
        p_t = s_p * z[sl.p_ts] if sl.sigma >= 0 else np.zeros(spec.dim - 1)   # the rows the layout has
        p_r = s_p * spec.friction.e_r * z[sl.p_r] if sl.p_r >= 0 else 0.0
        sigma = z[sl.sigma] if sl.sigma >= 0 else 0.0
        return PairState(a1, a2, z[sl.l1s].copy(), z[sl.l2s].copy(), s_p * z[sl.p_n], p_t, p_r, sigma,
                         nhat, tang, gap)

    def relative_velocity(self, z, k):
        """v_2(a2) - v_1(a1) of pair k at l+1 (world frame)."""
        self._evaluated_at(z)
        return self._pairs_at[k][5].copy()

    def checks(self, z, tol, solver_tol, touch) -> np.ndarray:
        """Per pair the flags of rows/checks.solution_checks at z (friction rows to switch, a body
        through a half-space, a penetrating gap, friction outside its cone)."""
        self._evaluated_at(z)
        flags = np.zeros(len(self.specs), np.int64)
        t = self.tables
        rk.solution_checks(t.pair_i, t.pair_f, np.ascontiguousarray(z, dtype=float), self._rep, tol, solver_tol,
                           touch, flags)
        return flags

    def support_wrench(self, z, s) -> np.ndarray:
        """(p_x, p_y, tau about the body origin) of support block s's friction impulse."""
        t = self.tables
        vcol, ycol, ny, _ = t.sup_i[s]
        E = t.sup_f[s, rs.S_E:rs.S_E + 9].reshape(3, 3)[:ny]
        return t.sup_f[s, rs.S_SCALE] * (E.T @ z[ycol:ycol + ny])


def _block_entries(sl, c0):
    """The pair_i entries of a pair's block that its kind fixes, relative to its first column c0:
    (has sigma, has p_r, [block length, a1, len a1, a2, len a2, l1, l2, p_n, p_t, p_r, sigma, dbar,
    dn, p_nr], s), -1 for an unknown the block lacks. Kept on a build_layout template (c0 = 0),
    whose moved copies (layout.PairSlots.moved) read them from it."""
    kept = sl.__dict__.get("_block_entries") if c0 == 0 else None
    if kept is not None:
        return kept
    p_n, p_r, sigma, dbar, dn, p_nr, s_col = (int(sl.p_n), int(sl.p_r), int(sl.sigma), int(sl.dbar), int(sl.dn),
                                              int(sl.p_nr), int(sl.s))
    end = max(p_n, sigma, p_r, dbar, dn, p_nr) + 1
    block = (end - c0, int(sl.a1[0]) - c0, len(sl.a1), int(sl.a2[0]) - c0, len(sl.a2), int(sl.l1[0]) - c0,
             int(sl.l2[0]) - c0, p_n - c0, int(sl.p_t[0]) - c0 if len(sl.p_t) else -1,
             p_r - c0 if p_r >= 0 else -1, sigma - c0 if sigma >= 0 else -1, dbar - c0 if dbar >= 0 else -1,
             dn - c0 if dn >= 0 else -1, p_nr - c0 if p_nr >= 0 else -1)
    out = (int(sigma >= 0), int(p_r >= 0), block, s_col - c0 if s_col >= 0 else -1)
    if c0 == 0:
        sl.__dict__["_block_entries"] = out
    return out


def _source_of(bodies, skeletons):
    """rows/tables.fill_state's source arrays made from BodyKinematics and SkeletonBlocks."""
    nb = len(bodies)
    R, p, th = np.zeros((nb, 3, 3)), np.zeros((nb, 3)), np.zeros(nb)
    J_at = np.zeros(nb, np.int64)
    jacs, at = [], 0
    h_body = np.zeros(nb)
    for b, kin in enumerate(bodies):
        R[b] = np.asarray(kin.R0, float)
        if kin.kind == PLANAR:
            q0 = np.asarray(kin.q0, float)
            p[b, :2], th[b] = q0[:2], q0[2]
        else:
            p[b] = np.asarray(kin.p0, float)
        h_body[b] = kin.h
        if kin.kind == ARTICULATED:
            jac = np.asarray(kin.jacobian, float)
            if jac.shape != (6, kin.ndof):
                raise ValueError(f"an articulated body needs a 6 x {kin.ndof} Jacobian, got {jac.shape}")
            J_at[b] = at
            jacs.append(jac.ravel())
            at += jac.size
    J = np.concatenate(jacs) if jacs else np.zeros(1)
    ks = [len(np.asarray(sk.v)) for sk in skeletons]
    voff = np.cumsum([0] + ks)[:-1].astype(np.int64)
    moff = np.cumsum([0] + [k * k for k in ks])[:-1].astype(np.int64)
    V = np.concatenate([np.asarray(sk.v, float) for sk in skeletons]) if skeletons else np.zeros(1)
    MB = np.concatenate([np.asarray(sk.M, float).ravel() for sk in skeletons]) if skeletons else np.zeros(1)
    FB = np.concatenate([np.asarray(sk.force, float) for sk in skeletons]) if skeletons else np.zeros(1)
    return (np.arange(nb, dtype=np.int64), R, p, th, J, J_at, h_body, np.arange(len(skeletons), dtype=np.int64),
            voff, moff, V, MB, FB)


_EMPTY = np.zeros(0)
_EMPTY_I = np.zeros(0, np.int64)
_EMPTY2 = np.zeros((0, 0))
_EYE = {2: np.eye(2), 3: np.eye(3)}


def _layer_scheme(spec) -> int:
    """rows/contact.py's form of eq (49) for a pair: rigid, [GI]'s as printed, or the midpoint
    rule (Compliance.scheme = "midpoint", and order 2's first stage: rattle.py, eq R11)."""
    comp = spec.compliance
    if comp is None:
        return rc.RIGID
    return rc.MIDPOINT if (comp.scheme == "midpoint" or spec.layer_share != 1.0) else rc.PAPER
