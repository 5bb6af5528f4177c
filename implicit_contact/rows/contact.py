r"""The rows of one pair: closest points, gap, friction with torsion, quasi-rigid layer, impulses.

Paper symbols in ASCII (Drake SAP style)::

    paper     code        meaning                                                      eqs
    a1, a2    a1, a2      closest points on body 1 / body 2, world frame               (15)-(16), (28)-(29)
    l1, l2    l1, l2      scaled KKT multipliers, one per function of each body        (17)-(18), (30)-(31)
    p_n       p_n         normal impulse, 0 <= p_n  _|_  max_i f_i(a2) >= 0            (19), (32)
    p_t,p_o   p_t         friction impulses along the tangents t, o                    (7), (21)
    p_r       p_r         torsional moment impulse about the normal                    (7), (21)
    -         s           scaled distance of a cone-form pair, 0 <= p_n _|_ s >= 0     (28n), (32n)
    sigma     sigma       slip-speed multiplier of the friction ellipsoid             (7), (22)
    dbar      dbar        algebraic offset of the compliant layer                      (34)
    delta_n   dn          normal deflection of the layer                               (35)
    p_nr      p_nr        impulse of the rigid core                                    (33), (55)

Rows of one pair (body 1 has functions f_i, i = 1..m, with the known active one k1; body 2 has
g_j), with N1 = grad f_k1(a1) + sum_{i != k1} l_i grad f_i(a1) the body-1 normal and
N2 = sum_j l_j grad g_j(a2):

    a1 - a2 + l_k1 N1 = 0                 (15) / (28)     d rows, paired with free unknowns
    N1 + N2 = 0                           (16) / (29)     d rows
    0 <= l_i  _|_  -f_i(a1) - dbar_1 >= 0        (17) / (30) / (34)
    0 <= l_j  _|_  -g_j(a2) - dbar_2 >= 0        (18) / (31) / (34)
    0 <= p_n  _|_  max_i f_i(a2) + dbar_1 >= 0   (19) / (32) / (36)
    e_t^2 mu p_n (t . v_rel) + p_t sigma = 0                     (21), friction, if mu > 0
    e_o^2 mu p_n (o . v_rel) + p_o sigma = 0                     3D only
    e_r   mu p_n (n . w_rel) + p~_r sigma = 0, p_r = e_r p~_r    3D, if e_r > 0
    0 <= sigma  _|_  mu^2 p_n^2 - p_t^2/e_t^2 - p_o^2/e_o^2 - p~_r^2 >= 0        (22)

The cone form (pair column P_S >= 0: body 1 an intersection of a rigid pair, PairSpec.cone_form).
[GI] divides eqs (24)-(25) by the multiplier of one active function k1 of body 1; Prop. 4.3 then
holds only while k1 stays active at a1, which between two intersections is not known within a
step (Sec. 7): with k1 inactive, N1 is not in body 1's normal cone and the rows admit touching
points of interpenetrating bodies (measured: 32 of 200 stacked bodies raised StepFailure, 7
penetrated). Dividing instead by the sum of body 1's multipliers, s = sum_i hat-l_i, leaves
every l_i complementary and needs no k1:

    N1 = sum_i l_i grad f_i(a1)           (all i)
    a1 - a2 + s N1 = 0                     (28n)     d rows
    N1 + N2 = 0                            (29)      d rows
    sum_i l_i - 1 = 0                      (29n)     1 row, paired with the free unknown s
    (30), (31) for every l_i, l_j
    0 <= p_n  _|_  s >= 0                  (32n)

A solution with s > 0 is the pair of closest points of separated bodies (the KKT conditions
(24)-(27), hat-l = s l). With s = 0, a1 = a2 lies on both boundaries and N1, a non-zero
combination of body 1's active gradients, lies in C(F, a1) and in -C(G, a2): a common
supporting plane, so the bodies touch and do not overlap (the proof of Prop. 4.3 with N1 in
place of grad f_k1 + sum l_i grad f_i). The gap row is s: smooth, no max over functions.

and, for a quasi-rigid pair ([GI] Sec. 5; dbar_c = dbar on the compliant side c, 0 elsewhere),

    g_c(a_c + delta_n u) = 0,  u = grad g_c(a_c) / |grad g_c(a_c)|                     (35)
    paper:    p_n - p_nr = (h k delta_n + c (delta_n - delta_n^l)) / s_p                (49)
    midpoint: p_n - p_nr = (h k (delta_n + delta_n^l)/2 + c (delta_n - delta_n^l)) / s_p
    0 <= p_nr  _|_  delta_max - delta_n >= 0                                             (55)

(g_c: the compliant side's function that is largest at a_c). v_rel = v_2(a2) - v_1(a1) is the
velocity of body 2's material point relative to body 1's and w_rel = omega_2 - omega_1, both at
l+1. The impulse on body 2 is P = s_p (p_n n + p_t t + p_o o) at a2 with moment
tau = s_p e_r p_r n, and minus that on body 1 at a1; n = N1/|N1| points from body 1 into
body 2. Its generalized impulse on body b (sign s_b = +1 for body 2, -1 for body 1, lever
r_b = a_b - p_b) enters that body's Newton-Euler rows:

    Q_b = s_b (A_v^T P + A_w^T (r_b x P + tau)),       F[v_b] -= Q_b.

Tangents: Gram-Schmidt on a fixed axis e of the pair, t = (e - (e.n) n)/|...|, o = n x t (3D);
t = z x n (2D). A fixed half-space side ("reduced") has its point on its plane, a = a0 + T s,
s in R^{d-1}, and its multiplier free (its complementarity pair is trivial; [GI] Example 1).

Geometric implicitness. A body function f is written in body coordinates, so at a world point
a it is evaluated as f(xi), xi = R^T (a - p) with the pose at l+1 (bodies.py). With
G = R grad f(xi), Hw = R H R^T and r = a - p, under a rotation increment dtheta and a
translation dp of the body:

    df = G . da - (r x G) . dtheta - G . dp
    dG = Hw da + (-[G]x + Hw [r]x) dtheta - Hw dp

Jacobian. Every row is differentiated with respect to the pair's local variables: its own
unknowns (block), the world points a1, a2, and each body's twist (dtheta, dp, domega, dv_o);
the twist columns become velocity columns through the body's T rows (bodies.py), and a1, a2
become their unknowns through T (a = a0 + T s). A pair's rows and its bodies' impulse rows
form one dense local block over [v of body 1, v of body 2, the pair's block] (rows and columns
alike), which assemble.py adds into J.

Scaling (applied by assemble.py): impulses are unknowns in units of
s_p = m max(h g_ref, IMPULSE_SPEED) (stepper._pair_spec), the Newton-Euler rows are divided by
diag(M) and the position-level rows ((15), (17)-(19), (35), (55)) by h, so that every row reads
about as a velocity.

2D pairs are 3D pairs in the plane z = 0 (bodies rotating about z): their vectors have zero z
and only the first d rows of (15), (16) are written.
"""
from __future__ import annotations

