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
* ARTICULATED (a body of a multi-body skeleton, or of any other root; v = its skeleton's
  velocities, shared by all its bodies): the body moves rigidly with its twist through DART's
  world Jacobian of its origin at l, J = [A_w; A_v] (6 x ndof, angular rows first):
  omega = A_w v, R+ = exp(h [omega]x) R, p+ = p + h A_v v; dtheta = h J_l(h omega) A_w dv,
  dp = h A_v dv. Exact for a free body; for a chain it differs from DART's joint-space update
  q+ = q (+) h v (which the stepper uses to write back) by O(h^2 |v|^2): a revolute link's
  origin moves along the chord instead of the arc. Such pairs run on the generic numpy path
  (quasi_rigid.CompliantPair with no compliance), not on the float hot path below.

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

Implementation. fun and jac run several times per step and bound the simulator's speed, so the
per-pair code avoids numpy calls on 3-vectors (see "Speed" below): rows on plain floats, common
primitives evaluated inline, the Jacobian as a few (coefficients x basis) products per pair
(_PairPlan), and jac reusing the rows of the fun call at the same point (StepProblem._pair).
comparisons/bench_assembly.py measures it; tests/test_formulation.py checks J by differences.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
import weakref

import numpy as np
import scipy.sparse as _sparse

from . import shapes as shp
from .params import Friction

FREE, PLANAR, FIXED = "free", "planar", "fixed"
ARTICULATED = "articulated"   # a body of a multi-body skeleton (or any other root): see BodyKinematics


# ---------------------------------------------------------------------------------------------
# small geometry helpers, 2D and 3D alike
# ---------------------------------------------------------------------------------------------
# Speed. Every quantity of a pair is a 2- or 3-vector or a small matrix, where a numpy call costs
# about 1 us of overhead and a float operation on plain Python numbers about 40 ns (np.cross of
# two 3-vectors costs ~20 us). So the hot path (StepProblem._pair) works on tuples of floats for
# vectors and tuples of rows for matrices, through the kits _V3 / _V2 below, and uses numpy only
# for the chain rule of the Jacobian, where one call handles a whole row block. The numpy
# helpers right below (_skew, _X, _W, Pose, _eval_functions, ...) serve the public API and
# reports, not the hot path.
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


def _so3_coefficients(th2):
    """(a, b, c) of exp([phi]x) = I + a K + b K^2 and J_l(phi) = I + b K + c K^2, th2 = |phi|^2."""
    th = math.sqrt(th2)
    if th < 1e-6:
        return 1.0, 0.5, 1.0 / 6.0
    s = math.sin(th)
    b = (1.0 - math.cos(th)) / th2
    return s / th, b, (th - s) / (th2 * th)


def _i_plus_k(f0, f1, f2, th2, a, b):
    """Rows of I + a K + b K^2 with K = [phi]x, using K^2 = phi phi^T - |phi|^2 I."""
    af0, af1, af2 = a * f0, a * f1, a * f2
    bf0, bf1, bf2 = b * f0, b * f1, b * f2
    bt = b * th2
    return ((1.0 + bf0 * f0 - bt, bf0 * f1 - af2, bf0 * f2 + af1),
            (bf1 * f0 + af2, 1.0 + bf1 * f1 - bt, bf1 * f2 - af0),
            (bf2 * f0 - af1, bf2 * f1 + af0, 1.0 + bf2 * f2 - bt))


def so3_exp(phi):
    f0, f1, f2 = (float(c) for c in phi)
    th2 = f0 * f0 + f1 * f1 + f2 * f2
    a, b, _ = _so3_coefficients(th2)
    return np.array(_i_plus_k(f0, f1, f2, th2, a, b))


def so3_left_jacobian(phi):
    f0, f1, f2 = (float(c) for c in phi)
    th2 = f0 * f0 + f1 * f1 + f2 * f2
    _, b, c = _so3_coefficients(th2)
    return np.array(_i_plus_k(f0, f1, f2, th2, b, c))


def _mm3(A, B):
    """A @ B of 3x3 row tuples."""
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = B
    return tuple((x0 * b00 + x1 * b10 + x2 * b20, x0 * b01 + x1 * b11 + x2 * b21,
                  x0 * b02 + x1 * b12 + x2 * b22) for x0, x1, x2 in A)


