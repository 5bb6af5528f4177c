r"""The state at l in a step's tables: body poses, Jacobians, mass matrices, forces, row scales.

A step problem's structure (kinds, columns, functions, local indices) is fixed by its layout;
each step fills its values from the state at l. ``fill_state`` reads them from source arrays:
the stepper's world buffers (poses now or half a step on, DART's Jacobians, mass matrices and
forces, step_kernels.py) or, for a problem built by hand, the same arrays made from its
BodyKinematics and SkeletonBlocks (formulation.StepProblem.refresh):

    body b of the step     source pose  R_src[src[b]], p_src[src[b]], th_src[src[b]] (planar angle),
                           its Jacobian J_src[J_at[b] : +6 k] (articulated), its h_body[b]
    skeleton s             M, v, force at the source offsets (moff, voff) of sk_src[s]

and writes rows/bodies.py's body_f (pose at l, planar angle, h) and body_jac, the skeletons'
M, v, h force, the row scale (Newton-Euler rows / diag(M), position-level rows / h) and the
support blocks' E = [[1, 0, -r_y], [0, 1, r_x], [0, 0, e_r]] with r = R(theta^l) c
(implicit_contact/support.py). A 2D fixed body is read in its plane: R's 2 x 2 block, p's
first two entries.
"""
from __future__ import annotations

from .._jit import lean_kernel
from . import bodies as rb
from . import dynamics as rd
from . import support as rs


@lean_kernel
def fill_state(src, R_src, p_src, th_src, J_src, J_at, h_body, sk_src, src_voff, src_moff, V_src, MB_src, FB_src,
               h, dim, body_i, body_f, body_jac, sk_i, sk_M, v0, hforce, scale, pos_rows, sup_body, sup_c, sup_er,
               sup_mun, sup_f):
    for b in range(body_i.shape[0]):
        w = src[b]
        kind = body_i[b, rb.B_KIND]
        for i in range(rb.NBF):
            body_f[b, i] = 0.0
        for i in range(3):
            for j in range(3):
                body_f[b, rb.B_R0 + 3 * i + j] = R_src[w, i, j]
            body_f[b, rb.B_P0 + i] = p_src[w, i]
        if kind == rb.PLANAR:
            body_f[b, rb.B_THETA0] = th_src[w]
            body_f[b, rb.B_P0 + 2] = 0.0
        elif dim[b] == 2:
            # a fixed 2D body: its pose in the plane z = 0
            for i in range(3):
                for j in range(3):
                    if i == 2 or j == 2:
                        body_f[b, rb.B_R0 + 3 * i + j] = 1.0 if i == j else 0.0
            body_f[b, rb.B_P0 + 2] = 0.0
        body_f[b, rb.B_H] = h_body[b]
        if body_i[b, rb.B_ART]:
            k = body_i[b, rb.B_NV]
            at, jo = body_i[b, rb.B_JAC], J_at[b]
            for i in range(6 * k):
                body_jac[at + i] = J_src[jo + i]
    for s in range(sk_i.shape[0]):
        col, k, off = sk_i[s, rd.K_VCOL], sk_i[s, rd.K_NV], sk_i[s, rd.K_MOFF]
        w = sk_src[s]
        vo, mo = src_voff[w], src_moff[w]
        for i in range(k):
            v0[col + i] = V_src[vo + i]
            hforce[col + i] = h * FB_src[vo + i]
            for j in range(k):
                sk_M[off + i * k + j] = MB_src[mo + i * k + j]
            scale[col + i] = 1.0 / max(MB_src[mo + i * k + i], 1e-300)
    for r in pos_rows:
        scale[r] = 1.0 / h
    for s in range(sup_f.shape[0]):
        b = sup_body[s]
        c0, c1 = sup_c[s, 0], sup_c[s, 1]
        r0 = body_f[b, rb.B_R0] * c0 + body_f[b, rb.B_R0 + 1] * c1
        r1 = body_f[b, rb.B_R0 + 3] * c0 + body_f[b, rb.B_R0 + 4] * c1
        E = sup_f[s]
        for i in range(9):
            E[rs.S_E + i] = 0.0
        E[rs.S_E + 0], E[rs.S_E + 2] = 1.0, -r1
        E[rs.S_E + 4], E[rs.S_E + 5] = 1.0, r0
        E[rs.S_E + 8] = sup_er[s]
        E[rs.S_SCALE] = sup_mun[s] * h