import math

import numpy as np

from .._jit import ONE, TWO, lean_kernel
from .. import shape_kernels as sk

# pair_i columns
(P_DIM, P_B1, P_B2, P_F1, P_M1, P_F2, P_M2, P_RED1, P_RED2, P_K1, P_FR, P_TORS, P_COMP, P_SIDE,
 P_C0, P_NBLK, P_A1, P_NA1, P_A2, P_NA2, P_L1, P_L2, P_PN, P_PT, P_PR, P_SIG, P_DBAR, P_DN, P_PNR,
 P_KV1, P_KV2, P_SPLIT, P_S) = range(33)
NPI = 33
# pair_f columns
(Q_SP, Q_MU, Q_ET, Q_EO, Q_ER) = range(5)
Q_AXIS = 5        # 3
Q_A01 = 8         # 3
Q_T1 = 11         # 9 (3 x 3 row-major, the first na1 columns used)
Q_A02 = 20        # 3
Q_T2 = 23         # 9
Q_K, Q_C, Q_DMAX, Q_DPREV, Q_H = 32, 33, 34, 35, 36
# the start-of-step contact frame of a split step's first stage (P_SPLIT, rattle.py): n, t, o at l
# and the levers a_b - p_b at l of body 1 and body 2
Q_N0, Q_T0, Q_O0, Q_R10, Q_R20 = 37, 40, 43, 46, 49
NPF = 52
# report columns
R_A1, R_A2, R_N, R_T, R_O = 0, 3, 6, 9, 12
R_GAP = 15
R_VREL = 16
R_WREL = 19
NREP = 22
# compliance schemes
RIGID, PAPER, MIDPOINT = 0, 1, 2

# local variables of a pair's derivatives, after its block (nblk): the world points and each
# body's twist (dtheta, dp, domega, dv_o)
V_A1, V_A2 = 0, 3
V_TW1, V_TW2 = 6, 18
V_TH, V_P, V_W, V_VO = 0, 3, 6, 9
NV_EXTRA = 30


@lean_kernel
def _skew(v, out):
    out[0, 0], out[0, 1], out[0, 2] = 0.0, -v[2], v[1]
    out[1, 0], out[1, 1], out[1, 2] = v[2], 0.0, -v[0]
    out[2, 0], out[2, 1], out[2, 2] = -v[1], v[0], 0.0


@lean_kernel
def _cross(a, b, out):
    out[0] = a[1] * b[2] - a[2] * b[1]
    out[1] = a[2] * b[0] - a[0] * b[2]
    out[2] = a[0] * b[1] - a[1] * b[0]


@lean_kernel
def _world_eval(par, R, p, a, r, G, Hw, xi, g, H, order):
    """f of one body function at the world point a of a body posed (R, p): sets r = a - p,
    G = R grad f(xi), Hw = R H R^T (order 2), xi = R^T r; returns f."""
    for i in range(3):
        r[i] = a[i] - p[i]
    for j in range(3):
        xi[j] = R[0, j] * r[0] + R[1, j] * r[1] + R[2, j] * r[2]
    f = sk.evaluate(par, xi, g, H, order)
    if order >= 1:
        for i in range(3):
            G[i] = R[i, 0] * g[0] + R[i, 1] * g[1] + R[i, 2] * g[2]
    if order >= 2:
        for i in range(3):
            for j in range(3):
                acc = 0.0
                for m in range(3):
                    for q in range(3):
                        acc += R[i, m] * H[m, q] * R[j, q]
                Hw[i, j] = acc
    return f


@lean_kernel
def _add_df(D, row, c, G, r, va, vtw, tmp):
    """D[row] += c df with df = G.da - (r x G).dtheta - G.dp (a at va, the body's twist at vtw)."""
    _cross(r, G, tmp)
    for i in range(3):
        D[row, va + i] += c * G[i]
        D[row, vtw + V_TH + i] -= c * tmp[i]
        D[row, vtw + V_P + i] -= c * G[i]


