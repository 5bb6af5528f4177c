r"""Compiled pieces of a step outside the MCP's rows: free flight, poses, broadphase boxes.

World tables (built by the stepper when it is made) describe the mobile skeletons (their
velocity columns in one world vector V, and their mass matrices' offsets in one buffer), the
bodies that carry contact pieces and the pieces themselves; per step the stepper fills V, the
positions Q, the mass matrices MB and forces FB from DART and these kernels do the rest:

* free flight ([GI] eq 21 with no contact): v_free = v + h M^-1 force per skeleton, the
  semi-implicit Euler step DART itself takes;
* poses now and after a step at given velocities, exactly as formulation.BodyKinematics
  moves them (FREE: R = exp(q_0:3), R+ = exp(h omega) R, p+ = p + h v_o; PLANAR: theta + h
  omega; ARTICULATED: the twist J v of DART's Jacobian at l);
* each piece's motion margin, 10 tol + h/2 (|v| + |omega| reach), and its world box: the
  rotated body-frame box of a bounded piece (centre R c + p, half extents |R| e), joined over
  the poses now and after the free step; unbounded pieces keep the exact boxes the stepper
  gives them;
* the exact closed overlap test of grown boxes on a list of pairs (broadphase.py's test).
"""
from __future__ import annotations

import math

import numpy as np

from ._jit import kernel, lean_kernel
from .sparse_lu import dense_lu, dense_lu_solve
from .rows.bodies import i_plus_k, so3_coefficients, twist

# body kinds of the world tables
FIXED, FREE, PLANAR, ARTICULATED = 0, 1, 2, 3


@kernel
def small_solve(A, b, out):
    """out = A^-1 b by LU with partial pivoting on a copy of A (sparse_lu.dense_lu); False if A is
    exactly singular."""
    M = A.copy()
    piv = np.empty(A.shape[0], np.int64)
    if not dense_lu(M, piv):
        return False
    for i in range(b.shape[0]):
        out[i] = b[i]
    dense_lu_solve(M, piv, out)
    return True


@kernel
def block_kicks(M, u, b, blocks, out):
    """out = u + M^-1 b for a block-diagonal M (n, n) whose blocks are (first column, size) rows of
    blocks; a block that is exactly singular gets NaN (a solve from there stops as NOT_FINITE)."""
    for r in range(blocks.shape[0]):
        c, k = blocks[r, 0], blocks[r, 1]
        dv = np.empty(k)
        if not small_solve(M[c:c + k, c:c + k], b[c:c + k], dv):
            dv[:] = np.nan
        for i in range(k):
            out[c + i] = u[c + i] + dv[i]


@kernel
def free_flight(sk_nv, sk_voff, sk_moff, V, MB, FB, h, VF):
    """VF = V + h M^-1 FB per skeleton (the semi-implicit Euler step with no contact)."""
    for s in range(sk_nv.shape[0]):
        k, off, moff = sk_nv[s], sk_voff[s], sk_moff[s]
        M = MB[moff:moff + k * k].reshape((k, k))
        dv = np.empty(k)
        small_solve(M, FB[off:off + k], dv)
        for i in range(k):
            VF[off + i] = V[off + i] + h * dv[i]


