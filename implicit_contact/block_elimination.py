r"""The sparse Newton step with local blocks eliminated first (a Schur complement), compiled.

A step problem's unknowns split into the rest r (velocities, impulses, joint and support rows) and,
per pair, its closest-point block b (a1, a2, l1, l2 and s: [GI] eqs 15-18, 28n-32n). A pair's
closest-point rows involve its own block and its bodies' velocities only, so in the Newton matrix
H the blocks are coupled to each other only through r:

    [ H_rr  H_rB ] [d_r]   [f_r]                                   H_BB = diag(D_1, D_2, ...)
    [ H_Br  H_BB ] [d_B] = [f_B],

and with X_b = D_b^-1 H_br and y_b = D_b^-1 f_b (small dense solves, one per pair)

    S d_r = f_r - sum_b H_rb y_b,    S = H_rr - sum_b H_rb X_b,      d_b = y_b - X_b d_r.

S is the reduced matrix the sparse LU factorises. Measured on 60 Newton matrices of 27
superquadrics in a box (n median 727, 8782 nonzeros): r has 308 unknowns, S 3587 nonzeros, its
factors 4389 entries against 13870, and the compiled LU (sparse_lu.py) 0.14 ms against 0.49 ms;
the two directions agreed to 1e-15 at the median (2e-8 at worst; the local blocks' condition
numbers were up to 1.7e4).

This module knows no physics: the caller (ncp.solve_mcp's ``blocks``) names the groups of unknowns
to eliminate. Groups coupled to each other in H's pattern disable the elimination (``ok``), and a
local block that is exactly singular at an iterate makes ``solve`` return None (ncp then takes the
whole matrix's LU).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

from . import sparse_lu
from ._jit import kernel, lean_kernel

RR, BB, BR, RB = 0, 1, 2, 3       # a stored entry of H by its row's and its column's part


@kernel
def _symbolic(indptr, indices, bptr, bidx, blk, rpos, cat, dst, Rptr, Ridx, Cptr, Cidx):
    """The parts of H's pattern (module docstring): blk (block of each unknown, -1 for r), rpos
    (position in r), per block its r-rows with entries in its columns R_b (Rptr, Ridx) and its
    r-columns C_b (Cptr, Cidx), and per stored entry p its kind cat[p] and, for BB, BR and RB
    entries, its place in the block's dense D (m x m), H_br (m x |C_b|) or H_rb (|R_b| x m)
    (dst[p], within the block). Returns (nr, False) when two blocks are coupled, else (nr, True)."""
    n = indptr.shape[0] - 1
    nb = bptr.shape[0] - 1
    local = np.full(n, -1, np.int64)
    for i in range(n):
        blk[i] = -1
    for b in range(nb):
        for k in range(bptr[b], bptr[b + 1]):
            blk[bidx[k]] = b
            local[bidx[k]] = k - bptr[b]
    nr = 0
    for i in range(n):
        rpos[i] = -1
        if blk[i] < 0:
            rpos[i] = nr
            nr += 1
    # C_b and the blocks' own entries, block by block
    colpos = np.full(n, -1, np.int64)
    Cptr[0] = 0
    for b in range(nb):
        m = bptr[b + 1] - bptr[b]
        start = Cptr[b]
        count = 0
        for k in range(bptr[b], bptr[b + 1]):
            i = bidx[k]
            for p in range(indptr[i], indptr[i + 1]):
                j = indices[p]
                if blk[j] >= 0 and blk[j] != b:
                    return nr, False
                if blk[j] < 0 and colpos[j] < start:          # (colpos from an earlier block: stale)
                    colpos[j] = start + count
                    Cidx[start + count] = j
                    count += 1
        Cptr[b + 1] = start + count
        for k in range(bptr[b], bptr[b + 1]):
            i = bidx[k]
            for p in range(indptr[i], indptr[i + 1]):
                j = indices[p]
                if blk[j] == b:
                    cat[p], dst[p] = BB, local[i] * m + local[j]
                else:
                    cat[p], dst[p] = BR, local[i] * count + (colpos[j] - start)
    # R_b: count, then fill in row order
    rcount = np.zeros(nb, np.int64)
    rmark = np.full(nb, -1, np.int64)
    for i in range(n):
        if blk[i] >= 0:
            continue
        for p in range(indptr[i], indptr[i + 1]):
            b = blk[indices[p]]
            if b >= 0 and rmark[b] != i:
                rmark[b] = i
                rcount[b] += 1
    Rptr[0] = 0
    for b in range(nb):
        Rptr[b + 1] = Rptr[b] + rcount[b]
    fill = np.zeros(nb, np.int64)
    for b in range(nb):
        rmark[b] = -1
    for i in range(n):
        if blk[i] >= 0:
            continue
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            b = blk[j]
            if b < 0:
                cat[p] = RR
                continue
            if rmark[b] != i:
                rmark[b] = i
                Ridx[Rptr[b] + fill[b]] = i
                fill[b] += 1
            cat[p] = RB
            dst[p] = (fill[b] - 1) * (bptr[b + 1] - bptr[b]) + local[j]
    return nr, True


@kernel
def _reduced_pattern(indptr, indices, blk, rpos, cat, dst, bptr, Rptr, Ridx, Cptr, Cidx, nr, Sp, Sj, upd_ptr, upd):
    """S's CSR pattern over r (Sp, Sj: columns sorted in each row) and the places of its entries:
    an RR entry p of H goes to S's data at dst[p] (overwritten here), the update of S(R_b[i],
    C_b[c]) at upd[upd_ptr[b] + i |C_b| + c]. Returns S's number of entries."""
    n = indptr.shape[0] - 1
    nb = Rptr.shape[0] - 1
    # the blocks each r-row meets (through its RB entries), in the row's order
    where = np.full(nr, -1, np.int64)        # per r-column: its position in the row being built
    cols = np.empty(nr, np.int64)
    rindex = np.zeros(nb, np.int64)          # per block: the next row of R_b
    bmark = np.full(nb, -1, np.int64)
    nnz = 0
    Sp[0] = 0
    for i in range(n):
        if blk[i] >= 0:
            continue
        ri = rpos[i]
        m = 0
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            if cat[p] == RR:
                c = rpos[j]
                if where[c] != ri:
                    where[c] = ri
                    cols[m] = c
                    m += 1
            else:
                b = blk[j]
                if bmark[b] != i:
                    bmark[b] = i
                    for q in range(Cptr[b], Cptr[b + 1]):
                        c = rpos[Cidx[q]]
                        if where[c] != ri:
                            where[c] = ri
                            cols[m] = c
                            m += 1
        sparse_lu.sort_head(cols, m)
        for t in range(m):
            Sj[nnz + t] = cols[t]
            where[cols[t]] = nnz + t          # (now: the data position of column cols[t] in this row)
        # RR entries and this row's updates
        for p in range(indptr[i], indptr[i + 1]):
            j = indices[p]
            if cat[p] == RR:
                dst[p] = where[rpos[j]]
        for p in range(indptr[i], indptr[i + 1]):
            b = blk[indices[p]]
            if b >= 0 and bmark[b] == i:
                bmark[b] = -2 - i             # (each block once a row)
                row = rindex[b]
                rindex[b] += 1
                nc = Cptr[b + 1] - Cptr[b]
                for q in range(Cptr[b], Cptr[b + 1]):
                    upd[upd_ptr[b] + row * nc + (q - Cptr[b])] = where[rpos[Cidx[q]]]
        for t in range(m):
            where[cols[t]] = -1 - nr          # (reset: no r-row index is negative)
        nnz += m
        Sp[ri + 1] = nnz
    return nnz


