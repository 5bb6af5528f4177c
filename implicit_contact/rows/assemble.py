r"""F(z) and dF/dz of one step from the row kernels (formulation.StepProblem builds the tables).

Every block of rows is a *plan* with a local index: the z indices of its rows and of its
columns, alike (a skeleton: its velocities; a pair: its bodies' velocities and its own block; a
support: its body's velocities and its own block). Each plan's kernel writes a dense local
residual FL and Jacobian JL over its local index; the assembly adds them into F and J:

    F[idx] += FL,    J[idx, idx] += JL

dense: J is the (n, n) array; sparse: J's values in CSR order, through a fixed pattern, one slot
per entry of every local block (formulation.StepProblem builds it when the layout is made).
Plans are added in a fixed order (skeletons, pairs, supports), so F and J do not depend on the
storage. Then the rows are scaled: F *= scale, J[i, :] *= scale[i].
"""
from __future__ import annotations

import numpy as np

from .._jit import kernel, lean_kernel
from ..sparse_lu import sort_head
from .bodies import body_states
from .contact import pair_rows
from .dynamics import skeleton_rows
from .support import support_rows


@lean_kernel
def _scatter(idx, base, L, FL, JL, F, J, data, slots, slot_base, need_jac, sparse):
    for i in range(L):
        F[idx[base + i]] += FL[i]
    if not need_jac:
        return
    if sparse:
        for i in range(L):
            for j in range(L):
                v = JL[i, j]
                if v != 0.0:
                    data[slots[slot_base + i * L + j]] += v
    else:
        for i in range(L):
            gi = idx[base + i]
            for j in range(L):
                v = JL[i, j]
                if v != 0.0:
                    J[gi, idx[base + j]] += v


@lean_kernel
def assemble(body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f,
             loc_idx, loc_off, slots, slot_off, scale, data_scale, z, F, J, data, rep,
             st_R, st_p, st_w, st_vo, st_T, FL, JL, ws, need_jac, sparse):
    """F (and J or its sparse values) of the step at z; rep: the pairs' reports (contact.R_*);
    ws: the pair rows' workspace (contact.workspace_size of the largest pair)."""
    body_states(body_i, body_f, body_jac, z, st_R, st_p, st_w, st_vo, st_T, ws)   # (ws: scratch until the pairs)
    n = F.shape[0]
    for i in range(n):
        F[i] = 0.0
    if need_jac:
        if sparse:
            for i in range(data.shape[0]):
                data[i] = 0.0
        else:
            for i in range(n):
                for j in range(n):
                    J[i, j] = 0.0
    plan = 0
    for s in range(sk_i.shape[0]):
        L = loc_off[plan + 1] - loc_off[plan]
        skeleton_rows(sk_i[s], sk_M, v0, hforce, z, FL, JL, need_jac)
        _scatter(loc_idx, loc_off[plan], L, FL, JL, F, J, data, slots, slot_off[plan], need_jac, sparse)
        plan += 1
    for k in range(pair_i.shape[0]):
        L = loc_off[plan + 1] - loc_off[plan]
        pair_rows(pair_i[k], pair_f[k], fpar, st_R, st_p, st_w, st_vo, st_T, z, FL, JL, rep[k], need_jac, ws)
        _scatter(loc_idx, loc_off[plan], L, FL, JL, F, J, data, slots, slot_off[plan], need_jac, sparse)
        plan += 1
    for s in range(sup_i.shape[0]):
        L = loc_off[plan + 1] - loc_off[plan]
        support_rows(sup_i[s], sup_f[s], z, FL, JL, need_jac)
        _scatter(loc_idx, loc_off[plan], L, FL, JL, F, J, data, slots, slot_off[plan], need_jac, sparse)
        plan += 1
    for i in range(n):
        F[i] *= scale[i]
    if need_jac:
        if sparse:
            for i in range(data.shape[0]):
                data[i] *= data_scale[i]
        else:
            for i in range(n):
                si = scale[i]
                for j in range(n):
                    J[i, j] *= si


@kernel
def sparse_pattern(n, loc_idx, loc_off, slot_off, slots, indptr, indices):
    """The CSR pattern of the union of every plan's local block (rows and columns: its local
    index) over n unknowns: indptr (n + 1) and indices (columns sorted within each row; room for
    slot_off[-1] entries), and slots (slot_off[-1]): the data position of local entry (i, j) of
    plan p at slots[slot_off[p] + i L + j], L the plan's size. Returns the number of entries.

    Row r's columns are those of the plans whose local index holds r, so the pattern is built
    row by row from the incidence of rows in plans (a plan's index has no repeats)."""
    nplan = loc_off.shape[0] - 1
    m_loc = loc_off[nplan]
    plan_of = np.empty(m_loc, np.int64)
    start = np.zeros(n + 1, np.int64)
    for p in range(nplan):
        for a in range(loc_off[p], loc_off[p + 1]):
            plan_of[a] = p
            start[loc_idx[a] + 1] += 1
    for r in range(n):
        start[r + 1] += start[r]
    fill = start[:n].copy()
    incidence = np.empty(m_loc, np.int64)      # per row, the positions in loc_idx that hold it
    for a in range(m_loc):
        r = loc_idx[a]
        incidence[fill[r]] = a
        fill[r] += 1
    mark = np.full(n, -1, np.int64)
    position = np.zeros(n, np.int64)
    cols = np.empty(n, np.int64)
    nnz = 0
    indptr[0] = 0
    for r in range(n):
        m = 0
        for e in range(start[r], start[r + 1]):
            p = plan_of[incidence[e]]
            for b in range(loc_off[p], loc_off[p + 1]):
                c = loc_idx[b]
                if mark[c] != r:
                    mark[c] = r
                    cols[m] = c
                    m += 1
        sort_head(cols, m)                  # (a row has tens of columns)
        for t in range(m):
            indices[nnz + t] = cols[t]
            position[cols[t]] = nnz + t
        for e in range(start[r], start[r + 1]):
            a = incidence[e]
            p = plan_of[a]
            L = loc_off[p + 1] - loc_off[p]
            base = slot_off[p] + (a - loc_off[p]) * L
            for j in range(L):
                slots[base + j] = position[loc_idx[loc_off[p] + j]]
        nnz += m
        indptr[r + 1] = nnz
    return nnz
