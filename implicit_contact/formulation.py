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
Newton-Euler rows are divided by diag(M) and the position-level rows ((15), (17)-(19)) by h, so
that they read as velocities; the friction rows are in velocity units by construction (scaled
impulses times velocities): a natural-residual tolerance then means about the same on every row.

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


def _eval_functions(funcs, pose: Pose, a, jac=True):
    """Values, world gradients, world Hessians, and their v-derivatives of body functions at a.

    Returns f (m,), G (m,d), Hw (m,d,d), dfdv (m,k), dGdv (m,d,k); without jac only f and G."""
    R, r = pose.R, a - pose.p
    xi = R.T @ r
    m, d, k = len(funcs), len(a), pose.B_th.shape[1]
    f = np.empty(m)
    G = np.empty((m, d))
    if not jac:
        for i, fn in enumerate(funcs):
            f[i] = fn.value(xi)
            G[i] = R @ fn.gradient(xi)
        return f, G, None, None, None
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

    def __post_init__(self):
        # the same blocks as slices (every block is contiguous), for fast reads and writes
        self.a1s, self.a2s = _as_slice(self.a1), _as_slice(self.a2)
        self.l1s, self.l2s, self.p_ts = _as_slice(self.l1), _as_slice(self.l2), _as_slice(self.p_t)
        self.rows_l1s, self.rows_l2s = _as_slice(self.rows_l1), _as_slice(self.rows_l2)
        self.l1_bounded = np.arange(len(self.rows_l1))   # which functions have complementarity rows
        self.l2_bounded = np.arange(len(self.rows_l2))


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
    """F(z) and dF/dz of one geometrically implicit step, for ``ncp.solve_mcp``.

    ``fun`` evaluates the rows only (line-search trials need no Jacobian); ``jac`` evaluates both
    and caches them for the last z. Every contiguous block is written through slices."""

    def __init__(self, h: float, skeletons: list, bodies: list, specs: list, layout: Layout):
        self.h = h
        self.skeletons = skeletons
        self.bodies = bodies
        self.specs = specs
        self.layout = layout
        self.lower, self.upper = layout.lower, layout.upper
        # Row scaling (see the module docstring): Newton-Euler rows / diag(M) and position-level
        # rows / h, so that every row but the unit-free normal rows (16) and cone rows reads as a
        # velocity and one tolerance means the same on all of them.
        scale = np.ones(layout.n)
        for s, sk in enumerate(skeletons):
            scale[_as_slice(layout.v_index[s])] = 1.0 / np.maximum(np.diag(sk.M), 1e-300)
        for spec, sl in zip(specs, layout.pairs):
            scale[sl.rows_geo[: spec.dim]] = 1.0 / h
            scale[sl.rows_l1] = 1.0 / h
            scale[sl.rows_l2] = 1.0 / h
            scale[sl.row_n] = 1.0 / h
        self._row_scale = scale
        self._body_skel = {sk.body: s for s, sk in enumerate(skeletons)}
        self._vslice = [_as_slice(b.vindex) if b.vindex is not None else None for b in bodies]
        self._reduced = []
        for spec in specs:
            r1 = _reduced_point(spec.obj1, bodies[spec.obj1.body]) if spec.obj1.fixed_halfspace else None
            r2 = _reduced_point(spec.obj2, bodies[spec.obj2.body]) if spec.obj2.fixed_halfspace else None
            self._reduced.append((r1, r2))
        self._key_f = self._key_j = None
        self._F = self._J = None
        self._pairs_at = None      # per-pair quantities at _key_f, for reports

    # -- unknown vector helpers ---------------------------------------------------------------
    def body_velocity(self, z, body_index):
        sl = self._vslice[body_index]
        return z[sl] if sl is not None else _EMPTY

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
        if self._key_f is None or not np.array_equal(z, self._key_f):
            self._F, _, self._pairs_at = self._assemble(z, False)
            self._key_f = z.copy()
        return self._F

    def jac(self, z):
        if self._key_j is None or not np.array_equal(z, self._key_j):
            F, J, pairs = self._assemble(z, True)
            self._key_j = z.copy()
            self._J = J
            self._F, self._key_f, self._pairs_at = F, self._key_j, pairs
        return self._J

    def _assemble(self, z, need_jac):
        lay = self.layout
        n = lay.n
        F = np.zeros(n)
        J = np.zeros((n, n)) if need_jac else None
        poses = [kin.pose(self.body_velocity(z, b)) for b, kin in enumerate(self.bodies)]
        for s, sk in enumerate(self.skeletons):
            vs = _as_slice(lay.v_index[s])
            F[vs] = sk.M @ (z[vs] - sk.v) - self.h * sk.force
            if need_jac:
                J[vs, vs] = sk.M
        pairs = [self._pair(z, k, spec, poses, F, J) for k, spec in enumerate(self.specs)]
        F *= self._row_scale
        if need_jac:
            J *= self._row_scale[:, None]
        return F, J, pairs

    def _pair(self, z, k, spec, poses, F, J):
        """Rows of pair k into F (and J if given); returns the pair's state for reports."""
        sl = self.layout.pairs[k]
        d = spec.dim
        b1, b2 = spec.obj1.body, spec.obj2.body
        P1, P2 = poses[b1], poses[b2]
        v1s, v2s = self._vslice[b1], self._vslice[b2]
        a1, T1, a2, T2 = self.points(z, k)
        jac = J is not None
        m1 = len(spec.obj1.functions)
        fa1, Ga1, Ha1, dfa1, dGa1 = _eval_functions(spec.obj1.functions, P1, a1, jac)
        fa2, Ga2, _, dfa2, _ = _eval_functions(spec.obj1.functions, P1, a2, jac)
        gb2, Gb2, Hb2, dgb2, dGb2 = _eval_functions(spec.obj2.functions, P2, a2, jac)
        l1, l2 = z[sl.l1s], z[sl.l2s]
        k1 = spec.k1
        c = l1.copy()
        c[k1] = 1.0                      # N1 = sum_i c_i G_i with c_k1 = 1
        N1 = c @ Ga1
        lk = l1[k1]
        r15 = slice(sl.rows_geo[0], sl.rows_geo[0] + d)
        r16 = slice(sl.rows_geo[0] + d, sl.rows_geo[0] + 2 * d)
        F[r15] = a1 - a2 + lk * N1                                  # (15) / (28)
        F[r16] = N1 + l2 @ Gb2                                      # (16) / (29)
        F[sl.rows_l1s] = -fa1[sl.l1_bounded]                        # (17) / (30)
        F[sl.rows_l2s] = -gb2[sl.l2_bounded]                        # (18) / (31)
        ia = int(np.argmax(fa2))
        F[sl.row_n] = fa2[ia]                                       # (19) / (32)
        nrm = math.sqrt(float(N1 @ N1))
        nhat = N1 / nrm
        tang, dtang = _tangents(nhat, spec.tangent_axis, jac)
        s_p = spec.impulse_scale
        fr = spec.with_friction
        p_n = z[sl.p_n]
        p_t = z[sl.p_ts] if fr else _EMPTY
        torsion = sl.p_r >= 0
        p_r = z[sl.p_r] if torsion else 0.0
        e_r = spec.friction.e_r
        Pvec = s_p * p_n * nhat
        if fr:
            Pvec = Pvec + s_p * (p_t @ tang)
        tau = s_p * e_r * p_r * nhat if torsion else None
        if jac:
            eye_d = _EYE[d]
            dN1_da1 = Ha1[0] if m1 == 1 else np.einsum("i,ijk->jk", c, Ha1)
            dN1_dv1 = (dGa1[0] if m1 == 1 else np.einsum("i,ijk->jk", c, dGa1)) if v1s is not None else None
            others = [i for i in range(m1) if i != k1]
            a1s, a2s = sl.a1s, sl.a2s
            J[r15, a1s] = (eye_d + lk * dN1_da1) @ T1
            J[r15, a2s] = -T2
            J[r15, sl.l1[k1]] = N1
            J[r16, a1s] = dN1_da1 @ T1
            J[r16, a2s] = (np.einsum("j,jkl->kl", l2, Hb2) if len(l2) > 1 else l2[0] * Hb2[0]) @ T2
            J[r16, sl.l2s] = Gb2.T
            for i in others:
                J[r15, sl.l1[i]] = lk * Ga1[i]
                J[r16, sl.l1[i]] = Ga1[i]
            if v1s is not None:
                J[r15, v1s] = lk * dN1_dv1
                J[r16, v1s] = dN1_dv1
            if v2s is not None:
                J[r16, v2s] = l2[0] * dGb2[0] if len(l2) == 1 else np.einsum("j,jkl->kl", l2, dGb2)
            for i, row in zip(sl.l1_bounded, sl.rows_l1):
                J[row, a1s] = -Ga1[i] @ T1
                if v1s is not None:
                    J[row, v1s] = -dfa1[i]
            for j, row in zip(sl.l2_bounded, sl.rows_l2):
                J[row, a2s] = -Gb2[j] @ T2
                if v2s is not None:
                    J[row, v2s] = -dgb2[j]
            J[sl.row_n, a2s] = Ga2[ia] @ T2
            if v1s is not None:
                J[sl.row_n, v1s] = dfa2[ia]
            # the normal's derivative: dn = Pn dN1, dN1 = dN1_da1 T1 da1 + dN1_dv1 dv1 + G_i dl_i
            Pn = (eye_d - np.outer(nhat, nhat)) / nrm
            dP_dn = s_p * p_n * eye_d
            if fr:
                for a in range(d - 1):
                    dP_dn = dP_dn + s_p * p_t[a] * dtang[a]
            dN1_a1 = dN1_da1 @ T1
        # generalized contact impulses: +P at a2 on body 2, -P at a1 on body 1 (and moments)
        for sign, b, Pz, a, T, aslc, vs in ((1.0, b2, P2, a2, T2, sl.a2s, v2s),
                                            (-1.0, b1, P1, a1, T1, sl.a1s, v1s)):
            if vs is None:
                continue
            r = a - Pz.p
            M_fac = Pz.A_v.T + Pz.A_w.T @ _X(r).T              # k x d: generalized impulse of a force
            gen = M_fac @ Pvec
            if torsion:
                gen = gen + Pz.A_w.T @ tau
            F[vs] -= sign * gen
            if not jac:
                continue
            J[vs, sl.p_n] -= sign * (M_fac @ (s_p * nhat))
            if fr:
                J[vs, sl.p_ts] -= sign * (M_fac @ (s_p * tang.T))
            if torsion:
                J[vs, sl.p_r] -= sign * (Pz.A_w.T @ (s_p * e_r * nhat))
            dgen_dr = sign * (Pz.A_w.T @ (-_X(Pvec).T))         # lever arm r = a - p(v)
            J[vs, aslc] -= dgen_dr @ T
            J[vs, vs] += dgen_dr @ Pz.B_p
            dgen_dn = sign * (M_fac @ dP_dn)
            if torsion:
                dgen_dn = dgen_dn + sign * (Pz.A_w.T * (s_p * e_r * p_r))
            G_ = dgen_dn @ Pn
            J[vs, sl.a1s] -= G_ @ dN1_a1
            if v1s is not None:
                J[vs, v1s] -= G_ @ dN1_dv1
            for i in others:
                J[vs, sl.l1[i]] -= G_ @ Ga1[i]
        vrel = None
        if fr:
            mu = spec.friction.mu
            vrel, dvrel = _relative_velocity(z, P1, P2, v1s, v2s, a1, a2, T1, T2, sl, jac)
            e = (spec.friction.e_t, spec.friction.e_o)
            sigma = z[sl.sigma]
            rows = sl.rows_fric
            cone = (mu * p_n) ** 2
            for a in range(d - 1):
                row = rows[a]
                ea2 = e[a] ** 2
                vt = tang[a] @ vrel
                F[row] = ea2 * mu * p_n * vt + p_t[a] * sigma
                cone -= (p_t[a] / e[a]) ** 2
                if jac:
                    J[row, sl.p_n] += ea2 * mu * vt
                    J[row, sl.p_t[a]] += sigma
                    J[row, sl.sigma] += p_t[a]
                    coef = ea2 * mu * p_n
                    for cols, block in dvrel:
                        J[row, cols] += coef * (tang[a] @ block)
                    dt_dN = (vrel @ dtang[a]) @ Pn
                    J[row, sl.a1s] += coef * (dt_dN @ dN1_a1)
                    if v1s is not None:
                        J[row, v1s] += coef * (dt_dN @ dN1_dv1)
                    for i in others:
                        J[row, sl.l1[i]] += coef * (dt_dN @ Ga1[i])
                    J[sl.sigma, sl.p_t[a]] = -2.0 * p_t[a] / e[a] ** 2
            if torsion:
                # e_r mu p_n (n . w_rel) + p~_r sigma = 0, p_r = e_r p~_r
                row = rows[d - 1]
                wrel = (P2.omega if v2s is not None else _ZERO3) - (P1.omega if v1s is not None else _ZERO3)
                wn = nhat @ wrel
                F[row] = e_r * mu * p_n * wn + p_r * sigma
                cone -= p_r ** 2
                if jac:
                    J[row, sl.p_n] += e_r * mu * wn
                    J[row, sl.p_r] += sigma
                    J[row, sl.sigma] += p_r
                    coef = e_r * mu * p_n
                    if v2s is not None:
                        J[row, v2s] += coef * (nhat @ P2.A_w)
                    if v1s is not None:
                        J[row, v1s] -= coef * (nhat @ P1.A_w)
                    dwn_dN = wrel @ Pn
                    J[row, sl.a1s] += coef * (dwn_dN @ dN1_a1)
                    if v1s is not None:
                        J[row, v1s] += coef * (dwn_dN @ dN1_dv1)
                    for i in others:
                        J[row, sl.l1[i]] += coef * (dwn_dN @ Ga1[i])
                    J[sl.sigma, sl.p_r] = -2.0 * p_r
            F[sl.sigma] = cone                                      # (22)
            if jac:
                J[sl.sigma, sl.p_n] = 2.0 * mu * mu * p_n
        return (a1, a2, nhat, tang, float(fa2[ia]), vrel)

    # -- reading the solution --------------------------------------------------------------------
    def unpack_pair(self, z, k) -> PairState:
        spec, sl = self.specs[k], self.layout.pairs[k]
        self.fun(z)
        a1, a2, nhat, tang, gap, _ = self._pairs_at[k]
        s_p = spec.impulse_scale
        p_t = s_p * z[sl.p_ts] if spec.with_friction else np.zeros(spec.dim - 1)
        p_r = s_p * spec.friction.e_r * z[sl.p_r] if sl.p_r >= 0 else 0.0
        sigma = z[sl.sigma] if sl.sigma >= 0 else 0.0
        return PairState(a1, a2, z[sl.l1s].copy(), z[sl.l2s].copy(), s_p * z[sl.p_n], p_t, p_r, sigma,
                         nhat, tang, gap)

    def relative_velocity(self, z, k):
        """v_2(a2) - v_1(a1) of pair k at l+1 (world frame)."""
        spec, sl = self.specs[k], self.layout.pairs[k]
        a1, T1, a2, T2 = self.points(z, k)
        b1, b2 = spec.obj1.body, spec.obj2.body
        P1 = self.bodies[b1].pose(self.body_velocity(z, b1))
        P2 = self.bodies[b2].pose(self.body_velocity(z, b2))
        return _relative_velocity(z, P1, P2, self._vslice[b1], self._vslice[b2], a1, a2, T1, T2, sl, False)[0]