@lean_kernel
def _numeric(indptr, indices, data, blk, cat, dst, bptr, bidx, Rptr, Cptr, d_ptr, x_ptr, rb_ptr, upd_ptr, upd, D, Dn,
             X, RB, piv, loc, mb, coupled, Sdata, col, acc):
    """From H's data: S's data (Sdata), each block's LU factors of D_nn (module docstring: its
    coupled unknowns) in Dn (m_b x m_b at d_ptr[b], pivots piv), D itself (D_nt and the diagonal of
    the decoupled unknowns, for _reduce_rhs), X_n = D_nn^-1 H_nr (X, m_b x |C_b| each) and H_rb
    (RB, |R_b| x m each); loc: per block its coupled local unknowns, then its decoupled ones; mb:
    the count of coupled ones. False if a local block is exactly singular. coupled, col, acc:
    scratch of n, the largest block's size and |C_b|."""
    n = indptr.shape[0] - 1
    nb = bptr.shape[0] - 1
    Sdata[:] = 0.0
    D[:] = 0.0
    X[:] = 0.0
    RB[:] = 0.0
    for i in range(n):
        coupled[i] = 0
        for p in range(indptr[i], indptr[i + 1]):
            if data[p] == 0.0:
                continue
            c = cat[p]
            if c == RR:
                Sdata[dst[p]] += data[p]
            elif c == BB:
                D[d_ptr[blk[i]] + dst[p]] += data[p]
                if indices[p] != i:
                    coupled[i] = 1
            elif c == BR:
                X[x_ptr[blk[i]] + dst[p]] += data[p]
                coupled[i] = 1
            else:
                RB[rb_ptr[blk[indices[p]]] + dst[p]] += data[p]
    for b in range(nb):
        m = bptr[b + 1] - bptr[b]
        nc = Cptr[b + 1] - Cptr[b]
        nrow = Rptr[b + 1] - Rptr[b]
        Db = D[d_ptr[b]:d_ptr[b] + m * m].reshape(m, m)
        # a row of H with its diagonal entry alone (an inactive multiplier's Fischer-Burmeister
        # row: da e_i) decouples its unknown: d_i = f_i / H_ii, and the rest of the block is solved
        # without it (a mesh hull's pair: 59 of its 70 unknowns at rest, example-robot-data's talos)
        lb = loc[bptr[b]:bptr[b + 1]]
        k = 0
        for a in range(m):
            if coupled[bidx[bptr[b] + a]]:
                lb[k] = a
                k += 1
        mn = k
        for a in range(m):
            if not coupled[bidx[bptr[b] + a]]:
                if Db[a, a] == 0.0:
                    return False
                lb[k] = a
                k += 1
        mb[b] = mn
        Dc = Dn[d_ptr[b]:d_ptr[b] + mn * mn].reshape(mn, mn)
        for r in range(mn):
            for c in range(mn):
                Dc[r, c] = Db[lb[r], lb[c]]
        pb = piv[bptr[b]:bptr[b] + mn]
        if not sparse_lu.dense_lu(Dc, pb):
            return False
        Xf = X[x_ptr[b]:x_ptr[b] + m * nc].reshape(m, nc)
        if mn < m:                     # (the decoupled rows of H_br are zero: X_n in the first rows)
            for r in range(mn):
                for c in range(nc):
                    Xf[r, c] = Xf[lb[r], c]
        Xb = X[x_ptr[b]:x_ptr[b] + mn * nc].reshape(mn, nc)
        for c in range(nc):
            nonzero = False
            for r in range(mn):
                col[r] = Xb[r, c]
                nonzero = nonzero or col[r] != 0.0
            if not nonzero:            # (a column of H_br that is zero at this iterate)
                continue
            sparse_lu.dense_lu_solve(Dc, pb, col[:mn])
            for r in range(mn):
                Xb[r, c] = col[r]
        RBb = RB[rb_ptr[b]:rb_ptr[b] + nrow * m].reshape(nrow, m)
        for r in range(nrow):
            for c in range(nc):
                acc[c] = 0.0
            nonzero = False
            for q in range(mn):
                a = RBb[r, lb[q]]
                if a != 0.0:
                    nonzero = True
                    for c in range(nc):
                        acc[c] += a * Xb[q, c]
            if nonzero:
                at = upd_ptr[b] + r * nc
                for c in range(nc):
                    Sdata[upd[at + c]] -= acc[c]
    return True


