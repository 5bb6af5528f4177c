"""Compiled value, gradient and Hessian of every convex function of shapes.py, by integer code.

shapes.py is the Python face of the shapes (validation, placement, boxes, mass properties); the
numbers of f, grad f and Hess f come from here, for the shapes' own methods and for the step's
row kernels alike, so each formula of the shapes' module docstring is written once.

A function is one row ``par`` of NPAR floats (see ``pack``): its code, its dimension and its
placement (centre c0, rotation R0, both in the body frame) and its own parameters. Points are
body-frame 3-vectors (a 2D function reads x[0], x[1] and leaves the z entries of its gradient
and Hessian zero), so the rows of a 2D pair are the 3D rows with z = 0.

    code          f(x), xl = R0^T (x - c0), X = xl / a                      par entries used
    BALL          (|x - c0|^2 - r^2) / (2 r)                                 c0, r
    ELLIPSOID     (s/2)(sum X_i^2 - 1),  s = (prod a)^(1/dim)                 c0, R0, a, s
    POWER         (s/q)(sum |X_i|^q - 1) (superquadric, superellipse)       c0, R0, a, q, s
    BARR          (s/n1)((|X|^n2 + |Y|^n2)^(n1/n2) + |Z|^n1 - 1)            c0, R0, a, n1, n2, s
    PLANE         n . x - d (n, d: the placed plane of shapes.plane())      n, d
    CYLINDER      (xl_0^2 + xl_1^2 - r^2) / (2 r) (axis: local z)            c0, R0, r

The Barr derivatives are those of shapes.py's module docstring (rho = |X| / w in [0, 1], so no
0 * inf on the axis).
"""
from __future__ import annotations

import math

import numpy as np

from ._jit import kernel, lean_kernel

BALL, ELLIPSOID, POWER, BARR, PLANE, CYLINDER = 1, 2, 3, 4, 5, 6
RAY_NEWTON_ITERATIONS = 100      # 1-D Newton from outside on a convex function: monotone
MACHINE_EPS = float(np.finfo(float).eps)

# par layout
CODE, DIM = 0, 1
C0 = 2            # 3
R0 = 5            # 9, row-major
AX = 14           # 3 semi-axes
N1, N2, S, RADIUS = 17, 18, 19, 20
NORMAL = 21       # 3
OFFSET = 24
NPAR = 25


def pack(code: int, dim: int, center=None, rotation=None, semi_axes=None, n1=2.0, n2=2.0, scale=1.0,
         radius=1.0, normal=None, offset=0.0) -> np.ndarray:
    """One function's par row (rotation: a dim x dim matrix; 2D rotations act about z)."""
    par = np.zeros(NPAR)
    par[CODE], par[DIM] = code, dim
    if center is not None:
        par[C0:C0 + dim] = center
    R = np.eye(3)
    if rotation is not None:
        R[:dim, :dim] = rotation
    par[R0:R0 + 9] = R.ravel()
    par[AX:AX + 3] = 1.0
    if semi_axes is not None:
        par[AX:AX + dim] = semi_axes
    par[N1], par[N2], par[S], par[RADIUS] = n1, n2, scale, radius
    if normal is not None:
        par[NORMAL:NORMAL + dim] = normal
    par[OFFSET] = offset
    return par


@lean_kernel
def _local_power(par, X0, X1, X2, order):
    """Single-exponent power sum in its local frame (the superquadric / superellipse), at the
    local point (X0, X1, X2): (f, local gradient (3), local Hessian diagonal (3))."""
    dim = int(par[DIM])
    q, s = par[N1], par[S]
    k = s / q
    v = 0.0
    g0 = g1 = g2 = h0 = h1 = h2 = 0.0
    for i in range(dim):
        a = par[AX + i]
        x = (X0 if i == 0 else (X1 if i == 1 else X2)) / a
        A = abs(x)
        A1 = A ** (q - 1.0)
        v += A1 * A
        gi = k * q * (A1 if x >= 0.0 else -A1) / a if order >= 1 else 0.0
        hi = k * q * (q - 1.0) * A ** (q - 2.0) / (a * a) if order >= 2 else 0.0
        if i == 0:
            g0, h0 = gi, hi
        elif i == 1:
            g1, h1 = gi, hi
        else:
            g2, h2 = gi, hi
    return k * (v - 1.0), g0, g1, g2, h0, h1, h2