@kernel
def body_poses(bd_kind, bd_sk, bd_joff, sk_voff, sk_nv, Q, Vel, h, R_given, p_given, JB, R_out, p_out, th_out):
    """Every body's pose after a step h at the world velocities Vel (h = 0: the pose at l).

    FREE: R = exp(h omega) exp(q_0:3), p = q_3:6 + h v_o; PLANAR: theta = q_2 + h omega,
    p = (q_0 + h v_x, q_1 + h v_y, 0) (th_out: theta); ARTICULATED: R = exp(h J_w v) R_given,
    p = p_given + h J_v v (JB: DART's world Jacobians, 6 x k row-major at bd_joff); FIXED: the
    given pose."""
    E = np.zeros((3, 3))
    R0 = np.zeros((3, 3))
    phi = np.zeros(3)
    w = np.zeros(3)
    vo = np.zeros(3)
    for b in range(bd_kind.shape[0]):
        kind = bd_kind[b]
        th_out[b] = 0.0
        if kind == FIXED:
            for i in range(3):
                p_out[b, i] = p_given[b, i]
                for j in range(3):
                    R_out[b, i, j] = R_given[b, i, j]
            continue
        s = bd_sk[b]
        off, k = sk_voff[s], sk_nv[s]
        if kind == PLANAR:
            th = Q[off + 2] + h * Vel[off + 2]
            c, sn = math.cos(th), math.sin(th)
            R_out[b, 0, 0], R_out[b, 0, 1], R_out[b, 0, 2] = c, -sn, 0.0
            R_out[b, 1, 0], R_out[b, 1, 1], R_out[b, 1, 2] = sn, c, 0.0
            R_out[b, 2, 0], R_out[b, 2, 1], R_out[b, 2, 2] = 0.0, 0.0, 1.0
            p_out[b, 0] = Q[off] + h * Vel[off]
            p_out[b, 1] = Q[off + 1] + h * Vel[off + 1]
            p_out[b, 2] = 0.0
            th_out[b] = th
            continue
        if kind == FREE:
            for i in range(3):
                phi[i] = Q[off + i]
            th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
            a, bb, _ = so3_coefficients(th2)
            i_plus_k(phi, th2, a, bb, R0)
            for i in range(3):
                w[i] = Vel[off + i]
                vo[i] = Vel[off + 3 + i]
                p_out[b, i] = Q[off + 3 + i] + h * vo[i]
        else:
            twist(JB, bd_joff[b], k, Vel, off, w, vo)
            for i in range(3):
                p_out[b, i] = p_given[b, i] + h * vo[i]
                for j in range(3):
                    R0[i, j] = R_given[b, i, j]
        if h == 0.0:
            for i in range(3):
                for j in range(3):
                    R_out[b, i, j] = R0[i, j]
            continue
        for i in range(3):
            phi[i] = h * w[i]
        th2 = phi[0] * phi[0] + phi[1] * phi[1] + phi[2] * phi[2]
        a, bb, _ = so3_coefficients(th2)
        i_plus_k(phi, th2, a, bb, E)
        for i in range(3):
            for j in range(3):
                R_out[b, i, j] = E[i, 0] * R0[0, j] + E[i, 1] * R0[1, j] + E[i, 2] * R0[2, j]


@kernel
def motion_margins(ob_body, ob_reach, bd_kind, bd_sk, bd_joff, sk_voff, sk_nv, VF, JB, h, base, margins):
    """Per piece: base + h/2 (|v| + |omega| reach) at the free-flight velocities (the MCP's v+
    differs from free flight: half a free step more of motion is allowed)."""
    w, vo = np.zeros(3), np.zeros(3)
    for o in range(ob_body.shape[0]):
        b = ob_body[o]
        margins[o] = base
        kind = bd_kind[b]
        if kind == FIXED:
            continue
        s = bd_sk[b]
        off, k = sk_voff[s], sk_nv[s]
        if kind == PLANAR:
            lin = math.sqrt(VF[off] ** 2 + VF[off + 1] ** 2)
            ang = abs(VF[off + 2])
        elif kind == FREE:
            lin = math.sqrt(VF[off + 3] ** 2 + VF[off + 4] ** 2 + VF[off + 5] ** 2)
            ang = math.sqrt(VF[off] ** 2 + VF[off + 1] ** 2 + VF[off + 2] ** 2)
        else:
            twist(JB, bd_joff[b], k, VF, off, w, vo)
            lin = math.sqrt(vo[0] * vo[0] + vo[1] * vo[1] + vo[2] * vo[2])
            ang = math.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
        margins[o] += 0.5 * h * (lin + ang * ob_reach[o])


