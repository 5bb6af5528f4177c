r"""Sparse LU factorisation with partial pivoting, compiled: the Newton step's linear solve.

A step problem's Newton matrix H = diag(da) + diag(db) J (ncp.solve_mcp) has a few nonzeros a
row and hardly fills in: on 27 superquadrics in a box (n ~ 700, 8500 nonzeros) its factors hold
~14,000. SuperLU (scipy.sparse.linalg.splu) takes ~0.7 ms a factorisation there, almost all of it
set-up around ~50,000 flops. This module is the left-looking LU of Gilbert & Peierls (SIAM J.
Sci. Stat. Comput. 9, 1988), the algorithm of CSparse's cs_lu (Davis, "Direct Methods for Sparse
Linear Systems", SIAM 2006, ch. 6), written from that description:

    P A Q = L U,    L unit lower triangular, U upper triangular, P and Q permutations.

Column k of L and U is x = L \ A(:, q[k]), a sparse triangular solve whose nonzero pattern is the
set of rows reachable from A(:, q[k])'s in the graph of L's columns found so far (a depth-first
search), so the work is proportional to the flops. The pivot of column k is the largest |x_i|
among the rows not yet pivotal (partial pivoting); the row q[k] itself is preferred if
|x_q[k]| >= PIVOT_TOL times that largest (it keeps the diagonal where the column order put it).

The column order Q (fill-reducing) is not computed here: the caller passes one (ncp takes
SuperLU's COLAMD order of the first matrix of a pattern and reuses it while the pattern holds).

Entries stored as exact zeros are skipped: a step problem's fixed pattern stores every entry a
row could have, and most are zero at any one iterate.

A matrix is reported singular (factor returns -1) when a column has no nonzero candidate pivot;
the caller then treats the Newton step as singular, as it did SuperLU's "exactly singular".
Numerically singular matrices factor with tiny pivots; ncp checks every solve's residual.
"""
from __future__ import annotations

import math

import numpy as np

from ._jit import lean_kernel

PIVOT_TOL = 1.0     # partial pivoting as SuperLU's default (DiagPivotThresh = 1)


@lean_kernel
def sort_head(a, m):
    """a[:m] sorted in place (insertion sort: the column lists of one sparse row, tens long)."""
    for t in range(1, m):
        c = a[t]
        u = t - 1
        while u >= 0 and a[u] > c:
            a[u + 1] = a[u]
            u -= 1
        a[u + 1] = c


@lean_kernel
def dense_lu(A, piv):
    """LU with partial pivoting of a small dense A in place (the multipliers below the diagonal,
    the row swaps in piv); False if A is exactly singular (a column without a nonzero pivot)."""
    m = A.shape[0]
    for k in range(m):
        p = k
        big = abs(A[k, k])
        for i in range(k + 1, m):
            if abs(A[i, k]) > big:
                big, p = abs(A[i, k]), i
        if big == 0.0:
            return False
        piv[k] = p
        if p != k:
            for j in range(m):
                A[k, j], A[p, j] = A[p, j], A[k, j]
        for i in range(k + 1, m):
            f = A[i, k] / A[k, k]
            A[i, k] = f
            if f != 0.0:
                for j in range(k + 1, m):
                    A[i, j] -= f * A[k, j]
    return True


@lean_kernel
def dense_lu_solve(A, piv, x):
    """x = A^-1 x in place, A and piv from dense_lu."""
    m = A.shape[0]
    for k in range(m):
        p = piv[k]
        if p != k:
            x[k], x[p] = x[p], x[k]
    for i in range(m):
        acc = x[i]
        for j in range(i):
            acc -= A[i, j] * x[j]
        x[i] = acc
    for i in range(m - 1, -1, -1):
        acc = x[i]
        for j in range(i + 1, m):
            acc -= A[i, j] * x[j]
        x[i] = acc / A[i, i]


