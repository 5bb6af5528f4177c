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

from ._jit import FALSE, kernel
from .memory import carry_pairs, known_gaps, warm_start
from .rows import checks as rk
from .rows import dynamics as rd
from .rows import support as rs
from .rows.tables import fill_state
from . import ncp
from .step_kernels import (all_finite, far_after, far_test, grown_boxes, kinematics, moved_beyond_margins,
                           overlapping)
from .rows.assemble import assemble
from .step_solver import _solve_dense

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
               FALSE, h, z0)
    for s in range(sup_i.shape[0]):
        ycol, ny, scol = sup_i[s, rs.S_Y], sup_i[s, rs.S_NY], sup_i[s, rs.S_SIG]
        for a in range(ny):
            z0[ycol + a] = sup_y[s, a]
        z0[scol] = sup_y[s, 3]
    return OK


@kernel
def finish(pair_i, pair_f, sk_i, z, rep, tol, solver_tol, touch, flags,
           sk_src, src_voff, VF, V_solved, far_pairs, far_gaps, far_left,
           ob_body, ob_radius, ob_bounded, bd_kind, bd_sk, sk_voff, margins, h, eligible, near_gaps):
    """solution_checks, the solved world velocities, far_after, moved_beyond_margins,
    known_gaps (module docstring)."""
    if rk.solution_checks(pair_i, pair_f, z, rep, tol, solver_tol, touch, flags) != 0:
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


# codes of step beyond those of prepare and finish
FIXED_MOVED, NEED_COAL, CANDIDATES, FAR_CHANGED, NOT_CONVERGED, NOT_FINITE_STATE = 5, 6, 7, 8, 9, 10


@kernel
def _solve(T, S, x0):
    """step_solver's dense solve of the problem T from x0 into the solver buffers S."""
    _solve_dense(T.body_i, T.body_f, T.body_jac, T.fpar, T.sk_i, T.sk_M, T.v0, T.hforce, T.pair_i, T.pair_f,
                 T.sup_i, T.sup_f, T.loc_idx, T.loc_off, T.scale, x0, T.lower, T.upper, S.opt, S.x, S.F, S.xt, S.Ft,
                 S.Phi, S.Phit, S.d, S.g, S.da, S.db, S.zk, S.Jz, S.history, S.steps, S.info, S.fbuf, S.work, S.J, S.H,
                 T.rep, T.st_R, T.st_p, T.st_w, T.st_vo, T.st_T, T.FL, T.JL, T.ws)


@kernel
def _reports_at(T, x, F):
    """The pairs' reports (and bodies' states) of the problem T at x (F: scratch)."""
    no_i = np.zeros(0, np.int64)
    no_f = np.zeros(0)
    assemble(T.body_i, T.body_f, T.body_jac, T.fpar, T.sk_i, T.sk_M, T.v0, T.hforce, T.pair_i, T.pair_f, T.sup_i,
             T.sup_f, T.loc_idx, T.loc_off, no_i, np.zeros(T.loc_off.shape[0], np.int64), T.scale, no_f, x, F,
             np.zeros((0, 0)), no_f, T.rep, T.st_R, T.st_p, T.st_w, T.st_vo, T.st_T, T.FL, T.JL, T.ws, FALSE, FALSE)