@lean_kernel
def _local_barr(par, X0, X1, X2, order):
    """Barr's superquadric in its local frame: g = w^n1 + |Z|^n1, w = (|X|^n2 + |Y|^n2)^(1/n2).
    Returns (f, local gradient (3), local Hessian xx, yy, xy, zz)."""
    q, p, s = par[N1], par[N2], par[S]
    a0, a1, a2 = par[AX], par[AX + 1], par[AX + 2]
    X, Y, Z = X0 / a0, X1 / a1, X2 / a2
    AX_, AY, AZ = abs(X), abs(Y), abs(Z)
    w = (AX_ ** p + AY ** p) ** (1.0 / p)
    rx = AX_ / w if w > 0.0 else 0.0
    ry = AY / w if w > 0.0 else 0.0
    k = s / q
    v = w ** q + AZ ** q
    g0 = g1 = g2 = hxx = hyy = hxy = hzz = 0.0
    if order >= 1:
        wq1 = w ** (q - 1.0)
        sx = 1.0 if X > 0.0 else (-1.0 if X < 0.0 else 0.0)
        sy = 1.0 if Y > 0.0 else (-1.0 if Y < 0.0 else 0.0)
        sz = 1.0 if Z > 0.0 else (-1.0 if Z < 0.0 else 0.0)
        g0 = k * q * wq1 * rx ** (p - 1.0) * sx / a0
        g1 = k * q * wq1 * ry ** (p - 1.0) * sy / a1
        g2 = k * q * AZ ** (q - 1.0) * sz / a2
        if order >= 2:
            wq2 = w ** (q - 2.0)
            hxx = k * q * wq2 * ((q - p) * rx ** (2.0 * p - 2.0) + (p - 1.0) * rx ** (p - 2.0)) / (a0 * a0)
            hyy = k * q * wq2 * ((q - p) * ry ** (2.0 * p - 2.0) + (p - 1.0) * ry ** (p - 2.0)) / (a1 * a1)
            hxy = k * q * (q - p) * wq2 * rx ** (p - 1.0) * ry ** (p - 1.0) * sx * sy / (a0 * a1)
            hzz = k * q * (q - 1.0) * AZ ** (q - 2.0) / (a2 * a2)
    return k * (v - 1.0), g0, g1, g2, hxx, hyy, hxy, hzz