@lean_kernel
def factor(n, Ap, Ai, Ax, q, tol, Lp, Li, Lx, Up, Ui, Ux, pinv, x, xi, stack, mark):
    """P A Q = L U of the CSC matrix (Ap, Ai, Ax) with column order q, into preallocated L
    (Lp, Li, Lx: CSC, unit diagonal stored first in each column, rows in pivot order) and U
    (Up, Ui, Ux: CSC, the diagonal stored last in each column); pinv[i] = the pivot step of
    row i. x, xi (2n), stack, mark: workspaces of length n (mark all -1 on entry).

    Returns the number of stored entries of L + U, -1 if A is structurally or exactly singular,
    -2 if L or U ran out of space (the caller retries with more)."""
    for i in range(n):
        pinv[i] = -1
        x[i] = 0.0
    lnz = 0
    unz = 0
    lcap = Li.shape[0]
    ucap = Ui.shape[0]
    for k in range(n):
        Lp[k] = lnz
        Up[k] = unz
        col = q[k]
        # --- the reach of A(:, col) in the graph of L (columns 0..k-1), topologically ordered in
        # xi[top:n] (a depth-first search from every nonzero of the column)
        top = n
        for pa in range(Ap[col], Ap[col + 1]):
            if Ax[pa] == 0.0:
                continue
            start = Ai[pa]
            if mark[start] == k:
                continue
            head = 0
            xi[0] = start
            while head >= 0:
                j = xi[head]
                jcol = pinv[j]
                if mark[j] != k:
                    mark[j] = k
                    stack[head] = Lp[jcol] + 1 if jcol >= 0 else 0   # skip L's unit diagonal
                done = True
                if jcol >= 0:
                    end = Lp[jcol + 1]
                    for p in range(stack[head], end):
                        i = Li[p]
                        if mark[i] == k:
                            continue
                        stack[head] = p + 1
                        head += 1
                        xi[head] = i
                        done = False
                        break
                if done:
                    head -= 1
                    top -= 1
                    xi[n + top] = j
        # --- x = L \ A(:, col) on that pattern
        for pa in range(Ap[col], Ap[col + 1]):
            x[Ai[pa]] += Ax[pa]
        for px in range(top, n):
            j = xi[n + px]
            jcol = pinv[j]
            if jcol < 0:
                continue
            xj = x[j]
            for p in range(Lp[jcol] + 1, Lp[jcol + 1]):
                x[Li[p]] -= Lx[p] * xj
        # --- U's column: the pivotal rows; the pivot: the largest of the others
        ipiv = -1
        big = -1.0
        if unz + (n - top) + 1 > ucap or lnz + (n - top) + 1 > lcap:
            return -2
        for px in range(top, n):
            i = xi[n + px]
            if pinv[i] < 0:
                t = abs(x[i])
                if t > big:
                    big = t
                    ipiv = i
            else:
                Ui[unz] = pinv[i]
                Ux[unz] = x[i]
                unz += 1
        if ipiv == -1 or not big > 0.0:
            for px in range(top, n):
                x[xi[n + px]] = 0.0
            return -1
        if pinv[col] < 0 and mark[col] == k and abs(x[col]) >= tol * big:
            ipiv = col
        pivot = x[ipiv]
        Ui[unz] = k
        Ux[unz] = pivot
        unz += 1
        pinv[ipiv] = k
        Li[lnz] = ipiv
        Lx[lnz] = 1.0
        lnz += 1
        for px in range(top, n):
            i = xi[n + px]
            if pinv[i] < 0:
                Li[lnz] = i
                Lx[lnz] = x[i] / pivot
                lnz += 1
            x[i] = 0.0
    Lp[n] = lnz
    Up[n] = unz
    for p in range(lnz):
        Li[p] = pinv[Li[p]]
    return lnz + unz


