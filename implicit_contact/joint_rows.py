r"""A step's joint rows (rows/dynamics.py) from what DART's joints carry: Coulomb joint friction and
enforced position limits, in the skeleton's own coordinates.

Both are rows F_r = g_r . v+ + c_r complementary to a bounded unknown lambda_r, whose generalized
impulse u_r lambda_r along g_r enters the skeleton's Newton-Euler rows:

    Coulomb friction of dof j, bound f:   g = e_j, c = 0,                  u = h f,   lambda in [-1, 1]
    lower limit lo of dof j:              g = e_j, c = (q_j - lo) / h,     u = h m_jj g,  lambda >= 0
    upper limit hi of dof j:              g = -e_j, c = (hi - q_j) / h,    u = h m_jj g,  lambda >= 0
    mimic f = m l + o (dofs f, l):         g = e_f - m e_l,                 u = h m_ff g,  lambda free
                                          c = (q_f - m q_l - o) / h

A limit row is geometrically implicit in joint space, as [GI]'s contact rows are in space: it
holds the position at l+1, q_j + h v_j+ >= lo (the dof's integratePositions is q + h v for every
joint type whose limits are accepted, dart_adapter._limits), with no stabilisation constant and
no bounce (inelastic, like the contacts); a mimic row holds the follower on its leader at l+1,
q_f + h v_f+ = m (q_l + h v_l+) + o, a bilateral constraint whose impulse acts on both dofs. u only scales the unknown (m_jj: the dof's diagonal of M
at l, g: gravity's magnitude, at least 1), as the pairs' impulse unit does.

Only the rows a step needs are built: friction and mimic rows always (a joint may stick at any
time; a mimic relation always holds), a
limit's row when the dof could reach it within the step (``near``), and a limit the solved step
crosses although its row was left out is added and the step solved again (``crossed``), as far
contact pairs are.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .layout import JointRows

FRICTION, LOWER, UPPER, MIMIC = "friction", "lower", "upper", "mimic"


@dataclass
class JointModel:
    """What the stepper knows of one skeleton's joints, read when it is built."""
    friction: np.ndarray | None    # per dof Coulomb friction force, or None
    limited: np.ndarray            # dofs with an enforced limit
    lower: np.ndarray              # their limits (-inf / inf where a side is open)
    upper: np.ndarray
    mimic: tuple = ()              # (follower dof, leader dof, multiplier, offset)

    @property
    def empty(self) -> bool:
        return self.friction is None and len(self.limited) == 0 and not self.mimic


def near(model: JointModel, q, v, v_free, h, slack) -> set:
    """The limit rows a step from (q, v) may need: a side within the distance the dof moves in
    two steps at the larger of |v| and |v_free| (plus slack) of its limit."""
    keys = set()
    for idx, j in enumerate(model.limited):
        reach = 2.0 * h * max(abs(v[j]), abs(v_free[j])) + slack
        if q[j] - model.lower[idx] <= reach:
            keys.add((LOWER, int(j)))
        if model.upper[idx] - q[j] <= reach:
            keys.add((UPPER, int(j)))
    return keys


def crossed(model: JointModel, q, v_next, h, tol, present) -> set:
    """Limit rows left out of a solved step whose limit the step crosses by more than tol."""
    keys = set()
    for idx, j in enumerate(model.limited):
        q_next = q[j] + h * v_next[j]
        if (LOWER, int(j)) not in present and q_next < model.lower[idx] - tol:
            keys.add((LOWER, int(j)))
        if (UPPER, int(j)) not in present and q_next > model.upper[idx] + tol:
            keys.add((UPPER, int(j)))
    return keys


def build(model: JointModel, limit_keys, q, M, h, gravity) -> JointRows | None:
    """The joint rows of one skeleton for a step of h at (q, M): friction rows for its dofs with
    friction, mimic rows, then the given limit rows, in a fixed order (their keys name them)."""
    k = len(q)
    keys = []
    if model.friction is not None:
        keys += [(FRICTION, int(j)) for j in np.flatnonzero(model.friction)]
    keys += [(MIMIC, int(f)) for f, _, _, _ in model.mimic]
    keys += sorted(limit_keys, key=lambda key: (key[1], key[0]))
    if not keys:
        return None
    n = len(keys)
    G, c, unit = np.zeros((n, k)), np.zeros(n), np.zeros(n)
    lo, hi = np.zeros(n), np.full(n, np.inf)
    where = {int(j): idx for idx, j in enumerate(model.limited)}
    mimic = {int(f): (int(ld), m, o) for f, ld, m, o in model.mimic}
    for r, (kind, j) in enumerate(keys):
        if kind == FRICTION:
            G[r, j], unit[r], lo[r], hi[r] = 1.0, h * model.friction[j], -1.0, 1.0
            continue
        unit[r] = h * max(M[j, j], 1e-300) * max(gravity, 1.0)
        if kind == MIMIC:
            ld, m, o = mimic[j]
            G[r, j], G[r, ld] = 1.0, -m
            c[r], lo[r] = (q[j] - m * q[ld] - o) / h, -np.inf
            continue
        if kind == LOWER:
            G[r, j], c[r] = 1.0, (q[j] - model.lower[where[j]]) / h
        else:
            G[r, j], c[r] = -1.0, (model.upper[where[j]] - q[j]) / h
    return JointRows(G, c, unit, lo, hi, tuple(keys))


def impulses(rows: JointRows, lam, kinds) -> np.ndarray:
    """Per dof, the generalized impulse sum_r u_r lambda_r g_r of the rows of the given kinds."""
    out = np.zeros(rows.G.shape[1])
    for r, (kind, _) in enumerate(rows.keys):
        if kind in kinds:
            out += rows.unit[r] * lam[r] * rows.G[r]
    return out