@lean_kernel
def evaluate(par, x, g, H, order):
    """f(x) of the function ``par`` at the body-frame point x (3,); order >= 1 writes its
    gradient into g (3,), order >= 2 its Hessian into H (3, 3) (both body frame, z entries zero
    for 2D functions). Returns f. Allocates nothing (it runs for every pair row evaluation)."""
    code = int(par[CODE])
    dim = int(par[DIM])
    if code == PLANE:
        v = -par[OFFSET]
        for i in range(dim):
            v += par[NORMAL + i] * x[i]
        if order >= 1:
            for i in range(3):
                g[i] = par[NORMAL + i] if i < dim else 0.0
        if order >= 2:
            for i in range(3):
                for j in range(3):
                    H[i, j] = 0.0
        return v
    if code == BALL:
        r = par[RADIUS]
        sq = 0.0
        for i in range(dim):
            y = x[i] - par[C0 + i]
            sq += y * y
            if order >= 1:
                g[i] = y / r
        if order >= 1:
            for i in range(dim, 3):
                g[i] = 0.0
        if order >= 2:
            for i in range(3):
                for j in range(3):
                    H[i, j] = 1.0 / r if (i == j and i < dim) else 0.0
        return (sq - r * r) / (2.0 * r)
    # local coordinates xl = R0^T (x - c0)
    d0 = x[0] - par[C0]
    d1 = x[1] - par[C0 + 1]
    d2 = x[2] - par[C0 + 2] if dim == 3 else 0.0
    X0 = par[R0] * d0 + par[R0 + 3] * d1 + par[R0 + 6] * d2
    X1 = par[R0 + 1] * d0 + par[R0 + 4] * d1 + par[R0 + 7] * d2
    X2 = par[R0 + 2] * d0 + par[R0 + 5] * d1 + par[R0 + 8] * d2 if dim == 3 else 0.0
    # the local gradient (l0, l1, l2) and Hessian (diagonal, plus xy for Barr's form)
    hxy = 0.0
    if code == ELLIPSOID:
        sc = par[S]
        a0, a1 = par[AX], par[AX + 1]
        a2 = par[AX + 2] if dim == 3 else 1.0
        Y0, Y1, Y2 = X0 / a0, X1 / a1, X2 / a2
        v = 0.5 * sc * (Y0 * Y0 + Y1 * Y1 + Y2 * Y2 - 1.0)
        l0, l1, l2 = sc * Y0 / a0, sc * Y1 / a1, sc * Y2 / a2
        h0, h1 = sc / (a0 * a0), sc / (a1 * a1)
        h2 = sc / (a2 * a2) if dim == 3 else 0.0
    elif code == POWER:
        v, l0, l1, l2, h0, h1, h2 = _local_power(par, X0, X1, X2, order)
    elif code == BARR:
        v, l0, l1, l2, h0, h1, hxy, h2 = _local_barr(par, X0, X1, X2, order)
    else:  # CYLINDER
        r = par[RADIUS]
        v = (X0 * X0 + X1 * X1 - r * r) / (2.0 * r)
        l0, l1, l2 = X0 / r, X1 / r, 0.0
        h0 = h1 = 1.0 / r
        h2 = 0.0
    # back to the body frame: g = R0 gl, H = R0 Hl R0^T
    if order >= 1:
        for i in range(3):
            g[i] = par[R0 + 3 * i] * l0 + par[R0 + 3 * i + 1] * l1 + par[R0 + 3 * i + 2] * l2
    if order >= 2:
        for i in range(3):
            ri0, ri1, ri2 = par[R0 + 3 * i], par[R0 + 3 * i + 1], par[R0 + 3 * i + 2]
            t0 = ri0 * h0 + ri1 * hxy
            t1 = ri0 * hxy + ri1 * h1
            t2 = ri2 * h2
            for j in range(i, 3):
                hij = t0 * par[R0 + 3 * j] + t1 * par[R0 + 3 * j + 1] + t2 * par[R0 + 3 * j + 2]
                H[i, j] = hij
                H[j, i] = hij
    return v


@kernel
def evaluate_many(par, X, order):
    """(f (n,), grad (n, dim), Hess (n, dim, dim)) at the rows of X (n, dim), body frame."""
    n, dim = X.shape
    f = np.empty(n)
    G = np.zeros((n, dim))
    Hs = np.zeros((n, dim, dim))
    x = np.zeros(3)
    g = np.zeros(3)
    H = np.zeros((3, 3))
    for k in range(n):
        for i in range(dim):
            x[i] = X[k, i]
        f[k] = evaluate(par, x, g, H, order)
        if order >= 1:
            for i in range(dim):
                G[k, i] = g[i]
        if order >= 2:
            for i in range(dim):
                for j in range(dim):
                    Hs[k, i, j] = H[i, j]
    return f, G, Hs


# ---------------------------------------------------------------------------------------------
# support points and ray exits of the bounded closed forms (shapes.py, closest._single_run)
# ---------------------------------------------------------------------------------------------
@lean_kernel
def dot(u, v, n):
    """u[:n] . v[:n], summed in index order (as the loops it replaces)."""
    acc = 0.0
    for i in range(n):
        acc += u[i] * v[i]
    return acc


