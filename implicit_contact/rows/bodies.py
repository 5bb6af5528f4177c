r"""Bodies at l+1 as functions of their velocity unknowns ([GI] eq 21, second line).

A body's pose at l+1 is q^{l+1} = q^l (+) h v^{l+1}, written exactly as DART integrates it, and
everything the rows need from it is evaluated once per body and evaluation of F:

* moving 3D bodies (a FreeJoint body, or any body of an articulated skeleton): omega = A_w v,
  v_o = A_v v with [A_w; A_v] DART's world Jacobian of the body origin at l (I6 for a FreeJoint
  body, dartpy 6.20's convention v = [omega; v_o] in the world frame):
      R+ = exp(h [omega]x) R0,    p+ = p0 + h v_o,
      dtheta = h J_l(h omega) A_w dv (world-frame rotation increment),   dp = h A_v dv,
  J_l the left Jacobian of SO(3). Exact for a free body; for a link of a chain it differs from
  DART's joint-space update q+ = q (+) h v (which writes the step back) by O(h^2 |v|^2).
* planar bodies (PlanarJoint in XY, v = [v_x, v_y, omega]): theta+ = theta0 + h omega,
  p+ = p0 + h (v_x, v_y); a 2D body is a 3D body in the plane z = 0 rotating about z.
* fixed bodies: their pose at l, no velocity columns.

exp and J_l share Rodrigues' form: with K = [phi]x, th = |phi|,
    exp(K) = I + (sin th / th) K + ((1 - cos th) / th^2) K^2,
    J_l    = I + ((1 - cos th) / th^2) K + ((th - sin th) / th^3) K^2,
and K^2 = phi phi^T - th^2 I; below th = 1e-6 the coefficients are their limits (1, 1/2, 1/6).

State of body b after ``body_states`` (indices of the step's tables): R[b] (3, 3), p[b] (3,),
w[b] (omega, 3,), vo[b] (3,), and T[b] (12, k): the rows of dtheta/dv (0:3), dp/dv (3:6),
domega/dv (6:9) and dv_o/dv (9:12), through which the pair rows' derivatives with respect to a
body's twist become derivatives with respect to its velocity unknowns.
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import lean_kernel

FIXED, MOVING, PLANAR = 0, 1, 2

# body_i columns (B_ART: a body of an articulated skeleton, moving by its Jacobian; kind MOVING)
B_KIND, B_VCOL, B_NV, B_JAC, B_ART = 0, 1, 2, 3, 4
NBI = 5
# body_f columns
B_R0, B_P0, B_THETA0, B_H = 0, 9, 12, 13
NBF = 14


@lean_kernel
def so3_coefficients(th2):
    """(a, b, c) of exp(K) = I + a K + b K^2 and J_l = I + b K + c K^2, th2 = |phi|^2."""
    th = math.sqrt(th2)
    if th < 1e-6:
        return 1.0, 0.5, 1.0 / 6.0
    s = math.sin(th)
    b = (1.0 - math.cos(th)) / th2
    return s / th, b, (th - s) / (th2 * th)


@lean_kernel
def i_plus_k(phi, th2, a, b, out):
    """out = I + a K + b K^2, K = [phi]x (K^2 = phi phi^T - th2 I)."""
    f0, f1, f2 = phi[0], phi[1], phi[2]
    bt = b * th2
    out[0, 0] = 1.0 + b * f0 * f0 - bt
    out[0, 1] = b * f0 * f1 - a * f2
    out[0, 2] = b * f0 * f2 + a * f1
    out[1, 0] = b * f1 * f0 + a * f2
    out[1, 1] = 1.0 + b * f1 * f1 - bt
    out[1, 2] = b * f1 * f2 - a * f0
    out[2, 0] = b * f2 * f0 - a * f1
    out[2, 1] = b * f2 * f1 + a * f0
    out[2, 2] = 1.0 + b * f2 * f2 - bt


@lean_kernel
def twist(jac, off, k, v, col, w, vo):
    """An articulated body's angular velocity w = A_w v and origin velocity vo = A_v v, from its
    6 x k Jacobian [A_w; A_v] (row-major at jac[off:]) and the skeleton's velocities v[col:col+k]."""
    for i in range(3):
        aw = 0.0
        av = 0.0
        for j in range(k):
            x = v[col + j]
            aw += jac[off + i * k + j] * x
            av += jac[off + (3 + i) * k + j] * x
        w[i] = aw
        vo[i] = av