@lean_kernel
def residual_ok(indptr, indices, data, d, rhs, rel):
    """Whether d solves the CSR system (indptr, indices, data) d = rhs to ||A d - rhs|| <= rel ||rhs||
    (and d is finite)."""
    n = indptr.shape[0] - 1
    rr = 0.0
    bb = 0.0
    for i in range(n):
        s = -rhs[i]
        for p in range(indptr[i], indptr[i + 1]):
            s += data[p] * d[indices[p]]
        rr += s * s
        bb += rhs[i] * rhs[i]
    return math.isfinite(rr) and rr <= rel * rel * bb


@lean_kernel
def nonzero_pattern(indptr, indices, data, out_ptr, out_idx):
    """The pattern of the entries of a compressed matrix that are not stored zeros, into out_ptr
    (n + 1) and out_idx; returns their number."""
    n = indptr.shape[0] - 1
    m = 0
    for i in range(n):
        out_ptr[i] = m
        for p in range(indptr[i], indptr[i + 1]):
            if data[p] != 0.0:
                out_idx[m] = indices[p]
                m += 1
    out_ptr[n] = m
    return m


@lean_kernel
def solve(n, q, pinv, Lp, Li, Lx, Up, Ui, Ux, b, out, work, transpose):
    """out = A^-1 b (transpose: A^-T b) from factor's P A Q = L U; work: length n."""
    if not transpose:
        # A = P^T L U Q^T: L y = P b, U z = y, out = Q z
        for i in range(n):
            work[pinv[i]] = b[i]
        for k in range(n):
            yk = work[k]
            for p in range(Lp[k] + 1, Lp[k + 1]):
                work[Li[p]] -= Lx[p] * yk
        for k in range(n - 1, -1, -1):
            last = Up[k + 1] - 1
            zk = work[k] / Ux[last]
            work[k] = zk
            for p in range(Up[k], last):
                work[Ui[p]] -= Ux[p] * zk
        for k in range(n):
            out[q[k]] = work[k]
    else:
        # A^T = Q U^T L^T P: U^T w = Q^T b, L^T v = w, out = P^T v
        for k in range(n):
            work[k] = b[q[k]]
        for k in range(n):
            last = Up[k + 1] - 1
            s = work[k]
            for p in range(Up[k], last):
                s -= Ux[p] * work[Ui[p]]
            work[k] = s / Ux[last]
        for k in range(n - 1, -1, -1):
            s = work[k]
            for p in range(Lp[k] + 1, Lp[k + 1]):
                s -= Lx[p] * work[Li[p]]
            work[k] = s
        for i in range(n):
            out[i] = work[pinv[i]]


def column_order(indptr, indices):
    """A fill-reducing column order (SuperLU's COLAMD) for CSC matrices of this pattern: taken
    from a strictly diagonally dominant matrix of the pattern plus the diagonal, which SuperLU
    always factorises (COLAMD looks at the pattern alone)."""
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla
    n = len(indptr) - 1
    A = sp.csc_matrix((np.ones(len(indices)), indices, indptr), shape=(n, n))
    A = (A + sp.diags(np.diff(indptr) + 1.0, format="csc")).tocsc()
    perm_c = spla.splu(A, permc_spec="COLAMD").perm_c     # column i of A goes to position perm_c[i]
    q = np.empty(n, np.int64)
    q[perm_c] = np.arange(n)
    return q


class Workspace:
    """The arrays of SparseLU for matrices of one order n, kept between factorisations (a Newton
    solve factorises a matrix of one pattern every iteration; allocating the factors' arrays
    afresh, ~4 x 200 kB on 27 superquadrics in a box, cost ~80 us of a 0.65 ms factorisation).
    The factors of the last SparseLU made with it live here: the next one overwrites them."""

    def __init__(self, n):
        self.n = n
        self.x, self.xi = np.empty(n), np.empty(2 * n, np.int64)
        self.stack, self.mark = np.empty(n, np.int64), np.empty(n, np.int64)
        self.pinv = np.empty(n, np.int64)
        self.Lp, self.Up = np.empty(n + 1, np.int64), np.empty(n + 1, np.int64)
        self.cap = 0
        self.work = np.empty(n)

    def factors(self, cap):
        """L's and U's index and value arrays with room for at least cap entries each."""
        if cap > self.cap:
            self.cap = cap
            self.Li, self.Lx = np.empty(cap, np.int64), np.empty(cap)
            self.Ui, self.Ux = np.empty(cap, np.int64), np.empty(cap)
        return self.Li, self.Lx, self.Ui, self.Ux


