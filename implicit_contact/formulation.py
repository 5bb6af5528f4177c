r"""One time step of [GI] as a mixed complementarity problem: unknowns, rows, Jacobian.

Paper symbols in ASCII (Drake SAP style)::

    paper     code        meaning                                                      eqs
    v^{l+1}   v           generalized velocities at the end of the step                (6), (21)
    a1, a2    a1, a2      closest points on body 1 / body 2, world frame               (15)-(16), (28)-(29)
    l1, l2    l1, l2      scaled KKT multipliers, one per function of each body        (17)-(18), (30)-(31)
    p_n       p_n         normal impulse, 0 <= p_n  _|_  max_i f_i(a2) >= 0            (19), (32)
    p_t,p_o   p_t         friction impulses along the tangents t, o                    (7), (21)
    p_r       p_r         torsional moment impulse about the normal                    (7), (21)
    sigma     sigma       slip-speed multiplier of the friction ellipsoid             (7), (22)

Geometric implicitness. A moving body's pose at l+1 is a function of its velocity unknowns,
q^{l+1} = q^l (+) h v^{l+1} ([GI] eq 21, second line), written exactly as DART integrates:

* FreeJoint (dartpy 6.20, v = [omega; v_o] in the world frame): R+ = exp(h [omega]x) R,
  p+ = p + h v_o. A perturbation of v moves the pose by the world-frame twist
  dtheta = h J_l(h omega) d omega, dp = h d v_o (J_l: left Jacobian of SO(3)).
* PlanarJoint in XY (v = [v_x, v_y, omega]): theta+ = theta + h omega, p+ = p + h [v_x, v_y].

A body function f is written in body coordinates, so at a world point a it is evaluated as
f(xi), xi = R^T (a - p). With G = R grad f(xi) (world gradient) and Hw = R H R^T, and r = a - p:

    df/da = G,                    df/dv = -(r x G) . B_theta - G . B_p
    dG/da = Hw,                   dG/dv = -[G]x B_theta + Hw [r]x B_theta - Hw B_p

(in 2D ``x`` is the scalar cross product and [.]x the 90-degree rotation; see ``_X`` below).

Rows of one pair (body 1 has functions f_i, i = 1..m, with the known active one k1; body 2 has
g_j), with N1 = grad f_k1(a1) + sum_{i != k1} l_i grad f_i(a1) the body-1 normal:

    a1 - a2 + l_k1 N1 = 0                 (15) / (28)     d rows, paired with free unknowns
    N1 + sum_j l_j grad g_j(a2) = 0       (16) / (29)     d rows
    0 <= l_i  _|_  -f_i(a1) >= 0          (17) / (30)
    0 <= l_j  _|_  -g_j(a2) >= 0          (18) / (31)
    0 <= p_n  _|_  max_i f_i(a2) >= 0     (19) / (32)
    e_t^2 mu p_n (t . v_rel) + p_t sigma = 0                     (21), friction, if mu > 0
    e_o^2 mu p_n (o . v_rel) + p_o sigma = 0                     3D only
    e_r   mu p_n (n . w_rel) + p~_r sigma = 0, p_r = e_r p~_r    3D, if e_r > 0
    0 <= sigma  _|_  mu^2 p_n^2 - p_t^2/e_t^2 - p_o^2/e_o^2 - p~_r^2 >= 0        (22)

v_rel = v_2(a2) - v_1(a1) is the velocity of body 2's material point relative to body 1's and
w_rel the relative angular velocity, both at l+1. The impulse on body 2 is
P = p_n n + p_t t + p_o o at a2 with moment p_r n, and minus that on body 1 at a1; n = N1/|N1|
points from body 1 into body 2. The tangents come from Gram-Schmidt on a fixed axis e of the
pair, t = (e - (e.n) n)/|...|, o = n x t, so they move smoothly with n.

A fixed half-space g = n.x - d as body 2 (the ground) fixes one coordinate of a2: a2 = a0 + T s
with s in R^{d-1}, and its multiplier pair 0 <= l2 _|_ -g(a2) becomes trivial, so l2 is free
(the paper's Example 1 drops a2y the same way). A fixed half-space as body 1 (the ground under a
box) fixes a1 the same way and frees l1.

Scaling. Impulses are unknowns in units of s_p = h m g_ref (a pair's weight impulse), the
Newton-Euler rows are divided by diag(M) (so they read as velocities), and the friction rows by
s_p: a natural-residual tolerance then means about the same on every row.

Dynamics rows of a skeleton ([GI] eq 21, first line, with DART's M, bias and applied forces at l):

    (M (v+ - v) - h (tau + tau_ext - c(q, v)) - sum_contacts J^T P) / diag(M) = 0
"""
from __future__ import annotations