@lean_kernel
def piece_boxes(ob_body, ob_bounded, ob_dim, ob_centre, ob_half, exact_lo, exact_hi, R1, p1, R2, p2, join,
                lo, hi):
    """World boxes of the pieces: bounded ones from their rotated body-frame boxes at pose 1,
    joined with pose 2 where join[body]; unbounded ones the given exact boxes."""
    for o in range(ob_body.shape[0]):
        if not ob_bounded[o]:
            for i in range(3):
                lo[o, i] = exact_lo[o, i]
                hi[o, i] = exact_hi[o, i]
            continue
        b = ob_body[o]
        for pose in range(2 if join[b] else 1):
            for i in range(3):
                if pose == 0:
                    c = p1[b, i]
                    e = 0.0
                    for j in range(3):
                        c += R1[b, i, j] * ob_centre[o, j]
                        e += abs(R1[b, i, j]) * ob_half[o, j]
                else:
                    c = p2[b, i]
                    e = 0.0
                    for j in range(3):
                        c += R2[b, i, j] * ob_centre[o, j]
                        e += abs(R2[b, i, j]) * ob_half[o, j]
                if ob_dim[o] == 2 and i == 2:
                    e = 0.0
                if pose == 0:
                    lo[o, i], hi[o, i] = c - e, c + e
                else:
                    lo[o, i] = min(lo[o, i], c - e)
                    hi[o, i] = max(hi[o, i], c + e)


@lean_kernel
def overlapping(P, glo, ghi, out):
    """out[k] = the grown boxes of pair P[k] overlap (closed intervals on every axis)."""
    count = 0
    for k in range(P.shape[0]):
        i, j = P[k, 0], P[k, 1]
        ok = True
        for a in range(3):
            if not (glo[i, a] <= ghi[j, a] and glo[j, a] <= ghi[i, a]):
                ok = False
                break
        out[k] = ok
        if ok:
            count += 1
    return count


# ---------------------------------------------------------------------------------------------
# pairs that cannot touch within the step (ImplicitContactStepper._far_pairs explains the bound)
# ---------------------------------------------------------------------------------------------
@lean_kernel
def _motion(o, ob_body, ob_radius, bd_kind, bd_sk, sk_voff, Vel, v):
    """(|omega| rho) of piece o's body at the world velocities Vel; v (3,): its origin's velocity."""
    b = ob_body[o]
    kind = bd_kind[b]
    v[0] = v[1] = v[2] = 0.0
    if kind == FIXED:
        return 0.0
    off = sk_voff[bd_sk[b]]
    if kind == PLANAR:
        v[0], v[1] = Vel[off], Vel[off + 1]
        return abs(Vel[off + 2]) * ob_radius[o]
    v[0], v[1], v[2] = Vel[off + 3], Vel[off + 4], Vel[off + 5]
    return math.sqrt(Vel[off] ** 2 + Vel[off + 1] ** 2 + Vel[off + 2] ** 2) * ob_radius[o]


@kernel
def far_test(P, gap, ob_body, ob_radius, bd_kind, bd_sk, sk_voff, Vel, h, tol, far):
    """far[k]: pair P[k] with a known lower bound gap[k] of its gap (NaN: unknown) cannot close
    within the step at the velocities Vel plus one free step of each body's own motion:
    g > h |v_i - v_j| + reach + own + 10 tol, reach = h (|omega_i| rho_i + |omega_j| rho_j),
    own = h (|v_i| + |v_j|) + reach."""
    vi = np.zeros(3)
    vj = np.zeros(3)
    count = 0
    for k in range(P.shape[0]):
        g = gap[k]
        far[k] = False
        if not (g == g):
            continue
        ri = _motion(P[k, 0], ob_body, ob_radius, bd_kind, bd_sk, sk_voff, Vel, vi)
        rj = _motion(P[k, 1], ob_body, ob_radius, bd_kind, bd_sk, sk_voff, Vel, vj)
        reach = h * (ri + rj)
        own = h * (math.sqrt(vi[0] ** 2 + vi[1] ** 2 + vi[2] ** 2) + math.sqrt(vj[0] ** 2 + vj[1] ** 2 + vj[2] ** 2))
        own += reach
        rel = math.sqrt((vi[0] - vj[0]) ** 2 + (vi[1] - vj[1]) ** 2 + (vi[2] - vj[2]) ** 2)
        if g > h * rel + reach + own + 10.0 * tol:
            far[k] = True
            count += 1
    return count