@lean_kernel
def body_states(body_i, body_f, body_jac, z, R, p, w, vo, T, scratch):
    """Every body's pose at l+1, angular and origin velocity and twist rows T (see the module
    docstring) at the unknowns z; scratch: 12 floats of workspace."""
    E = scratch[0:9].reshape((3, 3))
    phi = scratch[9:12]
    for b in range(body_i.shape[0]):
        kind = body_i[b, B_KIND]
        col, k = body_i[b, B_VCOL], body_i[b, B_NV]
        h = body_f[b, B_H]
        for i in range(12):
            for j in range(T.shape[2]):
                T[b, i, j] = 0.0
        for i in range(3):
            w[b, i] = 0.0
            vo[b, i] = 0.0
        if kind == FIXED:
            for i in range(3):
                p[b, i] = body_f[b, B_P0 + i]
                for j in range(3):
                    R[b, i, j] = body_f[b, B_R0 + 3 * i + j]
        elif kind == PLANAR:
            vx, vy, om = z[col], z[col + 1], z[col + 2]
            th = body_f[b, B_THETA0] + h * om
            c, s = math.cos(th), math.sin(th)
            R[b, 0, 0], R[b, 0, 1], R[b, 0, 2] = c, -s, 0.0
            R[b, 1, 0], R[b, 1, 1], R[b, 1, 2] = s, c, 0.0
            R[b, 2, 0], R[b, 2, 1], R[b, 2, 2] = 0.0, 0.0, 1.0
            p[b, 0] = body_f[b, B_P0] + h * vx
            p[b, 1] = body_f[b, B_P0 + 1] + h * vy
            p[b, 2] = 0.0
            w[b, 2] = om
            vo[b, 0], vo[b, 1] = vx, vy
            T[b, 2, 2] = h             # dtheta_z = h d omega
            T[b, 3, 0] = h             # dp = h (dv_x, dv_y)
            T[b, 4, 1] = h
            T[b, 8, 2] = 1.0           # domega_z / d omega
            T[b, 9, 0] = 1.0           # dv_o / d(v_x, v_y)
            T[b, 10, 1] = 1.0
        else:
            off = body_i[b, B_JAC]     # [A_w; A_v], 6 x k, row-major
            twist(body_jac, off, k, z, col, w[b], vo[b])
            for i in range(3):
                phi[i] = h * w[b, i]
            th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
            a, bb, cc = so3_coefficients(th2)
            i_plus_k(phi, th2, a, bb, E)
            for i in range(3):
                for j in range(3):
                    acc = 0.0
                    for m in range(3):
                        acc += E[i, m] * body_f[b, B_R0 + 3 * m + j]
                    R[b, i, j] = acc
                p[b, i] = body_f[b, B_P0 + i] + h * vo[b, i]
            i_plus_k(phi, th2, bb, cc, E)          # J_l(h omega)
            for i in range(3):
                for j in range(k):
                    acc = 0.0
                    for m in range(3):
                        acc += E[i, m] * body_jac[off + m * k + j]
                    T[b, i, j] = h * acc                               # dtheta / dv
                    T[b, 3 + i, j] = h * body_jac[off + (3 + i) * k + j]   # dp / dv
                    T[b, 6 + i, j] = body_jac[off + i * k + j]             # domega / dv
                    T[b, 9 + i, j] = body_jac[off + (3 + i) * k + j]       # dv_o / dv