@lean_kernel
def _pnorm(v, n, p):
    """||v[:n]||_p, scaled by the largest entry against overflow (shapes._pnorm of one vector)."""
    m = 0.0
    for i in range(n):
        m = max(m, abs(v[i]))
    if not m > 0.0:
        return m
    acc = 0.0
    for i in range(n):
        acc += (abs(v[i]) / m) ** p
    return m * acc ** (1.0 / p)


@lean_kernel
def _lp_support(D, n, p, out):
    """argmax {D.X : ||X||_p <= 1} of D[:n], into out[:n] (may be D)."""
    ps = p / (p - 1.0)
    N = _pnorm(D, n, ps)
    for i in range(n):
        s = 1.0 if D[i] > 0.0 else (-1.0 if D[i] < 0.0 else 0.0)
        out[i] = s * (abs(D[i]) / N) ** (ps - 1.0)


@lean_kernel
def support_local(par, d, xl, t2, u2):
    """The support point, in local coordinates, of a ball, an ellipsoid or a superquadric (both of
    Barr's levels) along the local direction d (dim entries, not zero), into xl: the argmax of
    D.X over the unit ball of g, D = a d, is the gradient of the dual norm, X_i = sgn D_i
    (|D_i| / ||D||_p*)^(p* - 1), applied at both levels of Barr's form. t2, u2: (2,) scratch."""
    code = int(par[CODE])
    dim = int(par[DIM])
    if code == BALL:
        nn = math.sqrt(dot(d, d, dim))
        for i in range(dim):
            xl[i] = par[RADIUS] * d[i] / nn
        return
    for i in range(dim):
        xl[i] = par[AX + i] * d[i]            # D = a d
    if code == ELLIPSOID:
        nn = math.sqrt(dot(xl, xl, dim))
        for i in range(dim):
            xl[i] = par[AX + i] * xl[i] / nn
        return
    if code == POWER:
        _lp_support(xl, dim, par[N1], xl)
        for i in range(dim):
            xl[i] *= par[AX + i]
        return
    # BARR (3D): the xy level inside the z level
    n1, n2 = par[N1], par[N2]
    D2 = xl[2]
    nxy = _pnorm(xl, 2, n2 / (n2 - 1.0))
    t2[0], t2[1] = nxy, D2
    _lp_support(t2, 2, n1, t2)
    if nxy > 0.0:
        u2[0], u2[1] = xl[0], xl[1]
        _lp_support(u2, 2, n2, u2)
        xl[0], xl[1] = t2[0] * u2[0], t2[0] * u2[1]
    else:
        xl[0] = xl[1] = 0.0
    xl[2] = t2[1]
    for i in range(3):
        xl[i] *= par[AX + i]


@lean_kernel
def _local_value(par, Xs, order, xb, gb, Hb):
    """f at the local point Xs (already times the semi-axes): evaluate at c0 + R0 Xs."""
    dim = int(par[DIM])
    for i in range(3):
        xb[i] = 0.0
    for i in range(dim):
        acc = 0.0
        for k in range(dim):
            acc += par[R0 + 3 * i + k] * Xs[k]
        xb[i] = par[C0 + i] + acc
    return evaluate(par, xb, gb, Hb, order)