from dataclasses import dataclass, field
import math

import numpy as np

from . import shapes as shp
from .params import Friction

FREE, PLANAR, FIXED = "free", "planar", "fixed"


# ---------------------------------------------------------------------------------------------
# small geometry helpers, 2D and 3D alike
# ---------------------------------------------------------------------------------------------
def _skew(x):
    return np.array([[0.0, -x[2], x[1]], [x[2], 0.0, -x[0]], [-x[1], x[0], 0.0]])


def _X(x):
    """Matrix of dtheta -> dtheta (x) x: 3D -[x]x (3x3); 2D the rotated x as a 2x1 column."""
    if x.shape[0] == 3:
        return -_skew(x)
    return np.array([[-x[1]], [x[0]]])


def _W(w):
    """Matrix of dr -> omega (x) dr: 3D [omega]x; 2D omega times the 90-degree rotation."""
    if w.shape[0] == 3:
        return _skew(w)
    return w[0] * np.array([[0.0, -1.0], [1.0, 0.0]])


def so3_exp(phi):
    th = math.sqrt(float(phi @ phi))
    K = _skew(phi)
    if th < 1e-6:
        return np.eye(3) + K + 0.5 * (K @ K)
    return np.eye(3) + (math.sin(th) / th) * K + ((1.0 - math.cos(th)) / th**2) * (K @ K)


def so3_left_jacobian(phi):
    th = math.sqrt(float(phi @ phi))
    K = _skew(phi)
    if th < 1e-6:
        return np.eye(3) + 0.5 * K + (1.0 / 6.0) * (K @ K)
    return (np.eye(3) + ((1.0 - math.cos(th)) / th**2) * K
            + ((th - math.sin(th)) / th**3) * (K @ K))


# ---------------------------------------------------------------------------------------------
# bodies at l+1 as functions of their velocity unknowns
# ---------------------------------------------------------------------------------------------
@dataclass
class Pose:
    """A body's pose at l+1 in the pair's dimension d, and how it moves with v.

    R (d,d), p (d,); B_th (dth,k), B_p (d,k): dtheta = B_th dv, dp = B_p dv (world frame);
    A_w (dth,k), A_v (d,k): omega = A_w v, velocity of the origin = A_v v. dth = 3 (3D) or 1 (2D).
    Fixed bodies have k = 0.
    """
    R: np.ndarray
    p: np.ndarray
    B_th: np.ndarray
    B_p: np.ndarray
    A_w: np.ndarray
    A_v: np.ndarray
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

    @property
    def ndof(self) -> int:
        return 0 if self.vindex is None else len(self.vindex)

    def pose(self, v) -> Pose:
        h, d = self.h, self.dim
        if self.kind == FIXED:
            R = self.R0[:d, :d]
            z = np.zeros((1 if d == 2 else 3, 0))
            return Pose(R, self.p0[:d], z, np.zeros((d, 0)), z, np.zeros((d, 0)),
                        np.zeros(1 if d == 2 else 3))
        if self.kind == FREE:
            w, vo = v[:3], v[3:]
            R = so3_exp(h * w) @ self.R0
            p = self.p0 + h * vo
            B_th = np.zeros((3, 6))
            B_th[:, :3] = h * so3_left_jacobian(h * w)
            B_p = np.zeros((3, 6))
            B_p[:, 3:] = h * np.eye(3)
            return Pose(R, p, B_th, B_p, _A_W_FREE, _A_V_FREE, w.copy())
        # planar, XY
        th = self.q0[2] + h * v[2]
        c, s = math.cos(th), math.sin(th)
        R = np.array([[c, -s], [s, c]])
        p = self.q0[:2] + h * v[:2]
        return Pose(R, p, h * _A_W_PLANAR, h * _A_V_PLANAR, _A_W_PLANAR, _A_V_PLANAR, v[2:3].copy())


