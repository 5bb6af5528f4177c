"""block_elimination: the sparse Newton step with local blocks eliminated first (a Schur
complement), against dense LAPACK solves, on synthetic matrices of a step problem's shape and on
the Newton matrices of a real sparse step (27 superquadrics in a box)."""
import numpy as np
import pytest
import scipy.sparse as sp

import implicit_contact as ic
from implicit_contact import block_elimination as be
from implicit_contact import ncp
from implicit_contact.layout import closest_point_blocks

SOLVE_TOL = 1e-10      # relative residual of a solve on matrices of condition <= ~1e4


def _block_structured(n_rest, sizes, seed, couple=False, stored_zeros=0):
    """A CSR matrix over n_rest 'rest' unknowns and groups of the given sizes after them: each
    group coupled to its own few rest unknowns (rows and columns) and to none of the other groups
    (couple: one entry between the first two groups); stored_zeros: exact zeros added to the
    pattern, as a step problem stores every entry its rows could have."""
    rng = np.random.default_rng(seed)
    n = n_rest + sum(sizes)
    A = np.zeros((n, n))
    A[:n_rest, :n_rest] = (rng.random((n_rest, n_rest)) < 0.1) * rng.standard_normal((n_rest, n_rest))
    A[np.arange(n_rest), np.arange(n_rest)] = rng.uniform(2.0, 4.0, n_rest) * rng.choice([-1.0, 1.0], n_rest)
    groups, at = [], n_rest
    for m in sizes:
        g = np.arange(at, at + m)
        rest = rng.choice(n_rest, 6, replace=False)
        A[np.ix_(g, g)] = rng.standard_normal((m, m)) + 4.0 * np.eye(m)
        A[np.ix_(g, rest)] = rng.standard_normal((m, 6))
        A[np.ix_(rest, g)] = rng.standard_normal((6, m))
        groups.append(g)
        at += m
    if couple:
        A[groups[0][0], groups[1][0]] = 0.5
    owner = np.full(n, -1)
    for k, g in enumerate(groups):
        owner[g] = k
    pattern = A != 0.0
    if stored_zeros:
        rows, cols = rng.integers(0, n, stored_zeros), rng.integers(0, n, stored_zeros)
        apart = (owner[rows] >= 0) & (owner[cols] >= 0) & (owner[rows] != owner[cols])
        pattern[rows[~apart], cols[~apart]] = True       # (zeros between groups would couple them)
    r, c = np.nonzero(pattern)
    H = sp.csr_matrix((A[r, c], (r, c)), shape=(n, n))    # exact zeros stored where A has none
    H.sort_indices()
    bptr = np.r_[0, np.cumsum(sizes)].astype(np.int64)
    bidx = np.concatenate(groups).astype(np.int64)
    return H, A, (bptr, bidx)


@pytest.mark.parametrize("n_rest, sizes, seed, stored_zeros", [(30, [7, 7, 5], 0, 0), (80, [7] * 12 + [3, 8], 1, 0),
                                                              (80, [7] * 12, 2, 400)])
def test_eliminated_solve_matches_the_dense_solve(n_rest, sizes, seed, stored_zeros):
    H, A, (bptr, bidx) = _block_structured(n_rest, sizes, seed, stored_zeros=stored_zeros)
    assert H.nnz - np.count_nonzero(A) >= stored_zeros // 2      # (the stored zeros are there)
    if np.linalg.cond(A) > 1e6:
        pytest.skip("the draw is ill-conditioned")
    structure = be.structure(H.indptr, H.indices, bptr, bidx)
    assert structure.ok and structure.nr == n_rest
    b = np.random.default_rng(seed + 10).standard_normal(A.shape[0])
    d = be.Elimination(structure, 1.5).solve(H.data, b)
    assert np.linalg.norm(A @ d - b) <= SOLVE_TOL * np.linalg.norm(b)
    assert np.allclose(d, np.linalg.solve(A, b), rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("seed, decoupled", [(5, 3), (6, 6), (7, 7)])
def test_rows_with_their_diagonal_alone_are_solved_apart(seed, decoupled):
    """A group's rows whose only nonzero is the diagonal (an inactive multiplier's row, da e_i: a
    mesh hull's planes) are taken out of its local LU (_numeric): the direction still solves the
    whole system, with some, most or all of a group's rows so (their off-diagonal entries stored
    zeros, as in a step problem's fixed pattern; their columns still filled)."""
    H, A, (bptr, bidx) = _block_structured(40, [7, 7, 7], seed)
    rng = np.random.default_rng(seed)
    data = H.data.copy()
    rows = np.repeat(np.arange(H.shape[0]), np.diff(H.indptr))
    for g in range(3):
        for i in rng.choice(bidx[bptr[g]:bptr[g + 1]], decoupled, replace=False):
            data[(rows == i) & (H.indices != i)] = 0.0
            A[i, np.arange(A.shape[0]) != i] = 0.0
    if np.linalg.cond(A) > 1e6:
        pytest.skip("the draw is ill-conditioned")
    elimination = be.Elimination(be.structure(H.indptr, H.indices, bptr, bidx), 1.5)
    b = rng.standard_normal(A.shape[0])
    d = elimination.solve(data, b)
    assert list(elimination.mb) == [7 - decoupled] * 3
    assert np.linalg.norm(A @ d - b) <= SOLVE_TOL * np.linalg.norm(b)
    assert np.allclose(d, np.linalg.solve(A, b), rtol=1e-9, atol=1e-12)


def test_coupled_groups_disable_it_and_a_singular_block_refuses_the_solve():
    H, A, (bptr, bidx) = _block_structured(30, [4, 4], 3, couple=True)
    assert not be.structure(H.indptr, H.indices, bptr, bidx).ok
    H, A, (bptr, bidx) = _block_structured(30, [4, 4], 4)
    data = H.data.copy()
    rows = np.repeat(np.arange(H.shape[0]), np.diff(H.indptr))
    first = set(bidx[:4].tolist())
    block = np.array([r in first and c in first for r, c in zip(rows, H.indices)])
    data[block] = 0.0                        # the first group's own block vanishes at this iterate
    elimination = be.Elimination(be.structure(H.indptr, H.indices, bptr, bidx), 1.5)
    assert elimination.solve(data, np.ones(H.shape[0])) is None


def test_real_newton_steps_match_the_whole_matrix_lu():
    """The Newton matrices of a sparse step (27 superquadrics dropped into a box, from t = 0.2 s,
    where they land): each eliminated direction against the whole matrix's direction, and a
    pattern whose groups (layout.closest_point_blocks) are never coupled."""
    from comparisons import stability
    world = stability.many_bodies_world(27, 0.01, stability.IMPLICIT)
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(20):
        stepper.step()
    seen = []
    original = ncp._SparsePattern.newton

    def newton(self, J, da, db, Phi, g):
        d = original(self, J, da, db, Phi, g)
        assert self.elimination is not None          # (the groups are uncoupled in every pattern)
        if d is not None and len(seen) < 6:
            n = J.shape[0]
            H = sp.csr_matrix((self.data, self.indices, self.indptr), shape=(n, n)).toarray()
            whole = np.linalg.solve(H, -Phi)
            seen.append(np.max(np.abs(d - whole)) / np.max(np.abs(whole)))
        return d
    ncp._SparsePattern.newton = newton
    try:
        stepper.step()
    finally:
        ncp._SparsePattern.newton = original
    assert len(seen) >= 3 and max(seen) <= 1e-8
    problem = next(iter(stepper._problems.values()))[0]
    bptr, bidx = closest_point_blocks(problem.layout)
    assert len(bptr) - 1 == len(problem.layout.pairs)
