r"""The Newton-Euler rows of a skeleton ([GI] eq 21, first line), with DART's M, bias and forces at l:

    M (v+ - v) - h (tau + tau_ext - c(q, v)) - sum_contacts J^T P = 0

The contact terms are added by the pair and support rows (their generalized impulses); these
rows hold M (v+ - v) - h force, and the block M of the Jacobian. (M includes h D + h^2 K of
DART's implicit joint dampers and springs, see dart_adapter.read_skeleton.)
"""
from __future__ import annotations

from .._jit import kernel

# sk_i columns: first velocity column, number of dofs, offset of M in sk_M (row-major k x k)
K_VCOL, K_NV, K_MOFF = 0, 1, 2
NKI = 3


@kernel
def skeleton_rows(ki, sk_M, v0, hforce, z, FL, JL, need_jac):
    """FL (k,) = M (v - v0) - h force over the skeleton's velocity columns; JL (k, k) = M."""
    col, k, off = ki[K_VCOL], ki[K_NV], ki[K_MOFF]
    for i in range(k):
        acc = -hforce[col + i]
        for j in range(k):
            m = sk_M[off + i * k + j]
            acc += m * (z[col + j] - v0[col + j])
            if need_jac:
                JL[i, j] = m
        FL[i] = acc
