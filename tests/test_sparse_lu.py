"""sparse_lu: the compiled left-looking LU of the sparse Newton step, against dense LAPACK solves."""
import numpy as np
import pytest
import scipy.sparse as sp

from implicit_contact import ncp, sparse_lu

SOLVE_TOL = 1e-10      # relative residual of a solve on matrices of condition <= ~1e4


def _random(n, density, seed, zero_diagonal=False):
    rng = np.random.default_rng(seed)
    A = sp.random(n, n, density=density, random_state=rng, format="csc")
    A = A + sp.diags(rng.uniform(0.5, 2.0, n) * rng.choice([-1.0, 1.0], n), format="csc")
    A = A.tocsc()
    if zero_diagonal:                      # every pivot must come off the diagonal
        P = sp.csc_matrix((np.ones(n), (np.roll(np.arange(n), 1), np.arange(n))), shape=(n, n))
        A = (P @ A).tocsc()
        A.setdiag(0.0)
        A.eliminate_zeros()
    return A


def _rel_residual(A, x, b):
    return np.linalg.norm(A @ x - b) / np.linalg.norm(b)


@pytest.mark.parametrize("n, density, seed, zero_diagonal", [(1, 1.0, 0, False), (7, 0.4, 1, False),
                                                             (60, 0.05, 2, False), (400, 0.01, 3, False),
                                                             (60, 0.05, 4, True)])
def test_solves_and_transposed_solves_match_the_matrix(n, density, seed, zero_diagonal):
    A = _random(n, density, seed, zero_diagonal)
    if np.linalg.cond(A.toarray()) > 1e6:
        pytest.skip("the draw is ill-conditioned")
    lu = sparse_lu.SparseLU(A.indptr, A.indices, A.data, sparse_lu.column_order(A.indptr, A.indices))
    assert lu.ok
    b = np.random.default_rng(seed + 100).standard_normal(n)
    assert _rel_residual(A, lu.solve(b), b) <= SOLVE_TOL
    assert _rel_residual(A.T, lu.solve(b, "T"), b) <= SOLVE_TOL
    assert np.allclose(lu.solve(b), np.linalg.solve(A.toarray(), b), rtol=1e-9, atol=1e-12)


def test_pivots_off_a_zero_diagonal_and_keeps_a_dominant_one():
    # [[0, 1], [1, 0]]: the only pivots are off the diagonal
    A = sp.csc_matrix(np.array([[0.0, 1.0], [1.0, 0.0]]))
    lu = sparse_lu.SparseLU(A.indptr, A.indices, A.data, np.arange(2))
    assert lu.ok and np.allclose(lu.solve(np.array([2.0, 3.0])), [3.0, 2.0])
    # partial pivoting: a diagonal entry smaller than PIVOT_TOL times the column's largest is passed over
    A = sp.csc_matrix(np.array([[1e-12, 1.0], [1.0, 1.0]]))
    lu = sparse_lu.SparseLU(A.indptr, A.indices, A.data, np.arange(2))
    assert lu.pinv[1] == 0                  # row 1 pivots the first column
    b = np.array([1.0, 2.0])
    assert _rel_residual(A, lu.solve(b), b) <= SOLVE_TOL


def test_stored_zeros_are_skipped():
    A = _random(80, 0.04, 5)
    C = A.tocoo()
    rng = np.random.default_rng(6)
    extra = {(int(i), int(j)) for i, j in rng.integers(0, 80, (300, 2))} - set(zip(C.row.tolist(), C.col.tolist()))
    ei, ej = np.array(sorted(extra)).T
    # the same matrix with ~300 more entries stored as exact zeros (a step problem's fixed pattern)
    B = sp.csc_matrix((np.concatenate([C.data, np.zeros(len(ei))]),
                       (np.concatenate([C.row, ei]), np.concatenate([C.col, ej]))), shape=(80, 80))
    assert B.nnz == A.nnz + len(ei) and np.array_equal(B.toarray(), A.toarray())
    q = sparse_lu.column_order(A.indptr, A.indices)
    la = sparse_lu.SparseLU(A.indptr, A.indices, A.data, q)
    lb = sparse_lu.SparseLU(B.indptr, B.indices, B.data, q)
    assert la.nnz == lb.nnz                         # the same factors: the zeros made no fill
    b = rng.standard_normal(80)
    assert np.array_equal(la.solve(b), lb.solve(b))


def test_singular_matrices_are_reported():
    # an empty column: structurally singular
    A = sp.csc_matrix(np.array([[1.0, 0.0], [2.0, 0.0]]))
    assert not sparse_lu.SparseLU(A.indptr, A.indices, A.data, np.arange(2)).ok
    # two equal columns: exactly singular in floating point
    A = sp.csc_matrix(np.array([[1.0, 1.0, 0.0], [2.0, 2.0, 0.0], [0.0, 0.0, 3.0]]))
    assert not sparse_lu.SparseLU(A.indptr, A.indices, A.data, np.arange(3)).ok


def test_factors_grow_past_a_too_small_capacity():
    A = _random(120, 0.05, 7)
    q = sparse_lu.column_order(A.indptr, A.indices)
    small = sparse_lu.SparseLU(A.indptr, A.indices, A.data, q, capacity=3)
    roomy = sparse_lu.SparseLU(A.indptr, A.indices, A.data, q)
    assert small.ok and small.nnz == roomy.nnz
    b = np.random.default_rng(8).standard_normal(120)
    assert np.array_equal(small.solve(b), roomy.solve(b))


def test_residual_check_refuses_a_wrong_or_non_finite_solution():
    A = sp.csr_matrix(_random(30, 0.1, 9))
    x = np.random.default_rng(10).standard_normal(30)
    b = A @ x
    assert sparse_lu.residual_ok(A.indptr.astype(np.int64), A.indices.astype(np.int64), A.data, x, b, 1e-12)
    assert not sparse_lu.residual_ok(A.indptr.astype(np.int64), A.indices.astype(np.int64), A.data,
                                     x + 1e-3, b, 1e-6)
    bad = x.copy()
    bad[3] = np.nan
    assert not sparse_lu.residual_ok(A.indptr.astype(np.int64), A.indices.astype(np.int64), A.data, bad, b, 1e-4)


def test_sparse_newton_step_equals_the_dense_one():
    """ncp's sparse Newton step (sparse_lu on H^T) against the dense step on the same H."""
    n = 50
    J = sp.csr_matrix(_random(n, 0.08, 11))
    rng = np.random.default_rng(12)
    da, db = rng.uniform(0.0, 1.0, n), rng.uniform(0.0, 1.0, n)
    da[:5], db[:5] = 1.0, 0.0                          # rows at a bound: H's row is the identity's
    Phi = rng.standard_normal(n)
    g = np.empty(n)
    pattern = ncp._SparsePattern(J)
    d = pattern.newton(J, da, db, Phi, g)
    H = np.diag(da) + db[:, None] * J.toarray()
    assert d is not None
    assert np.allclose(d, np.linalg.solve(H, -Phi), rtol=1e-9, atol=1e-12)
    assert np.allclose(g, H.T @ Phi)
    # a second iterate of the same pattern reuses the column order
    order = pattern.order
    d2 = pattern.newton(J, 0.5 * da, db, Phi, g)
    H2 = np.diag(0.5 * da) + db[:, None] * J.toarray()
    assert pattern.order is order and np.allclose(d2, np.linalg.solve(H2, -Phi), rtol=1e-9, atol=1e-12)
