r"""The Newton-Euler rows of a skeleton ([GI] eq 21, first line), with DART's M, bias and forces at l,
and the skeleton's joint rows:

    M (v+ - v) - h (tau + tau_ext - c(q, v)) - sum_contacts J^T P - sum_r u_r g_r lambda_r = 0

The contact terms are added by the pair and support rows (their generalized impulses); these
rows hold M (v+ - v) - h force - sum_r u_r g_r lambda_r and their block of the Jacobian. (M
includes h D + h^2 K of DART's implicit joint dampers and springs, see dart_adapter.read_skeleton.)

Joint rows are constraints written in the skeleton's own velocities, one unknown lambda_r each
(dimensionless; u_r lambda_r is its generalized impulse along g_r, in N s or N m s):

    F_r = g_r . v+ + c_r,      lo_r <= lambda_r <= hi_r  complementary to F_r  (ncp.py's MCP)

Coulomb joint friction of dof j (DART's setCoulombFriction, force bound f): g_r = e_j, c_r = 0,
u_r = h f, lambda_r in [-1, 1]. That is the MCP of maximal dissipation in one dimension: the
joint sticks (v_j+ = 0) while the impulse it needs is at most h f, else it slides with the impulse
at the bound opposite its velocity (lambda_r = -1 => v_j+ >= 0, lambda_r = 1 => v_j+ <= 0), as
DART's JointCoulombFrictionConstraint does for its boxed LCP.

A skeleton's plan (rows/assemble.py) is its k velocity columns followed by its n_j joint-row
columns. Its float table in sk_M at K_MOFF: M (k x k, row-major), then per joint row g_r (k), c_r,
u_r.
"""
from __future__ import annotations

from .._jit import lean_kernel

# sk_i columns: first velocity column, number of dofs, offset of its float table in sk_M, first
# joint-row column, number of joint rows
K_VCOL, K_NV, K_MOFF, K_JCOL, K_NJ = 0, 1, 2, 3, 4
NKI = 5


def table_size(k: int, nj: int) -> int:
    """Floats of a skeleton's table in sk_M: M, then (g, c, u) per joint row."""
    return k * k + nj * (k + 2)


@lean_kernel
def skeleton_rows(ki, sk_M, v0, hforce, z, FL, JL, need_jac):
    """FL (k + n_j,) = [M (v - v0) - h force - sum_r u_r g_r lambda_r; g_r . v + c_r] over the
    skeleton's plan (its velocity columns, then its joint-row columns); JL = [[M, -u g^T], [g, 0]]."""
    col, k, off = ki[K_VCOL], ki[K_NV], ki[K_MOFF]
    jcol, nj = ki[K_JCOL], ki[K_NJ]
    for i in range(k):
        acc = -hforce[col + i]
        for j in range(k):
            m = sk_M[off + i * k + j]
            acc += m * (z[col + j] - v0[col + j])
            if need_jac:
                JL[i, j] = m
        FL[i] = acc
    if nj == 0:
        return
    base = off + k * k
    for r in range(nj):
        g = base + r * (k + 2)
        c, u = sk_M[g + k], sk_M[g + k + 1]
        lam = z[jcol + r]
        acc = c
        for i in range(k):
            gi = sk_M[g + i]
            FL[i] -= u * gi * lam
            acc += gi * z[col + i]
            if need_jac:
                JL[i, k + r] = -u * gi
                JL[k + r, i] = gi
        FL[k + r] = acc
        if need_jac:
            for q in range(nj):
                JL[k + r, k + q] = 0.0