@kernel
def step(B, MB_src, FB_src, fat_lo, fat_hi, fat_P, mask, kin, mem_i, mem_f, mem_z, mem_rep, new_f,
         new_z, new_rep, h, tol, solver_tol, touch, axis_limit, use_far):
    """The whole step between reading DART and writing it back, when it repeats the last one's
    structure (ImplicitContactStepper._repeat_step): kinematics, the candidate pairs (the same as
    the context's), the far pairs (the same), prepare, the solve (S; polished in SP), finish and
    the next memory (new_f, new_z, new_rep). B: the bundles (bundles.Repeat) of the world W, the
    problem's tables T, the solver S and polishing solver SP, the context C. Returns OK or why
    the general step must take over (the world buffers then hold the step's kinematics, as _read
    leaves them). kin: check the state read (q, v and forces finite) and do the kinematics (False:
    a second call after coal was queried on fresh fat boxes, NEED_COAL, or the caller did them).
    MB_src, FB_src: the skeletons' mass matrices and forces the rows read (W.MB, W.FB; order 2's
    first stage: its MB1, FB1, rattle.py eq R1)."""
    W, T, S, SP, C = B.W, B.T, B.S, B.SP, B.C
    if kin and not all_finite(W.Q, W.V, W.TAU, W.FEXT):
        return NOT_FINITE_STATE       # (the general step refuses the state, ImplicitContactStepper._begin)
    if kin and kinematics(W, h, 10.0 * tol, FALSE):
        return FIXED_MOVED
    if not grown_boxes(W, fat_lo, fat_hi):
        return NEED_COAL
    nf = fat_P.shape[0]
    count = overlapping(fat_P, W.glo, W.ghi, mask)
    cand = C.cand
    if count != cand.shape[0]:
        return CANDIDATES
    c = 0
    for k in range(nf):
        if mask[k]:
            if fat_P[k, 0] != cand[c, 0] or fat_P[k, 1] != cand[c, 1]:
                return CANDIDATES
            c += 1
    far = C.far
    for k in range(far.shape[0]):
        far[k] = False
    if use_far:
        far_test(cand, C.gaps, W.ob_body, W.ob_radius, W.bd_kind, W.bd_sk, W.sk_voff, W.VF, h, tol, far)
    nfar = 0
    for k in range(far.shape[0]):
        if far[k] == C.near[k]:
            return FAR_CHANGED
        if far[k]:
            nfar += 1
    code = prepare(T.body_i, T.body_f, T.body_jac, T.sk_i, T.sk_M, T.v0, T.hforce, T.pair_i, T.pair_f, T.scale,
                   T.sup_i, T.sup_f, C.src, W.R_now, W.p_now, W.th_now, W.JB, C.J_at, C.h_body, C.sk_src, W.sk_voff,
                   W.sk_moff, W.V, MB_src, FB_src, W.VF, h, T.body_dim, T.pos_rows, T.sup_body, T.sup_c, T.sup_er,
                   T.sup_mun, mem_i, mem_f, mem_z, mem_rep, C.identity, touch, axis_limit, C.sup_y, C.z0)
    if code != OK:
        return code
    _solve(T, S, C.z0)
    if S.info[ncp.I_STATUS] != ncp.S_CONVERGED:
        return NOT_CONVERGED
    x = S.x
    if S.fbuf[ncp.F_RESIDUAL] > 1e-3 * S.opt[ncp.O_TOL]:
        # polish: one Newton step at tol / 1000 (step_solver.solve), kept if it lowers the residual
        _solve(T, SP, S.x)
        if SP.fbuf[ncp.F_RESIDUAL] < S.fbuf[ncp.F_RESIDUAL]:
            x = SP.x
        else:
            _reports_at(T, S.x, SP.Ft)     # the polish did not help: the reports of S.x again
    # the far pairs and their bounds, in the order of the candidates
    fP = C.far_P
    fg = C.far_g
    j = 0
    for k in range(far.shape[0]):
        if far[k]:
            fP[j, 0], fP[j, 1] = cand[k, 0], cand[k, 1]
            fg[j] = C.gaps[k]
            j += 1
    code = finish(T.pair_i, T.pair_f, T.sk_i, x, T.rep, tol, solver_tol, touch, C.flags,
                  C.sk_src, W.sk_voff, W.VF, W.V_solved, fP[:nfar], fg[:nfar], C.left[:nfar], W.ob_body, W.ob_radius,
                  W.ob_bounded, W.bd_kind, W.bd_sk, W.sk_voff, W.margins, h, C.eligible, C.near_gaps)
    if code != OK:
        return code
    for i in range(new_f.shape[0]):
        for q in range(new_f.shape[1]):
            new_f[i, q] = T.pair_f[i, q]
        for q in range(new_rep.shape[1]):
            new_rep[i, q] = T.rep[i, q]
    for i in range(x.shape[0]):
        new_z[i] = x[i]
    for i in range(W.V.shape[0]):
        W.DV_solved[i] = (W.V_solved[i] - W.V[i]) / h       # DART's accelerations of the step
    # the next far-pair test's bounds: far pairs their bounds after the step, the others known_gaps
    j = 0
    n = 0
    for k in range(far.shape[0]):
        if far[k]:
            C.gaps[k] = C.left[j]
            j += 1
        else:
            C.gaps[k] = C.near_gaps[n]
            n += 1
    return OK
