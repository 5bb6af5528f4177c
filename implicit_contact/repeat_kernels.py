"""The compiled halves of a step that repeats the last one's structure (ImplicitContactStepper._repeat_step).

Each is a sequence of the kernels the general step uses one by one, in one call:

    prepare   memory.carry_pairs (tangent axes, layer deflections at l; the rows must not change),
              rows/tables.fill_state (the state at l), memory.warm_start (the start of the solve)
    finish    rows/checks.solution_checks (nothing for a recovery to correct), the solved
              velocities as a world vector, step_kernels.far_after (the pairs left out stay out of
              reach), step_kernels.moved_beyond_margins (no end-of-step broadphase needed),
              memory.known_gaps (the next far-pair test's bounds)

so the step between them is step_solver's compiled solve. Either returns a code: OK, or why the
general step must take over (it then starts the step afresh).
"""
from __future__ import annotations

import numpy as np

from ._jit import kernel
from .memory import carry_pairs, known_gaps, warm_start
from .rows import checks as rk
from .rows import dynamics as rd
from .rows import support as rs
from .rows.tables import fill_state
from .step_kernels import far_after, moved_beyond_margins

OK, ROWS_CHANGE, RECOVERY, FAR_REACHED, MOVED = 0, 1, 2, 3, 4


@kernel
def prepare(body_i, body_f, body_jac, sk_i, sk_M, v0, hforce, pair_i, pair_f, scale, sup_i, sup_f,
            src, R_src, p_src, th_src, J_src, J_at, h_body, sk_src, src_voff, src_moff, V_src, MB_src, FB_src,
            VF, h, body_dim, pos_rows, sup_body, sup_c, sup_er, sup_mun,
            mem_i, mem_f, mem_z, mem_rep, identity, touch, axis_limit, sup_y, z0):
    """carry_pairs, fill_state, warm_start (module docstring); sup_y (n_sup, 4): the support
    blocks' last y and sigma (the y entries beyond a block's size unused)."""
    if not carry_pairs(pair_i, pair_f, mem_i, mem_f, mem_z, mem_rep, touch, axis_limit):
        return ROWS_CHANGE
    fill_state(src, R_src, p_src, th_src, J_src, J_at, h_body, sk_src, src_voff, src_moff, V_src, MB_src, FB_src,
               h, body_dim, body_i, body_f, body_jac, sk_i, sk_M, v0, hforce, scale, pos_rows, sup_body, sup_c,
               sup_er, sup_mun, sup_f)
    n = z0.shape[0]
    v_free = np.zeros(n)
    for s in range(sk_i.shape[0]):
        col, k = sk_i[s, rd.K_VCOL], sk_i[s, rd.K_NV]
        off = src_voff[sk_src[s]]
        for i in range(k):
            v_free[col + i] = VF[off + i]
    for i in range(n):
        z0[i] = 0.0
    warm_start(pair_i, pair_f, body_i, body_f, body_jac, sk_i, v0, v_free, identity, mem_i, mem_f, mem_z, mem_rep,
               False, h, z0)
    for s in range(sup_i.shape[0]):
        ycol, ny, scol = sup_i[s, rs.S_Y], sup_i[s, rs.S_NY], sup_i[s, rs.S_SIG]
        for a in range(ny):
            z0[ycol + a] = sup_y[s, a]
        z0[scol] = sup_y[s, 3]
    return OK


@kernel
def finish(pair_i, pair_f, fpar, sk_i, z, rep, st_R, st_p, tol, solver_tol, touch, flags,
           sk_src, src_voff, VF, V_solved, far_pairs, far_gaps, far_left,
           ob_body, ob_radius, ob_bounded, bd_kind, bd_sk, sk_voff, margins, h, eligible, near_gaps):
    """solution_checks, the solved world velocities, far_after, moved_beyond_margins,
    known_gaps (module docstring)."""
    if rk.solution_checks(pair_i, pair_f, fpar, z, rep, st_R, st_p, tol, solver_tol, touch, flags) != 0:
        return RECOVERY
    for i in range(VF.shape[0]):
        V_solved[i] = VF[i]
    for s in range(sk_i.shape[0]):
        col, k = sk_i[s, rd.K_VCOL], sk_i[s, rd.K_NV]
        off = src_voff[sk_src[s]]
        for i in range(k):
            V_solved[off + i] = z[col + i]
    if far_pairs.shape[0] and far_after(far_pairs, far_gaps, ob_body, ob_radius, bd_kind, bd_sk, sk_voff, V_solved,
                                        h, tol, far_left):
        return FAR_REACHED
    if moved_beyond_margins(ob_body, ob_radius, ob_bounded, bd_kind, bd_sk, sk_voff, V_solved, VF, margins, h, tol):
        return MOVED
    known_gaps(pair_i, z, rep, eligible, tol, near_gaps)
    return OK
