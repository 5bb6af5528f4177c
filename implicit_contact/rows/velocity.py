r"""The rows of order 2's second stage (implicit_contact/rattle.py, eqs R5-R7), compiled.

At the fixed geometry q+ every closed pair c has four rows of velocity: G_c v = (n . v_rel,
t . v_rel, o . v_rel, n . w_rel), v_rel the velocity of body 2's material point at a2 relative
to body 1's at a1, w_rel = omega_2 - omega_1. With DART's world Jacobian of a body's origin
J_b = [A_w; A_v] (angular rows first), lever r_b = a_b - p_b and s_1 = -1, s_2 = +1:

    G_c[e] += s_b (e^T A_v + (r_b x e)^T A_w)     e = n, t, o
    G_c[3] += s_b n^T A_w

Unknowns x = [v+; per pair P_n, (P_t, P_o), (P~_r), (sigma)] (impulses in units of s_p); pair
table pi = (first column, tangent unknowns, torsion unknown, sigma, patch vertices, core open,
layered patch, parent column),
pf = (mu, e_t, e_o, e_r, s_p, R1_n, R1_t, R1_o, R1~_r, L, beta). Rows:

    M (v+ - u) - h/2 f - sum_c s_p W_c^T (P_c - R1_c)                   (R5), scaled by 1/diag(M)
    n . v_rel                         complementary to P_n >= 0        (R6)
    e^2 mu P_n (e . v_rel) + P_e sigma,   e_r mu P_n (n . w_rel) + P~_r sigma    (R7): [GI] (21)
    mu^2 P_n^2 - P_t^2/e_t^2 - P_o^2/e_o^2 - P~_r^2  complementary to sigma >= 0   [GI] (22)

with W_c's columns (G_c[0], G_c[1], G_c[2], e_r G_c[3]) for (P_n, P_t, P_o, P~_r).

Joint rows (joint_rows.py) at the velocity level, after the pairs: row r with direction g_r
(nv,), unit u_r and stage 1's generalized impulse k_r along g_r:

    g_r . v+   complementary to lambda_r in its bounds;   (R5) gets - g_r (u_r lambda_r - k_r)

(Coulomb friction: the total impulse u_r lambda_r within h f and opposite the end velocity; a
limit closed at q+ and a mimic relation: the end velocity along g_r is held at 0, resp. >= 0.)

A quasi-rigid pair (rattle.py, R11-R14) has a known normal load L, its layer's impulse over the
step, and for a stiff damper a part at the end velocity, -beta n . v_rel (R14): its normal
unknown is the core's impulse P_n,core and the pair's normal impulse is
L - beta n . v_rel + P_n,core, in (R5) and in the friction rows (R7) alike. Its core closed at q+: (R6) for
P_n,core; open (pi's V_OPEN = 1): the row P_n,core = 0 (free bounds). A rigid pair has L = 0.

A patch (a face on a face; pi's V_NVERT = m > 0) is its friction point c followed by its m
vertices, frictionless pairs whose normal impulses carry the patch's normal load (so that the
load can move within the patch). The point's P_n is then their sum, the row P_n - sum_i P_n,i = 0
in place of (R6), and its own normal column is not applied; its friction rows see that P_n.
A layered patch (a quasi-rigid face on a face, V_LAYER = 1) has a known total: its point's
unknown x[c] is then the common normal velocity w of its loaded vertices, each vertex's row
n . v_rel,i - w complementary to P_n,i >= 0 (V_PARENT: the point's column), and the point's row
sum_i P_n,i - (L - beta w) (the core's impulse) complementary to w >= 0 when its core is closed,
= 0 (w free) when open. The load then sits where the face does not turn into the layer.
"""
from __future__ import annotations

from .._jit import lean_kernel

# pair_i columns
V_COL, V_NT, V_NR, V_NS, V_NVERT, V_OPEN, V_LAYER, V_PARENT = 0, 1, 2, 3, 4, 5, 6, 7
NVI = 8
# pair_f columns
V_MU, V_ET, V_EO, V_ER, V_SP, V_R1, V_LOAD, V_DAMP = 0, 1, 2, 3, 4, 5, 9, 10
NVF = 11


