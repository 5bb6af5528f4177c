r"""What a step remembers of the last one: its pairs' solution, and the warm start made from it.

``PairMemory`` keeps the last committed step's problem tables, its solution z and its pairs'
reports (closest points, normals; rows/contact.py), and answers per pair key the quantities the
stepper's decisions read (``memory.get(key)["p_n"]`` and so on: last normal impulse, points,
multipliers, friction, tangent axis, layer deflection, and the Euclidean distance of a
separated pair). Nothing is copied per pair: the records are read from the arrays on demand.

``warm_start`` (compiled) makes the next step's start from it, pair by pair, for every pair the
memory holds: closest points carried along with their bodies (``contact_shift``), multipliers
and impulses kept (in the new pair's units, friction rotated into its tangents if its axis
changed), a quasi-rigid layer extrapolated at its last rate; velocities start at their values
at l for skeletons that touched, at free flight for the others. New pairs are seeded by the
stepper from static closest points.

Contact shift. Each closest point moves with its own body's translation (a free or planar body:
its origin's velocity; a body of an articulated skeleton: its material velocity
v_o + omega x (a - p), since a link's origin may sit at a joint that does not move); the point
on a fixed body also slides along its surface with the other body's tangential translation
(the contact point of a rolling disc travels along the ground; a falling body's target point
stays put). Exact for steady rolling on flat ground.
"""
from __future__ import annotations

import math

import numpy as np

from ._jit import kernel, lean_kernel
from .rows import bodies as rb
from .rows import contact as rc
from .rows import dynamics as rd


class PairMemory:
    """The last committed step's pairs (see the module docstring)."""

    def __init__(self, problem=None, z=None, specs=()):
        if problem is None:                    # remembers nothing (the first step, after free flight)
            self.keys = {}
            return
        t = problem.tables
        problem._evaluated_at(z)
        self.pair_i = t.pair_i.copy()
        self.pair_f = t.pair_f.copy()
        self.z = np.array(z, float)
        self.rep = problem._rep.copy()
        self.keys = {spec.key: k for k, spec in enumerate(specs)}
        self.compliance_k = [spec.compliance.k_n if spec.compliance is not None else 0.0 for spec in specs]

    def carried(self, problem, z) -> "PairMemory":
        """The memory of a step whose pairs are this memory's, in the same rows of the same
        problem (the stepper's _repeat_step): the keys are kept, the arrays read anew."""
        t = problem.tables
        problem._evaluated_at(z)
        new = PairMemory.__new__(PairMemory)
        new.pair_i, new.pair_f = t.pair_i.copy(), t.pair_f.copy()
        new.z, new.rep = np.array(z, float), problem._rep.copy()
        new.keys, new.compliance_k = self.keys, self.compliance_k
        return new

    def carried_arrays(self, pair_f, z, rep) -> "PairMemory":
        """The memory of a step whose pairs are this memory's in the same rows, from its new
        pair parameters, solution and reports (repeat_kernels.step's new_f, new_z, new_rep)."""
        new = PairMemory.__new__(PairMemory)
        new.pair_i, new.pair_f, new.z, new.rep = self.pair_i, pair_f, z, rep
        new.keys, new.compliance_k = self.keys, self.compliance_k
        return new

    def __contains__(self, key) -> bool:
        return key in self.keys

    def __len__(self) -> int:
        return len(self.keys)

    def get(self, key):
        k = self.keys.get(key)
        return None if k is None else _Record(self, k)

    def __getitem__(self, key):
        return _Record(self, self.keys[key])

    def values(self):
        return [_Record(self, k) for k in self.keys.values()]

    def index(self, key) -> int:
        """The pair's row in the memory's tables, -1 if it holds none."""
        return self.keys.get(key, -1)