class SparseLU:
    """The factors of one square CSC matrix (indptr, indices, data) in the column order q.

    ``SparseLU(indptr, indices, data, q)``; ``.ok`` is False if the matrix is singular (no
    nonzero pivot candidate in some column); ``.solve(b, trans)`` as SuperLU's; ``.nnz`` the
    entries of L + U. workspace: a Workspace of order n to hold the factors (reused; see there)."""

    def __init__(self, indptr, indices, data, q, tol=PIVOT_TOL, capacity=None, workspace=None):
        n = len(indptr) - 1
        self.n, self.q = n, np.ascontiguousarray(q, dtype=np.int64)
        cap = capacity or max(4 * len(data) + n, 16)
        ip = np.ascontiguousarray(indptr, dtype=np.int64)
        ix = np.ascontiguousarray(indices, dtype=np.int64)
        ax = np.ascontiguousarray(data, dtype=float)
        ws = self.ws = workspace if workspace is not None and workspace.n == n else Workspace(n)
        self.pinv, self.Lp, self.Up = ws.pinv, ws.Lp, ws.Up
        while True:
            self.Li, self.Lx, self.Ui, self.Ux = ws.factors(cap)
            ws.mark.fill(-1)
            self.nnz = int(factor(n, ip, ix, ax, self.q, tol, self.Lp, self.Li, self.Lx, self.Up, self.Ui,
                                  self.Ux, self.pinv, ws.x, ws.xi, ws.stack, ws.mark))
            if self.nnz != -2:
                break
            cap = 2 * max(cap, ws.cap)
        self.ok = self.nnz >= 0

    def solve(self, b, trans="N"):
        out = np.empty(self.n)
        solve(self.n, self.q, self.pinv, self.Lp, self.Li, self.Lx, self.Up, self.Ui, self.Ux,
              np.ascontiguousarray(b, dtype=float), out, self.ws.work, trans == "T")
        return out


class KeptOrder:
    """The factorisations of one solve's matrices of one pattern (CSR arrays, read as CSC), in a
    column order kept while the factors stay within refill times the entries that order first
    gave: first_order() at the start (None: COLAMD of the first matrix's nonzeros), COLAMD of
    the current nonzeros once the factors outgrow it (the nonzeros of a Newton matrix change
    with the active pieces of its FB rows). One Workspace; the factors' capacity is kept."""

    def __init__(self, n, refill, first_order=None):
        self.n, self.refill, self.first_order = n, refill, first_order
        self.order = self.fill = None
        self.reordered = False       # (an order of the nonzeros replaced first_order's)
        self.capacity = 0
        self.workspace = Workspace(n)

    def factor(self, indptr, indices, data, entries) -> SparseLU:
        """SparseLU of the matrix (entries: its count of nonzeros, for the factors' first room)."""
        n = self.n
        if self.order is None:
            if self.first_order is not None and not self.reordered:
                self.order = self.first_order()
            else:
                ptr, idx = np.empty(n + 1, np.int64), np.empty(len(data), np.int64)
                m = nonzero_pattern(indptr, indices, data, ptr, idx)
                self.order = column_order(ptr, idx[:m])
            self.fill = None
        self.capacity = max(self.capacity, 3 * entries + n)
        lu = SparseLU(indptr, indices, data, self.order, capacity=self.capacity, workspace=self.workspace)
        self.capacity = max(self.capacity, lu.nnz)
        if lu.ok and self.fill is None:
            self.fill = lu.nnz
        elif lu.ok and lu.nnz > self.refill * self.fill + n:
            self.order, self.reordered = None, True      # the nonzeros moved on: their order next time
        return lu