@lean_kernel
def _add_dG(D3, c, G, Hw, r, va, vtw, S, Sr):
    """D3 (3, NV) += c dG, dG = Hw da + (-[G]x + Hw [r]x) dtheta - Hw dp."""
    _skew(G, S)
    _skew(r, Sr)
    for i in range(3):
        for j in range(3):
            hr = Hw[i, 0] * Sr[0, j] + Hw[i, 1] * Sr[1, j] + Hw[i, 2] * Sr[2, j]
            D3[i, va + j] += c * Hw[i, j]
            D3[i, vtw + V_TH + j] += c * (hr - S[i, j])
            D3[i, vtw + V_P + j] -= c * Hw[i, j]


@lean_kernel
def _add_dvpoint(D3, sgn, wb, rb, va, vtw, S, Sr):
    """D3 += sgn d(v_o + omega x r), r = a - p: dv_o - [r]x domega + [omega]x (da - dp)."""
    _skew(rb, Sr)
    _skew(wb, S)
    for q in range(3):
        D3[q, vtw + V_VO + q] += sgn
        for m in range(3):
            D3[q, vtw + V_W + m] -= sgn * Sr[q, m]
            D3[q, va + m] += sgn * S[q, m]
            D3[q, vtw + V_P + m] -= sgn * S[q, m]


@lean_kernel
def _fold_row(Drow, out, sign, nblk, x0, ca1, na1, T1, ca2, na2, T2, Tb1, k1, Tb2, k2):
    """out (a row of the local block, columns [v1 (k1), v2 (k2), block]) += sign * the row of
    derivatives Drow over the local variables, chained to the unknowns (see the docstring)."""
    ob = k1 + k2
    for c in range(nblk):
        out[ob + c] += sign * Drow[c]
    for i in range(3):
        da1 = Drow[x0 + V_A1 + i]
        if da1 != 0.0:
            for c in range(na1):
                out[ob + ca1 + c] += sign * da1 * T1[3 * i + c]
        da2 = Drow[x0 + V_A2 + i]
        if da2 != 0.0:
            for c in range(na2):
                out[ob + ca2 + c] += sign * da2 * T2[3 * i + c]
    for j in range(k1):
        acc = 0.0
        for i in range(12):
            acc += Drow[x0 + V_TW1 + i] * Tb1[i, j]
        out[j] += sign * acc
    for j in range(k2):
        acc = 0.0
        for i in range(12):
            acc += Drow[x0 + V_TW2 + i] * Tb2[i, j]
        out[k1 + j] += sign * acc


@lean_kernel
def _add_frozen_slip(D, row, c, e0, r10, r20, TW1, TW2, tmp):
    """D[row] += c d(e0 . v_rel0): the slip along e0 of the material points at the levers r_b0
    (fixed), d = sum_b s_b (e0 . dv_o + (r_b0 x e0) . domega)."""
    _cross(r20, e0, tmp)
    for q in range(3):
        D[row, TW2 + V_VO + q] += c * e0[q]
        D[row, TW2 + V_W + q] += c * tmp[q]
    _cross(r10, e0, tmp)
    for q in range(3):
        D[row, TW1 + V_VO + q] -= c * e0[q]
        D[row, TW1 + V_W + q] -= c * tmp[q]


@lean_kernel
def _tangent_derivatives(n, e, en, t, nu, o, Dt, Do):
    """dt/dn and do/dn for t = u / |u|, u = e - (e.n) n, o = n x t (nu = |u|, en = e.n):
    du/dn = -n e^T - (e.n) I, dt/dn = Q du/dn with Q = (I - t t^T) / nu, do/dn = -[t]x + [n]x dt/dn.
    Written with q = Q n and [n]x Q = ([n]x - o t^T) / nu as sums of outer products."""
    tn = t[0] * n[0] + t[1] * n[1] + t[2] * n[2]
    q0, q1, q2 = (n[0] - tn * t[0]) / nu, (n[1] - tn * t[1]) / nu, (n[2] - tn * t[2]) / nu
    k = en / nu
    for i in range(3):
        qi = q0 if i == 0 else (q1 if i == 1 else q2)
        for j in range(3):
            Dt[i, j] = -qi * e[j] - k * ((1.0 if i == j else 0.0) - t[i] * t[j])
    w0, w1, w2 = n[1] * q2 - n[2] * q1, n[2] * q0 - n[0] * q2, n[0] * q1 - n[1] * q0
    # do/dn = -[t]x - (n x q) e^T - k ([n]x - o t^T); [v]x = [[0, -v2, v1], [v2, 0, -v0], [-v1, v0, 0]]
    for i in range(3):
        wi = w0 if i == 0 else (w1 if i == 1 else w2)
        for j in range(3):
            if i == j:
                st = 0.0
                sn = 0.0
            elif (i, j) == (0, 1):
                st, sn = -t[2], -n[2]
            elif (i, j) == (0, 2):
                st, sn = t[1], n[1]
            elif (i, j) == (1, 0):
                st, sn = t[2], n[2]
            elif (i, j) == (1, 2):
                st, sn = -t[0], -n[0]
            elif (i, j) == (2, 0):
                st, sn = -t[1], -n[1]
            else:
                st, sn = t[0], n[0]
            Do[i, j] = -st - wi * e[j] - k * (sn - o[i] * t[j])


@lean_kernel
def _take(ws, at, n):
    """n zeroed floats of the workspace ws from at: (the view, the next free index)."""
    v = ws[at:at + n]
    for i in range(n):
        v[i] = 0.0
    return v, at + n


def workspace_size(m1: int, m2: int, nblk: int) -> int:
    """Floats of the workspace of one pair's _pair_rows (an upper bound of what it takes)."""
    nv = nblk + NV_EXTRA
    return 65 * 9 + 24 * (m1 + m2) + nv * (nblk + 12 * 3 + 1)