class _Record:
    """One pair of a PairMemory, read by name: a1, a2, normal, l1, l2, p_n, p_t, p_r, sigma,
    axis, dbar, deflection, deflection_prev, p_nr, k, distance (physical units)."""

    __slots__ = ("m", "k")

    def __init__(self, memory, k):
        self.m, self.k = memory, k

    def __getitem__(self, name):
        m, k = self.m, self.k
        pi, pf, z, r = m.pair_i[k], m.pair_f[k], m.z, m.rep[k]
        d, c0 = int(pi[rc.P_DIM]), int(pi[rc.P_C0])
        s_p = pf[rc.Q_SP]
        if name == "p_n":
            return s_p * z[c0 + pi[rc.P_PN]]
        if name == "a1":
            return r[rc.R_A1:rc.R_A1 + d].copy()
        if name == "a2":
            return r[rc.R_A2:rc.R_A2 + d].copy()
        if name == "normal":
            return r[rc.R_N:rc.R_N + d].copy()
        if name == "l1":
            return z[c0 + pi[rc.P_L1]:c0 + pi[rc.P_L1] + pi[rc.P_M1]].copy()
        if name == "l2":
            return z[c0 + pi[rc.P_L2]:c0 + pi[rc.P_L2] + pi[rc.P_M2]].copy()
        if name == "p_t":
            return s_p * z[c0 + pi[rc.P_PT]:c0 + pi[rc.P_PT] + d - 1] if pi[rc.P_FR] else np.zeros(d - 1)
        if name == "p_r":
            return s_p * pf[rc.Q_ER] * z[c0 + pi[rc.P_PR]] if pi[rc.P_TORS] else 0.0
        if name == "sigma":
            return float(z[c0 + pi[rc.P_SIG]]) if pi[rc.P_FR] else 0.0
        if name == "axis":
            return pf[rc.Q_AXIS:rc.Q_AXIS + 3].copy() if d == 3 else None
        if name == "dbar":
            return float(z[c0 + pi[rc.P_DBAR]]) if pi[rc.P_DBAR] >= 0 else 0.0
        if name == "deflection":
            return float(z[c0 + pi[rc.P_DN]]) if pi[rc.P_DN] >= 0 else 0.0
        if name == "deflection_prev":
            return float(pf[rc.Q_DPREV]) if pi[rc.P_COMP] != rc.RIGID else 0.0
        if name == "p_nr":
            return s_p * float(z[c0 + pi[rc.P_PNR]]) if pi[rc.P_PNR] >= 0 else 0.0
        if name == "k":
            return m.compliance_k[k]
        if name == "distance":
            # Euclidean distance of the separated pieces (their closest points solve eqs 15-18
            # exactly); gap is body 1's function at a2, an algebraic distance that may exceed it
            if r[rc.R_GAP] <= 0.0:
                return 0.0
            a = r[rc.R_A2:rc.R_A2 + d] - r[rc.R_A1:rc.R_A1 + d]
            return float(math.sqrt(a @ a))
        raise KeyError(name)


@kernel
def _point_velocity(body_i, body_f, body_jac, v0, b, a, out):
    """The velocity the contact shift moves a closest point a of body b with (module docstring)."""
    kind = body_i[b, rb.B_KIND]
    for q in range(3):
        out[q] = 0.0
    if kind == rb.FIXED:
        return
    col, k = body_i[b, rb.B_VCOL], body_i[b, rb.B_NV]
    if kind == rb.PLANAR:
        out[0], out[1] = v0[col], v0[col + 1]
        return
    jo = body_i[b, rb.B_JAC]
    w = np.zeros(3)
    rb.twist(body_jac, jo, k, v0, col, w, out)
    if body_i[b, rb.B_ART]:
        r0 = a[0] - body_f[b, rb.B_P0]
        r1 = a[1] - body_f[b, rb.B_P0 + 1]
        r2 = a[2] - body_f[b, rb.B_P0 + 2]
        out[0] += w[1] * r2 - w[2] * r1
        out[1] += w[2] * r0 - w[0] * r2
        out[2] += w[0] * r1 - w[1] * r0


