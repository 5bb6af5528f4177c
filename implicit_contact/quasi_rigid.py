r"""Rows of a quasi-rigid pair ([GI] Sec. 5, eqs 33-40): a compliant layer over a rigid core.

One body of the pair (the compliant side c, body 1 or 2) is deformed by a uniform algebraic
offset dbar: its functions become g_j + dbar <= 0 (the sub-level set of eq 34), so the
closest-point rows of that side read 0 <= l_j _|_ -(g_j(a_c) + dbar) >= 0, and, when the compliant
side is body 1, the gap reads f(a2) + dbar >= 0 (eq 36). The geometric deflection delta_n is the
distance from a_c along the unit normal u = grad g(a_c)/|grad g(a_c)| back to the undeformed
surface, eq (35):

    g(a_c + delta_n u) = 0.

The pair's normal impulse p_n (the unknown of the rigid rows, which keeps its place in the
Newton-Euler and friction rows) is the sum of the spring's and the core's, eq (33):
p_n = p_ns + p_nr. The spring-damper (eq 37, normal part) and the core (eq 36):

    paper:    p_n - p_nr = h k delta_n + c (delta_n - delta_n^l)                 eq (49)
    midpoint: p_n - p_nr = h k (delta_n + delta_n^l)/2 + c (delta_n - delta_n^l)
    0 <= p_nr  _|_  delta_max - delta_n >= 0                                       eq (55)

The complementarity of the spring is carried by the rigid gap row: 0 <= p_n _|_ gap >= 0; since
p_nr > 0 needs delta_n = delta_max > 0, hence p_ns > 0, p_n > 0 iff p_ns > 0 (without damping;
with damping a relaxing layer can carry p_ns = 0 while delta_n > 0, and then p_n = 0 as well).
Unknowns added per pair: dbar, delta_n (free) and p_nr (>= 0, only with a finite core).

These rows are evaluated in plain numpy (a quasi-rigid pair is rarer and small), with the same
chain rule as the rigid rows; tests/test_formulation.py checks the Jacobian by differences.

The same class is the generic pair path: with spec.compliance None it writes exactly the rigid
rows (15)-(22) (no dbar, delta_n, p_nr) from general Pose matrices (A_w, A_v, B_th, B_p), so it
serves every pair the float hot path of formulation._PairPlan does not: pairs with a body of an
articulated skeleton (BodyKinematics kind ARTICULATED, whose velocity columns are its skeleton's;
tests/test_articulated.py checks that Jacobian by differences).
"""
from __future__ import annotations

import math

import numpy as np

from . import formulation as fm