@lean_kernel
def _reduce_rhs(f, blk, rpos, bptr, bidx, Rptr, Ridx, d_ptr, rb_ptr, D, Dn, RB, piv, loc, mb, y, f_r, col):
    """y_b = D_b^-1 f_b for every block (y over all unknowns, its r entries unused: the
    decoupled unknowns first, f_i / H_ii, then D_nn^-1 (f_n - D_nt y_t)) and
    f_r = f_r - sum_b H_rb y_b. col: scratch of the largest block's size."""
    n = f.shape[0]
    nb = bptr.shape[0] - 1
    for i in range(n):
        if blk[i] < 0:
            f_r[rpos[i]] = f[i]
    for b in range(nb):
        m = bptr[b + 1] - bptr[b]
        mn = mb[b]
        lb = loc[bptr[b]:bptr[b + 1]]
        Db = D[d_ptr[b]:d_ptr[b] + m * m].reshape(m, m)
        for q in range(mn, m):
            a = lb[q]
            col[q] = f[bidx[bptr[b] + a]] / Db[a, a]
        for r in range(mn):
            acc = f[bidx[bptr[b] + lb[r]]]
            for q in range(mn, m):
                acc -= Db[lb[r], lb[q]] * col[q]
            col[r] = acc
        sparse_lu.dense_lu_solve(Dn[d_ptr[b]:d_ptr[b] + mn * mn].reshape(mn, mn), piv[bptr[b]:bptr[b] + mn], col[:mn])
        for q in range(m):
            y[bidx[bptr[b] + lb[q]]] = col[q]
        nrow = Rptr[b + 1] - Rptr[b]
        for r in range(nrow):
            acc = 0.0
            for q in range(m):
                acc += RB[rb_ptr[b] + r * m + lb[q]] * col[q]
            f_r[rpos[Ridx[Rptr[b] + r]]] -= acc


