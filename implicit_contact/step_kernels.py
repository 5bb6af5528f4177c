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

from ._jit import kernel
from .rows.bodies import i_plus_k, so3_coefficients

# body kinds of the world tables
FIXED, FREE, PLANAR, ARTICULATED = 0, 1, 2, 3


@kernel
def small_solve(A, b, out):
    """out = A^-1 b by LU with partial pivoting on a copy of A; False if A is exactly singular."""
    n = A.shape[0]
    M = A.copy()
    x = b.copy()
    for k in range(n):
        p = k
        big = abs(M[k, k])
        for i in range(k + 1, n):
            if abs(M[i, k]) > big:
                big, p = abs(M[i, k]), i
        if big == 0.0:
            return False
        if p != k:
            for j in range(n):
                M[k, j], M[p, j] = M[p, j], M[k, j]
            x[k], x[p] = x[p], x[k]
        for i in range(k + 1, n):
            f = M[i, k] / M[k, k]
            if f != 0.0:
                for j in range(k + 1, n):
                    M[i, j] -= f * M[k, j]
                x[i] -= f * x[k]
    for i in range(n - 1, -1, -1):
        acc = x[i]
        for j in range(i + 1, n):
            acc -= M[i, j] * out[j]
        out[i] = acc / M[i, i]
    return True


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
            jo = bd_joff[b]
            for i in range(3):
                aw = 0.0
                av = 0.0
                for j in range(k):
                    aw += JB[jo + i * k + j] * Vel[off + j]
                    av += JB[jo + (3 + i) * k + j] * Vel[off + j]
                w[i], vo[i] = aw, av
                p_out[b, i] = p_given[b, i] + h * av
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
            jo = bd_joff[b]
            lin = 0.0
            ang = 0.0
            for i in range(3):
                aw = 0.0
                av = 0.0
                for j in range(k):
                    aw += JB[jo + i * k + j] * VF[off + j]
                    av += JB[jo + (3 + i) * k + j] * VF[off + j]
                ang += aw * aw
                lin += av * av
            lin, ang = math.sqrt(lin), math.sqrt(ang)
        margins[o] += 0.5 * h * (lin + ang * ob_reach[o])


@kernel
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


@kernel
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