@kernel
def far_after(P, gap, ob_body, ob_radius, bd_kind, bd_sk, sk_voff, Vel, h, tol, left):
    """left[k]: the lower bound of far pair k's gap after a step at the velocities Vel,
    g - h (|v_i - v_j| + |omega_i| rho_i + |omega_j| rho_j); returns how many are <= tol."""
    vi = np.zeros(3)
    vj = np.zeros(3)
    violated = 0
    for k in range(P.shape[0]):
        ri = _motion(P[k, 0], ob_body, ob_radius, bd_kind, bd_sk, sk_voff, Vel, vi)
        rj = _motion(P[k, 1], ob_body, ob_radius, bd_kind, bd_sk, sk_voff, Vel, vj)
        rel = math.sqrt((vi[0] - vj[0]) ** 2 + (vi[1] - vj[1]) ** 2 + (vi[2] - vj[2]) ** 2)
        left[k] = gap[k] - h * (rel + ri + rj)
        if left[k] <= tol:
            violated += 1
    return violated


@lean_kernel
def moved_beyond_margins(ob_body, ob_radius, ob_bounded, bd_kind, bd_sk, sk_voff, V_solved, VF, margins, h, tol):
    """Whether some piece's solved motion leaves what its broadphase margin allowed for
    (ImplicitContactStepper._uncovered). A piece's candidate box joins its boxes at l and after
    the free step, each grown by its margin; its solved end pose is covered if it lies within the
    margin (less 9 tol) of either pose: h (|dv| + |d omega| rho) with dv the solved velocity
    minus the free-flight one, or minus zero (a body brought to rest ends where it was). Always
    for articulated and unbounded moving pieces."""
    for o in range(ob_body.shape[0]):
        b = ob_body[o]
        kind = bd_kind[b]
        if kind == FIXED:
            continue
        if kind == ARTICULATED or not ob_bounded[o]:
            return True
        off = sk_voff[bd_sk[b]]
        allowed = margins[o] - 9.0 * tol
        if (_motion_off(kind, V_solved, VF, off, 1.0, h, ob_radius[o]) > allowed
                and _motion_off(kind, V_solved, VF, off, 0.0, h, ob_radius[o]) > allowed):
            return True
    return False


@lean_kernel
def _motion_off(kind, V_solved, VF, off, s, h, rho):
    """h (|v - s v_F| + |omega - s omega_F| rho) of a free or planar body at columns off."""
    if kind == PLANAR:
        lin = math.sqrt((V_solved[off] - s * VF[off]) ** 2 + (V_solved[off + 1] - s * VF[off + 1]) ** 2)
        ang = abs(V_solved[off + 2] - s * VF[off + 2])
    else:
        lin = math.sqrt((V_solved[off + 3] - s * VF[off + 3]) ** 2 + (V_solved[off + 4] - s * VF[off + 4]) ** 2
                        + (V_solved[off + 5] - s * VF[off + 5]) ** 2)
        ang = math.sqrt((V_solved[off] - s * VF[off]) ** 2 + (V_solved[off + 1] - s * VF[off + 1]) ** 2
                        + (V_solved[off + 2] - s * VF[off + 2]) ** 2)
    return h * (lin + ang * rho)


@lean_kernel
def all_finite(a, b, c, d):
    """Whether every entry of the four arrays is finite."""
    for x in (a, b, c, d):
        for i in range(x.shape[0]):
            if not math.isfinite(x[i]):
                return False
    return True


@kernel
def assemble_forces(W, h):
    """Each skeleton's force at l, tau + tau_ext - (Coriolis + gravity), with its joint springs
    and dampers implicit as DART treats them: force -= K (q - q_rest + h v) + D v, and
    M += h D + h^2 K on the diagonal (dart_adapter's module docstring)."""
    for i in range(W.FB.shape[0]):
        W.FB[i] = W.TAU[i] + W.FEXT[i] - W.CG[i] - (W.SPK[i] * (W.Q[i] - W.SPQ0[i] + h * W.V[i]) + W.SPD[i] * W.V[i])
    for s in range(W.sk_nv.shape[0]):
        k, off, moff = W.sk_nv[s], W.sk_voff[s], W.sk_moff[s]
        for i in range(k):
            W.MB[moff + i * k + i] += h * W.SPD[off + i] + h * h * W.SPK[off + i]