@lean_kernel
def velocity_rows(body, a, frame, bcol, bk, bJ, bp, G):
    """G (npairs, 4, nv) of the closed pairs (module docstring). body (npairs, 2): each end's
    body index or -1 (fixed); a (npairs, 2, 3) the points; frame (npairs, 3, 3) rows n, t, o;
    per body its first column bcol, dofs bk, Jacobian bJ (nb, 6, kmax), origin bp (nb, 3)."""
    G[:] = 0.0
    for c in range(body.shape[0]):
        for side in range(2):
            b = body[c, side]
            if b < 0:
                continue
            sgn = 1.0 if side == 1 else -1.0
            r0 = a[c, side, 0] - bp[b, 0]
            r1 = a[c, side, 1] - bp[b, 1]
            r2 = a[c, side, 2] - bp[b, 2]
            col, k = bcol[b], bk[b]
            for row in range(3):
                e0, e1, e2 = frame[c, row, 0], frame[c, row, 1], frame[c, row, 2]
                m0 = r1 * e2 - r2 * e1          # r x e
                m1 = r2 * e0 - r0 * e2
                m2 = r0 * e1 - r1 * e0
                for j in range(k):
                    G[c, row, col + j] += sgn * (e0 * bJ[b, 3, j] + e1 * bJ[b, 4, j] + e2 * bJ[b, 5, j]
                                                 + m0 * bJ[b, 0, j] + m1 * bJ[b, 1, j] + m2 * bJ[b, 2, j])
            n0, n1, n2 = frame[c, 0, 0], frame[c, 0, 1], frame[c, 0, 2]
            for j in range(k):
                G[c, 3, col + j] += sgn * (n0 * bJ[b, 0, j] + n1 * bJ[b, 1, j] + n2 * bJ[b, 2, j])