@lean_kernel
def _back(d_r, y, blk, rpos, bptr, bidx, Cptr, Cidx, x_ptr, X, loc, mb, d):
    """d: d_r on r, and d_b = y_b - X_b d_r[C_b] on the blocks (X_b's rows: the coupled unknowns;
    the decoupled ones are y_b's)."""
    n = d.shape[0]
    nb = bptr.shape[0] - 1
    for i in range(n):
        if blk[i] < 0:
            d[i] = d_r[rpos[i]]
    for b in range(nb):
        m = bptr[b + 1] - bptr[b]
        mn = mb[b]
        nc = Cptr[b + 1] - Cptr[b]
        for q in range(m):
            i = bidx[bptr[b] + loc[bptr[b] + q]]
            acc = y[i]
            if q < mn:
                for c in range(nc):
                    acc -= X[x_ptr[b] + q * nc + c] * d_r[rpos[Cidx[Cptr[b] + c]]]
            d[i] = acc


class Structure:
    """What Elimination needs of one pattern of H (CSR indptr, indices, stored zeros allowed) and
    one grouping of unknowns (bptr, bidx: group g is bidx[bptr[g]:bptr[g + 1]]): the parts, each
    stored entry's destination and S's pattern (_symbolic, _reduced_pattern); ``ok`` is False if
    two groups are coupled in the pattern (then nothing else is made). Made once per pattern and
    grouping (structure()), shared by the solves of that problem."""

    def __init__(self, indptr, indices, bptr, bidx):
        n = len(indptr) - 1
        self.n = n
        self.source = (bptr, bidx)      # (the caller's arrays, for matches: identity)
        self.indptr = np.ascontiguousarray(indptr, dtype=np.int64)
        self.indices = np.ascontiguousarray(indices, dtype=np.int64)
        self.bptr = np.ascontiguousarray(bptr, dtype=np.int64)
        self.bidx = np.ascontiguousarray(bidx, dtype=np.int64)
        nnz, nb = len(self.indices), len(self.bptr) - 1
        self.blk, self.rpos = np.empty(n, np.int64), np.empty(n, np.int64)
        self.cat, self.dst = np.zeros(nnz, np.int64), np.zeros(nnz, np.int64)
        self.Rptr, self.Ridx = np.zeros(nb + 1, np.int64), np.zeros(max(nnz, 1), np.int64)
        self.Cptr, self.Cidx = np.zeros(nb + 1, np.int64), np.zeros(max(nnz, 1), np.int64)
        nr, self.ok = _symbolic(self.indptr, self.indices, self.bptr, self.bidx, self.blk, self.rpos, self.cat,
                                self.dst, self.Rptr, self.Ridx, self.Cptr, self.Cidx)
        self.nr = int(nr)
        if not self.ok:
            return
        m = np.diff(self.bptr)
        nrow, ncol = np.diff(self.Rptr), np.diff(self.Cptr)
        self.d_ptr = np.r_[0, np.cumsum(m * m)].astype(np.int64)
        self.x_ptr = np.r_[0, np.cumsum(m * ncol)].astype(np.int64)
        self.rb_ptr = np.r_[0, np.cumsum(nrow * m)].astype(np.int64)
        self.upd_ptr = np.r_[0, np.cumsum(nrow * ncol)].astype(np.int64)
        self.upd = np.zeros(max(int(self.upd_ptr[-1]), 1), np.int64)
        cap = nnz + int(self.upd_ptr[-1])
        self.Sp, Sj = np.zeros(self.nr + 1, np.int64), np.zeros(max(cap, 1), np.int64)
        s_nnz = _reduced_pattern(self.indptr, self.indices, self.blk, self.rpos, self.cat, self.dst, self.bptr,
                                 self.Rptr, self.Ridx, self.Cptr, self.Cidx, self.nr, self.Sp, Sj, self.upd_ptr,
                                 self.upd)
        self.Sj = Sj[:s_nnz].copy()
        self.big_m, self.big_c = max(1, int(m.max(initial=0))), max(1, int(ncol.max(initial=0)))
        self._order = None

    def column_order(self):
        """The reverse Cuthill-McKee order of S's pattern (stored entries) made symmetric, made
        once: it depends on the problem's structure alone. S couples the bodies that touch, a
        graph with few edges a node, and on it RCM orders as well as COLAMD for less: measured on
        the S of 27 superquadrics in a box (~300 unknowns, median of 12), 4404 entries in the
        factors and 0.13 ms an LU against 4554 and 0.14 ms with COLAMD (SuperLU's, of the same
        pattern), 0.07 ms to order against 0.76 ms."""
        if self._order is None:
            A = sp.csr_matrix((np.ones(len(self.Sj)), self.Sj, self.Sp), shape=(self.nr, self.nr))
            self._order = np.asarray(reverse_cuthill_mckee((A + A.T).tocsr(), symmetric_mode=True), np.int64)
        return self._order

    def matches(self, indptr, indices, bptr, bidx) -> bool:
        return (bptr is self.source[0] and bidx is self.source[1] and len(indices) == len(self.indices)
                and np.array_equal(indptr, self.indptr) and np.array_equal(indices, self.indices))


