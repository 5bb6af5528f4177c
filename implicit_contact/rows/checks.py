r"""What a solved step's pairs are checked for before the step is accepted (compiled).

Per pair k of a step problem at its solution z (the rows' reports rep at z),
``solution_checks`` sets flags[k] to a sum of:

    OFF       friction rows but p_n <= touch (sigma undetermined; recovery.friction_rows)
    ON        friction (mu > 0) without rows but p_n > touch (recovery.friction_rows)
    THROUGH   a fixed half-space as body 2 with its free multiplier l2 <= 0: the far-side root
              of eqs (15)-(19) of a body wholly through it (recovery._passed_through)
    GAP       p_n not finite, or the gap below -tol (a penetrating solution)
    CONE      friction rows with |(p_t / e_t, p_o / e_o)| = f_t > (mu p_n + 1e3 solver_tol s_p)
              (1 + 1e-8) and (f_t / s_p)^2 - (mu p_n / s_p)^2 > CONE_SLACK solver_tol (a friction
              impulse outside its cone by more than the solver's tolerance explains: the cone row
              (22) is quadratic in the scaled impulses, so a converged solve may leave f_t up to
              sqrt(solver_tol) s_p outside a cone of p_n = 0; a quadruped's foot touching with
              p_n ~ 1e-9 N s and 1e-7 N s of friction balancing the other feet, example-robot-data
              quadruped at t = 0.337 s, was refused at every substep)

``touch`` is in scaled units (of s_p), tol [m]; impulses p = s_p z.
"""
from __future__ import annotations

import math

from .._jit import lean_kernel
from . import contact as rc

OFF, ON, THROUGH, GAP, CONE = 1, 2, 4, 8, 16
CONE_SLACK = 10.0    # (module docstring) the cone row's residual a converged solve may leave, in tols


@lean_kernel
def solution_checks(pair_i, pair_f, z, rep, tol, solver_tol, touch, flags):
    """flags[k] per pair (module docstring); returns their bitwise or."""
    every = 0
    for k in range(pair_i.shape[0]):
        pi, pf = pair_i[k], pair_f[k]
        c0 = pi[rc.P_C0]
        s_p = pf[rc.Q_SP]
        f = 0
        zn = z[c0 + pi[rc.P_PN]]
        pn = zn if math.isfinite(zn) else 0.0
        fr = pi[rc.P_FR] != 0
        if fr and pn <= touch:
            f |= OFF
        if pf[rc.Q_MU] > 0.0 and not fr and pn > touch:
            f |= ON
        if pi[rc.P_RED2] != 0 and pi[rc.P_M2] > 0 and z[c0 + pi[rc.P_L2]] <= 0.0:
            f |= THROUGH
        p_n = s_p * zn
        if not math.isfinite(p_n) or rep[k, rc.R_GAP] < -tol:
            f |= GAP
        if fr:
            pt = s_p * z[c0 + pi[rc.P_PT]] / pf[rc.Q_ET]
            po = s_p * z[c0 + pi[rc.P_PT] + 1] / pf[rc.Q_EO] if pi[rc.P_DIM] == 3 else 0.0
            ft = math.hypot(pt, po)
            bound = pf[rc.Q_MU] * p_n + 1e3 * solver_tol * s_p
            excess = (ft / s_p) ** 2 - (pf[rc.Q_MU] * p_n / s_p) ** 2
            if ft > bound * (1.0 + 1e-8) and excess > CONE_SLACK * solver_tol:
                f |= CONE
        flags[k] = f
        every |= f
    return every