@lean_kernel
def _tangents(n, e, t, o):
    """Gram-Schmidt tangents of rows/contact.py: t = (e - (e.n) n)/|...|, o = n x t."""
    en = e[0] * n[0] + e[1] * n[1] + e[2] * n[2]
    u0, u1, u2 = e[0] - en * n[0], e[1] - en * n[1], e[2] - en * n[2]
    nu = math.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    t[0], t[1], t[2] = u0 / nu, u1 / nu, u2 / nu
    o[0] = n[1] * t[2] - n[2] * t[1]
    o[1] = n[2] * t[0] - n[0] * t[2]
    o[2] = n[0] * t[1] - n[1] * t[0]


@lean_kernel
def _carry_multipliers(pi, oi, z_old, c0, o0, z0):
    """A pair's multipliers (and a cone-form pair's s) from its memory: the same pair, with the
    same functions on the same sides."""
    for i in range(pi[rc.P_M1]):
        z0[c0 + pi[rc.P_L1] + i] = z_old[o0 + oi[rc.P_L1] + i]
    for i in range(pi[rc.P_M2]):
        z0[c0 + pi[rc.P_L2] + i] = z_old[o0 + oi[rc.P_L2] + i]
    if pi[rc.P_S] >= 0:
        z0[c0 + pi[rc.P_S]] = z_old[o0 + oi[rc.P_S]]