class _V3:
    """3-vectors as tuples of floats, 3x3 matrices as tuples of rows (see "Speed" above)."""

    I = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))

    @staticmethod
    def sI(s):
        """s I."""
        return ((s, 0.0, 0.0), (0.0, s, 0.0), (0.0, 0.0, s))

    @staticmethod
    def sub(a, b):
        return (a[0] - b[0], a[1] - b[1], a[2] - b[2])

    @staticmethod
    def add(a, b):
        return (a[0] + b[0], a[1] + b[1], a[2] + b[2])

    @staticmethod
    def axpy(s, x, y):
        """s x + y."""
        return (y[0] + s * x[0], y[1] + s * x[1], y[2] + s * x[2])

    @staticmethod
    def scale(s, x):
        return (s * x[0], s * x[1], s * x[2])

    @staticmethod
    def dot(a, b):
        return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]

    @staticmethod
    def comb(c, vs):
        """sum_i c_i vs_i."""
        x = y = z = 0.0
        for ci, v in zip(c, vs):
            x += ci * v[0]
            y += ci * v[1]
            z += ci * v[2]
        return (x, y, z)

    @staticmethod
    def mv(R, x):
        x0, x1, x2 = x
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R
        return (r00 * x0 + r01 * x1 + r02 * x2, r10 * x0 + r11 * x1 + r12 * x2,
                r20 * x0 + r21 * x1 + r22 * x2)

    @staticmethod
    def mtv(R, x):
        """R^T x, or the row vector x^T R."""
        x0, x1, x2 = x
        (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = R
        return (r00 * x0 + r10 * x1 + r20 * x2, r01 * x0 + r11 * x1 + r21 * x2,
                r02 * x0 + r12 * x1 + r22 * x2)

    @staticmethod
    def cross(a, b):
        """a x b (the moment of b at lever a), as a dth-tuple."""
        a0, a1, a2 = a
        b0, b1, b2 = b
        return (a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0)

    @staticmethod
    def wcross(w, r):
        """omega x r."""
        return _V3.cross(w, r)

    @staticmethod
    def X(x):
        """_X(x) = -[x]x: dtheta -> dtheta x x."""
        x0, x1, x2 = x
        return ((0.0, x2, -x1), (-x2, 0.0, x0), (x1, -x0, 0.0))

    @staticmethod
    def XT(x):
        """_X(x)^T = [x]x: dr -> x x dr (d(x x P) = X(P)^T ... see _pair)."""
        x0, x1, x2 = x
        return ((0.0, -x2, x1), (x2, 0.0, -x0), (-x1, x0, 0.0))

    W = XT                      # _W(omega) = [omega]x
    tscale = scale              # of a dth-vector (rotations: 3 in 3D, 1 in 2D)

    @staticmethod
    def vW(y, w):
        """The row y^T _W(omega) = y x omega."""
        return _V3.cross(y, w)

    mm = staticmethod(lambda A, B: _mm3(A, B))     # A @ B, 3x3 rows

    @staticmethod
    def affine(red, s):
        """a0 + T s of a reduced point (T: 3x2)."""
        (a0, a1, a2), ((t00, t01), (t10, t11), (t20, t21)) = red
        s0, s1 = s
        return (a0 + (t00 * s0 + t01 * s1), a1 + (t10 * s0 + t11 * s1), a2 + (t20 * s0 + t21 * s1))


class _V2:
    """The 2D kit: the same names; cross products and rotations are 1-tuples / 2x1 columns."""

    I = ((1.0, 0.0), (0.0, 1.0))

    @staticmethod
    def sI(s):
        return ((s, 0.0), (0.0, s))

    @staticmethod
    def sub(a, b):
        return (a[0] - b[0], a[1] - b[1])

    @staticmethod
    def add(a, b):
        return (a[0] + b[0], a[1] + b[1])

    @staticmethod
    def axpy(s, x, y):
        return (y[0] + s * x[0], y[1] + s * x[1])

    @staticmethod
    def scale(s, x):
        return (s * x[0], s * x[1])

    @staticmethod
    def dot(a, b):
        return a[0] * b[0] + a[1] * b[1]

    @staticmethod
    def comb(c, vs):
        x = y = 0.0
        for ci, v in zip(c, vs):
            x += ci * v[0]
            y += ci * v[1]
        return (x, y)

    @staticmethod
    def mv(R, x):
        x0, x1 = x
        (r00, r01), (r10, r11) = R
        return (r00 * x0 + r01 * x1, r10 * x0 + r11 * x1)

    @staticmethod
    def mtv(R, x):
        x0, x1 = x
        (r00, r01), (r10, r11) = R
        return (r00 * x0 + r10 * x1, r01 * x0 + r11 * x1)

    @staticmethod
    def cross(a, b):
        return (a[0] * b[1] - a[1] * b[0],)

    @staticmethod
    def wcross(w, r):
        return (-w[0] * r[1], w[0] * r[0])

    @staticmethod
    def X(x):
        return ((-x[1],), (x[0],))

    @staticmethod
    def XT(x):
        return ((-x[1], x[0]),)

    @staticmethod
    def W(w):
        return ((0.0, -w[0]), (w[0], 0.0))

    @staticmethod
    def vW(y, w):
        return (w[0] * y[1], -w[0] * y[0])

    @staticmethod
    def tscale(s, x):
        return (s * x[0],)

    @staticmethod
    def mm(A, B):
        """A @ B for A with rows of length 2 (B: 2 rows)."""
        B0, B1 = B
        return tuple(tuple(a0 * x + a1 * y for x, y in zip(B0, B1)) for a0, a1 in A)

    @staticmethod
    def affine(red, s):
        (a0, a1), ((t0,), (t1,)) = red
        return (a0 + t0 * s[0], a1 + t1 * s[0])


_VEC = {2: _V2, 3: _V3}


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
    jacobian: np.ndarray | None = None   # ARTICULATED: DART's world Jacobian of the body origin at l
    #                                      (6 x ndof of its skeleton, angular rows first)

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
        if self.kind == ARTICULATED:
            # The body moves rigidly with its twist at l+1 through the Jacobian at l:
            # omega = A_w v, v_o = A_v v, R+ = exp(h [omega]x) R0, p+ = p0 + h v_o. Exact for a
            # free body; for a chain it agrees with DART's joint-space update q+ = q (+) h v to
            # O(h^2 |v|^2) (the chord of a revolute link's arc instead of the arc; the stepper
            # writes back with DART's integratePositions). Only the generic (numpy) pair path
            # (quasi_rigid.CompliantPair) evaluates such bodies.
            A_w, A_v = self.jacobian[:3], self.jacobian[3:]
            w = A_w @ v
            R = so3_exp(h * w) @ self.R0
            p = self.p0 + h * (A_v @ v)
            return Pose(R, p, h * (so3_left_jacobian(h * w) @ A_w), h * A_v, A_w, A_v, w)
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


class _BodyNow:
    """The hot path's view of a body at l+1 for one evaluation: R (rows), p, omega, v_o as floats;
    for a free body, what its J_l(h omega) is made of (dtheta = h J_l d omega; see theta_into)."""

    __slots__ = ("R", "p", "w", "vo", "_jl", "_Rn")

    def __init__(self, R, p, w, vo, jl=None):
        self.R, self.p, self.w, self.vo, self._jl, self._Rn = R, p, w, vo, jl, None

    def theta_into(self, out):
        """out[:] = h J_l(h omega), the 3x3 block of dtheta / d omega of a free body."""
        h, f0, f1, f2, th2, b, c = self._jl
        np.multiply(_i_plus_k(f0, f1, f2, th2, b, c), h, out=out)

    @property
    def Rn(self):
        """R as a numpy array (only rotated Hessians need it)."""
        if self._Rn is None:
            self._Rn = np.array(self.R)
        return self._Rn


def _body_now(kin: BodyKinematics, R0, p0, v):
    """_BodyNow of a moving body from its velocity unknowns v (floats); the same pose as
    BodyKinematics.pose, written out in floats: R+ = exp(h [omega]x) R0 (Rodrigues), p+ = p0 + h v_o."""
    h = kin.h
    if kin.kind == FREE:
        w0, w1, w2, u0, u1, u2 = v
        f0, f1, f2 = h * w0, h * w1, h * w2
        th2 = f0 * f0 + f1 * f1 + f2 * f2
        a, b, c = _so3_coefficients(th2)
        R = _mm3(_i_plus_k(f0, f1, f2, th2, a, b), R0)
        p = (p0[0] + h * u0, p0[1] + h * u1, p0[2] + h * u2)
        return _BodyNow(R, p, (w0, w1, w2), (u0, u1, u2), (h, f0, f1, f2, th2, b, c))
    # planar, XY
    vx, vy, om = v
    th = p0[2] + h * om                 # p0 is q0 = [x, y, theta] for planar bodies
    c, s = math.cos(th), math.sin(th)
    return _BodyNow(((c, -s), (s, c)), (p0[0] + h * vx, p0[1] + h * vy), (om,), (vx, vy))


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
            f[i], g = fn.value_gradient(xi)
            G[i] = R @ g
        return f, G, None, None, None
    Hw = np.empty((m, d, d))
    for i, fn in enumerate(funcs):
        f[i], g, H = fn.value_gradient_hessian(xi)
        G[i] = R @ g
        Hw[i] = R @ H @ R.T
    if k == 0:
        return f, G, Hw, np.zeros((m, 0)), np.zeros((m, d, 0))
    Xr = _X(r)
    # dtheta (x) r = Xr dth, so df = -G.(Xr dth + dp)
    move = Xr @ pose.B_th + pose.B_p                      # d x k: material displacement of a
    dfdv = -G @ move
    dGdv = np.empty((m, d, k))
    for i in range(m):
        # dG = dtheta (x) G - Hw (dtheta (x) r + dp)
        dGdv[i] = _X(G[i]) @ pose.B_th - Hw[i] @ move
    return f, G, Hw, dfdv, dGdv


# How the hot path evaluates one body function, cached per function object (_function_info):
# an inline kernel for the common primitives, else the shape's own API (about 3-4 us per call
# through its checks and conversions, ten times the arithmetic of a sphere or a plane), and the
# Hessian when it is constant: 0.0 (planes), a float c for c I (spheres, discs: rotation
# invariant, so R H R^T = c I without a product), or the body-frame matrix; for a kernel whose
# Hessian varies (single-exponent superquadrics), a _HessianKernel evaluated only when the
# Jacobian needs it; None if it varies and comes with each evaluation of the shape's API.
_FUNCTION_INFO = weakref.WeakKeyDictionary()


def _function_info(fn):
    """(kernel or None, Hessian info) of a body function (see above)."""
    try:
        return _FUNCTION_INFO[fn]
    except KeyError:
        pass
    except TypeError:            # not weak-referenceable: classify every time (rare)
        return _classify(fn)
    info = _FUNCTION_INFO[fn] = _classify(fn)
    return info


def _classify(fn):
    kern, hi = _kernel(fn), _classify_hessian(fn)
    if kern is not None and hi is None:
        hi = _hessian_kernel(fn)
        if hi is None:           # a kernel needs its Hessian from somewhere: use the shape's API
            kern = None
    return kern, hi


class _HessianKernel:
    """The body-frame Hessian of a kernel function at xi (a tuple), as a (d, d) array."""

    __slots__ = ("at",)

    def __init__(self, at):
        self.at = at


def _late_hessian(fn, hi, x):
    """A Hessian the rows left for the Jacobian: hi is None (the shape's API at the array x),
    (kernel, xi) from _evaluate, or already a float / matrix."""
    if hi is None:
        return np.asarray(fn.hessian(x), float)
    if type(hi) is tuple:
        return hi[0].at(hi[1])
    return hi


def _hessian_kernel(fn):
    """_HessianKernel of a single-exponent superquadric / superellipse (the only kernel with a
    varying Hessian): R0 diag(s (q - 1) |X_i|^(q-2) / a_i^2) R0^T, X = R0^T (x - c) / a; checked
    against the shape's hessian like _kernel_agrees, else None."""
    if not (isinstance(fn, shp._PowerSumBase) and fn._single):
        return None
    a = tuple(float(v) for v in fn.semi_axes)
    q, sm = float(fn._n1), float(fn._s)
    c = tuple(float(v) for v in fn._c0)
    R0n = np.array(fn._R0, float)
    R0 = tuple(map(tuple, R0n.tolist()))
    V = _VEC[len(a)]
    rotated = bool(fn._rotated)

    def at(x):
        xl = V.mtv(R0, V.sub(x, c))
        diag = [sm * (q - 1.0) * abs(u / ai) ** (q - 2.0) / (ai * ai) for u, ai in zip(xl, a)]
        return (R0n * diag) @ R0n.T if rotated else np.diag(diag)

    rng = np.random.default_rng(1)
    for _ in range(3):
        x = rng.normal(size=fn.dim) * 0.7
        H = np.asarray(fn.hessian(x), float)
        if np.max(np.abs(at(tuple(x.tolist())) - H)) > 1e-12 * (1.0 + np.max(np.abs(H))):
            return None
    return _HessianKernel(at)


def _classify_hessian(fn):
    if not getattr(fn, "constant_hessian", False):
        return None
    H = np.array(fn.hessian(np.zeros(fn.dim)), float)
    if not H.any():
        return 0.0
    if np.array_equal(H, H[0, 0] * np.eye(len(H))):
        return float(H[0, 0])
    return H


def _kernel(fn):
    """x (tuple, body frame) -> (f, grad f as a tuple) for spheres / discs, half-spaces /
    half-planes and ellipsoids / ellipses: the formulas of shapes.py written on floats.
    Each kernel is checked against the shape's value_gradient once; any disagreement (a shape
    whose formula changed, a subclass) leaves that function on the shape's API."""
    kern = None
    kind = type(fn)
    if kind in (shp.Sphere, shp.Disc):
        # f = (|x - c|^2 - r^2) / (2 r), grad = (x - c) / r (a ball's placement rotation drops out)
        r, c = float(fn.radius), tuple(fn.center.tolist())
        inv2r, rr = 1.0 / (2.0 * r), r * r
        if len(c) == 3:
            def kern(x, c0=c[0], c1=c[1], c2=c[2]):
                y0, y1, y2 = x[0] - c0, x[1] - c1, x[2] - c2
                return (y0 * y0 + y1 * y1 + y2 * y2 - rr) * inv2r, (y0 / r, y1 / r, y2 / r)
        else:
            def kern(x, c0=c[0], c1=c[1]):
                y0, y1 = x[0] - c0, x[1] - c1
                return (y0 * y0 + y1 * y1 - rr) * inv2r, (y0 / r, y1 / r)
    elif kind in (shp.HalfSpace, shp.HalfPlane):
        # f = n . x - d with the placed plane (n, d) = plane(); grad = n
        n_b, off = fn.plane()
        n = tuple(float(v) for v in n_b)
        off = float(off)
        if len(n) == 3:
            def kern(x, n0=n[0], n1=n[1], n2=n[2]):
                return n0 * x[0] + n1 * x[1] + n2 * x[2] - off, n
        else:
            def kern(x, n0=n[0], n1=n[1]):
                return n0 * x[0] + n1 * x[1] - off, n
    elif isinstance(fn, shp._PowerSumBase) and fn._single:
        # X = R0^T (x - c) / a: f = (s/q)(sum |X_i|^q - 1), grad = R0 (s |X_i|^(q-1) sgn X_i / a_i)
        a = tuple(float(v) for v in fn.semi_axes)
        q, sm = float(fn._n1), float(fn._s)
        c = tuple(float(v) for v in fn._c0)
        R0 = tuple(map(tuple, np.asarray(fn._R0, float).tolist()))
        V = _VEC[len(a)]
        kq = sm / q

        def kern(x):
            v, gl = 0.0, []
            for u, ai in zip(V.mtv(R0, V.sub(x, c)), a):
                X = u / ai
                A1 = abs(X) ** (q - 1.0)
                v += A1 * abs(X)
                gl.append(sm * (A1 if X >= 0.0 else -A1) / ai)
            return kq * (v - 1.0), V.mv(R0, gl)
    elif kind in (shp.Ellipsoid, shp.Ellipse):
        # xl = R0^T (x - c), X = xl / a: f = (s/2)(|X|^2 - 1), grad = R0 (s X / a), s = (prod a)^(1/d)
        a = tuple(float(v) for v in fn.semi_axes)
        dim = len(a)
        sm = float(np.prod(fn.semi_axes) ** (1.0 / dim))
        c = tuple(fn.center.tolist())
        R0 = tuple(map(tuple, fn.rotation_matrix.tolist()))
        V = _VEC[dim]

        def kern(x):
            xl = V.mtv(R0, V.sub(x, c))
            X = [u / ai for u, ai in zip(xl, a)]
            gl = [sm * u / ai for u, ai in zip(X, a)]
            return 0.5 * sm * (sum(u * u for u in X) - 1.0), V.mv(R0, gl)
    if kern is not None and not _kernel_agrees(fn, kern):
        kern = None
    return kern


def _kernel_agrees(fn, kern):
    rng = np.random.default_rng(0)
    for _ in range(3):
        x = rng.normal(size=fn.dim) * 0.7
        v, g = fn.value_gradient(x)
        kv, kg = kern(tuple(x.tolist()))
        scale = 1.0 + abs(float(v)) + float(np.max(np.abs(g)))
        if abs(kv - float(v)) > 1e-12 * scale or np.max(np.abs(np.array(kg) - g)) > 1e-12 * scale:
            return False
    return True


def _evaluate(funcs, infos, S: _BodyNow, a, V, need_h):
    """Hot-path body functions at the world point a: r = a - p, values f, world gradients G
    (tuples), per function its body-frame Hessian (evaluated if it varies and need_h, else the
    constant info of _function_info; None if it varies and is not needed), and xi as an array
    (None if only kernels ran)."""
    r = V.sub(a, S.p)
    xi = V.mtv(S.R, r)                  # xi = R^T (a - p)
    R = S.R
    f, G, H = [], [], []
    x = None
    for fn, (kern, hi) in zip(funcs, infos):
        if kern is not None:
            v, g = kern(xi)
            if type(hi) is _HessianKernel:
                hi = hi.at(xi) if need_h else (hi, xi)      # see _late_hessian
        else:
            if x is None:
                x = np.array(xi)
            if need_h and hi is None:
                v, g, hi = fn.value_gradient_hessian(x)
            else:
                v, g = fn.value_gradient(x)
            g = g.tolist()
        f.append(v)
        G.append(V.mv(R, g))
        H.append(hi)
    return r, f, G, H, x


def _hessian_sum(weights, H, S: _BodyNow):
    """sum_i w_i R H_i R^T as (s, M): s I + M, M (rows) None when every H_i is a multiple of I."""
    s, Mb = 0.0, None
    for w, Hi in zip(weights, H):
        if isinstance(Hi, float):
            s += w * Hi
        else:
            Mb = w * Hi if Mb is None else Mb + w * Hi
    if Mb is None:
        return s, None
    Rn = S.Rn
    return s, (Rn @ Mb @ Rn.T).tolist()


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
    compliance: object = None  # an ic.Compliance: a quasi-rigid pair (see quasi_rigid.py)
    compliant_side: int = 2    # which body carries the deformed layer
    delta_prev: float = 0.0    # its normal deflection at l
    generic: bool = False      # evaluate on the generic numpy path (quasi_rigid.CompliantPair), e.g.
    #                            a pair with an ARTICULATED body; compliance implies it


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
    supports: tuple = ()       # support.SupportSlots per support block (after all pairs)


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


_REDUCED_CACHE = weakref.WeakKeyDictionary()


def _reduced_point(obj: ContactObject, kin: "BodyKinematics"):
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


def _reduced_point_uncached(obj: ContactObject, kin: "BodyKinematics"):
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
    return np.array([n, t, _V3.cross(n, t)])


def build_layout(nv_per_skeleton: list, specs: list, supports: tuple = ()) -> Layout:
    """Allocate z: velocities first, then each pair's unknowns, then the support blocks'
    (support.SupportSpec); rows follow the same order."""
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
        dbar = dn = p_nr = -1
        if spec.compliance is not None:
            dbar, dn = col, col + 1
            col += 2
            lower += [-np.inf, -np.inf]; upper += [np.inf, np.inf]
            if math.isfinite(spec.compliance.delta_max):
                p_nr = col; col += 1
                lower.append(0.0); upper.append(np.inf)
        slots.append(PairSlots(a1, a2, l1, l2, p_n, p_t, p_r, sigma, rows_geo, rows_l1, rows_l2,
                               p_n, rows_fric, dbar, dn, p_nr))
    from .support import allocate
    support_slots, col = allocate(col, supports, lower, upper)
    return Layout(col, v_index, slots, np.array(lower), np.array(upper), tuple(support_slots))


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


class _Side:
    """A moving body of a pair: the sign of the pair's impulse on it (+1 body 2, -1 body 1), its
    velocity rows vs in z (F), the same rows in the plan's Jacobian block jv (vs itself on the
    dense path, local rows on the sparse path), and the block columns of omega and v_o (free
    v = [omega; v_o], planar v = [v_x, v_y, omega]; see _PairPlan)."""

    __slots__ = ("sign", "vs", "jv", "free", "ow", "ov", "th_rows", "B2w")

    def __init__(self, sign, vs, free, first, jv):
        self.sign, self.vs, self.free, self.jv = sign, vs, free, jv
        self.ow, self.ov = (first, first + 3) if free else (first + 2, first)
        self.th_rows = None            # rows of its TH in the plan's Bg (free bodies: set per call)


class _PairPlan:
    """Everything about one pair that does not depend on z, prepared once per problem.

    Jacobian (see StepProblem._pair). A pair's rows and unknowns form one contiguous block of z,
    and it touches only its moving bodies' velocities, which come first in z. Its Jacobian lives
    on the columns (and rows) of those velocities and of its block, which the plan addresses in
    one of two ways, fixed by the problem (StepProblem: "Jacobian storage"):
      dense: J is the problem's (n x n) array, and the columns are the window [lo, hi) from the
        first of those velocities to the end of the block (``cols``), written through views;
      sparse: J is the pair's own dense block over ``local_index`` = [velocities of body 1,
        velocities of body 2, its block] (rows and columns alike), and ``cols`` is all of it. The
        window of a many-body problem is as wide as z; this block has about 30 columns.
    Every chain-rule term is a small coefficient (built from floats) times a basis row block over
    those columns, so each row family costs one matrix product whatever the number of terms. The
    bases, (rows x columns):

      Bg = [DR11; DR12; TH1; DR22; TH2; E_l1; E_l2]    rows (15)-(19) and dn (TH only if moving)
      B2 = [DR2; dn; E_imp; -DR1; EV2; EW2; -EV1; -EW1]    friction rows, impulse rows (windows)

    DA = da/dz (T of a reduced point), DR = d(a - p)/dz of the lever arms r11 = a1 - p1,
    r12 = a2 - p1 and r22 = a2 - p2 (dp = h dv_o), TH = dtheta/dz (h at a planar body's omega
    column; h J_l(h omega) at a free body's, written per call), EV, EW = dv_o/dz, domega/dz,
    E_l, E_imp = unit rows of the multipliers and of the impulse unknowns p_n .. sigma; dn is
    written per call."""

    def __init__(self, problem, k, spec, sl):
        d = spec.dim
        self.spec, self.sl, self.d, self.dth, self.V = spec, sl, d, 3 if d == 3 else 1, _VEC[d]
        self.b1, self.b2 = spec.obj1.body, spec.obj2.body
        kin1, kin2 = problem.bodies[self.b1], problem.bodies[self.b2]
        if self.b1 == self.b2 and kin1.vindex is not None:
            raise ValueError("a pair needs two different bodies")
        self.fns1, self.fns2 = tuple(spec.obj1.functions), tuple(spec.obj2.functions)
        self.m1, self.m2 = len(self.fns1), len(self.fns2)
        self.infos1 = [_function_info(f) for f in self.fns1]
        self.infos2 = [_function_info(f) for f in self.fns2]
        self.Hc1, self.Hc2 = [hi for _, hi in self.infos1], [hi for _, hi in self.infos2]
        self.fr = sl.sigma >= 0                # the rows the layout has (the stepper toggles
        self.torsion = sl.p_r >= 0             # spec.with_friction between layouts)
        # reduced points of fixed half-spaces: a = a0 + T s, constant gradient, no Hessian
        r1, r2 = problem._reduced[k]
        self.red1 = None if r1 is None else (tuple(r1[0].tolist()), tuple(map(tuple, r1[1].tolist())))
        self.red2 = None if r2 is None else (tuple(r2[0].tolist()), tuple(map(tuple, r2[1].tolist())))
        self.Gc1 = self.Gc2 = None
        if r1 is not None:
            self.Gc1 = _evaluate(self.fns1, self.infos1, problem._states[self.b1], self.red1[0], self.V, False)[2]
        if r2 is not None:
            self.Gc2 = _evaluate(self.fns2, self.infos2, problem._states[self.b2], self.red2[0], self.V, False)[2]
        self.axis_src = self.axis = None       # spec.tangent_axis as floats (the stepper may set it late)
        # the rest depends only on the layout, the bodies' kinds, columns and h, and the reduced
        # points' T: built once and kept with the layout's slots (the stepper reuses layouts)
        compact = problem._sparse
        key = (d, kin1.kind, kin2.kind, kin1.h, kin2.h, _first(kin1.vindex), _first(kin2.vindex),
               None if r1 is None else r1[1].tobytes(), None if r2 is None else r2[1].tobytes(), compact)
        cache = sl.__dict__.setdefault("_plan_geometry", {})
        geometry = cache.get(key)
        if geometry is None:
            if len(cache) > 16:
                cache.clear()
            geometry = cache[key] = _pair_geometry(sl, d, kin1, kin2, problem._vslice[self.b1],
                                                   problem._vslice[self.b2], r1, r2, self.fr, compact)
        self.__dict__.update(geometry)


def _first(index):
    return None if index is None else int(index[0])


def _pair_geometry(sl, d, kin1, kin2, vs1, vs2, r1, r2, fr, compact=False):
    """The z-independent attributes of a _PairPlan that depend on the layout and the bodies only
    (row and column slices, moving sides, the bases Bg and B2), as a dict. compact: address the
    Jacobian as the pair's own block over local_index (the sparse path, see _PairPlan)."""
    dth = 3 if d == 3 else 1
    m1, m2 = len(sl.l1), len(sl.l2)
    g = {}
    # rows: (15)-(19) are the block's first rows up to p_n; friction, torsion and cone rows the
    # rest (rows share the indices of the unknowns they pair with)
    c0 = int(sl.rows_geo[0])
    hi = (sl.sigma if fr else sl.p_n) + 1
    g["rows"] = slice(c0, hi)
    g["n_geo"] = sl.p_n + 1 - c0
    # the Jacobian's columns: segments (first index in z, count, first column of J's block)
    moving = [(int(kin.vindex[0]), len(kin.vindex)) for kin in (kin1, kin2) if kin.vindex is not None]
    if compact:
        segs, at = [], 0
        for first, count in moving + [(c0, hi - c0)]:
            segs.append((first, count, at))
            at += count
        nw = at
        g["local_index"] = np.concatenate([np.arange(f, f + c) for f, c, _ in segs])
    else:
        lo = min([c0] + [first for first, _ in moving])
        segs, nw = [(lo, hi - lo, 0)], hi - lo
        g["local_index"] = None

    def loc(index):
        """The column of J's block (and, on the sparse path, its row) of index in z."""
        for first, count, at in segs:
            if first <= index < first + count:
                return index - first + at
        raise AssertionError("an index outside the pair's columns")

    def rows_of(first, count):
        """Rows first .. first + count of z as J's rows (a slice)."""
        return slice(loc(first), loc(first) + count) if compact else slice(first, first + count)

    g["cols"] = slice(0, nw) if compact else slice(segs[0][0], segs[0][0] + nw)
    g["geo_rows"] = rows_of(c0, sl.p_n + 1 - c0)
    g["fric_rows"] = rows_of(int(sl.p_t[0]), hi - int(sl.p_t[0])) if fr else None
    side2 = side1 = None
    if kin2.vindex is not None:
        first = int(kin2.vindex[0])
        side2 = _Side(1.0, vs2, kin2.kind == FREE, loc(first), rows_of(first, len(kin2.vindex)) if compact else vs2)
    if kin1.vindex is not None:
        first = int(kin1.vindex[0])
        side1 = _Side(-1.0, vs1, kin1.kind == FREE, loc(first), rows_of(first, len(kin1.vindex)) if compact else vs1)
    g["side1"], g["side2"] = side1, side2

    def unit(first, count):
        """Unit rows of the unknowns first .. first + count of z."""
        E = np.zeros((count, nw))
        E[:, loc(first):loc(first) + count] = np.eye(count)
        return E

    def unit_local(at, count):
        E = np.zeros((count, nw))
        E[:, at:at + count] = np.eye(count)
        return E

    DA1, DA2 = np.zeros((d, nw)), np.zeros((d, nw))
    DA1[:, loc(int(sl.a1[0])):loc(int(sl.a1[-1])) + 1] = _EYE[d] if r1 is None else r1[1]
    DA2[:, loc(int(sl.a2[0])):loc(int(sl.a2[-1])) + 1] = _EYE[d] if r2 is None else r2[1]
    EV, EW, DP, TH = {}, {}, {None: 0.0}, {}
    for side, kin in ((side1, kin1), (side2, kin2)):
        if side is not None:
            EV[side], EW[side] = unit_local(side.ov, d), unit_local(side.ow, dth)
            DP[side] = kin.h * EV[side]
            TH[side] = np.zeros((3, nw)) if side.free else kin.h * EW[side]
    DR11, DR12, DR22 = DA1 - DP[side1], DA2 - DP[side1], DA2 - DP[side2]
    blocks = [DR11, DR12]
    if side1 is not None:
        side1.th_rows = slice(2 * d, 2 * d + dth)
        blocks.append(TH[side1])
    blocks.append(DR22)
    if side2 is not None:
        n0 = sum(len(b) for b in blocks)
        side2.th_rows = slice(n0, n0 + dth)
        blocks.append(TH[side2])
    blocks += [unit(int(sl.l1[0]), m1), unit(int(sl.l2[0]), m2)]
    g["Bg"] = np.vstack(blocks)
    # B2 = [DR2; dn; E_imp; -DR1; EV2; EW2; -EV1; -EW1] (absent sides dropped; body 1's blocks
    # carry its sign -1 of v_rel = v_2 - v_1). A body's impulse rows need only [DR2; dn; E_imp]
    # (body 2) or [dn; E_imp; -DR1] (body 1): windows of B2.
    g["n_imp"] = n_imp = hi - sl.p_n
    blocks = ([DR22] if side2 else []) + [np.zeros((d, nw)), unit(sl.p_n, n_imp)]
    blocks += [-DR11] if side1 else []
    blocks += ([EV[side2], EW[side2]] if side2 else []) + ([-EV[side1], -EW[side1]] if side1 else [])
    g["B2"] = B2 = np.vstack(blocks)
    o = d if side2 else 0
    g["dn_rows"] = slice(o, o + d)
    if side2:
        side2.B2w = B2[:2 * d + n_imp]
    if side1:
        side1.B2w = B2[o:o + 2 * d + n_imp]
    g["K2"] = len(B2)
    # zero coefficient blocks
    g["zd"], g["zth"], g["zvw"] = (0.0,) * d, (0.0,) * dth, (0.0,) * (d + dth)
    g["zl1"], g["zl2"] = (0.0,) * m1, (0.0,) * m2
    return g


class StepProblem:
    """F(z) and dF/dz of one geometrically implicit step, for ``ncp.solve_mcp``.

    ``fun`` evaluates the rows only (line-search trials need no Jacobian); ``jac`` evaluates both
    and caches them for the last z. Both run the same code for the rows (``_pair``), so F is
    bitwise the same either way; the solver asks for J where it has just evaluated F, and then
    ``jac`` only finishes the pair evaluations that ``fun`` left suspended.

    Jacobian storage. Below SPARSE_MIN_UNKNOWNS unknowns (``jacobian="auto"``) J is a dense
    (n x n) array; from there on a scipy.sparse CSR matrix (``ncp.solve_mcp`` then factorises it
    with sparse LU). A many-body problem has thousands of unknowns but each pair touches about 30
    of them: dense J and its LU grow as n^2 and n^3, and a pair's dense column window (see
    _PairPlan) as wide as z. The sparse path gives every plan a dense block over its own indices
    and sums the blocks into CSR through a pattern fixed per problem (_sparse_pattern).

    Plan protocol (every entry of ``_plans``: the hot-path pairs _PairPlan, and the generic
    plans quasi_rigid.CompliantPair and support.SupportPlan; a new kind of block follows it):
      * ``plan.generator(z, F)`` returns a generator. ``next()`` adds the plan's rows into F
        (unscaled; F's rows are scaled afterwards) and yields its report (pairs) or None.
        ``send(J)`` then adds its Jacobian entries into J and yields (the rows' frame is kept,
        so nothing is recomputed); J may also never be sent (fun only).
      * ``plan.local_index``: the indices of z of every row and every column it writes into J
        (its own rows / unknowns and its bodies' velocities), an int array.
      * J is addressed with z's indices, ``J[rows, cols] = ...`` / ``+=`` / ``-=``, rows and
        cols each an int, a contiguous slice or an index array: on the dense path J is the
        (n x n) array, on the sparse path a _LocalJacobian over local_index (writing outside
        it raises IndexError). Entries start at zero and several plans may add to one entry
        (the velocity rows of a body); a plan must not read entries others wrote. The hot
        path _PairPlan instead receives the plain local block (its slices are precomputed).
    Row scaling (_row_scale) is applied by the assembly, after every plan has written."""

    def __init__(self, h: float, skeletons: list, bodies: list, specs: list, layout: Layout,
                 supports: tuple = (), jacobian: str = "auto"):
        if jacobian not in ("auto", "dense", "sparse"):
            raise ValueError(f"jacobian must be 'auto', 'dense' or 'sparse', got {jacobian!r}")
        self.h = h
        # Jacobian storage (see the class docstring): sparse from SPARSE_MIN_UNKNOWNS unknowns
        self._sparse = jacobian == "sparse" or (jacobian == "auto" and layout.n >= SPARSE_MIN_UNKNOWNS)
        self.supports = tuple(supports)    # support.SupportSpec per layout.supports block
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
        scale[_position_rows(layout)] = 1.0 / h
        self._row_scale = scale
        self._row_scale_col = scale[:, None]
        self._body_skel = {sk.body: s for s, sk in enumerate(skeletons)}
        self._vslice = [_as_slice(b.vindex) if b.vindex is not None else None for b in bodies]
        self._skel = [(_as_slice(lay_v), sk.M, sk.v, h * sk.force)
                      for lay_v, sk in zip(layout.v_index, skeletons)]
        self._reduced = []
        for spec in specs:
            r1 = _reduced_point(spec.obj1, bodies[spec.obj1.body]) if spec.obj1.fixed_halfspace else None
            r2 = _reduced_point(spec.obj2, bodies[spec.obj2.body]) if spec.obj2.fixed_halfspace else None
            self._reduced.append((r1, r2))
        # hot-path body data: fixed bodies' poses once; moving bodies' R0 rows and p0 (q0 planar)
        self._states = []
        self._moving = []
        for b, kin in enumerate(bodies):
            if kin.kind == ARTICULATED:
                self._states.append(None)      # generic pairs only: no hot-path state
                continue
            if kin.vindex is None:
                d = kin.dim
                R = tuple(map(tuple, np.asarray(kin.R0, float)[:d, :d].tolist()))
                p = tuple(np.asarray(kin.p0, float)[:d].tolist())
                self._states.append(_BodyNow(R, p, (0.0,) * (3 if d == 3 else 1), (0.0,) * d))
            else:
                self._states.append(None)
                R0 = tuple(map(tuple, np.asarray(kin.R0, float).tolist()))
                base = kin.p0 if kin.kind == FREE else kin.q0
                self._moving.append((b, kin, self._vslice[b], R0, tuple(np.asarray(base, float).tolist())))
        from .quasi_rigid import CompliantPair
        self._plans = [CompliantPair(self, k) if self._generic(spec) else _PairPlan(self, k, spec, sl)
                       for k, (spec, sl) in enumerate(zip(specs, layout.pairs))]
        if len(self.supports) != len(layout.supports):
            raise ValueError("the layout's support blocks and the problem's supports differ")
        from .support import SupportPlan
        self._plans += [SupportPlan(self, sp, ss) for sp, ss in zip(self.supports, layout.supports)]
        self._n_pairs = len(specs)
        self._pattern = None       # the sparse path's index pattern (see _sparse_pattern)
        self._key_f = self._key_j = None
        self._F = self._J = None
        self._reports = None       # per-pair quantities at _key_f as floats (see _pairs_at)
        self._reports_np = None
        self._resume = None        # the suspended pair evaluations at _key_f (see _pair)

    def _generic(self, spec) -> bool:
        """Pairs the hot path (_PairPlan) does not handle: quasi-rigid pairs, pairs flagged
        generic, and pairs with an ARTICULATED body."""
        return (spec.compliance is not None or spec.generic
                or ARTICULATED in (self.bodies[spec.obj1.body].kind, self.bodies[spec.obj2.body].kind))

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
            self._F, reports, self._resume = self._rows(z, False)
            self._reports, self._reports_np = reports, None
            self._key_f = z.copy()
        return self._F

    def jac(self, z):
        if self._key_j is None or not np.array_equal(z, self._key_j):
            if self._resume is not None and np.array_equal(z, self._key_f):
                # the solver asks for J where it last evaluated F: finish those evaluations
                J = self._jacobian(self._resume)
            else:
                F, reports, resume = self._rows(z, True)
                J = self._jacobian(resume)
                self._F, self._key_f, self._reports, self._reports_np = F, z.copy(), reports, None
            self._resume = None
            self._key_j = z.copy()
            self._J = J
        return self._J

    def _assemble(self, z, need_jac):
        """(F, J or None, per pair (a1, a2, normal, tangents, gap, v_rel) as arrays)."""
        F, reports, resume = self._rows(z, need_jac)
        return F, (self._jacobian(resume) if need_jac else None), [_report_arrays(r) for r in reports]

    @property
    def _pairs_at(self):
        """Per pair (a1, a2, normal, tangents, gap, v_rel) at the last evaluated z, as arrays
        (made on demand: the evaluations keep them as floats)."""
        if self._reports_np is None and self._reports is not None:
            self._reports_np = [_report_arrays(r) for r in self._reports]
        return self._reports_np

    def _rows(self, z, need_hessians):
        """F (scaled), the pairs' reports (floats), and per pair the suspended evaluation that
        makes its Jacobian when resumed (see _pair). need_hessians: evaluate varying Hessians
        right away."""
        n = self.layout.n
        F = np.zeros(n)
        zl = z.tolist()                  # the hot path reads unknowns as floats
        states = list(self._states)
        for b, kin, vs, R0, p0 in self._moving:
            states[b] = _body_now(kin, R0, p0, zl[vs])
        for vs, M, v, hforce in self._skel:
            F[vs] = M @ (z[vs] - v) - hforce
        resume = [self._pair(pl, zl, states, F, need_hessians) if isinstance(pl, _PairPlan)
                  else pl.generator(z, F) for pl in self._plans]
        pairs = [next(g) for g in resume][: self._n_pairs]     # support blocks yield no report
        F *= self._row_scale
        return F, pairs, resume

    def _jacobian(self, resume):
        if self._sparse:
            return self._jacobian_sparse(resume)
        n = self.layout.n
        J = np.zeros((n, n))
        for vs, M, _, _ in self._skel:
            J[vs, vs] = M
        for g in resume:
            g.send(J)
        J *= self._row_scale_col
        return J

    def _sparse_pattern(self):
        """The sparse path's fixed pattern (the layout does not change within a problem): every
        block (a skeleton's M, a plan's Jacobian block over its local_index) is a dense square
        view into one value buffer; summing duplicates of (row, column) in CSR order is one
        bincount through a precomputed slot per buffer entry."""
        n = self.layout.n
        index = [np.arange(vs.start, vs.stop) for vs, _, _, _ in self._skel]
        index += [np.asarray(pl.local_index, dtype=np.int64) for pl in self._plans]
        sizes = [len(ix) * len(ix) for ix in index]
        ends = np.cumsum([0] + sizes)
        values = np.zeros(int(ends[-1]))
        views = [values[a:b].reshape(len(ix), len(ix)) for a, b, ix in zip(ends[:-1], ends[1:], index)]
        if index:
            rows = np.concatenate([np.repeat(ix, len(ix)) for ix in index])
            cols = np.concatenate([np.tile(ix, len(ix)) for ix in index])
        else:
            rows = cols = np.zeros(0, np.int64)
        keys, slot = np.unique(rows * n + cols, return_inverse=True)
        entry_rows = keys // n
        indptr = np.zeros(n + 1, np.int64)
        np.cumsum(np.bincount(entry_rows, minlength=n), out=indptr[1:])
        n_sk = len(self._skel)
        blocks = [view if isinstance(pl, _PairPlan) else _LocalJacobian(view, ix)
                  for pl, view, ix in zip(self._plans, views[n_sk:], index[n_sk:])]
        self._pattern = (values, views[:n_sk], blocks, slot.ravel(), len(keys), keys % n, indptr,
                         self._row_scale[entry_rows])
        return self._pattern

    def _jacobian_sparse(self, resume):
        """J as a scipy.sparse CSR matrix from the plans' blocks (see _sparse_pattern)."""
        values, sk_views, blocks, slot, nnz, indices, indptr, scale = self._pattern or self._sparse_pattern()
        values[:] = 0.0
        for view, (_, M, _, _) in zip(sk_views, self._skel):
            view[:] = M
        for g, block in zip(resume, blocks):
            g.send(block)
        data = np.bincount(slot, weights=values, minlength=nnz)
        data *= scale
        n = self.layout.n
        return _sparse.csr_matrix((data, indices, indptr), shape=(n, n))

    def _pair(self, pl: _PairPlan, zl, states, F, need_h):
        """One pair, in two phases (a generator). next() writes its rows into F and yields its
        report (a1, a2, normal, tangents, gap, v_rel); send(J) then writes its Jacobian into J,
        from the same frame: ``jac`` at the point of the last ``fun`` (where the solver always
        asks for it) resumes those evaluations instead of redoing the rows. The rows are
        computed on floats; the Jacobian is the chain rule of the same formulas, as coefficient
        rows times the plan's bases (see _PairPlan)."""
        spec, sl, V, d = pl.spec, pl.sl, pl.V, pl.d
        S1, S2 = states[pl.b1], states[pl.b2]
        side1, side2 = pl.side1, pl.side2
        a1 = zl[sl.a1s] if pl.red1 is None else V.affine(pl.red1, zl[sl.a1s])
        a2 = zl[sl.a2s] if pl.red2 is None else V.affine(pl.red2, zl[sl.a2s])
        l1, l2 = zl[sl.l1s], zl[sl.l2s]
        k1, m1 = spec.k1, pl.m1
        # body functions: lever r = a - p, values, world gradients (Hessian data for the
        # Jacobian). A fixed half-space side has a constant gradient and no value row (l free).
        if pl.red1 is None:
            r11, f1, G1, H1, x11 = _evaluate(pl.fns1, pl.infos1, S1, a1, V, need_h)
        else:
            r11, f1, G1, H1, x11 = None, None, pl.Gc1, pl.Hc1, None
        r12, f12, G12, _, _ = _evaluate(pl.fns1, pl.infos1, S1, a2, V, False)
        if pl.red2 is None:
            r22, f2, G2, H2, x22 = _evaluate(pl.fns2, pl.infos2, S2, a2, V, need_h)
        else:
            r22, f2, G2, H2, x22 = None, None, pl.Gc2, pl.Hc2, None

        # -- (15)-(19)
        if m1 == 1:
            c1, N1 = (1.0,), G1[0]
        else:
            c1 = list(l1)
            c1[k1] = 1.0                 # N1 = sum_i c_i G_i with c_k1 = 1
            N1 = V.comb(c1, G1)
        lk = l1[k1]
        N2 = V.comb(l2, G2)
        rows = [*V.axpy(lk, N1, V.sub(a1, a2)), *V.add(N1, N2)]       # (15) / (28), (16) / (29)
        if f1 is not None:
            rows += [-x for x in f1]                                   # (17) / (30)
        if f2 is not None:
            rows += [-x for x in f2]                                   # (18) / (31)
        ia = 0 if m1 == 1 else max(range(m1), key=f12.__getitem__)     # the first maximiser
        gap = f12[ia]
        rows.append(gap)                                               # (19) / (32)

        # -- normal, tangents (Gram-Schmidt on the pair's axis in 3D), impulse on body 2
        nrm = math.sqrt(V.dot(N1, N1))
        n = V.scale(1.0 / nrm, N1)
        if d == 3:
            if spec.tangent_axis is not pl.axis_src:
                pl.axis_src, pl.axis = spec.tangent_axis, tuple(float(x) for x in spec.tangent_axis)
            e = pl.axis
            en = V.dot(e, n)
            u = V.axpy(-en, n, e)
            nu = math.sqrt(V.dot(u, u))
            t = V.scale(1.0 / nu, u)
            tang = (t, V.cross(n, t))
        else:
            tang = ((-n[1], n[0]),)
        s_p = spec.impulse_scale
        fr, torsion = pl.fr, pl.torsion
        p_n = zl[sl.p_n]
        p_t = zl[sl.p_ts] if fr else ()
        p_r = zl[sl.p_r] if torsion else 0.0
        e_r = spec.friction.e_r
        P = V.scale(s_p * p_n, n)
        for pa, ta in zip(p_t, tang):
            P = V.axpy(s_p * pa, ta, P)
        tau = V.scale(s_p * e_r * p_r, n) if torsion else None
        # generalized impulses: +P at a2 (moment +tau) on body 2, -P at a1 (-tau) on body 1;
        # a force P at lever r is the moment r x P and the force P
        for side, r in ((side2, r22), (side1, r11)):
            if side is None:
                continue
            gw = V.cross(r, P)
            if torsion:
                gw = V.add(gw, tau)
            gen = gw + P if side.free else P + gw
            if side.sign > 0.0:
                F[side.vs] -= gen
            else:
                F[side.vs] += gen

        # -- friction (21)-(22)
        vrel = None
        if fr:
            mu = spec.friction.mu
            e_ax = (spec.friction.e_t, spec.friction.e_o)
            sigma = zl[sl.sigma]
            vrel = (0.0,) * d                # v_2(a2) - v_1(a1): v_o + omega x r of each body
            wrel = (0.0,) * pl.dth
            if side2 is not None:
                vrel = V.add(vrel, V.add(S2.vo, V.wcross(S2.w, r22)))
                wrel = S2.w
            if side1 is not None:
                vrel = V.sub(vrel, V.add(S1.vo, V.wcross(S1.w, r11)))
                wrel = V.sub(wrel, S1.w) if d == 3 else (wrel[0] - S1.w[0],)
            cone = (mu * p_n) ** 2
            vt = [V.dot(ta, vrel) for ta in tang]
            for a in range(d - 1):
                rows.append(e_ax[a] ** 2 * mu * p_n * vt[a] + p_t[a] * sigma)
                cone -= (p_t[a] / e_ax[a]) ** 2
            if torsion:
                # e_r mu p_n (n . w_rel) + p~_r sigma = 0, p_r = e_r p~_r
                wn = V.dot(n, wrel)
                rows.append(e_r * mu * p_n * wn + p_r * sigma)
                cone -= p_r ** 2
            rows.append(cone)                                          # (22)
        F[pl.rows] = rows
        J = yield a1, a2, n, tang, gap, vrel

        # ---- Jacobian. Material displacement of a point of a body (the world change of
        # R^T (a - p)): DM = DR - X(r) TH; then df = G . DM and dG = X(G) TH + Hw DM, so for
        # N = sum_i w_i G_i (N1: w = c, N2: w = l2) dN = H DR + C TH + (G_i at the l_i columns)
        # with H = sum_i w_i Hw_i and C = X(N) - H X(r). Row by row over the blocks of Bg.
        I, mI, zd, zth = V.I, _NEG_I[d], pl.zd, pl.zth
        has1, has2 = side1 is not None, side2 is not None
        zt1, zt2 = (zth if has1 else ()), (zth if has2 else ())
        Bg = pl.Bg
        if has1 and side1.free:
            S1.theta_into(Bg[side1.th_rows, side1.ow:side1.ow + 3])
        if has2 and side2.free:
            S2.theta_into(Bg[side2.th_rows, side2.ow:side2.ow + 3])
        # Hessians that vary with the point and were not evaluated with the rows
        H1 = [_late_hessian(fn, hi, x11) for fn, hi in zip(pl.fns1, H1)]
        H2 = [_late_hessian(fn, hi, x22) for fn, hi in zip(pl.fns2, H2)]
        s1, M1 = _hessian_sum(c1, H1, S1)
        s2, M2 = _hessian_sum(l2, H2, S2)
        H1r, C1 = _curvature(s1, M1, N1, r11, V, has1)
        H2r, C2 = _curvature(s2, M2, N2, r22, V, has2)
        Pn = _normalizer(n, nrm)                                       # dn = Pn dN1
        PH1 = V.mm(Pn, H1r) if M1 is not None else tuple(V.scale(s1, row) for row in Pn)   # Pn H1
        PC1 = V.mm(Pn, C1) if has1 else ((),) * d
        if m1 == 1:
            l15, l16, ldn = tuple((x,) for x in N1), ((0.0,),) * d, ((0.0,),) * d
        else:
            PG = [V.mv(Pn, g) for g in G1]
            l15 = tuple(tuple(N1[i] if j == k1 else lk * G1[j][i] for j in range(m1)) for i in range(d))
            l16 = tuple(tuple(0.0 if j == k1 else G1[j][i] for j in range(m1)) for i in range(d))
            ldn = tuple(tuple(0.0 if j == k1 else PG[j][i] for j in range(m1)) for i in range(d))
        G2T = tuple(zip(*G2))
        zl1, zl2 = pl.zl1, pl.zl2
        lkC1 = tuple(V.tscale(lk, c) for c in C1) if has1 else C1
        flat = []                        # coefficient rows, concatenated
        for i in range(d):                                             # (15)
            flat += V.axpy(lk, H1r[i], I[i]) + mI[i] + lkC1[i] + zd + zt2 + l15[i] + zl2
        for i in range(d):                                             # (16)
            flat += H1r[i] + zd + C1[i] + H2r[i] + C2[i] + l16[i] + G2T[i]
        if f1 is not None:                                             # (17): -G DM11
            for g in G1:
                flat += V.scale(-1.0, g) + zd + (V.cross(r11, g) if has1 else ()) + zd + zt2 + zl1 + zl2
        if f2 is not None:                                             # (18): -G DM22
            for g in G2:
                flat += zd + zd + zt1 + V.scale(-1.0, g) + (V.cross(r22, g) if has2 else ()) + zl1 + zl2
        g = G12[ia]                                                    # (19): G DM12
        flat += zd + g + (V.tscale(-1.0, V.cross(r12, g)) if has1 else ()) + zd + zt2 + zl1 + zl2
        for i in range(d):                                             # dn
            flat += PH1[i] + zd + PC1[i] + zd + zt2 + ldn[i] + zl2
        out = np.fromiter(flat, float, len(flat)).reshape(-1, len(Bg)) @ Bg
        ng = pl.n_geo
        J[pl.geo_rows, pl.cols] = out[:ng]
        dn = out[ng:]

        # -- rows downstream of n: friction, torsion, cone and the generalized impulses, over the
        # blocks of B2 = [DR2; dn; E_imp; -DR1; EV2; EW2; -EV1; -EW1] (E_imp: p_n, p_t.., p_r, sigma)
        B2 = pl.B2
        B2[pl.dn_rows] = dn
        if fr:
            Dt = _tangent_derivatives(n, e, en, t, nu, tang[1]) if d == 3 else (_ROT90_ROWS,)
            zt = (0.0,) * (d - 1)
            p_r_pad = (0.0,) if torsion else ()
            z2, z1 = (zd if has2 else ()), (zd if has1 else ())
            flat = []                    # coefficient rows, concatenated
            for a in range(d - 1):
                # e_a^2 mu p_n (t_a . v_rel) + p_t[a] sigma; d v_rel = sum_bodies +-(EV + X(r) EW + W DR)
                ta, ea2 = tang[a], e_ax[a] ** 2
                ca = ea2 * mu * p_n
                cta = V.scale(ca, ta)
                flat += (V.vW(cta, S2.w) if has2 else ()) + V.scale(ca, V.mtv(Dt[a], vrel))
                flat.append(ea2 * mu * vt[a])
                flat += zt[:a] + (sigma,) + zt[a + 1:] + p_r_pad
                flat.append(p_t[a])
                if has1:
                    flat += V.vW(cta, S1.w)
                if has2:
                    flat += cta + V.cross(r22, cta)
                if has1:
                    flat += cta + V.cross(r11, cta)
            if torsion:
                # e_r mu p_n (n . w_rel) + p~_r sigma; d w_rel = EW2 - EW1
                cr = e_r * mu * p_n
                crn = V.scale(cr, n)
                flat += z2 + V.scale(cr, wrel) + (e_r * mu * wn,) + zt + (sigma, p_r) + z1
                if has2:
                    flat += zd + crn
                if has1:
                    flat += zd + crn
            flat += z2 + zd                                            # the cone row
            flat.append(2.0 * mu * mu * p_n)
            flat += tuple(-2.0 * pa / ea ** 2 for pa, ea in zip(p_t, e_ax)) + ((-2.0 * p_r,) if torsion else ())
            flat.append(0.0)
            flat += z1 + (pl.zvw if has2 else ()) + (pl.zvw if has1 else ())
            C = np.fromiter(flat, float, len(flat)).reshape(-1, pl.K2)
            J[pl.fric_rows, pl.cols] = C @ B2
        # generalized impulses of P = s_p (p_n n + sum_a p_t[a] t_a) and tau = s_p e_r p_r n:
        # rows -sign (d(r x P + tau); dP), with dP = DPn dn + s_p (n, t_a at p_n, p_t) and
        # d(r x P) = X(r)^T dP - X(P)^T DR = ... - sign X(P)^T (sign DR), sign DR in the window
        if has1 or has2:
            DPn = _dP_dn(s_p * p_n, [s_p * pa for pa in p_t], Dt if fr else (), d)
            sn, st = V.scale(s_p, n), ([V.scale(s_p, ta) for ta in tang] if fr else [])
            c_tau, ern = s_p * e_r * p_r, V.scale(s_p * e_r, n)
            imp_end = (0.0,) * (pl.n_imp - d)                          # p_r, sigma
            # force rows: dn columns DPn, impulse columns s_p n, s_p t_a (p_r and sigma: none)
            vcore = [(*dp, *pc, *imp_end) for dp, pc in zip(DPn, zip(sn, *st))]
            # moment rows: impulse column p_r carries s_p e_r n (tau), sigma none
            wtail = [(x, 0.0) for x in ern] if torsion else [(0.0,) if fr else ()] * pl.dth
            XPT = {1.0: V.XT(V.scale(-1.0, P)), -1.0: V.XT(P)}         # -sign X(P)^T
            for side, r in ((side2, r22), (side1, r11)):
                if side is None:
                    continue
                XD = V.mm(V.XT(r), DPn)                                # X(r)^T dP / dn
                if torsion:
                    XD = [V.add(row, Ii) for row, Ii in zip(XD, V.sI(c_tau))]   # + d tau / dn
                moments = zip(V.cross(r, sn), *[V.cross(r, x) for x in st])   # r x (s_p n), r x (s_p t_a)
                wrows = [(dr, (*xd, *mc, *tl)) for dr, xd, mc, tl in zip(XPT[side.sign], XD, moments, wtail)]
                rows_ = wrows + [(zd, v) for v in vcore] if side.free else [(zd, v) for v in vcore] + wrows
                flat = []
                if side is side2:
                    for drc, rest in rows_:
                        flat += drc + rest
                else:
                    for drc, rest in rows_:
                        flat += rest + drc
                C = np.fromiter(flat, float, len(flat)).reshape(-1, 2 * d + pl.n_imp)
                if side.sign > 0.0:
                    J[side.jv, pl.cols] -= C @ side.B2w
                else:
                    J[side.jv, pl.cols] += C @ side.B2w
        yield

    # -- reading the solution --------------------------------------------------------------------
    def unpack_pair(self, z, k) -> PairState:
        spec, sl = self.specs[k], self.layout.pairs[k]
        self.fun(z)
        a1, a2, nhat, tang, gap, _ = self._pairs_at[k]
        s_p = spec.impulse_scale
        p_t = s_p * z[sl.p_ts] if sl.sigma >= 0 else np.zeros(spec.dim - 1)   # the rows the layout has
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


class _LocalJacobian:
    """A plan's Jacobian block on the sparse path (see StepProblem, "Jacobian storage"): a dense
    (m, m) array over the plan's local_index (sorted or not; rows and columns alike), indexed
    with z's indices like the dense J: an int, a contiguous slice, or an index array per axis.
    Writing outside local_index raises IndexError."""

    __slots__ = ("array", "index", "_order", "_sorted")

    def __init__(self, array, index):
        self.array, self.index = array, index
        self._order = np.argsort(index, kind="stable")
        self._sorted = index[self._order]

    def _local(self, key):
        if isinstance(key, slice):
            start, stop, step = key.indices(int(self._sorted[-1]) + 1 if len(self._sorted) else 0)
            count = len(range(start, stop, step))
            if count == 0:
                return slice(0, 0)
            at = self._local(start)
            if step != 1 or self._local(start + count - 1) != at + count - 1:
                raise IndexError(f"{key} is not one contiguous block of the plan's local_index")
            return slice(at, at + count)
        keys = np.asarray(key)
        pos = np.searchsorted(self._sorted, keys)
        if np.any(pos >= len(self._sorted)) or np.any(self._sorted[np.minimum(pos, len(self._sorted) - 1)] != keys):
            raise IndexError(f"index {key} is outside the plan's local_index")
        local = self._order[pos]
        return int(local) if local.ndim == 0 else local

    def __getitem__(self, key):
        r, c = key
        return self.array[self._local(r), self._local(c)]

    def __setitem__(self, key, value):
        r, c = key
        self.array[self._local(r), self._local(c)] = value


SPARSE_MIN_UNKNOWNS = 250   # measured crossover of the dense and the sparse J + LU (comparisons/bench_many_bodies.py)

_EMPTY = np.zeros(0)
_ZERO3 = np.zeros(3)
_EYE = {2: np.eye(2), 3: np.eye(3)}
_ROT90_ROWS = ((0.0, -1.0), (1.0, 0.0))


def _report_arrays(report):
    a1, a2, n, tang, gap, vrel = report
    return (np.array(a1), np.array(a2), np.array(n), np.array(tang), float(gap),
            None if vrel is None else np.array(vrel))


def _as_slice(index):
    """A contiguous index array as a slice (layouts only allocate contiguous blocks)."""
    if len(index) == 0:
        return slice(0, 0)
    return slice(int(index[0]), int(index[-1]) + 1)


def _normalizer(n, nrm):
    """Rows of (I - n n^T) / nrm: the derivative of N / |N| at N = nrm n."""
    if len(n) == 3:
        n0, n1, n2 = n
        return (((1.0 - n0 * n0) / nrm, -n0 * n1 / nrm, -n0 * n2 / nrm),
                (-n1 * n0 / nrm, (1.0 - n1 * n1) / nrm, -n1 * n2 / nrm),
                (-n2 * n0 / nrm, -n2 * n1 / nrm, (1.0 - n2 * n2) / nrm))
    n0, n1 = n
    return (((1.0 - n0 * n0) / nrm, -n0 * n1 / nrm), (-n1 * n0 / nrm, (1.0 - n1 * n1) / nrm))


def _tangent_derivatives(n, e, en, t, nu, o):
    """Rows of dt/dn and do/dn for t = u / |u|, u = e - (e.n) n, o = n x t (nu = |u|, en = e.n):
    du/dn = -n e^T - (e.n) I, dt/dn = Q du/dn with Q = (I - t t^T) / nu, do/dn = -[t]x + [n]x dt/dn.
    Written with q = Q n and [n]x Q = ([n]x - o t^T) / nu as sums of outer products."""
    n0, n1, n2 = n
    e0, e1, e2 = e
    t0, t1, t2 = t
    o0, o1, o2 = o
    tn = t0 * n0 + t1 * n1 + t2 * n2
    q0, q1, q2 = (n0 - tn * t0) / nu, (n1 - tn * t1) / nu, (n2 - tn * t2) / nu
    k = en / nu
    # dt/dn = -q e^T - k (I - t t^T)
    dt = ((-q0 * e0 - k * (1.0 - t0 * t0), -q0 * e1 + k * t0 * t1, -q0 * e2 + k * t0 * t2),
          (-q1 * e0 + k * t1 * t0, -q1 * e1 - k * (1.0 - t1 * t1), -q1 * e2 + k * t1 * t2),
          (-q2 * e0 + k * t2 * t0, -q2 * e1 + k * t2 * t1, -q2 * e2 - k * (1.0 - t2 * t2)))
    # do/dn = -[t]x - (n x q) e^T - k ([n]x - o t^T)
    w0, w1, w2 = n1 * q2 - n2 * q1, n2 * q0 - n0 * q2, n0 * q1 - n1 * q0
    do = ((-w0 * e0 + k * o0 * t0, t2 - w0 * e1 - k * (-n2 - o0 * t1), -t1 - w0 * e2 - k * (n1 - o0 * t2)),
          (-t2 - w1 * e0 - k * (n2 - o1 * t0), -w1 * e1 + k * o1 * t1, t0 - w1 * e2 - k * (-n0 - o1 * t2)),
          (t1 - w2 * e0 - k * (-n1 - o2 * t0), -t0 - w2 * e1 - k * (n0 - o2 * t1), -w2 * e2 + k * o2 * t2))
    return dt, do


def _dP_dn(s, c, mats, d):
    """Rows of s I + sum_a c[a] mats[a] (dP/dn = s_p p_n I + sum_a s_p p_t[a] dt_a/dn)."""
    if not mats:
        return ((s, 0.0, 0.0), (0.0, s, 0.0), (0.0, 0.0, s)) if d == 3 else ((s, 0.0), (0.0, s))
    if d == 2:                                          # dt/dn = the 90-degree rotation
        return ((s, -c[0]), (c[0], s))
    c0, c1 = c
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = mats[0]
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = mats[1]
    return ((s + c0 * a00 + c1 * b00, c0 * a01 + c1 * b01, c0 * a02 + c1 * b02),
            (c0 * a10 + c1 * b10, s + c0 * a11 + c1 * b11, c0 * a12 + c1 * b12),
            (c0 * a20 + c1 * b20, c0 * a21 + c1 * b21, s + c0 * a22 + c1 * b22))


def _curvature(s, M, N, r, V, moving):
    """Rows of H = s I + M (M None: 0) and, for a moving body, C = X(N) - H X(r): dN = H DR + C TH.
    Row i of M X(r) is r x M_i (y^T X(r) = (r x y)^T), so no matrix product is needed."""
    H = V.sI(s) if M is None else tuple(V.axpy(s, Ii, Mi) for Ii, Mi in zip(V.I, M))
    if not moving:
        return H, ((),) * len(N)
    if M is None:
        return H, V.X(V.axpy(-s, r, N))                # X is linear: X(N) - s X(r) = X(N - s r)
    XN, Xr = V.X(N), V.X(r)
    return H, tuple(tuple(xa - s * xb - c for xa, xb, c in zip(xn, xr, V.cross(r, Mi)))
                    for xn, xr, Mi in zip(XN, Xr, M))


_NEG_I = {2: ((-1.0, 0.0), (0.0, -1.0)), 3: ((-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0))}


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
    n = tuple(float(x) for x in nhat)
    e = tuple(float(x) for x in axis)
    en = _V3.dot(e, n)
    u = _V3.axpy(-en, n, e)
    nu = math.sqrt(_V3.dot(u, u))
    t = _V3.scale(1.0 / nu, u)
    o = _V3.cross(n, t)
    tang = np.array([t, o])
    if not jac:
        return tang, None
    return tang, [np.array(m) for m in _tangent_derivatives(n, e, en, t, nu, o)]
