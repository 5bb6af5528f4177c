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

import numpy as np

from ._jit import kernel, lean_kernel

BALL, ELLIPSOID, POWER, BARR, PLANE, CYLINDER = 1, 2, 3, 4, 5, 6

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