@kernel
def split_end_forces(W, h, U, stiff):
    """Order 2's second-stage forces at (q+, u) (rattle.py, eqs R5, R9, R10), after DART's M and
    Coriolis and gravity forces at (q+, u) were read into W.MB, W.CG: tau + tau_ext - (Coriolis +
    gravity) - K (q + h/2 u - q_rest) - D u, the joint springs at the midpoint of q and q+ and
    the dampers at the mean velocity u (W.Q: q at l); a damper stiff for its dof (h D / 2 >
    stiff M_ii) acts at v+ instead: - D v+ = - D u - D (v+ - u), M += h/2 D on the diagonal
    (stage 2 solves for v+ - u, as assemble_forces's tables for v+ - v). Without springs and
    dampers this is assemble_forces's force to the bit."""
    for i in range(W.FB.shape[0]):
        W.FB[i] = W.TAU[i] + W.FEXT[i] - W.CG[i] - (W.SPK[i] * (W.Q[i] + 0.5 * h * U[i] - W.SPQ0[i]) + W.SPD[i] * U[i])
    for s in range(W.sk_nv.shape[0]):
        k, off, moff = W.sk_nv[s], W.sk_voff[s], W.sk_moff[s]
        for i in range(k):
            d = W.SPD[off + i]
            if 0.5 * h * d > stiff * W.MB[moff + i * k + i]:
                W.MB[moff + i * k + i] += 0.5 * h * d


@kernel
def free_coriolis_jacobian(M, w, out):
    """dc/dv (6, 6) into out: DART's Coriolis forces c of one rigid body on a FreeJoint, in
    closed form from its mass matrix M (6, 6) at q and its angular velocity w (world frame),
    where dart_adapter.coriolis_jacobian takes 12 calls into DART. The velocities are [w; v] of
    the body origin, both in the world frame; with m the mass, r the centre of mass from the
    origin and I the rotational inertia about the centre of mass (both in the world frame), the
    Newton-Euler equations at the origin give

        M = [[I + m [r]^T [r],  m [r]], [m [r]^T,  m 1]],
        c = [w x I w + m r x (w x (w x r));  m w x (w x r)],

    so m, r and I are read off M, c does not depend on v, and with D = d(w x (w x r))/dw =
    -[w x r] - [w][r]:

        dc/dw = [[ [w] I - [I w] + m [r] D ];  [ m D ]],   dc/dv = 0.

    Agrees with coriolis_jacobian to round-off (tests/test_rattle.py)."""
    m = M[3, 3]
    r0 = 0.5 * (M[2, 4] - M[1, 5]) / m        # (m [r] = M[:3, 3:], skew)
    r1 = 0.5 * (M[0, 5] - M[2, 3]) / m
    r2 = 0.5 * (M[1, 3] - M[0, 4]) / m
    Sr = np.array(((0.0, -r2, r1), (r2, 0.0, -r0), (-r1, r0, 0.0)))
    Sw = np.array(((0.0, -w[2], w[1]), (w[2], 0.0, -w[0]), (-w[1], w[0], 0.0)))
    I = np.empty((3, 3))
    for i in range(3):
        for j in range(3):
            I[i, j] = M[i, j] - m * (Sr[0, i] * Sr[0, j] + Sr[1, i] * Sr[1, j] + Sr[2, i] * Sr[2, j])
    c0, c1, c2 = w[1] * r2 - w[2] * r1, w[2] * r0 - w[0] * r2, w[0] * r1 - w[1] * r0      # w x r
    D = np.empty((3, 3))
    Iw = np.empty(3)
    for i in range(3):
        Iw[i] = I[i, 0] * w[0] + I[i, 1] * w[1] + I[i, 2] * w[2]
        for j in range(3):
            D[i, j] = -(Sw[i, 0] * Sr[0, j] + Sw[i, 1] * Sr[1, j] + Sw[i, 2] * Sr[2, j])
    D[0, 1] += c2
    D[0, 2] -= c1
    D[1, 0] -= c2
    D[1, 2] += c0
    D[2, 0] += c1
    D[2, 1] -= c0
    SIw = np.array(((0.0, -Iw[2], Iw[1]), (Iw[2], 0.0, -Iw[0]), (-Iw[1], Iw[0], 0.0)))
    out[:, :] = 0.0
    for i in range(3):
        for j in range(3):
            out[i, j] = (Sw[i, 0] * I[0, j] + Sw[i, 1] * I[1, j] + Sw[i, 2] * I[2, j]) - SIw[i, j] \
                + m * (Sr[i, 0] * D[0, j] + Sr[i, 1] * D[1, j] + Sr[i, 2] * D[2, j])
            out[3 + i, j] = m * D[i, j]