_A_W_FREE = np.hstack([np.eye(3), np.zeros((3, 3))])
_A_V_FREE = np.hstack([np.zeros((3, 3)), np.eye(3)])
_A_W_PLANAR = np.array([[0.0, 0.0, 1.0]])
_A_V_PLANAR = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def _eval_functions(funcs, pose: Pose, a):
    """Values, world gradients, world Hessians, and their v-derivatives of body functions at a.

    Returns f (m,), G (m,d), Hw (m,d,d), dfdv (m,k), dGdv (m,d,k)."""
    R, r = pose.R, a - pose.p
    xi = R.T @ r
    m, d, k = len(funcs), len(a), pose.B_th.shape[1]
    f = np.empty(m)
    G = np.empty((m, d))
    Hw = np.empty((m, d, d))
    for i, fn in enumerate(funcs):
        f[i], g, H = fn.value_gradient_hessian(xi)
        G[i] = R @ g
        Hw[i] = R @ H @ R.T
    if k == 0:
        return f, G, Hw, np.zeros((m, 0)), np.zeros((m, d, 0))
    Xr = _X(r)
    # dtheta (x) r = Xr dtheta, so df = -G.(Xr dth + dp)
    move = Xr @ pose.B_th + pose.B_p                      # d x k: material displacement of a
    dfdv = -G @ move
    dGdv = np.empty((m, d, k))
    for i in range(m):
        # dG = dtheta (x) G - Hw (dtheta (x) r + dp)
        dGdv[i] = _X(G[i]) @ pose.B_th - Hw[i] @ move
    return f, G, Hw, dfdv, dGdv


# ---------------------------------------------------------------------------------------------
# pairs
# ---------------------------------------------------------------------------------------------
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
    k1: int = 0
    tangent_axis: np.ndarray | None = None
    impulse_scale: float = 1.0
    objects: tuple = ()        # the stepper's own records of the two pieces, for reports


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


@dataclass
class Layout:
    """Packs and unpacks the unknown vector z of one step; no other code does index arithmetic."""
    n: int
    v_index: list              # per skeleton: column indices of its velocities
    pairs: list                # PairSlots per pair
    lower: np.ndarray
    upper: np.ndarray


def _reduced_point(obj: ContactObject, kin: "BodyKinematics"):
    """For a fixed half-space: a = a0 + T s (a0 on the plane, T orthonormal tangents), world frame."""
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


def _least_aligned_axis(n):
    e = np.zeros(len(n))
    e[int(np.argmin(np.abs(n)))] = 1.0
    return e


def _tangent_basis(n, e):
    u = e - (e @ n) * n
    t = u / np.linalg.norm(u)
    return np.array([n, t, np.cross(n, t)])


def build_layout(nv_per_skeleton: list, specs: list) -> Layout:
    """Allocate z: velocities first, then each pair's unknowns; rows follow the same order."""
    lower, upper = [], []
    col = 0
    v_index = []
    for nv in nv_per_skeleton:
        v_index.append(np.arange(col, col + nv))
        lower += [-np.inf] * nv
        upper += [np.inf] * nv
        col += nv
    slots = []
    for spec in specs:
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
        slots.append(PairSlots(a1, a2, l1, l2, p_n, p_t, p_r, sigma, rows_geo, rows_l1, rows_l2,
                               p_n, rows_fric))
    return Layout(col, v_index, slots, np.array(lower), np.array(upper))


# ---------------------------------------------------------------------------------------------
# the step problem
# ---------------------------------------------------------------------------------------------
@dataclass
class SkeletonBlock:
    """Newton-Euler data of one skeleton at l: M v+ = M v + h force + sum J^T P."""
    M: np.ndarray
    v: np.ndarray
    force: np.ndarray
    body: int                  # its contact body in StepProblem.bodies


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