_STRUCTURES = []          # the last few Structures made (structure())
_KEPT_STRUCTURES = 8


def structure(indptr, indices, bptr, bidx) -> Structure:
    """The Structure of a pattern and grouping, made once: a step's solves (its re-solves, the
    polish, the recoveries) share its problem's pattern and groups (the same bptr and bidx
    objects, layout.closest_point_blocks)."""
    for st in _STRUCTURES:
        if st.matches(indptr, indices, bptr, bidx):
            return st
    st = Structure(indptr, indices, bptr, bidx)
    _STRUCTURES.insert(0, st)
    del _STRUCTURES[_KEPT_STRUCTURES:]
    return st


class Elimination:
    """The Newton solves of one solve_mcp on a Structure: ``solve(data, rhs)`` gives H d = rhs by
    S's LU (sparse_lu.py) and the local solves, or None if a local block or S is singular. S's
    column order is its pattern's (Structure.column_order), kept while the factors stay within
    refill times the entries that order first gave, then COLAMD's of the current nonzeros for the
    rest of the solve, as ncp does for H (sparse_lu.KeptOrder; a solve's round-off depends on its
    problem and start alone)."""

    def __init__(self, structure: Structure, refill):
        st = self.structure = structure
        self.Sdata = np.zeros(len(st.Sj))
        self.D, self.X = np.zeros(max(int(st.d_ptr[-1]), 1)), np.zeros(max(int(st.x_ptr[-1]), 1))
        self.Dn = np.zeros_like(self.D)
        self.RB, self.piv = np.zeros(max(int(st.rb_ptr[-1]), 1)), np.zeros(st.n, np.int64)
        self.loc, self.mb = np.zeros(max(st.n, 1), np.int64), np.zeros(len(st.bptr) - 1, np.int64)
        self.coupled = np.zeros(st.n, np.int64)
        self.y, self.f_r = np.zeros(st.n), np.zeros(st.nr)
        self.col, self.acc = np.zeros(st.big_m), np.zeros(st.big_c)     # _numeric's and _reduce_rhs' scratch
        self.factors = sparse_lu.KeptOrder(st.nr, refill, st.column_order)

    def solve(self, data, rhs):
        st = self.structure
        if not _numeric(st.indptr, st.indices, data, st.blk, st.cat, st.dst, st.bptr, st.bidx, st.Rptr, st.Cptr,
                        st.d_ptr, st.x_ptr, st.rb_ptr, st.upd_ptr, st.upd, self.D, self.Dn, self.X, self.RB, self.piv,
                        self.loc, self.mb, self.coupled, self.Sdata, self.col, self.acc):
            return None
        # S's CSR arrays read as CSC are S^T: factorised as they are, S d = f is the transposed solve
        lu = self.factors.factor(st.Sp, st.Sj, self.Sdata, len(self.Sdata))
        if not lu.ok:
            return None
        _reduce_rhs(np.ascontiguousarray(rhs, dtype=float), st.blk, st.rpos, st.bptr, st.bidx, st.Rptr, st.Ridx,
                    st.d_ptr, st.rb_ptr, self.D, self.Dn, self.RB, self.piv, self.loc, self.mb, self.y, self.f_r,
                    self.col)
        d_r = lu.solve(self.f_r, "T")
        d = np.empty(st.n)
        _back(d_r, self.y, st.blk, st.rpos, st.bptr, st.bidx, st.Cptr, st.Cidx, st.x_ptr, self.X, self.loc, self.mb, d)
        return d