@lean_kernel
def ray_exit(par, ob, ub, w, Hb):
    """tau >= 0 where the ray ob + tau ub (body frame, dim entries, ub not zero) from inside a ball,
    an ellipsoid or a superquadric leaves it: the quadrics' closed form (the largest root of
    |P + tau U| = 1 in scaled coordinates, without cancellation); for the power sums g(tau U) =
    tau^n1 g(U) from the centre, else Newton from a tau right of the root (g convex along the
    ray, so Newton from the right is monotone). w: (6, 3) scratch."""
    code = int(par[CODE])
    dim = int(par[DIM])
    P, U, X, xb, gb = w[0], w[1], w[2], w[3], w[4]
    for i in range(dim):                         # local: (o - c0) R0, u R0
        acc = 0.0
        accu = 0.0
        for k in range(dim):
            acc += (ob[k] - par[C0 + k]) * par[R0 + 3 * k + i]
            accu += ub[k] * par[R0 + 3 * k + i]
        P[i] = acc
        U[i] = accu
    for i in range(dim):
        s = par[RADIUS] if code == BALL else par[AX + i]
        P[i] /= s
        U[i] /= s
    if code == BALL or code == ELLIPSOID:  # (as shapes._quadric_exit)
        uu, pu, pp = dot(U, U, dim), dot(P, U, dim), dot(P, P, dim)
        if pp >= 1.0:
            return 0.0
        sq = math.sqrt(pu * pu + uu * (1.0 - pp))
        return (1.0 - pp) / (pu + sq) if pu >= 0.0 else (sq - pu) / uu
    q = par[N1]
    s = par[S]
    anyp = False
    for i in range(dim):
        anyp = anyp or P[i] != 0.0
    if not anyp:                                 # g(tau U) = tau^n1 g(U)
        for i in range(dim):
            X[i] = U[i] * par[AX + i]
        return (_local_value(par, X, 0, xb, gb, Hb) * q / s + 1.0) ** (-1.0 / q)
    for i in range(dim):
        X[i] = P[i] * par[AX + i]
    if _local_value(par, X, 0, xb, gb, Hb) * q / s + 1.0 >= 1.0:
        return 0.0
    tau = (math.sqrt(dot(P, P, dim)) + math.sqrt(dim)) / math.sqrt(dot(U, U, dim))
    for _ in range(RAY_NEWTON_ITERATIONS):
        for i in range(dim):
            X[i] = (P[i] + tau * U[i]) * par[AX + i]
        value = _local_value(par, X, 1, xb, gb, Hb)
        slope = 0.0
        for i in range(dim):
            gl = 0.0
            for k in range(dim):
                gl += gb[k] * par[R0 + 3 * k + i]
            slope += gl * (U[i] * par[AX + i])
        v = (value * q / s + 1.0) - 1.0          # (g - 1, as shapes' phi computes it)
        tau, done = newton_from_right_step(tau, v, slope * q / s)
        if done:
            break
    return tau


@lean_kernel
def newton_from_right_step(tau, v, dv):
    """One step of 1-D Newton on a convex phi from a tau right of its root, phi(tau) = v,
    phi'(tau) = dv (ray_exit, shapes._newton_from_right): (the next tau, whether to stop). It
    stops at a slope that is not positive, at a step that does not move tau left (then keeping
    the smaller positive tau) and at a step below 4 eps tau."""
    if not dv > 0.0:
        return tau, True
    step = v / dv
    tau_new = tau - step
    if tau_new >= tau or step <= 4.0 * MACHINE_EPS * tau:
        return (min(tau, tau_new) if tau_new > 0.0 else tau), True
    return tau_new, False


@kernel
def local_support(par, d):
    """support_local for Python callers (shapes.py): a new (dim,) array."""
    dim = int(par[DIM])
    dd, xl = np.zeros(3), np.zeros(3)
    for i in range(dim):
        dd[i] = d[i]
    support_local(par, dd, xl, np.zeros(2), np.zeros(2))
    return xl[:dim].copy()


@kernel
def ray_exit_from(par, o, u):
    """ray_exit for Python callers (shapes.py): o, u body-frame (dim,)."""
    dim = int(par[DIM])
    ob, ub = np.zeros(3), np.zeros(3)
    for i in range(dim):
        ob[i], ub[i] = o[i], u[i]
    return ray_exit(par, ob, ub, np.zeros((6, 3)), np.zeros((3, 3)))