@lean_kernel
def stage2_rows(x, M, u, hf, scale, G, pi, pf, jg, ju, jk, jcol, F, J, need_jac):
    """F (n,) and, when need_jac, J (n, n) of (R5)-(R7) and the joint rows at x (module docstring)."""
    nv = M.shape[0]
    n = F.shape[0]
    for i in range(n):
        F[i] = 0.0
    if need_jac:
        for i in range(n):
            for j in range(n):
                J[i, j] = 0.0
    for i in range(nv):
        acc = -hf[i]
        for j in range(nv):
            acc += M[i, j] * (x[j] - u[j])
            if need_jac:
                J[i, j] = M[i, j]
        F[i] = acc
    for cp in range(pi.shape[0]):
        c, nt, nr, ns = pi[cp, V_COL], pi[cp, V_NT], pi[cp, V_NR], pi[cp, V_NS]
        nvert = pi[cp, V_NVERT]
        layered_patch = nvert > 0 and pi[cp, V_LAYER] > 0
        m = 1 + nt + nr
        s_p, e_r = pf[cp, V_SP], pf[cp, V_ER]
        # the pair's normal impulse p_n: x[c] + L - beta n . v_rel (a pair; L = beta = 0 if
        # rigid), x[c] (a rigid patch's point), or its vertices' sum (a layered patch's point)
        beta = pf[cp, V_DAMP] if nvert == 0 else 0.0
        wn = 0.0
        if beta != 0.0:
            for i in range(nv):
                wn += G[cp, 0, i] * x[i]
        load = pf[cp, V_LOAD] - beta * wn
        p_n = x[c] + load
        if layered_patch:
            p_n = 0.0
            for k in range(cp + 1, cp + 1 + nvert):
                p_n += x[pi[k, V_COL]]
        # (R5): the impulse columns n, t, (o), (torsion), and their rows of G (a patch's point:
        # no normal column, its vertices carry the load)
        for q in range(1 if nvert > 0 else 0, m):
            grow = q if q < 1 + nt else 3
            w = s_p * (e_r if grow == 3 else 1.0)
            r1 = pf[cp, V_R1 + grow]
            dP = x[c + q] - r1
            if q == 0:
                dP += load
            for i in range(nv):
                g = G[cp, grow, i] * w
                F[i] -= g * dP
                if need_jac:
                    J[i, c + q] = -g
                    if q == 0 and beta != 0.0:
                        for j in range(nv):
                            J[i, j] += g * beta * G[cp, 0, j]
        if layered_patch:
            # a layered patch's point: x[c] is the common normal velocity w of its loaded
            # vertices; the vertices' sum less the layer's L - beta w is the core's impulse
            b = pf[cp, V_DAMP]
            acc = b * x[c] - pf[cp, V_LOAD]
            if need_jac:
                J[c, c] = b
            for k in range(cp + 1, cp + 1 + nvert):
                acc += x[pi[k, V_COL]]
                if need_jac:
                    J[c, pi[k, V_COL]] = 1.0
            F[c] = acc
        elif nvert > 0:
            # a patch's point: P_n = the sum of its vertices' normal impulses
            acc = x[c]
            if need_jac:
                J[c, c] = 1.0
            for k in range(cp + 1, cp + 1 + nvert):
                acc -= x[pi[k, V_COL]]
                if need_jac:
                    J[c, pi[k, V_COL]] = -1.0
            F[c] = acc
        elif pi[cp, V_OPEN] > 0:
            # a quasi-rigid pair whose core is open at q+: no core impulse
            F[c] = x[c]
            if need_jac:
                J[c, c] = 1.0
        else:
            # (R6); a layered patch's vertex: its normal velocity above the patch's w
            acc = 0.0
            for i in range(nv):
                acc += G[cp, 0, i] * x[i]
                if need_jac:
                    J[c, i] = G[cp, 0, i]
            parent = pi[cp, V_PARENT]
            if parent >= 0:
                acc -= x[parent]
                if need_jac:
                    J[c, parent] = -1.0
            F[c] = acc
        if ns == 0:
            continue
        # (R7), [GI] (21)-(22)
        mu = pf[cp, V_MU]
        sigma = x[c + m]
        cone = (mu * p_n) ** 2
        for q in range(1, m):
            grow = q if q < 1 + nt else 3
            if grow == 3:
                wgt, e2 = e_r, 1.0
            else:
                e = pf[cp, V_ET] if grow == 1 else pf[cp, V_EO]
                wgt, e2 = e * e, e * e
            slip = 0.0
            for i in range(nv):
                slip += G[cp, grow, i] * x[i]
            r = c + q
            F[r] = wgt * mu * p_n * slip + x[r] * sigma
            cone -= x[r] * x[r] / e2
            if need_jac:
                for i in range(nv):
                    J[r, i] = wgt * mu * p_n * G[cp, grow, i]
                    if beta != 0.0:
                        J[r, i] -= wgt * mu * beta * slip * G[cp, 0, i]
                if layered_patch:
                    for k in range(cp + 1, cp + 1 + nvert):
                        J[r, pi[k, V_COL]] = wgt * mu * slip
                else:
                    J[r, c] = wgt * mu * slip
                J[r, r] = sigma
                J[r, c + m] = x[r]
                J[c + m, r] = -2.0 * x[r] / e2
        F[c + m] = cone
        if need_jac:
            if layered_patch:
                for k in range(cp + 1, cp + 1 + nvert):
                    J[c + m, pi[k, V_COL]] = 2.0 * mu * mu * p_n
            else:
                J[c + m, c] = 2.0 * mu * mu * p_n
            if beta != 0.0:
                for i in range(nv):
                    J[c + m, i] = -2.0 * mu * mu * p_n * beta * G[cp, 0, i]
    for r in range(jg.shape[0]):
        c = jcol[r]
        acc = 0.0
        for i in range(nv):
            g = jg[r, i]
            acc += g * x[i]
            F[i] -= g * (ju[r] * x[c] - jk[r])
            if need_jac:
                J[c, i] = g
                J[i, c] = -g * ju[r]
        F[c] = acc
    for i in range(nv):
        F[i] *= scale[i]
        if need_jac:
            for j in range(n):
                J[i, j] *= scale[i]
