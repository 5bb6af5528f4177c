"""The step residual of [GI] eqs (15)-(22) and its analytic Jacobian against central differences."""
import math

import numpy as np
import pytest

from implicit_contact import formulation as fm
from implicit_contact.testing import jacobian_error, random_blocks, random_body, random_pair_problem, random_point
from implicit_contact import shapes as shp
from implicit_contact.params import Compliance, Friction

H = 0.01
EPS_FD = 1e-6            # central-difference step
ATOL_FD = 5e-6           # |J - J_fd|: truncation O(eps^2 |F'''|) + round-off O(1e-16 |F| / eps) on rows / h
ROUND_SCALED = 1e-13     # round-off of a position-level row of lengths ~0.1 m, scaled by 1/h (h = 0.01)


CASES = [
    # (dim, kinds, piece 1, piece 2, body 2 is a fixed half-space, friction)
    (2, ("planar", "fixed"), shp.Disc(1.0, center=[0.1, 0.2]), shp.HalfPlane([0.0, 1.0], 0.0), True, Friction(0.4)),
    (2, ("planar", "planar"), shp.Ellipse([1.0, 0.5]), shp.Superellipse([0.6, 0.3], 4.0), False, Friction(0.4)),
    (2, ("planar", "fixed"), shp.Disc(0.7), shp.Intersection.rectangle([0.5, 0.3]), False, Friction(0.3)),
    (3, ("free", "fixed"), shp.Sphere(0.5, center=[0.1, 0.0, 0.2]), shp.HalfSpace([0, 0, 1], 0.0), True,
     Friction(0.3, 1.0, 0.8, 0.2)),
    (3, ("free", "free"), shp.Ellipsoid([1.0, 0.5, 0.7]), shp.Superquadric([0.5, 0.4, 0.3], 4.0), False,
     Friction(0.3, 1.0, 0.8, 0.2)),
    (3, ("free", "free"), shp.Sphere(0.4), shp.Intersection.box([0.3, 0.2, 0.1]), False, Friction(0.3, 1.0, 1.0, 0.0)),
    (3, ("free", "fixed"), shp.Ellipsoid([0.3, 0.2, 0.1]), shp.Sphere(2.0), False, Friction(0.0)),
    # body 1 an intersection: the cone form of eqs (28)-(32) (rows/contact.py, 28n-32n)
    (3, ("free", "free"), shp.Intersection.box([0.3, 0.2, 0.1]), shp.Intersection.box([0.2, 0.2, 0.4]), False,
     Friction(0.3, 1.0, 0.8, 0.2)),
    (3, ("free", "fixed"), shp.Intersection.box([0.3, 0.2, 0.1]), shp.HalfSpace([0, 0, 1], 0.0), True,
     Friction(0.5)),
    (2, ("planar", "planar"), shp.Intersection.rectangle([0.5, 0.3]), shp.Intersection.rectangle([0.2, 0.6]), False,
     Friction(0.4)),
    (3, ("free", "free"), shp.Intersection.box([0.3, 0.2, 0.1]), shp.Ellipsoid([0.2, 0.3, 0.4]), False,
     Friction(0.0)),
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_step_jacobian_matches_central_differences(case):
    dim, kinds, piece1, piece2, fixed2, friction = CASES[case]
    problem, z = random_pair_problem(dim, kinds, piece1, piece2, friction, np.random.default_rng(case), H, fixed2)
    err = jacobian_error(problem, z, EPS_FD)
    np.testing.assert_array_equal(problem.fun(z), problem._assemble(z, False)[0])
    assert err <= ATOL_FD


def test_layout_builds_only_the_rows_the_pair_needs():
    """Example 1's 11 unknowns ([GI] Sec. 6.1); no friction rows at mu = 0; no torsion at e_r = 0."""
    disc, ground = shp.Disc(1.0), shp.HalfPlane([0.0, 1.0], 0.0)
    o1, o2 = fm.ContactObject(0, (disc,), False), fm.ContactObject(1, (ground,), True)
    n = lambda fr, d=2: fm.build_layout([3 if d == 2 else 6], [fm.PairSpec("k", o1, o2, d, fr, fr.active)]).n
    assert n(Friction(0.4)) == 11           # v(3) a1(2) a2x(1) l1 l2 p_n p_t sigma
    assert n(Friction(0.0)) == 9
    s1, s2 = fm.ContactObject(0, (shp.Sphere(1.0),), False), fm.ContactObject(1, (shp.HalfSpace([0, 0, 1], 0),), True)
    n3 = lambda fr: fm.build_layout([6], [fm.PairSpec("k", s1, s2, 3, fr, fr.active, 0, np.eye(3)[0])]).n
    assert n3(Friction(0.2, 1, 1, 0.3)) == 6 + 3 + 2 + 2 + 1 + 2 + 1 + 1
    assert n3(Friction(0.2, 1, 1, 0.0)) == 6 + 3 + 2 + 2 + 1 + 2 + 1
    assert n3(Friction(0.0)) == 6 + 3 + 2 + 2 + 1


def test_cone_form_layout_and_an_exact_stack():
    """Body 1 an intersection: one more unknown, s, than [GI]'s k1 form (eqs 28n-32n), and a cube
    resting exactly on a box face to face solves every row of the pair: a1 = a2 on both faces,
    l = 1 on the box's top face and on the cube's bottom face, s = 0 (touching)."""
    box, cube = shp.Intersection.box([0.2, 0.2, 0.05]), shp.Intersection.box([0.1, 0.1, 0.1])    # half extents
    o1, o2 = fm.ContactObject(0, tuple(box.functions), False), fm.ContactObject(1, tuple(cube.functions), False)
    spec = fm.PairSpec("k", o1, o2, 3, Friction(0.0), False, 0, np.eye(3)[0])
    assert spec.cone_form
    layout = fm.build_layout([6, 6], [spec])
    sl = layout.pairs[0]
    assert layout.n == 12 + 3 + 3 + 1 + 6 + 6 + 1         # v, a1, a2, s, l1, l2, p_n
    assert layout.lower[sl.s] == -np.inf and layout.upper[sl.s] == np.inf
    h = 0.01
    rest = np.zeros(6)
    bodies = [fm.BodyKinematics(fm.FREE, 3, np.eye(3), np.zeros(3), np.zeros(6), h, np.arange(0, 6), 1.0),
              fm.BodyKinematics(fm.FREE, 3, np.eye(3), np.array([0.05, -0.02, 0.15]), np.zeros(6), h,
                                np.arange(6, 12), 1.0)]
    blocks = [fm.SkeletonBlock(np.eye(6), rest, rest, b) for b in range(2)]
    problem = fm.StepProblem(h, blocks, bodies, [spec], layout)
    z = np.zeros(layout.n)
    point = np.array([0.03, 0.01, 0.05])                  # on both faces, inside the overlap
    problem.pack_points(z, 0, point, point)
    f1 = [f.value(point) for f in box.functions]
    f2 = [f.value(point - bodies[1].p0) for f in cube.functions]
    z[sl.l1s] = [1.0 if abs(v) < 1e-15 else 0.0 for v in f1]
    z[sl.l2s] = [1.0 if abs(v) < 1e-15 else 0.0 for v in f2]
    assert sum(z[sl.l1s]) == 1.0 and sum(z[sl.l2s]) == 1.0
    F = problem.fun(z)
    natural = np.abs(z - np.clip(z - F, layout.lower, layout.upper))   # 0 at an MCP solution
    np.testing.assert_allclose(natural, 0.0, atol=ROUND_SCALED)
    z[sl.s] = 1e-3                                         # a separated s with touching points
    assert np.max(np.abs(problem.fun(z)[sl.a1])) > 1e-4


COMPLIANT_CASES = [
    # (dim, kinds, piece 1, piece 2, compliant side, friction, compliance)
    (2, ("planar", "fixed"), shp.Disc(1.0), shp.HalfPlane([0.0, 1.0], 0.0), 2, Friction(0.0),
     Compliance(1000.0, 0.0, 0.05)),
    (2, ("planar", "planar"), shp.Ellipse([1.0, 0.5]), shp.Disc(0.6), 2, Friction(0.4),
     Compliance(500.0, 3.0, math.inf, "midpoint")),
    (3, ("free", "fixed"), shp.Sphere(0.5), shp.Ellipsoid([2.0, 1.5, 1.0]), 2, Friction(0.3, 1.0, 0.8, 0.2),
     Compliance(1e4, 10.0, 0.01)),
    (3, ("free", "free"), shp.Sphere(0.4), shp.Intersection.box([0.3, 0.2, 0.1]), 1, Friction(0.3),
     Compliance(1e3, 0.0, 0.02)),
    # body 1 an intersection (the cone form), its layer on either side
    (3, ("free", "free"), shp.Intersection.box([0.3, 0.2, 0.1]), shp.Sphere(0.4), 1, Friction(0.3, 1.0, 0.8, 0.2),
     Compliance(1e3, 5.0, 0.02)),
    (3, ("free", "fixed"), shp.Intersection.box([0.3, 0.2, 0.1]), shp.Intersection.box([1.0, 1.0, 0.1]), 2,
     Friction(0.4), Compliance(1e4, 0.0, math.inf, "midpoint")),
]


@pytest.mark.parametrize("case", range(len(COMPLIANT_CASES)))
def test_quasi_rigid_step_jacobian_matches_central_differences(case):
    dim, kinds, piece1, piece2, side, friction, compliance = COMPLIANT_CASES[case]
    problem, z = random_pair_problem(dim, kinds, piece1, piece2, friction, np.random.default_rng(100 + case), H,
                                     compliance=compliance, compliant_side=side, delta_prev=0.003)
    sl = problem.layout.pairs[0]
    assert jacobian_error(problem, z, EPS_FD) <= ATOL_FD
    # the layer adds dbar, delta_n and, with a finite core, p_nr
    assert sl.dbar >= 0 and sl.dn >= 0 and (sl.p_nr >= 0) == math.isfinite(compliance.delta_max)


def _many_body_problem(dim, jacobian, seed=7):
    """A fixed ground (body 0) and five moving bodies: each on the ground, a chain of body / body
    pairs sharing bodies, one quasi-rigid pair and one more rigid pair; in 2D one body also has
    support friction (rows/support.py)."""
    from implicit_contact.support import SupportFriction, SupportSpec
    rng = np.random.default_rng(seed)
    kind = "free" if dim == 3 else "planar"
    bodies, nv, col = [random_body("fixed", dim, rng, 0, H)[0]], [], 0
    for _ in range(5):
        kin, k = random_body(kind, dim, rng, col, H)
        bodies.append(kin)
        nv.append(k)
        col += k
    if dim == 3:
        ground = shp.HalfSpace([0, 0, 1], 0.0)
        pieces = [shp.Sphere(0.4), shp.Ellipsoid([0.5, 0.3, 0.4]), shp.Superquadric([0.4, 0.3, 0.2], 4.0),
                  shp.Intersection.box([0.3, 0.2, 0.25]), shp.Sphere(0.3, center=[0.1, 0.0, 0.0])]
        fr, axis = Friction(0.3, 1.0, 0.8, 0.2), np.array([1.0, 0.0, 0.0])
    else:
        ground = shp.HalfPlane([0.0, 1.0], 0.0)
        pieces = [shp.Disc(0.4), shp.Ellipse([0.5, 0.3]), shp.Superellipse([0.4, 0.3], 4.0),
                  shp.Intersection.rectangle([0.3, 0.2]), shp.Disc(0.3, center=[0.1, 0.0])]
        fr, axis = Friction(0.4), None
    obj = [fm.ContactObject(b, tuple(p.functions), False) for b, p in enumerate(pieces, start=1)]
    specs = [fm.PairSpec(("g", b), obj[b - 1], fm.ContactObject(0, (ground,), True), dim, fr, b % 2 == 1, 0, axis, 0.05)
             for b in range(1, 6)]
    for b in range(1, 4):
        specs.append(fm.PairSpec((b, b + 1), obj[b - 1], obj[b], dim, fr, True, 0, axis, 0.05))
    specs.append(fm.PairSpec((4, 5), obj[3], obj[4], dim, fr, True, 0, axis, 0.05,
                             compliance=Compliance(1e3, 1.0, 0.02), compliant_side=2, delta_prev=0.003))
    specs.append(fm.PairSpec((1, 5), obj[0], obj[4], dim, fr, True, 0, axis, 0.05))
    supports = (SupportSpec(2, SupportFriction(0.3, 5.0, (0.1, 0.0), 0.2)),) if dim == 2 else ()
    layout = fm.build_layout(nv, specs, supports)
    blocks = random_blocks(bodies, rng)
    problem = fm.StepProblem(H, blocks, bodies, specs, layout, supports, jacobian=jacobian)
    z = random_point(layout, rng)
    return problem, z


@pytest.mark.parametrize("dim", [2, 3])
def test_sparse_jacobian_equals_the_dense_one_on_a_many_body_problem(dim):
    """The sparse path (per-plan blocks over local columns through a fixed CSR pattern) gives the
    dense path's J, and the same F bitwise from fun and from jac."""
    import scipy.sparse as sp
    dense, z = _many_body_problem(dim, "dense")
    sparse, _ = _many_body_problem(dim, "sparse")
    assert not dense._sparse and sparse._sparse
    Js = sparse.jac(z)
    assert sp.issparse(Js)
    np.testing.assert_array_equal(sparse.fun(z), dense.fun(z))
    np.testing.assert_array_equal(sparse.fun(z), sparse._assemble(z, False)[0])
    Jd = dense.jac(z)
    scale = np.maximum(1.0, np.abs(Jd))
    assert np.max(np.abs(Js.toarray() - Jd) / scale) <= 1e-14      # summation order only
    # and a solve from the same start takes the same path
    from implicit_contact import ncp
    opts = ncp.SolverOptions(max_iterations=3)
    rd = ncp.solve_mcp(dense.fun, dense.jac, z, dense.lower, dense.upper, opts)
    rs = ncp.solve_mcp(sparse.fun, sparse.jac, z, sparse.lower, sparse.upper, opts)
    assert rd.steps == rs.steps
    np.testing.assert_allclose(rs.x, rd.x, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("dim", [2, 3])
def test_a_layout_from_moved_templates_is_the_layout_allocated_pair_by_pair(dim):
    """build_layout moves one template per kind of pair block (layout._pair_template, PairSlots.moved);
    on pairs of every kind (with and without friction, on a fixed half-space, the cone form, a
    quasi-rigid pair) each block equals the one allocated in place, field by field."""
    from implicit_contact import layout as lay
    problem, _ = _many_body_problem(dim, "dense")
    layout = problem.layout
    col = sum(len(v) for v in layout.v_index)
    lower, upper = [], []
    for spec, moved in zip(problem.specs, layout.pairs):
        start = len(lower)
        ref = lay._allocate_pair(spec, col + start, lower, upper)
        for name in lay.PairSlots._ARRAYS + ("l1_bounded", "l2_bounded"):
            assert getattr(moved, name).dtype == getattr(ref, name).dtype
            np.testing.assert_array_equal(getattr(moved, name), getattr(ref, name), err_msg=name)
        for name in ("p_n", "p_r", "sigma", "row_n", "dbar", "dn", "p_nr", "s", "a1s", "a2s", "l1s", "l2s", "p_ts",
                     "rows_l1s", "rows_l2s"):
            assert getattr(moved, name) == getattr(ref, name), name
    np.testing.assert_array_equal(layout.lower[col:col + len(lower)], lower)
    np.testing.assert_array_equal(layout.upper[col:col + len(upper)], upper)


def test_sparse_pattern_is_the_union_of_the_plans_blocks_with_every_slot_on_its_entry():
    """rows/assemble.sparse_pattern against a set oracle: overlapping plans of unsorted local
    indices (as skeletons, pairs and supports share velocity columns), a row in no plan."""
    from implicit_contact.rows.assemble import sparse_pattern
    rng = np.random.default_rng(3)
    n = 40
    plans = [rng.choice(n - 1, size=size, replace=False) for size in (6, 1, 9, 4, 12, 6)]
    loc_idx = np.concatenate(plans).astype(np.int64)
    loc_off = np.cumsum([0] + [len(p) for p in plans]).astype(np.int64)
    slot_off = np.cumsum([0] + [len(p) ** 2 for p in plans]).astype(np.int64)
    slots, indices = np.empty(slot_off[-1], np.int64), np.empty(slot_off[-1], np.int64)
    indptr = np.empty(n + 1, np.int64)
    nnz = sparse_pattern(n, loc_idx, loc_off, slot_off, slots, indptr, indices)
    expected = sorted({(int(r), int(c)) for p in plans for r in p for c in p})
    assert nnz == len(expected) == indptr[n]
    got = [(r, int(indices[k])) for r in range(n) for k in range(indptr[r], indptr[r + 1])]
    assert got == expected                           # CSR, columns sorted within each row, no repeats
    assert indptr[n - 1] == indptr[n]                # the last row is in no plan: empty
    for p, ix in enumerate(plans):
        L = len(ix)
        for i in range(L):
            for j in range(L):
                k = slots[slot_off[p] + i * L + j]
                assert indptr[ix[i]] <= k < indptr[ix[i] + 1] and indices[k] == ix[j]


def test_transfer_maps_a_pair_whose_bodies_were_swapped_since_the_old_solve():
    """recovery._transfer from a solve kept before flip_intersections swapped a pair's bodies
    (the stepper's spec list is edited in place, so the old problem's own specs show the new
    order): the old points, multipliers and normal impulse arrive swapped, not as a shape error
    (measured first on example-robot-data's solo.urdf, a 46-plane foot hull on a ground box)."""
    from implicit_contact import recovery
    rng = np.random.default_rng(7)
    h = 0.01
    bodies, nv, col = [], [], 0
    for _ in range(2):
        kin, k = random_body(fm.FREE, 3, rng, col, h)
        bodies.append(kin)
        nv.append(k)
        col += k
    blocks = random_blocks(bodies, rng)
    big, small = shp.Intersection.box([0.2, 0.3, 0.1]), shp.Intersection.polytope(
        np.r_[np.eye(3), -np.eye(3), [[1.0, 1.0, 1.0]] / np.sqrt(3)], np.r_[np.full(6, 0.1), 0.12])
    fr = Friction(0.5)
    o_big, o_small = fm.ContactObject(0, tuple(big.functions), False), fm.ContactObject(1, tuple(small.functions), False)
    axis = np.array([1.0, 0.0, 0.0])
    spec_old = fm.PairSpec(("big", "small"), o_big, o_small, 3, fr, True, 0, axis, 0.05)
    spec_new = fm.PairSpec(("small", "big"), o_small, o_big, 3, fr, True, 0, axis, 0.05)
    specs = [spec_old]
    old = fm.StepProblem(h, blocks, bodies, specs, fm.build_layout(nv, specs))
    new = fm.StepProblem(h, blocks, bodies, [spec_new], fm.build_layout(nv, [spec_new]))
    x = random_point(old.layout, rng)
    before = old.unpack_pair(x, 0)
    specs[0] = spec_new                                # what flip_intersections does to the list
    z = recovery._transfer(old, x, new)
    after = new.unpack_pair(z, 0)
    np.testing.assert_allclose(after.a1, before.a2, atol=1e-14)
    np.testing.assert_allclose(after.a2, before.a1, atol=1e-14)
    np.testing.assert_array_equal(after.l1, before.l2)
    np.testing.assert_array_equal(after.l2, before.l1)
    assert after.p_n == before.p_n
    np.testing.assert_array_equal(z[new.layout.v_index[0]], x[old.layout.v_index[0]])


def test_cone_check_refuses_what_the_solver_tolerance_does_not_explain():
    """CONE (rows/checks.py) against the cone row (22), which is quadratic in the scaled impulses:
    a converged solve (natural residual <= tol) may leave the friction up to sqrt(tol) outside a
    cone of p_n = 0, and up to ~tol / (2 mu p_n) outside a loaded one; the check refuses only
    what that does not explain."""
    from implicit_contact.rows import checks as rk
    dim, kinds, piece1, piece2, fixed2, friction = CASES[3]       # sphere on a half-space, mu = 0.3
    problem, z = random_pair_problem(dim, kinds, piece1, piece2, friction, np.random.default_rng(3), H, fixed2)
    sl, mu, tol = problem.layout.pairs[0], friction.mu, 1e-10

    def flags(zn, zt):
        w = z.copy()
        w[sl.p_n], w[sl.p_t], w[sl.p_r], w[sl.sigma] = zn, [zt, 0.0], 0.0, 1.0    # sliding: sigma > 0
        cone_row = problem.fun(w)[sl.sigma]                        # its natural residual, sigma > 0
        return cone_row, problem.checks(w, 1e-6, tol, 1e-9)[0] & rk.CONE

    # p_n = 0: friction sqrt(tol / 2) is a converged row (residual tol / 2) and passes ...
    row, cone = flags(0.0, math.sqrt(0.5 * tol))
    assert abs(row) <= tol and not cone
    # ... 10 sqrt(tol) is a residual of 100 tol: refused
    row, cone = flags(0.0, 10.0 * math.sqrt(tol))
    assert abs(row) > rk.CONE_SLACK * tol and cone
    # loaded (p_n = 1 scaled): within the linear slack 1e3 tol passes, 1e4 tol beyond mu p_n is refused
    assert not flags(1.0, mu + 5e2 * tol)[1]
    row, cone = flags(1.0, mu + 1e4 * tol)
    assert abs(row) > rk.CONE_SLACK * tol and cone