@kernel
def warm_start(pair_i, pair_f, body_i, body_f, body_jac, sk_i, v0, v_free, mem, old_i, old_f, z_old, rep_old,
               cold, h, z0):
    """z0 of a new step from the memory (module docstring): for every pair k with mem[k] >= 0
    (its row in the memory's tables old_i, old_f, z_old, rep_old) and every skeleton. Entries of
    pairs without memory are left for the caller."""
    v1 = np.zeros(3)
    v2 = np.zeros(3)
    nv = np.zeros(3)
    touched = np.zeros(z0.shape[0], np.bool_)
    for k in range(pair_i.shape[0]):
        j = mem[k]
        if j < 0:
            continue
        pi, pf, oi, of = pair_i[k], pair_f[k], old_i[j], old_f[j]
        d = pi[rc.P_DIM]
        c0, o0 = pi[rc.P_C0], oi[rc.P_C0]
        b1, b2 = pi[rc.P_B1], pi[rc.P_B2]
        r = rep_old[j]
        a1o = r[rc.R_A1:rc.R_A1 + 3]
        a2o = r[rc.R_A2:rc.R_A2 + 3]
        _point_velocity(body_i, body_f, body_jac, v0, b1, a1o, v1)
        _point_velocity(body_i, body_f, body_jac, v0, b2, a2o, v2)
        g0, g1, g2 = a2o[0] - a1o[0], a2o[1] - a1o[1], a2o[2] - a1o[2]
        gn = math.sqrt(g0 * g0 + g1 * g1 + g2 * g2)
        has_n = gn > 1e-12
        if has_n:
            nv[0], nv[1], nv[2] = g0 / gn, g1 / gn, g2 / gn
        fixed1 = body_i[b1, rb.B_KIND] == rb.FIXED
        fixed2 = body_i[b2, rb.B_KIND] == rb.FIXED
        t1 = v1[0] * nv[0] + v1[1] * nv[1] + v1[2] * nv[2] if has_n else 0.0
        t2 = v2[0] * nv[0] + v2[1] * nv[1] + v2[2] * nv[2] if has_n else 0.0
        a1 = np.zeros(3)
        a2 = np.zeros(3)
        for q in range(3):
            s1 = v1[q] + ((v2[q] - t2 * nv[q]) if fixed1 else 0.0)
            s2 = v2[q] + ((v1[q] - t1 * nv[q]) if fixed2 else 0.0)
            a1[q] = a1o[q] + h * s1
            a2[q] = a2o[q] + h * s2
        # points into the new pair's unknowns: a = a0 + T s, s = T^T (a - a0) (T orthonormal)
        for which in range(2):
            col = pi[rc.P_A1] if which == 0 else pi[rc.P_A2]
            na = pi[rc.P_NA1] if which == 0 else pi[rc.P_NA2]
            T = pf[rc.Q_T1:rc.Q_T1 + 9] if which == 0 else pf[rc.Q_T2:rc.Q_T2 + 9]
            a0 = pf[rc.Q_A01:rc.Q_A01 + 3] if which == 0 else pf[rc.Q_A02:rc.Q_A02 + 3]
            a = a1 if which == 0 else a2
            for c in range(na):
                acc = 0.0
                for q in range(3):
                    acc += T[3 * q + c] * (a[q] - a0[q])
                z0[c0 + col + c] = acc
        _carry_multipliers(pi, oi, z_old, c0, o0, z0)
        sp_old, sp = of[rc.Q_SP], pf[rc.Q_SP]
        p_n = sp_old * z_old[o0 + oi[rc.P_PN]]
        pt0 = sp_old * z_old[o0 + oi[rc.P_PT]] if oi[rc.P_FR] else 0.0
        pt1 = sp_old * z_old[o0 + oi[rc.P_PT] + 1] if (oi[rc.P_FR] and d == 3) else 0.0
        p_r = sp_old * of[rc.Q_ER] * z_old[o0 + oi[rc.P_PR]] if oi[rc.P_TORS] else 0.0
        sigma = z_old[o0 + oi[rc.P_SIG]] if oi[rc.P_FR] else 0.0
        if p_n > 0.0:
            for b in (b1, b2):
                if body_i[b, rb.B_KIND] != rb.FIXED:
                    touched[body_i[b, rb.B_VCOL]] = True
        if d == 3:
            ax_old = of[rc.Q_AXIS:rc.Q_AXIS + 3]
            ax_new = pf[rc.Q_AXIS:rc.Q_AXIS + 3]
            known = ax_old[0] != 0.0 or ax_old[1] != 0.0 or ax_old[2] != 0.0
            if known and (ax_old[0] != ax_new[0] or ax_old[1] != ax_new[1] or ax_old[2] != ax_new[2]):
                # the friction impulse, expressed in the new tangents: new @ (old^T p_t)
                n = r[rc.R_N:rc.R_N + 3]
                to, oo, tn, on = np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3)
                _tangents(n, ax_old, to, oo)
                _tangents(n, ax_new, tn, on)
                f0 = pt0 * to[0] + pt1 * oo[0]
                f1 = pt0 * to[1] + pt1 * oo[1]
                f2 = pt0 * to[2] + pt1 * oo[2]
                pt0 = tn[0] * f0 + tn[1] * f1 + tn[2] * f2
                pt1 = on[0] * f0 + on[1] * f1 + on[2] * f2
        if cold:
            p_n, pt0, pt1, p_r, sigma = 0.0, 0.0, 0.0, 0.0, 0.0
        z0[c0 + pi[rc.P_PN]] = p_n / sp
        if pi[rc.P_FR]:
            z0[c0 + pi[rc.P_PT]] = pt0 / sp
            if d == 3:
                z0[c0 + pi[rc.P_PT] + 1] = pt1 / sp
            if pi[rc.P_TORS]:
                z0[c0 + pi[rc.P_PR]] = p_r / (sp * pf[rc.Q_ER])
            z0[c0 + pi[rc.P_SIG]] = sigma
        if pi[rc.P_DBAR] >= 0 and oi[rc.P_DBAR] >= 0:
            # the layer keeps deforming at its last rate; the spring follows (eq 49)
            dn_old = z_old[o0 + oi[rc.P_DN]]
            rate = dn_old - of[rc.Q_DPREV]
            dn = dn_old + rate
            z0[c0 + pi[rc.P_DBAR]] = z_old[o0 + oi[rc.P_DBAR]] + rate
            z0[c0 + pi[rc.P_DN]] = dn
            dprev = pf[rc.Q_DPREV]
            stiff = 0.5 * (dn + dprev) if pi[rc.P_COMP] == rc.MIDPOINT else dn
            spring = pf[rc.Q_H] * pf[rc.Q_K] * stiff + pf[rc.Q_C] * (dn - dprev)
            p_nr = 0.0
            if pi[rc.P_PNR] >= 0:
                p_nr_old = sp_old * z_old[o0 + oi[rc.P_PNR]] if oi[rc.P_PNR] >= 0 else 0.0
                p_nr = p_nr_old / sp
                z0[c0 + pi[rc.P_PNR]] = p_nr
            if sp_old * z_old[o0 + oi[rc.P_PN]] > 0.0 and spring > 0.0 and not cold:
                z0[c0 + pi[rc.P_PN]] = spring / sp + p_nr
    for s in range(sk_i.shape[0]):
        col, k = sk_i[s, rd.K_VCOL], sk_i[s, rd.K_NV]
        use_v0 = touched[col] and not cold
        for i in range(k):
            z0[col + i] = v0[col + i] if use_v0 else v_free[col + i]