@lean_kernel
def pair_rows(pi, pf, fpar, R, p, w, vo, T, z, FL, JL, rep, need_jac, ws):
    """One pair's rows and impulses at z (the bodies' states from bodies.body_states).

    FL (L,): the local residual [F of body 1's velocity rows, body 2's, the pair's own rows]
    (unscaled; the impulse entries are -Q_b); JL (L, L): its Jacobian over the same local
    indices, written when need_jac; rep (NREP,): a1, a2, n, t, o, gap, v_rel, w_rel.
    L = kv1 + kv2 + nblk (pair_i columns P_KV1, P_KV2, P_NBLK); ws: a workspace of at least
    workspace_size(m1, m2, nblk) floats."""
    b1, b2 = pi[P_B1], pi[P_B2]
    _pair_rows(pi, pf, fpar, R[b1], p[b1], w[b1], vo[b1], T[b1], R[b2], p[b2], w[b2], vo[b2], T[b2],
               z, FL, JL, rep, need_jac, ws)


@lean_kernel
def _pair_rows(pi, pf, fpar, R1, p1, w1, vo1, Tb1, R2, p2, w2, vo2, Tb2, z, FL, JL, rep, need_jac, ws):
    d = pi[P_DIM]
    m1, m2 = pi[P_M1], pi[P_M2]
    f1o, f2o = pi[P_F1], pi[P_F2]
    red1, red2 = pi[P_RED1] != 0, pi[P_RED2] != 0
    k1 = pi[P_K1]
    cs = pi[P_S]
    cone_form = cs >= 0                           # body 1's normal normalised by sum l = 1 (29n)
    fr, tors = pi[P_FR] != 0, pi[P_TORS] != 0
    comp, side = pi[P_COMP], pi[P_SIDE]
    c0, nblk = pi[P_C0], pi[P_NBLK]
    ca1, na1, ca2, na2 = pi[P_A1], pi[P_NA1], pi[P_A2], pi[P_NA2]
    cl1, cl2, cpn = pi[P_L1], pi[P_L2], pi[P_PN]
    cpt, cpr, csig = pi[P_PT], pi[P_PR], pi[P_SIG]
    cdbar, cdn, cpnr = pi[P_DBAR], pi[P_DN], pi[P_PNR]
    s_p, mu, e_r = pf[Q_SP], pf[Q_MU], pf[Q_ER]
    T1 = pf[Q_T1:Q_T1 + 9]
    T2 = pf[Q_T2:Q_T2 + 9]
    # velocity columns per body: the local block is [v1 (kv1), v2 (kv2), block (nblk)]
    kv1, kv2 = pi[P_KV1], pi[P_KV2]
    ob = kv1 + kv2
    L = ob + nblk
    nv = nblk + NV_EXTRA
    x0 = nblk
    at = 0                                        # the next free float of the workspace ws
    for i in range(L):
        FL[i] = 0.0
    if need_jac:
        for i in range(L):
            for j in range(L):
                JL[i, j] = 0.0

    # -- the points, multipliers and impulses
    a1, at = _take(ws, at, 3)
    a2, at = _take(ws, at, 3)
    for i in range(3):
        acc1 = pf[Q_A01 + i]
        for c in range(na1):
            acc1 += T1[3 * i + c] * z[c0 + ca1 + c]
        a1[i] = acc1
        acc2 = pf[Q_A02 + i]
        for c in range(na2):
            acc2 += T2[3 * i + c] * z[c0 + ca2 + c]
        a2[i] = acc2
    l1 = z[c0 + cl1:c0 + cl1 + m1]
    l2 = z[c0 + cl2:c0 + cl2 + m2]
    p_n = z[c0 + cpn]
    dbar = z[c0 + cdbar] if comp != RIGID else 0.0
    dn_ = z[c0 + cdn] if comp != RIGID else 0.0
    off1 = dbar if (comp != RIGID and side == 1) else 0.0
    off2 = dbar if (comp != RIGID and side == 2) else 0.0

    # -- body functions: body 1 at a1 and a2, body 2 at a2
    f1, at = _take(ws, at, m1)
    G1_flat, at = _take(ws, at, m1 * 3)
    G1 = G1_flat.reshape((m1, 3))
    H1_flat, at = _take(ws, at, m1 * 3 * 3)
    H1 = H1_flat.reshape((m1, 3, 3))
    f12, at = _take(ws, at, m1)
    G12_flat, at = _take(ws, at, m1 * 3)
    G12 = G12_flat.reshape((m1, 3))
    f2, at = _take(ws, at, m2)
    G2_flat, at = _take(ws, at, m2 * 3)
    G2 = G2_flat.reshape((m2, 3))
    H2_flat, at = _take(ws, at, m2 * 3 * 3)
    H2 = H2_flat.reshape((m2, 3, 3))
    r11, at = _take(ws, at, 3)
    r12, at = _take(ws, at, 3)
    r22, at = _take(ws, at, 3)
    xi, at = _take(ws, at, 3)
    g, at = _take(ws, at, 3)
    H_flat, at = _take(ws, at, 3 * 3)
    H = H_flat.reshape((3, 3))
    Hdummy_flat, at = _take(ws, at, 3 * 3)
    Hdummy = Hdummy_flat.reshape((3, 3))
    order = 2 if need_jac else 1
    for i in range(m1):
        f1[i] = _world_eval(fpar[f1o + i], R1, p1, a1, r11, G1[i], H1[i], xi, g, H, order)
        f12[i] = _world_eval(fpar[f1o + i], R1, p1, a2, r12, G12[i], Hdummy, xi, g, H, ONE)
    for j in range(m2):
        f2[j] = _world_eval(fpar[f2o + j], R2, p2, a2, r22, G2[j], H2[j], xi, g, H, order)

    # -- (15)-(19)
    c1, at = _take(ws, at, m1)
    for i in range(m1):
        c1[i] = l1[i]
    if not cone_form:
        c1[k1] = 1.0                              # N1 = sum_i c_i G_i with c_k1 = 1
    N1, at = _take(ws, at, 3)
    N2, at = _take(ws, at, 3)
    for i in range(m1):
        for q in range(3):
            N1[q] += c1[i] * G1[i, q]
    for j in range(m2):
        for q in range(3):
            N2[q] += l2[j] * G2[j, q]
    lk = l1[k1]
    if cone_form:
        lk = z[c0 + cs]
    own = ob                                      # the pair's first row in FL / JL
    row = 0
    for q in range(d):
        FL[own + row] = a1[q] - a2[q] + lk * N1[q]                     # (15) / (28)
        row += 1
    for q in range(d):
        FL[own + row] = N1[q] + N2[q]                                  # (16) / (29)
        row += 1
    if cone_form:
        acc = -1.0
        for i in range(m1):
            acc += l1[i]
        FL[own + row] = acc                                            # (29n): sum_i l_i = 1
        row += 1
    if not red1:
        for i in range(m1):
            FL[own + row] = -(f1[i] + off1)                            # (17) / (30) / (34)
            row += 1
    if not red2:
        for j in range(m2):
            FL[own + row] = -(f2[j] + off2)                            # (18) / (31) / (34)
            row += 1
    ia = 0
    for i in range(1, m1):
        if f12[i] > f12[ia]:
            ia = i                                                     # the first maximiser
    gap = f12[ia] + off1
    FL[own + row] = lk if cone_form else gap                           # (19) / (32) / (36) / (32n)
    row += 1

    # -- normal, tangents, impulse
    nrm = math.sqrt(N1[0] * N1[0] + N1[1] * N1[1] + N1[2] * N1[2])
    n, at = _take(ws, at, 3)
    for q in range(3):
        n[q] = N1[q] / nrm
    t, at = _take(ws, at, 3)
    o, at = _take(ws, at, 3)
    e = pf[Q_AXIS:Q_AXIS + 3]
    en = 0.0
    nu = 1.0
    if d == 3:
        en = e[0] * n[0] + e[1] * n[1] + e[2] * n[2]
        u0, u1, u2 = e[0] - en * n[0], e[1] - en * n[1], e[2] - en * n[2]
        nu = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
        t[0], t[1], t[2] = u0 / nu, u1 / nu, u2 / nu
        _cross(n, t, o)
    else:
        t[0], t[1] = -n[1], n[0]
    pt0 = z[c0 + cpt] if fr else 0.0
    pt1 = z[c0 + cpt + 1] if (fr and d == 3) else 0.0
    p_r = z[c0 + cpr] if tors else 0.0
    P, at = _take(ws, at, 3)
    tau, at = _take(ws, at, 3)
    for q in range(3):
        P[q] = s_p * (p_n * n[q] + pt0 * t[q] + pt1 * o[q])
        tau[q] = s_p * e_r * p_r * n[q]

    # -- relative velocity at l+1
    vrel, at = _take(ws, at, 3)
    wrel, at = _take(ws, at, 3)
    tmp, at = _take(ws, at, 3)
    _cross(w2, r22, tmp)
    for q in range(3):
        vrel[q] += vo2[q] + tmp[q]
    _cross(w1, r11, tmp)
    for q in range(3):
        vrel[q] -= vo1[q] + tmp[q]
        wrel[q] = w2[q] - w1[q]

    # -- friction (21)-(22)
    sigma = 0.0
    vt0 = t[0] * vrel[0] + t[1] * vrel[1] + t[2] * vrel[2]
    vt1 = o[0] * vrel[0] + o[1] * vrel[1] + o[2] * vrel[2]
    wn = n[0] * wrel[0] + n[1] * wrel[1] + n[2] * wrel[2]
    split = pi[P_SPLIT] != 0
    n0 = pf[Q_N0:Q_N0 + 3]
    t0 = pf[Q_T0:Q_T0 + 3]
    o0 = pf[Q_O0:Q_O0 + 3]
    r10 = pf[Q_R10:Q_R10 + 3]
    r20 = pf[Q_R20:Q_R20 + 3]
    if split:
        # the first stage of a split step (rattle.py, eq R4): the slip through the mean of the
        # rows at l and at l+1, (W(q^l) + W(q^{l+1}))^T u / 2
        vrel0, at = _take(ws, at, 3)
        _cross(w2, r20, tmp)
        for q in range(3):
            vrel0[q] = vo2[q] + tmp[q]
        _cross(w1, r10, tmp)
        for q in range(3):
            vrel0[q] -= vo1[q] + tmp[q]
        vt0 = 0.5 * (vt0 + t0[0] * vrel0[0] + t0[1] * vrel0[1] + t0[2] * vrel0[2])
        vt1 = 0.5 * (vt1 + o0[0] * vrel0[0] + o0[1] * vrel0[1] + o0[2] * vrel0[2])
        wn = 0.5 * (wn + n0[0] * wrel[0] + n0[1] * wrel[1] + n0[2] * wrel[2])
    if fr:
        sigma = z[c0 + csig]
        et2, eo2 = pf[Q_ET] ** 2, pf[Q_EO] ** 2
        FL[own + row] = et2 * mu * p_n * vt0 + pt0 * sigma
        row += 1
        cone = (mu * p_n) ** 2 - (pt0 / pf[Q_ET]) ** 2
        if d == 3:
            FL[own + row] = eo2 * mu * p_n * vt1 + pt1 * sigma
            row += 1
            cone -= (pt1 / pf[Q_EO]) ** 2
        if tors:
            # e_r mu p_n (n . w_rel) + p~_r sigma = 0, p_r = e_r p~_r
            FL[own + row] = e_r * mu * p_n * wn + p_r * sigma
            row += 1
            cone -= p_r * p_r
        FL[own + row] = cone                                           # (22)
        row += 1

    # -- the quasi-rigid layer (35), (49), (55)
    Gc, at = _take(ws, at, 3)
    Hc_flat, at = _take(ws, at, 3 * 3)
    Hc = Hc_flat.reshape((3, 3))
    rc, at = _take(ws, at, 3)
    uc, at = _take(ws, at, 3)
    Gy, at = _take(ws, at, 3)
    ry, at = _take(ws, at, 3)
    gnorm = 1.0
    dspring = 0.0
    if comp != RIGID:
        if side == 2:
            fc_all, ac, Rc, pc, mc, fco = f2, a2, R2, p2, m2, f2o
        else:
            fc_all, ac, Rc, pc, mc, fco = f1, a1, R1, p1, m1, f1o
        jc = 0
        for j in range(1, mc):
            if fc_all[j] > fc_all[jc]:
                jc = j
        _world_eval(fpar[fco + jc], Rc, pc, ac, rc, Gc, Hc, xi, g, H, TWO)
        gnorm = math.sqrt(Gc[0] * Gc[0] + Gc[1] * Gc[1] + Gc[2] * Gc[2])
        y, at = _take(ws, at, 3)
        for q in range(3):
            uc[q] = Gc[q] / gnorm
            y[q] = ac[q] + dn_ * uc[q]
        fy = _world_eval(fpar[fco + jc], Rc, pc, y, ry, Gy, Hdummy, xi, g, H, ONE)
        FL[own + row] = fy                                             # (35)
        row += 1
        kn, cn, dprev = pf[Q_K], pf[Q_C], pf[Q_DPREV]
        hq = pf[Q_H]
        if comp == MIDPOINT:
            spring = hq * kn * 0.5 * (dn_ + dprev) + cn * (dn_ - dprev)
            dspring = hq * kn * 0.5 + cn
        else:
            spring = hq * kn * dn_ + cn * (dn_ - dprev)
            dspring = hq * kn + cn
        p_nr = z[c0 + cpnr] if cpnr >= 0 else 0.0
        FL[own + row] = (p_n - p_nr) - spring / s_p                    # (49)
        row += 1
        if cpnr >= 0:
            FL[own + row] = pf[Q_DMAX] - dn_                           # (55)
            row += 1

    # -- generalized impulses: F[v_b] -= s_b (A_v^T P + A_w^T (r_b x P + tau)); a split step's
    #    first stage applies them in the frame at l (rattle.py, eq R2): P, tau along n0, t0, o0
    #    at the levers r_b0
    M1, at = _take(ws, at, 3)
    M2, at = _take(ws, at, 3)
    if split:
        for q in range(3):
            P[q] = s_p * (p_n * n0[q] + pt0 * t0[q] + pt1 * o0[q])
            tau[q] = s_p * e_r * p_r * n0[q]
        _cross(r10, P, M1)
        _cross(r20, P, M2)
    else:
        _cross(r11, P, M1)
        _cross(r22, P, M2)
    for q in range(3):
        M1[q] += tau[q]
        M2[q] += tau[q]
    for j in range(kv1):
        acc = 0.0
        for q in range(3):
            acc += Tb1[9 + q, j] * P[q] + Tb1[6 + q, j] * M1[q]
        FL[j] += acc                                                   # s_1 = -1
    for j in range(kv2):
        acc = 0.0
        for q in range(3):
            acc += Tb2[9 + q, j] * P[q] + Tb2[6 + q, j] * M2[q]
        FL[kv1 + j] -= acc                                             # s_2 = +1

    # -- report
    for q in range(3):
        rep[R_A1 + q] = a1[q]
        rep[R_A2 + q] = a2[q]
        rep[R_N + q] = n[q]
        rep[R_T + q] = t[q]
        rep[R_O + q] = o[q]
        rep[R_VREL + q] = vrel[q]
        rep[R_WREL + q] = wrel[q]
    rep[R_GAP] = gap
    if not need_jac:
        return

    # ---- Jacobian over the local variables (block, a1, a2, twist 1, twist 2), then folded
    D_flat, at = _take(ws, at, nblk * nv)
    D = D_flat.reshape((nblk, nv))
    S_flat, at = _take(ws, at, 3 * 3)
    S = S_flat.reshape((3, 3))
    Sr_flat, at = _take(ws, at, 3 * 3)
    Sr = Sr_flat.reshape((3, 3))
    A1v, A2v = x0 + V_A1, x0 + V_A2
    TW1, TW2 = x0 + V_TW1, x0 + V_TW2
    # dN1 = sum_i c_i dG1_i + sum_{i != k1} G1_i dl_i;  dN2 = sum_j l_j dG2_j + G2_j dl_j
    dN1_flat, at = _take(ws, at, 3 * nv)
    dN1 = dN1_flat.reshape((3, nv))
    dN2_flat, at = _take(ws, at, 3 * nv)
    dN2 = dN2_flat.reshape((3, nv))
    for i in range(m1):
        _add_dG(dN1, c1[i], G1[i], H1[i], r11, A1v, TW1, S, Sr)
        if i != k1 or cone_form:
            for q in range(3):
                dN1[q, cl1 + i] += G1[i, q]
    for j in range(m2):
        _add_dG(dN2, l2[j], G2[j], H2[j], r22, A2v, TW2, S, Sr)
        for q in range(3):
            dN2[q, cl2 + j] += G2[j, q]
    row = 0
    for q in range(d):                                                 # (15)
        D[row, A1v + q] += 1.0
        D[row, A2v + q] -= 1.0
        D[row, (cs if cone_form else cl1 + k1)] += N1[q]
        for c in range(nv):
            D[row, c] += lk * dN1[q, c]
        row += 1
    for q in range(d):                                                 # (16)
        for c in range(nv):
            D[row, c] += dN1[q, c] + dN2[q, c]
        row += 1
    if cone_form:                                                      # (29n)
        for i in range(m1):
            D[row, cl1 + i] += 1.0
        row += 1
    if not red1:                                                       # (17)
        for i in range(m1):
            _add_df(D, row, -1.0, G1[i], r11, A1v, TW1, tmp)
            if comp != RIGID and side == 1:
                D[row, cdbar] -= 1.0
            row += 1
    if not red2:                                                       # (18)
        for j in range(m2):
            _add_df(D, row, -1.0, G2[j], r22, A2v, TW2, tmp)
            if comp != RIGID and side == 2:
                D[row, cdbar] -= 1.0
            row += 1
    if cone_form:                                                      # (32n)
        D[row, cs] += 1.0
    else:                                                              # (19)
        _add_df(D, row, 1.0, G12[ia], r12, A2v, TW1, tmp)
        if comp != RIGID and side == 1:
            D[row, cdbar] += 1.0
    row += 1
    # dn = Pn dN1, Pn = (I - n n^T) / |N1|
    dn_flat, at = _take(ws, at, 3 * nv)
    dn = dn_flat.reshape((3, nv))
    for q in range(3):
        for m in range(3):
            pnm = ((1.0 if q == m else 0.0) - n[q] * n[m]) / nrm
            if pnm != 0.0:
                for c in range(nv):
                    dn[q, c] += pnm * dN1[m, c]
    Dt_flat, at = _take(ws, at, 3 * 3)
    Dt = Dt_flat.reshape((3, 3))
    Do_flat, at = _take(ws, at, 3 * 3)
    Do = Do_flat.reshape((3, 3))
    if d == 3:
        _tangent_derivatives(n, e, en, t, nu, o, Dt, Do)
    else:
        Dt[0, 1], Dt[1, 0] = -1.0, 1.0                                 # t = z x n
    dt_flat, at = _take(ws, at, 3 * nv)
    dt = dt_flat.reshape((3, nv))
    do_flat, at = _take(ws, at, 3 * nv)
    do = do_flat.reshape((3, nv))
    for q in range(3):
        for m in range(3):
            if Dt[q, m] != 0.0 or Do[q, m] != 0.0:
                for c in range(nv):
                    dt[q, c] += Dt[q, m] * dn[m, c]
                    do[q, c] += Do[q, m] * dn[m, c]
    # dP = s_p (n dp_n + t dp_t + o dp_o + p_n dn + p_t dt + p_o do); dtau = s_p e_r (n dp_r + p_r dn)
    dP_flat, at = _take(ws, at, 3 * nv)
    dP = dP_flat.reshape((3, nv))
    dtau_flat, at = _take(ws, at, 3 * nv)
    dtau = dtau_flat.reshape((3, nv))
    for q in range(3):
        if split:                                  # a constant frame: P and tau linear in the impulses
            dP[q, cpn] += s_p * n0[q]
            if fr:
                dP[q, cpt] += s_p * t0[q]
                if d == 3:
                    dP[q, cpt + 1] += s_p * o0[q]
            if tors:
                dtau[q, cpr] += s_p * e_r * n0[q]
            continue
        dP[q, cpn] += s_p * n[q]
        if fr:
            dP[q, cpt] += s_p * t[q]
            if d == 3:
                dP[q, cpt + 1] += s_p * o[q]
        for c in range(nv):
            dP[q, c] += s_p * (p_n * dn[q, c] + pt0 * dt[q, c] + pt1 * do[q, c])
        if tors:
            dtau[q, cpr] += s_p * e_r * n[q]
            for c in range(nv):
                dtau[q, c] += s_p * e_r * p_r * dn[q, c]
    if fr:
        # d v_rel = sum_b s_b (dv_o - [r_b]x domega + [omega_b]x (da_b - dp_b)); d w_rel = dw2 - dw1
        dvrel_flat, at = _take(ws, at, 3 * nv)
        dvrel = dvrel_flat.reshape((3, nv))
        _add_dvpoint(dvrel, 1.0, w2, r22, A2v, TW2, S, Sr)
        _add_dvpoint(dvrel, -1.0, w1, r11, A1v, TW1, S, Sr)
        et2, eo2 = pf[Q_ET] ** 2, pf[Q_EO] ** 2
        # a split step's first stage: half the slip at l+1 and half through the frame at l,
        # d(t0 . v_rel0) = sum_b s_b (t0 . dv_o + (r_b0 x t0) . domega)
        half = 0.5 if split else 1.0
        ca = et2 * mu
        D[row, cpn] += ca * vt0
        D[row, cpt] += sigma
        D[row, csig] += pt0
        for c in range(nv):
            D[row, c] += half * ca * p_n * (vrel[0] * dt[0, c] + vrel[1] * dt[1, c] + vrel[2] * dt[2, c]
                                            + t[0] * dvrel[0, c] + t[1] * dvrel[1, c] + t[2] * dvrel[2, c])
        if split:
            _add_frozen_slip(D, row, 0.5 * ca * p_n, t0, r10, r20, TW1, TW2, tmp)
        row += 1
        if d == 3:
            ca = eo2 * mu
            D[row, cpn] += ca * vt1
            D[row, cpt + 1] += sigma
            D[row, csig] += pt1
            for c in range(nv):
                D[row, c] += half * ca * p_n * (vrel[0] * do[0, c] + vrel[1] * do[1, c] + vrel[2] * do[2, c]
                                                + o[0] * dvrel[0, c] + o[1] * dvrel[1, c] + o[2] * dvrel[2, c])
            if split:
                _add_frozen_slip(D, row, 0.5 * ca * p_n, o0, r10, r20, TW1, TW2, tmp)
            row += 1
        if tors:
            cr = e_r * mu
            D[row, cpn] += cr * wn
            D[row, cpr] += sigma
            D[row, csig] += p_r
            for c in range(nv):
                D[row, c] += half * cr * p_n * (wrel[0] * dn[0, c] + wrel[1] * dn[1, c] + wrel[2] * dn[2, c])
            for q in range(3):
                nq = half * n[q] + (0.5 * n0[q] if split else 0.0)
                D[row, TW2 + V_W + q] += cr * p_n * nq
                D[row, TW1 + V_W + q] -= cr * p_n * nq
            row += 1
        D[row, cpn] += 2.0 * mu * mu * p_n                             # cone
        D[row, cpt] -= 2.0 * pt0 / pf[Q_ET] ** 2
        if d == 3:
            D[row, cpt + 1] -= 2.0 * pt1 / pf[Q_EO] ** 2
        if tors:
            D[row, cpr] -= 2.0 * p_r
        row += 1
    if comp != RIGID:
        # (35): d g(y) = Gy . dy - (r_y x Gy) . dtheta_c - Gy . dp_c, dy = da_c + u d dn + dn du,
        # du = Pu dGc, Pu = (I - u u^T) / |Gc|
        Ac, TWc = (A2v, TW2) if side == 2 else (A1v, TW1)
        dGc_flat, at = _take(ws, at, 3 * nv)
        dGc = dGc_flat.reshape((3, nv))
        _add_dG(dGc, 1.0, Gc, Hc, rc, Ac, TWc, S, Sr)
        gyu, at = _take(ws, at, 3)  # dn Gy^T Pu
        for m in range(3):
            acc = 0.0
            for q in range(3):
                acc += Gy[q] * ((1.0 if q == m else 0.0) - uc[q] * uc[m]) / gnorm
            gyu[m] = dn_ * acc
        _cross(ry, Gy, tmp)
        for q in range(3):
            D[row, Ac + q] += Gy[q]
            D[row, TWc + V_TH + q] -= tmp[q]
            D[row, TWc + V_P + q] -= Gy[q]
            D[row, cdn] += Gy[q] * uc[q]
            for c in range(nv):
                D[row, c] += gyu[q] * dGc[q, c]
        row += 1
        D[row, cpn] += 1.0                                             # (49)
        D[row, cdn] -= dspring / s_p
        if cpnr >= 0:
            D[row, cpnr] -= 1.0
        row += 1
        if cpnr >= 0:                                                  # (55)
            D[row, cdn] -= 1.0
            row += 1
    for r_ in range(nblk):
        _fold_row(D[r_], JL[own + r_], 1.0, nblk, x0, ca1, na1, T1, ca2, na2, T2, Tb1, kv1, Tb2, kv2)

    # impulse rows: dQ_b = s_b (A_v^T dP + A_w^T dM_b), dM_b = -[P]x (da_b - dp_b) + [r_b]x dP + dtau
    if kv1 + kv2 > 0:
        _skew(P, S)
        DQ, at = _take(ws, at, nv)
        dM_flat, at = _take(ws, at, 3 * nv)
        dM = dM_flat.reshape((3, nv))
        for body in range(2):
            if body == 0:
                kv, Tb, rb, Av, TW, sgn, first = kv1, Tb1, r11, A1v, TW1, -1.0, 0
            else:
                kv, Tb, rb, Av, TW, sgn, first = kv2, Tb2, r22, A2v, TW2, 1.0, kv1
            if kv == 0:
                continue
            if split:                              # the constant lever at l
                _skew(r10 if body == 0 else r20, Sr)
            else:
                _skew(rb, Sr)
            for q in range(3):
                for c in range(nv):
                    acc = dtau[q, c]
                    for m in range(3):
                        acc += Sr[q, m] * dP[m, c]
                    dM[q, c] = acc
                if split:
                    continue
                for m in range(3):
                    dM[q, Av + m] -= S[q, m]
                    dM[q, TW + V_P + m] += S[q, m]
            for j in range(kv):
                for c in range(nv):
                    acc = 0.0
                    for q in range(3):
                        acc += Tb[9 + q, j] * dP[q, c] + Tb[6 + q, j] * dM[q, c]
                    DQ[c] = acc
                # F[v_b] -= s_b Q_b
                _fold_row(DQ, JL[first + j], -sgn, nblk, x0, ca1, na1, T1, ca2, na2, T2, Tb1, kv1, Tb2, kv2)