@kernel
def free_stage1_tables(M, w, F, h, C, M1, F1):
    """Order 2's stage-1 tables of one body on a FreeJoint without joint springs (rattle.py, R1;
    stepper._stage1_tables): C = dc/dv (free_coriolis_jacobian, from M (6, 6) and the angular
    velocity w), M1 (36,) = M + h/2 C row by row, F1 (6,) = F / 2."""
    free_coriolis_jacobian(M, w, C)
    c = 0.5 * h
    for i in range(6):
        for j in range(6):
            M1[6 * i + j] = M[i, j] + c * C[i, j]
        F1[i] = 0.5 * F[i]


@kernel
def given_poses(W):
    """The fixed and articulated bodies' poses from DART's transforms TG (4 x 4); returns whether a
    fixed body moved since the last call (its unbounded pieces' exact boxes are then stale)."""
    for b in W.read_bodies:
        for i in range(3):
            W.p_given[b, i] = W.TG[b, i, 3]
            for j in range(3):
                W.R_given[b, i, j] = W.TG[b, i, j]
    moved = False
    for f in range(W.fixed.shape[0]):
        b = W.fixed[f]
        for i in range(3):
            if W.p_given[b, i] != W.p_fixed[f, i]:
                moved = True
            W.p_fixed[f, i] = W.p_given[b, i]
            for j in range(3):
                if W.R_given[b, i, j] != W.R_fixed[f, i, j]:
                    moved = True
                W.R_fixed[f, i, j] = W.R_given[b, i, j]
    return moved


@kernel
def kinematics(W, h, base, half):
    """A step's state at l from what was read of DART: forces (assemble_forces), given poses
    (given_poses), free flight, poses now and after the free step, motion margins, and (half) the
    poses half a step on at v. Returns whether a fixed body moved."""
    assemble_forces(W, h)
    moved = given_poses(W)
    free_flight(W.sk_nv, W.sk_voff, W.sk_moff, W.V, W.MB, W.FB, h, W.VF)
    body_poses(W.bd_kind, W.bd_sk, W.bd_joff, W.sk_voff, W.sk_nv, W.Q, W.V, 0.0, W.R_given, W.p_given, W.JB,
               W.R_now, W.p_now, W.th_now)
    body_poses(W.bd_kind, W.bd_sk, W.bd_joff, W.sk_voff, W.sk_nv, W.Q, W.VF, h, W.R_given, W.p_given, W.JB,
               W.R_pred, W.p_pred, W.th_pred)
    motion_margins(W.ob_body, W.ob_reach, W.bd_kind, W.bd_sk, W.bd_joff, W.sk_voff, W.sk_nv, W.VF, W.JB, h, base,
                   W.margins)
    if half:
        body_poses(W.bd_kind, W.bd_sk, W.bd_joff, W.sk_voff, W.sk_nv, W.Q, W.V, 0.5 * h, W.R_given, W.p_given,
                   W.JB, W.R_half, W.p_half, W.th_half)
    return moved


@kernel
def grown_boxes(W, fat_lo, fat_hi):
    """The pieces' boxes (piece_boxes, now joined with after the free step) grown by their
    margins into W.glo, W.ghi; returns whether every grown box lies inside its fat box (fat_lo,
    fat_hi; False when they are empty)."""
    glo, ghi = W.glo, W.ghi
    piece_boxes(W.ob_body, W.ob_bounded, W.ob_dim, W.ob_centre, W.ob_half, W.exact_lo, W.exact_hi, W.R_now, W.p_now,
                W.R_pred, W.p_pred, W.is_mobile, glo, ghi)
    inside = fat_lo.shape[0] == glo.shape[0] and glo.shape[0] > 0
    for o in range(glo.shape[0]):
        m = W.margins[o]
        for a in range(3):
            glo[o, a] -= m
            ghi[o, a] += m
            if inside and (glo[o, a] < fat_lo[o, a] or ghi[o, a] > fat_hi[o, a]):
                inside = False
    return inside