_EMPTY = np.zeros(0)
_ZERO3 = np.zeros(3)
_EYE = {2: np.eye(2), 3: np.eye(3)}


def _as_slice(index):
    """A contiguous index array as a slice (layouts only allocate contiguous blocks)."""
    if len(index) == 0:
        return slice(0, 0)
    return slice(int(index[0]), int(index[-1]) + 1)


def _relative_velocity(z, P1, P2, v1s, v2s, a1, a2, T1, T2, sl, jac):
    """v_rel = v_2(a2) - v_1(a1) and, if jac, its derivative blocks [(cols, d x ncols)]."""
    vrel = np.zeros(len(a1))
    blocks = []
    for sign, Pz, vs, a, T, aslc in ((1.0, P2, v2s, a2, T2, sl.a2s), (-1.0, P1, v1s, a1, T1, sl.a1s)):
        if vs is None:
            continue
        vb = z[vs]
        Xr = _X(a - Pz.p)
        vrel += sign * (Pz.A_v @ vb + Xr @ (Pz.A_w @ vb))
        if jac:
            Ww = _W(Pz.omega)
            blocks.append((vs, sign * (Pz.A_v + Xr @ Pz.A_w - Ww @ Pz.B_p)))
            blocks.append((aslc, sign * (Ww @ T)))
    return vrel, blocks


_ROT90 = np.array([[0.0, -1.0], [1.0, 0.0]])


def _tangents(nhat, axis, jac=True):
    """Tangent directions and, if jac, d(tangent)/d(nhat) (d-1 of each)."""
    d = len(nhat)
    if d == 2:
        return (_ROT90 @ nhat)[None, :], [_ROT90]
    e = axis
    u = e - (e @ nhat) * nhat
    nu = math.sqrt(float(u @ u))
    t = u / nu
    if not jac:
        return np.array([t, np.cross(nhat, t)]), None
    du_dn = -np.outer(nhat, e) - (e @ nhat) * np.eye(3)
    dt_dn = (np.eye(3) - np.outer(t, t)) / nu @ du_dn
    o = np.cross(nhat, t)
    do_dn = -_skew(t) + _skew(nhat) @ dt_dn
    return np.array([t, o]), [dt_dn, do_dn]