@lean_kernel
def choose_axis(axis, normal, limit, out):
    """A pair's tangent axis (rows/contact.py, Gram-Schmidt on it): kept while |axis . n| <= limit,
    else the world axis least aligned with n (the first of the smallest |n_i|). Returns whether
    it changed."""
    dot = axis[0] * normal[0] + axis[1] * normal[1] + axis[2] * normal[2]
    known = axis[0] != 0.0 or axis[1] != 0.0 or axis[2] != 0.0
    if known and abs(dot) <= limit:
        for i in range(3):
            out[i] = axis[i]
        return False
    nn = math.sqrt(normal[0] ** 2 + normal[1] ** 2 + normal[2] ** 2)
    best = 0
    for i in range(1, 3):
        if abs(normal[i]) / nn < abs(normal[best]) / nn:
            best = i
    for i in range(3):
        out[i] = 1.0 if i == best else 0.0
    return True


@kernel
def carry_pairs(pair_i, pair_f, old_i, old_f, z_old, rep_old, touch, limit):
    """The pair parameters a step takes from the memory when every pair persists in the same
    rows (memory row k = pair k; ImplicitContactStepper._pair_spec for one pair): the tangent
    axis kept or re-chosen (choose_axis), the layer's deflection at l (delta_prev). Returns
    False if a pair's friction rows would change (they are built iff mu > 0 and the last
    p_n > touch s_p): the layout must then change."""
    out = np.zeros(3)
    for k in range(pair_i.shape[0]):
        pi, pf, oi, of = pair_i[k], pair_f[k], old_i[k], old_f[k]
        p_n = of[rc.Q_SP] * z_old[oi[rc.P_C0] + oi[rc.P_PN]]
        rows = pf[rc.Q_MU] > 0.0 and p_n > touch * pf[rc.Q_SP]
        if rows != (pi[rc.P_FR] != 0):
            return False
        if pi[rc.P_DIM] == 3:
            choose_axis(of[rc.Q_AXIS:rc.Q_AXIS + 3], rep_old[k, rc.R_N:rc.R_N + 3], limit, out)
            for i in range(3):
                pf[rc.Q_AXIS + i] = out[i]
        if pi[rc.P_COMP] != rc.RIGID:
            pf[rc.Q_DPREV] = z_old[oi[rc.P_C0] + oi[rc.P_DN]]
    return True


@lean_kernel
def known_gaps(pair_i, z, rep, eligible, tol, out):
    """Per pair of a memory: the known lower bound of its gap for the next far-pair test
    (ImplicitContactStepper._known_gap): the Euclidean distance of its separated closest points
    minus 10 tol if its normal impulse was exactly 0, else NaN (NaN too where not eligible)."""
    for k in range(pair_i.shape[0]):
        out[k] = np.nan
        if not eligible[k] or z[pair_i[k, rc.P_C0] + pair_i[k, rc.P_PN]] != 0.0:
            continue
        dist = 0.0
        if rep[k, rc.R_GAP] > 0.0:
            d = pair_i[k, rc.P_DIM]
            acc = 0.0
            for q in range(d):
                g = rep[k, rc.R_A2 + q] - rep[k, rc.R_A1 + q]
                acc += g * g
            dist = math.sqrt(acc)
        out[k] = dist - 10.0 * tol
