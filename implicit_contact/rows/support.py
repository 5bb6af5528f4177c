r"""Rows of the 2.5D support friction of a planar body (implicit_contact/support.py derives them).

Scaled unknowns y = (p_x, p_y, tau / e_r) / (mu P) and sigma >= 0 of one support block, with
E = [[1, 0, -r_y], [0, 1, r_x], [0, 0, e_r]] (the last row only with torsion; r = R(theta^l) c):

    u + sigma y_xy = 0,  e_r omega + sigma y_3 = 0      (rows at y:  E v + sigma y = 0)
    0 <= sigma  _|_  1 - |y|^2 >= 0                      (row at sigma)
    F[v] -= mu P E^T y                                   (the body's generalized impulse)

Local block: [the body's velocities (3), y (ny), sigma].
"""
from __future__ import annotations

from .._jit import lean_kernel

# sup_i columns: the body's velocity column, y's column, ny, sigma's column
S_VCOL, S_Y, S_NY, S_SIG = 0, 1, 2, 3
NSI = 4
# sup_f columns: E (3 x 3 row-major), mu P
S_E, S_SCALE = 0, 9
NSF = 10


@lean_kernel
def support_rows(si, sf, z, FL, JL, need_jac):
    """FL (3 + ny + 1,) and JL over [v (3), y (ny), sigma] of one support block."""
    vcol, ycol, ny, scol = si[S_VCOL], si[S_Y], si[S_NY], si[S_SIG]
    L = 3 + ny + 1
    scale = sf[S_SCALE]
    sigma = z[scol]
    for i in range(L):
        FL[i] = 0.0
    yy = 0.0
    for a in range(ny):
        ya = z[ycol + a]
        yy += ya * ya
        acc = sigma * ya
        for j in range(3):
            e = sf[S_E + 3 * a + j]
            acc += e * z[vcol + j]
            FL[j] -= scale * e * ya
        FL[3 + a] = acc
    FL[3 + ny] = 1.0 - yy
    if not need_jac:
        return
    for i in range(L):
        for j in range(L):
            JL[i, j] = 0.0
    for a in range(ny):
        ya = z[ycol + a]
        for j in range(3):
            e = sf[S_E + 3 * a + j]
            JL[j, 3 + a] -= scale * e
            JL[3 + a, j] += e
        JL[3 + a, 3 + a] += sigma
        JL[3 + a, 3 + ny] += ya
        JL[3 + ny, 3 + a] -= 2.0 * ya