class CompliantPair:
    """One quasi-rigid (or generic rigid, spec.compliance None) pair of a StepProblem, with the
    generator interface of the rigid pairs: next() writes its rows into F and yields its report;
    send(J) writes its Jacobian."""

    def __init__(self, problem, k):
        self.problem, self.k = problem, k

    @property
    def local_index(self) -> np.ndarray:
        """Indices of z (sorted) of every row and column its Jacobian writes: its bodies'
        velocities and its own block (the plan protocol of formulation.StepProblem)."""
        pb = self.problem
        spec, sl = pb.specs[self.k], pb.layout.pairs[self.k]
        end = max(sl.p_n, sl.sigma, sl.p_r, sl.dbar, sl.dn, sl.p_nr) + 1
        parts = [np.arange(int(sl.rows_geo[0]), end)]
        for b in (spec.obj1.body, spec.obj2.body):
            vs = pb._vslice[b]
            if vs is not None:
                parts.append(np.arange(vs.start, vs.stop))
        return np.unique(np.concatenate(parts))

    def generator(self, z, F):
        report = self._evaluate(z, F, None)
        J = yield report
        if J is not None:
            self._evaluate(z, np.zeros_like(F), J)
        yield

    def _evaluate(self, z, F, J):
        pb, k = self.problem, self.k
        spec, sl = pb.specs[k], pb.layout.pairs[k]
        comp = spec.compliance
        d = spec.dim
        b1, b2 = spec.obj1.body, spec.obj2.body
        P1 = pb.bodies[b1].pose(pb.body_velocity(z, b1))
        P2 = pb.bodies[b2].pose(pb.body_velocity(z, b2))
        v1s, v2s = pb._vslice[b1], pb._vslice[b2]
        a1, T1, a2, T2 = pb.points(z, k)
        jac = J is not None
        f1 = spec.obj1.functions
        m1 = len(f1)
        fa1, Ga1, Ha1, dfa1, dGa1 = fm._eval_functions(f1, P1, a1, jac)
        fa2, Ga2, _, dfa2, _ = fm._eval_functions(f1, P1, a2, jac)
        gb2, Gb2, Hb2, dgb2, dGb2 = fm._eval_functions(spec.obj2.functions, P2, a2, jac)
        l1, l2 = z[sl.l1s], z[sl.l2s]
        rigid = comp is None
        dbar, dn = (0.0, 0.0) if rigid else (z[sl.dbar], z[sl.dn])
        side = 0 if rigid else spec.compliant_side
        k1 = spec.k1
        c = l1.copy()
        c[k1] = 1.0
        N1 = c @ Ga1
        lk = l1[k1]
        r15 = slice(int(sl.rows_geo[0]), int(sl.rows_geo[0]) + d)
        r16 = slice(int(sl.rows_geo[0]) + d, int(sl.rows_geo[0]) + 2 * d)
        off1 = dbar if side == 1 else 0.0
        off2 = dbar if side == 2 else 0.0
        F[r15] = a1 - a2 + lk * N1                                       # (15) / (28)
        F[r16] = N1 + l2 @ Gb2                                           # (16) / (29)
        F[sl.rows_l1s] = -(fa1[sl.l1_bounded] + off1)                    # (17) / (34)
        F[sl.rows_l2s] = -(gb2[sl.l2_bounded] + off2)                    # (18) / (34)
        ia = int(np.argmax(fa2))
        F[sl.row_n] = fa2[ia] + off1                                     # (19) / (36)
        nrm = math.sqrt(float(N1 @ N1))
        nhat = N1 / nrm
        tang, dtang = fm._tangents(nhat, spec.tangent_axis, jac)
        s_p = spec.impulse_scale
        fr = sl.sigma >= 0
        p_n = z[sl.p_n]
        p_t = z[sl.p_ts] if fr else fm._EMPTY
        torsion = sl.p_r >= 0
        p_r = z[sl.p_r] if torsion else 0.0
        e_r = spec.friction.e_r
        Pvec = s_p * p_n * nhat
        if fr:
            Pvec = Pvec + s_p * (p_t @ tang)
        tau = s_p * e_r * p_r * nhat if torsion else None
        # eq (35) on the compliant side's active function at its point
        if rigid:
            pass
        elif side == 2:
            funcs, Pc, ac, Tc, acs, vcs, gvals = spec.obj2.functions, P2, a2, T2, sl.a2s, v2s, gb2
        else:
            funcs, Pc, ac, Tc, acs, vcs, gvals = f1, P1, a1, T1, sl.a1s, v1s, fa1
        if not rigid:
            j = int(np.argmax(gvals))
            fc = (funcs[j],)
            _, Gc, Hc, _, dGc = fm._eval_functions(fc, Pc, ac, jac)
            gnorm = math.sqrt(float(Gc[0] @ Gc[0]))
            u = Gc[0] / gnorm
            y = ac + dn * u
            fy, Gy, _, dfy, _ = fm._eval_functions(fc, Pc, y, jac)
            F[sl.dbar] = fy[0]                                           # (35)
            # spring-damper and core
            kn, cn = comp.k_n, comp.c_n
            dprev = spec.delta_prev
            h = pb.h
            spring = h * kn * (0.5 * (dn + dprev) if comp.scheme == "midpoint" else dn) + cn * (dn - dprev)
            dspring = h * kn * (0.5 if comp.scheme == "midpoint" else 1.0) + cn
            p_nr = z[sl.p_nr] if sl.p_nr >= 0 else 0.0
            F[sl.dn] = (p_n - p_nr) - spring / s_p                       # (49)
            if sl.p_nr >= 0:
                F[sl.p_nr] = comp.delta_max - dn                         # (55)
        if jac:
            eye_d = fm._EYE[d]
            dN1_da1 = np.einsum("i,ijk->jk", c, Ha1)
            dN1_dv1 = np.einsum("i,ijk->jk", c, dGa1) if v1s is not None else None
            others = [i for i in range(m1) if i != k1]
            J[r15, sl.a1s] = (eye_d + lk * dN1_da1) @ T1
            J[r15, sl.a2s] = -T2
            J[r15, sl.l1[k1]] = N1
            J[r16, sl.a1s] = dN1_da1 @ T1
            J[r16, sl.a2s] = np.einsum("j,jkl->kl", l2, Hb2) @ T2
            J[r16, sl.l2s] = Gb2.T
            for i in others:
                J[r15, sl.l1[i]] = lk * Ga1[i]
                J[r16, sl.l1[i]] = Ga1[i]
            if v1s is not None:
                J[r15, v1s] = lk * dN1_dv1
                J[r16, v1s] = dN1_dv1
            if v2s is not None:
                J[r16, v2s] = np.einsum("j,jkl->kl", l2, dGb2)
            for i, row in zip(sl.l1_bounded, sl.rows_l1):
                J[row, sl.a1s] = -Ga1[i] @ T1
                if v1s is not None:
                    J[row, v1s] = -dfa1[i]
                if side == 1:
                    J[row, sl.dbar] = -1.0
            for jj, row in zip(sl.l2_bounded, sl.rows_l2):
                J[row, sl.a2s] = -Gb2[jj] @ T2
                if v2s is not None:
                    J[row, v2s] = -dgb2[jj]
                if side == 2:
                    J[row, sl.dbar] = -1.0
            J[sl.row_n, sl.a2s] = Ga2[ia] @ T2
            if v1s is not None:
                J[sl.row_n, v1s] = dfa2[ia]
            if side == 1:
                J[sl.row_n, sl.dbar] = 1.0
            if not rigid:
                # (35): d g(y) = G(y).(da_c + u d dn + dn du) + dfdv(y) dv, du = (I - u u^T)/|G| dG(a_c)
                Pu = (eye_d - np.outer(u, u)) / gnorm
                gy_du = dn * (Gy[0] @ Pu)                                 # row: d g(y) / d G(a_c)
                J[sl.dbar, acs] = (Gy[0] + gy_du @ Hc[0]) @ Tc
                J[sl.dbar, sl.dn] = Gy[0] @ u
                if vcs is not None:
                    J[sl.dbar, vcs] = dfy[0] + gy_du @ dGc[0]
                # spring and core
                J[sl.dn, sl.p_n] = 1.0
                J[sl.dn, sl.dn] = -dspring / s_p
                if sl.p_nr >= 0:
                    J[sl.dn, sl.p_nr] = -1.0
                    J[sl.p_nr, sl.dn] = -1.0
            Pn = (eye_d - np.outer(nhat, nhat)) / nrm
            dP_dn = s_p * p_n * eye_d
            if fr:
                for a in range(d - 1):
                    dP_dn = dP_dn + s_p * p_t[a] * dtang[a]
            dN1_a1 = dN1_da1 @ T1
        # generalized contact impulses: +P at a2 on body 2, -P at a1 on body 1 (and moments)
        for sign, Pz, a, T, aslc, vs in ((1.0, P2, a2, T2, sl.a2s, v2s), (-1.0, P1, a1, T1, sl.a1s, v1s)):
            if vs is None:
                continue
            r = a - Pz.p
            M_fac = Pz.A_v.T + Pz.A_w.T @ fm._X(r).T
            gen = M_fac @ Pvec
            if torsion:
                gen = gen + Pz.A_w.T @ tau
            F[vs] -= sign * gen
            if not jac:
                continue
            J[vs, sl.p_n] -= sign * (M_fac @ (s_p * nhat))
            if fr:
                J[vs, sl.p_ts] -= sign * (M_fac @ (s_p * tang.T))
            if torsion:
                J[vs, sl.p_r] -= sign * (Pz.A_w.T @ (s_p * e_r * nhat))
            dgen_dr = sign * (Pz.A_w.T @ (-fm._X(Pvec).T))
            J[vs, aslc] -= dgen_dr @ T
            J[vs, vs] += dgen_dr @ Pz.B_p
            dgen_dn = sign * (M_fac @ dP_dn)
            if torsion:
                dgen_dn = dgen_dn + sign * (Pz.A_w.T * (s_p * e_r * p_r))
            G_ = dgen_dn @ Pn
            J[vs, sl.a1s] -= G_ @ dN1_a1
            if v1s is not None:
                J[vs, v1s] -= G_ @ dN1_dv1
            for i in others:
                J[vs, sl.l1[i]] -= G_ @ Ga1[i]
        vrel = None
        if fr:
            mu = spec.friction.mu
            vrel, dvrel = fm._relative_velocity(z, P1, P2, v1s, v2s, a1, a2, T1, T2, sl, jac)
            e = (spec.friction.e_t, spec.friction.e_o)
            sigma = z[sl.sigma]
            rows = sl.rows_fric
            cone = (mu * p_n) ** 2
            for a in range(d - 1):
                row = rows[a]
                ea2 = e[a] ** 2
                vt = tang[a] @ vrel
                F[row] = ea2 * mu * p_n * vt + p_t[a] * sigma
                cone -= (p_t[a] / e[a]) ** 2
                if jac:
                    J[row, sl.p_n] += ea2 * mu * vt
                    J[row, sl.p_t[a]] += sigma
                    J[row, sl.sigma] += p_t[a]
                    coef = ea2 * mu * p_n
                    for cols, block in dvrel:
                        J[row, cols] += coef * (tang[a] @ block)
                    dt_dN = (vrel @ dtang[a]) @ Pn
                    J[row, sl.a1s] += coef * (dt_dN @ dN1_a1)
                    if v1s is not None:
                        J[row, v1s] += coef * (dt_dN @ dN1_dv1)
                    for i in others:
                        J[row, sl.l1[i]] += coef * (dt_dN @ Ga1[i])
                    J[sl.sigma, sl.p_t[a]] = -2.0 * p_t[a] / e[a] ** 2
            if torsion:
                row = rows[d - 1]
                wrel = (P2.omega if v2s is not None else fm._ZERO3) - (P1.omega if v1s is not None else fm._ZERO3)
                wn = nhat @ wrel
                F[row] = e_r * mu * p_n * wn + p_r * sigma
                cone -= p_r ** 2
                if jac:
                    J[row, sl.p_n] += e_r * mu * wn
                    J[row, sl.p_r] += sigma
                    J[row, sl.sigma] += p_r
                    coef = e_r * mu * p_n
                    if v2s is not None:
                        J[row, v2s] += coef * (nhat @ P2.A_w)
                    if v1s is not None:
                        J[row, v1s] -= coef * (nhat @ P1.A_w)
                    dwn_dN = wrel @ Pn
                    J[row, sl.a1s] += coef * (dwn_dN @ dN1_a1)
                    if v1s is not None:
                        J[row, v1s] += coef * (dwn_dN @ dN1_dv1)
                    for i in others:
                        J[row, sl.l1[i]] += coef * (dwn_dN @ Ga1[i])
                    J[sl.sigma, sl.p_r] = -2.0 * p_r
            F[sl.sigma] = cone                                           # (22)
            if jac:
                J[sl.sigma, sl.p_n] = 2.0 * mu * mu * p_n
        return (tuple(a1), tuple(a2), tuple(nhat), tuple(map(tuple, tang)), float(fa2[ia] + off1),
                None if vrel is None else tuple(vrel))