class StepProblem:
    """F(z) and dF/dz of one geometrically implicit step, for ``ncp.solve_mcp``."""

    def __init__(self, h: float, skeletons: list, bodies: list, specs: list, layout: Layout):
        self.h = h
        self.skeletons = skeletons
        self.bodies = bodies
        self.specs = specs
        self.layout = layout
        self.lower, self.upper = layout.lower, layout.upper
        self._row_scale = [1.0 / np.maximum(np.diag(sk.M), 1e-300) for sk in skeletons]
        self._reduced = []
        for spec in specs:
            r1 = _reduced_point(spec.obj1, bodies[spec.obj1.body]) if spec.obj1.fixed_halfspace else None
            r2 = _reduced_point(spec.obj2, bodies[spec.obj2.body]) if spec.obj2.fixed_halfspace else None
            self._reduced.append((r1, r2))
        self._cache_x = None
        self._cache = None

    # -- unknown vector helpers ---------------------------------------------------------------
    def body_velocity(self, z, body_index):
        kin = self.bodies[body_index]
        return z[kin.vindex] if kin.vindex is not None else np.zeros(0)

    def points(self, z, k):
        """World closest points a1, a2 of pair k and their Jacobians wrt their unknowns."""
        sl = self.layout.pairs[k]
        r1, r2 = self._reduced[k]
        d = self.specs[k].dim
        if r1 is None:
            a1, T1 = z[sl.a1], np.eye(d)
        else:
            a1, T1 = r1[0] + r1[1] @ z[sl.a1], r1[1]
        if r2 is None:
            a2, T2 = z[sl.a2], np.eye(d)
        else:
            a2, T2 = r2[0] + r2[1] @ z[sl.a2], r2[1]
        return a1, T1, a2, T2

    def pack_points(self, z, k, a1, a2):
        sl = self.layout.pairs[k]
        r1, r2 = self._reduced[k]
        z[sl.a1] = a1 if r1 is None else r1[1].T @ (a1 - r1[0])
        z[sl.a2] = a2 if r2 is None else r2[1].T @ (a2 - r2[0])

    # -- evaluation -----------------------------------------------------------------------------
    def fun(self, z):
        return self._evaluate(z)[0]

    def jac(self, z):
        return self._evaluate(z)[1]

    def _evaluate(self, z):
        if self._cache_x is not None and np.array_equal(z, self._cache_x):
            return self._cache
        F, J = self._assemble(z)
        self._cache_x = z.copy()
        self._cache = (F, J)
        return F, J

    def _assemble(self, z):
        lay = self.layout
        n = lay.n
        F = np.zeros(n)
        J = np.zeros((n, n))
        poses = [kin.pose(self.body_velocity(z, b)) for b, kin in enumerate(self.bodies)]
        # Newton-Euler rows, before contact impulses: M (v+ - v) - h force
        gen = []  # per skeleton: accumulated generalized contact impulse, and its Jacobian rows
        for s, sk in enumerate(self.skeletons):
            idx = lay.v_index[s]
            F[idx] = sk.M @ (z[idx] - sk.v) - self.h * sk.force
            J[np.ix_(idx, idx)] = sk.M
        body_to_skel = {sk.body: s for s, sk in enumerate(self.skeletons)}
        for k, spec in enumerate(self.specs):
            self._pair(z, k, spec, poses, body_to_skel, F, J)
        for s in range(len(self.skeletons)):
            idx = lay.v_index[s]
            F[idx] *= self._row_scale[s]
            J[idx, :] *= self._row_scale[s][:, None]
        return F, J

    def _pair(self, z, k, spec, poses, body_to_skel, F, J):
        sl = self.layout.pairs[k]
        d = spec.dim
        b1, b2 = spec.obj1.body, spec.obj2.body
        P1, P2 = poses[b1], poses[b2]
        v1i = self.bodies[b1].vindex
        v2i = self.bodies[b2].vindex
        a1, T1, a2, T2 = self.points(z, k)
        f1 = spec.obj1.functions
        g2 = spec.obj2.functions
        m1 = len(f1)
        # body-1 functions at a1 and at a2, body-2 functions at a2
        fa1, Ga1, Ha1, dfa1, dGa1 = _eval_functions(f1, P1, a1)
        fa2, Ga2, _, dfa2, _ = _eval_functions(f1, P1, a2)
        gb2, Gb2, Hb2, dgb2, dGb2 = _eval_functions(g2, P2, a2)
        l1 = z[sl.l1]
        l2 = z[sl.l2]
        k1 = spec.k1
        c = l1.copy()
        c[k1] = 1.0                     # N1 = sum_i c_i G_i with c_k1 = 1
        N1 = c @ Ga1
        dN1_da1 = np.tensordot(c, Ha1, axes=1)           # d x d
        dN1_dv1 = np.tensordot(c, dGa1, axes=1)          # d x k1
        rg = sl.rows_geo
        r15, r16 = rg[:d], rg[d:]
        lk = l1[k1]
        # (15)/(28): a1 - a2 + l_k1 N1
        F[r15] = a1 - a2 + lk * N1
        J[np.ix_(r15, sl.a1)] = (np.eye(d) + lk * dN1_da1) @ T1
        J[np.ix_(r15, sl.a2)] = -T2
        J[r15, sl.l1[k1]] = N1
        for i in range(m1):
            if i != k1:
                J[r15, sl.l1[i]] = lk * Ga1[i]
        if v1i is not None:
            J[np.ix_(r15, v1i)] = lk * dN1_dv1
        # (16)/(29): N1 + sum_j l_j G2_j
        F[r16] = N1 + l2 @ Gb2
        J[np.ix_(r16, sl.a1)] = dN1_da1 @ T1
        J[np.ix_(r16, sl.a2)] = np.tensordot(l2, Hb2, axes=1) @ T2
        for i in range(m1):
            if i != k1:
                J[r16, sl.l1[i]] = Ga1[i]
        J[np.ix_(r16, sl.l2)] = Gb2.T
        if v1i is not None:
            J[np.ix_(r16, v1i)] = dN1_dv1
        if v2i is not None:
            J[np.ix_(r16, v2i)] = np.tensordot(l2, dGb2, axes=1)
        # (17)/(30) and (18)/(31)
        for i, row in enumerate(sl.rows_l1):
            F[row] = -fa1[i]
            J[row, sl.a1] = -Ga1[i] @ T1
            if v1i is not None:
                J[row, v1i] = -dfa1[i]
        for j, row in enumerate(sl.rows_l2):
            F[row] = -gb2[j]
            J[row, sl.a2] = -Gb2[j] @ T2
            if v2i is not None:
                J[row, v2i] = -dgb2[j]
        # (19)/(32): gap = max_i f_i(a2)
        ia = int(np.argmax(fa2))
        F[sl.row_n] = fa2[ia]
        J[sl.row_n, sl.a2] = Ga2[ia] @ T2
        if v1i is not None:
            J[sl.row_n, v1i] = dfa2[ia]
        # contact frame
        nrm = math.sqrt(float(N1 @ N1))
        nhat = N1 / nrm
        Pn = (np.eye(d) - np.outer(nhat, nhat)) / nrm        # dn = Pn dN1
        # dN1 wrt every unknown it depends on: a1 (through T1), l1 (i != k1), v1
        dN1 = {"a1": dN1_da1 @ T1, "v1": dN1_dv1}
        tang, dtang = _tangents(nhat, Pn, spec.tangent_axis)
        s_p = spec.impulse_scale
        p_n = z[sl.p_n]
        fr = spec.with_friction
        p_t = z[sl.p_t] if fr else np.zeros(0)
        p_r = z[sl.p_r] if sl.p_r >= 0 else 0.0
        e_r = spec.friction.e_r
        # impulse on body 2 (world), in physical units
        Pvec = s_p * (p_n * nhat + (p_t @ tang if fr else 0.0))
        tau = s_p * e_r * p_r * nhat if (d == 3 and sl.p_r >= 0) else None
        # derivative of Pvec wrt nhat (through n and tangents)
        dP_dn = s_p * p_n * np.eye(d)
        if fr:
            for a in range(d - 1):
                dP_dn = dP_dn + s_p * p_t[a] * dtang[a]
        dtau_dn = s_p * e_r * p_r * np.eye(d) if tau is not None else None
        # distribute onto the two bodies: body 2 gets +P at a2, body 1 gets -P at a1
        for side, (b, Pz, a, T, aidx) in enumerate(((b2, P2, a2, T2, sl.a2), (b1, P1, a1, T1, sl.a1))):
            vi = self.bodies[b].vindex
            if vi is None:
                continue
            s = body_to_skel[b]
            sign = 1.0 if side == 0 else -1.0
            r = a - Pz.p
            XrT = _X(r).T                                  # moment arm: r (x) P = XrT P
            M_fac = Pz.A_v.T + Pz.A_w.T @ XrT              # k x d: generalized impulse of a force
            gen = sign * (M_fac @ Pvec)
            if tau is not None:
                gen = gen + sign * (Pz.A_w.T @ tau)
            F[vi] -= gen
            # d/d(force vector components)
            dgen_dP = sign * M_fac
            # unknown p_n, p_t, p_r
            J[vi, sl.p_n] -= dgen_dP @ (s_p * nhat)
            if fr:
                for a_ in range(d - 1):
                    J[vi, sl.p_t[a_]] -= dgen_dP @ (s_p * tang[a_])
            if tau is not None:
                J[vi, sl.p_r] -= sign * (Pz.A_w.T @ (s_p * e_r * nhat))
            # through the lever arm r = a - p(v)
            dgen_dr = sign * (Pz.A_w.T @ (-_X(Pvec).T))    # k x d
            J[np.ix_(vi, aidx)] -= dgen_dr @ T
            J[np.ix_(vi, vi)] -= dgen_dr @ (-Pz.B_p)
            # through the normal (and tangents): Pvec(n), tau(n)
            dgen_dn = dgen_dP @ dP_dn
            if tau is not None:
                dgen_dn = dgen_dn + sign * (Pz.A_w.T @ dtau_dn)
            G_ = dgen_dn @ Pn                               # k x d, times dN1
            J[np.ix_(vi, sl.a1)] -= G_ @ dN1["a1"]
            if v1i is not None:
                J[np.ix_(vi, v1i)] -= G_ @ dN1["v1"]
            for i in range(m1):
                if i != k1:
                    J[vi, sl.l1[i]] -= G_ @ Ga1[i]
        if not fr:
            return
        # relative velocity of body 2's point a2 to body 1's point a1 at l+1
        mu = spec.friction.mu
        vrel, dvrel = self._relative_velocity(z, P1, P2, v1i, v2i, a1, a2, T1, T2, sl)
        e = (spec.friction.e_t, spec.friction.e_o)
        sigma = z[sl.sigma]
        rows = sl.rows_fric
        for a_ in range(d - 1):
            row = rows[a_]
            ea2 = e[a_] ** 2
            vt = tang[a_] @ vrel
            F[row] = ea2 * mu * p_n * vt + p_t[a_] * sigma
            J[row, sl.p_n] += ea2 * mu * vt
            J[row, sl.p_t[a_]] += sigma
            J[row, sl.sigma] += p_t[a_]
            # d vt = t . dvrel + vrel . dt, dt = dtang[a] Pn dN1
            coef = ea2 * mu * p_n
            for name, cols in dvrel.items():
                J[np.ix_([row], cols[0])] += coef * (tang[a_] @ cols[1])[None, :]
            dt_dN = vrel @ dtang[a_] @ Pn                  # (d,)
            J[row, sl.a1] += coef * dt_dN @ dN1["a1"]
            if v1i is not None:
                J[row, v1i] += coef * dt_dN @ dN1["v1"]
            for i in range(m1):
                if i != k1:
                    J[row, sl.l1[i]] += coef * dt_dN @ Ga1[i]
        cone = (mu * p_n) ** 2 - (p_t[0] / e[0]) ** 2
        if d == 3:
            cone -= (p_t[1] / e[1]) ** 2
        if sl.p_r >= 0:
            # torsion: e_r mu p_n (n . w_rel) + p~_r sigma = 0
            row = rows[d - 1]
            w2 = P2.omega if v2i is not None else np.zeros(3)
            w1 = P1.omega if v1i is not None else np.zeros(3)
            wrel = w2 - w1
            wn = nhat @ wrel
            F[row] = e_r * mu * p_n * wn + p_r * sigma
            J[row, sl.p_n] += e_r * mu * wn
            J[row, sl.p_r] += sigma
            J[row, sl.sigma] += p_r
            coef = e_r * mu * p_n
            if v2i is not None:
                J[row, v2i] += coef * nhat @ P2.A_w
            if v1i is not None:
                J[row, v1i] -= coef * nhat @ P1.A_w
            dwn_dN = wrel @ Pn
            J[row, sl.a1] += coef * dwn_dN @ dN1["a1"]
            if v1i is not None:
                J[row, v1i] += coef * dwn_dN @ dN1["v1"]
            for i in range(m1):
                if i != k1:
                    J[row, sl.l1[i]] += coef * dwn_dN @ Ga1[i]
            cone -= p_r ** 2
        F[sl.sigma] = cone
        J[sl.sigma, sl.p_n] = 2.0 * mu * mu * p_n
        J[sl.sigma, sl.p_t[0]] = -2.0 * p_t[0] / e[0] ** 2
        if d == 3:
            J[sl.sigma, sl.p_t[1]] = -2.0 * p_t[1] / e[1] ** 2
        if sl.p_r >= 0:
            J[sl.sigma, sl.p_r] = -2.0 * p_r

    def _relative_velocity(self, z, P1, P2, v1i, v2i, a1, a2, T1, T2, sl):
        """v_rel = v_2(a2) - v_1(a1) and its derivatives {name: (cols, d x len(cols))}."""
        d = len(a1)
        vrel = np.zeros(d)
        dv = {}
        for sign, Pz, vi, a, T, acols, tag in ((1.0, P2, v2i, a2, T2, sl.a2, "2"),
                                               (-1.0, P1, v1i, a1, T1, sl.a1, "1")):
            if vi is None:
                continue
            vb = z[vi]
            r = a - Pz.p
            w = Pz.omega
            vel = Pz.A_v @ vb + _X(r) @ (Pz.A_w @ vb)
            vrel += sign * vel
            Ww = _W(w)
            dv["v" + tag] = (vi, sign * (Pz.A_v + _X(r) @ Pz.A_w - Ww @ Pz.B_p))
            dv["a" + tag] = (acols, sign * (Ww @ T))
        return vrel, dv

    # -- reading the solution --------------------------------------------------------------------
    def unpack_pair(self, z, k) -> PairState:
        spec, sl = self.specs[k], self.layout.pairs[k]
        a1, _, a2, _ = self.points(z, k)
        poses = {b: self.bodies[b].pose(self.body_velocity(z, b)) for b in (spec.obj1.body, spec.obj2.body)}
        P1 = poses[spec.obj1.body]
        fa1, Ga1, *_ = _eval_functions(spec.obj1.functions, P1, a1)
        fa2, *_ = _eval_functions(spec.obj1.functions, P1, a2)
        l1 = z[sl.l1].copy()
        c = l1.copy()
        c[spec.k1] = 1.0
        N1 = c @ Ga1
        nhat = N1 / np.linalg.norm(N1)
        tang, _ = _tangents(nhat, np.eye(spec.dim), spec.tangent_axis)
        s_p = spec.impulse_scale
        p_t = s_p * z[sl.p_t] if spec.with_friction else np.zeros(spec.dim - 1)
        p_r = s_p * spec.friction.e_r * z[sl.p_r] if sl.p_r >= 0 else 0.0
        sigma = z[sl.sigma] if sl.sigma >= 0 else 0.0
        return PairState(a1, a2, l1, z[sl.l2].copy(), s_p * z[sl.p_n], p_t, p_r, sigma, nhat, tang,
                         float(np.max(fa2)))


def _tangents(nhat, Pn, axis):
    """Tangent directions and d(tangent)/d(nhat) (d-1 of each)."""
    d = len(nhat)
    if d == 2:
        S = np.array([[0.0, -1.0], [1.0, 0.0]])
        return np.array([S @ nhat]), [S]
    e = axis
    u = e - (e @ nhat) * nhat
    nu = np.linalg.norm(u)
    t = u / nu
    du_dn = -np.outer(nhat, e) - (e @ nhat) * np.eye(3)
    dt_dn = (np.eye(3) - np.outer(t, t)) / nu @ du_dn
    o = np.cross(nhat, t)
    do_dn = -_skew(t) + _skew(nhat) @ dt_dn
    return np.array([t, o]), [dt_dn, do_dn]
