"""Solve one step's MCP: ncp's iteration driven by the step's compiled rows, no Python in between.

ncp.mcp_iterations is the solver, written once as a generator of requests (F at a trial point,
J, J z, the Newton and Levenberg-Marquardt solves). For a dense step problem (below
formulation.SPARSE_MIN_UNKNOWNS unknowns) ``_solve_dense`` answers every request inside one
compiled call: the rows come from rows/assemble.py and the linear algebra from ncp's dense
kernels, so a whole solve costs one call from Python. A sparse problem is driven from Python by
ncp.solve_mcp (scipy's sparse LU), with the rows still compiled.

``solve`` also polishes: a converged solve whose residual lies in (1e-3 tol, tol] takes one
more Newton step at tol / 1000. The solution becomes the next step's warm start; a resting or
rolling contact accepted at, say, 0.5 tol would be carried at that error (a slow sink of
~tol h per step) instead of being exact, and one more Newton step from inside the quadratic
basin makes it round-off exact.

``solve`` also finishes stalls: a solve that fails within ENDGAME_RESIDUAL of a solution is
handed to ncp.newton_min_map (Newton on the min-map with least-norm steps), whose answer is taken
only if it meets the same tol (redundant contacts, an edge lying on a face: a singular Jacobian).
"""
from __future__ import annotations

from dataclasses import replace
import math

import numpy as np

from . import bundles
from . import ncp
from ._jit import FALSE, TRUE, kernel, lean_kernel
from .formulation import StepProblem
from .layout import closest_point_blocks
from .rows.assemble import assemble
from .rows import velocity as rv


@kernel
def _solve_dense(body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f,
                 loc_idx, loc_off, scale, x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz,
                 history, steps, info, fbuf, work, J, H, rep, st_R, st_p, st_w, st_vo, st_T, FL, JL, ws):
    """One solve of a dense step problem; the outcome in the ncp buffers, the pairs' reports at
    the final iterate in rep."""
    no_f = np.zeros(0)
    _solve_regularised(body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f,
                       loc_idx, loc_off, scale, x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz,
                       history, steps, info, fbuf, work, J, H, rep, st_R, st_p, st_w, st_vo, st_T, FL, JL, ws,
                       no_f, no_f)


@kernel
def _solve_regularised(body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f,
                       loc_idx, loc_off, scale, x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz,
                       history, steps, info, fbuf, work, J, H, rep, st_R, st_p, st_w, st_vo, st_T, FL, JL, ws,
                       weight, centre):
    """_solve_dense of F(x) + weight (x - centre), Jacobian J + diag(weight) (_regularise; weight
    empty: F itself): ncp.solve_proximal's inner solves, one compiled call each (solve_regularised)."""
    no_i = np.zeros(0, np.int64)
    no_f = np.zeros(0)
    slot_off = np.zeros(loc_off.shape[0], np.int64)
    # the first point here, and no Newton iteration when it solves the problem (ncp.first_point)
    ncp.start_point(x0, lo, hi, xt)
    assemble(body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f,
             loc_idx, loc_off, no_i, slot_off, scale, no_f, xt, Ft, J, no_f, rep,
             st_R, st_p, st_w, st_vo, st_T, FL, JL, ws, FALSE, FALSE)
    _regularise(weight, centre, xt, Ft, J, FALSE)
    if ncp.first_point(lo, hi, opt, x, F, xt, Ft, Phi, history, info, fbuf, work) == ncp.ITERATE:
        _newton_dense(body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f,
                      loc_idx, loc_off, scale, x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz,
                      history, steps, info, fbuf, work, J, H, rep, st_R, st_p, st_w, st_vo, st_T, FL, JL, ws,
                      no_i, no_f, slot_off, weight, centre)


@lean_kernel
def _regularise(weight, centre, x, F, J, jac):
    """F += weight (x - centre), or (jac) J += diag(weight), in the order of ncp.solve_proximal's
    Python expressions F(z) + wk * (z - centre) and J + np.diag(wk) (every entry plus its diagonal
    matrix's, 0.0 off it), so that the compiled inner solve is theirs bit for bit; nothing when
    weight is empty."""
    if weight.shape[0] == 0:
        return
    if jac:
        n = J.shape[0]
        for i in range(n):
            for j in range(n):
                J[i, j] = J[i, j] + (weight[i] if i == j else 0.0)
    else:
        for i in range(F.shape[0]):
            F[i] = F[i] + weight[i] * (x[i] - centre[i])


@kernel
def _newton_dense(body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f,
                  loc_idx, loc_off, scale, x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz,
                  history, steps, info, fbuf, work, J, H, rep, st_R, st_p, st_w, st_vo, st_T, FL, JL, ws,
                  no_i, no_f, slot_off, weight, centre):
    """_solve_regularised's Newton iterations after its first point, with its empty tables no_i,
    no_f and its slot offsets (a kernel of its own: a kernel that iterates a generator pays ~0.65
    us on entry, also when it returns before the loop)."""
    Fj = np.empty(x0.shape[0])
    for req in ncp.mcp_iterations(x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz, history,
                                  steps, info, fbuf, work, TRUE):
        if req == ncp.REQ_F:
            assemble(body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f,
                     loc_idx, loc_off, no_i, slot_off, scale, no_f, xt, Ft, J, no_f, rep,
                     st_R, st_p, st_w, st_vo, st_T, FL, JL, ws, FALSE, FALSE)
            _regularise(weight, centre, xt, Ft, J, FALSE)
        elif req == ncp.REQ_J:
            assemble(body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f,
                     loc_idx, loc_off, no_i, slot_off, scale, no_f, x, Fj, J, no_f, rep,
                     st_R, st_p, st_w, st_vo, st_T, FL, JL, ws, TRUE, FALSE)
            _regularise(weight, centre, x, Fj, J, TRUE)
            info[ncp.I_BAD] = ncp.nonfinite(J)
        else:
            ncp.dense_request(req, J, zk, Jz, da, db, Phi, H, g, d, info, fbuf)
    # the reports at the final iterate: the last evaluation was there unless the solve stopped
    # after a rejected trial (a failed line search)
    if np.isfinite(fbuf[ncp.F_RESIDUAL]) and info[ncp.I_STATUS] in (ncp.S_LINE_SEARCH_FAILED, ncp.S_SINGULAR):
        assemble(body_i, body_f, body_jac, fpar, sk_i, sk_M, v0, hforce, pair_i, pair_f, sup_i, sup_f,
                 loc_idx, loc_off, no_i, slot_off, scale, no_f, x, Fj, J, no_f, rep,
                 st_R, st_p, st_w, st_vo, st_T, FL, JL, ws, FALSE, FALSE)


@kernel
def _solve_stage2(M, u, hf, scale, G, pi, pf, jg, ju, jk, jcol, x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g,
                  da, db, zk, Jz, history, steps, info, fbuf, work, J, H):
    """One solve of order 2's second stage (rattle.Stage2: rows/velocity.stage2_rows) into the
    ncp buffers, every request answered inside the call, as _solve_dense."""
    n = x0.shape[0]
    Fj = np.empty(n)
    Jf = np.empty((0, 0))
    for req in ncp.mcp_iterations(x0, lo, hi, opt, x, F, xt, Ft, Phi, Phit, d, g, da, db, zk, Jz, history,
                                  steps, info, fbuf, work):
        if req == ncp.REQ_F:
            rv.stage2_rows(xt, M, u, hf, scale, G, pi, pf, jg, ju, jk, jcol, Ft, Jf, FALSE)
        elif req == ncp.REQ_J:
            rv.stage2_rows(x, M, u, hf, scale, G, pi, pf, jg, ju, jk, jcol, Fj, J, TRUE)
            info[ncp.I_BAD] = ncp.nonfinite(J)
        else:
            ncp.dense_request(req, J, zk, Jz, da, db, Phi, H, g, d, info, fbuf)


def solve_stage2(stage, x0, options: ncp.SolverOptions) -> ncp.McpResult:
    """Order 2's second stage (rattle.Stage2) from x0: ncp's solver on its compiled rows, one call."""
    x = np.ascontiguousarray(x0, dtype=float)      # (the bounds are Stage2's own, well formed)
    lo, hi = stage.lower, stage.upper
    n = x.shape[0]
    buf, J, H, opt = _stage2_buffers(n, options)
    _solve_stage2(stage.M, stage.u, stage.hf, stage.scale, stage.G, stage.pi, stage.pf, stage.jg, stage.ju,
                  stage.jk, stage.jcol, x, lo, hi, opt, buf.x, buf.F, buf.xt, buf.Ft,
                  buf.Phi, buf.Phit, buf.d, buf.g, buf.da, buf.db, buf.zk, buf.Jz, buf.history, buf.steps,
                  buf.info, buf.fbuf, buf.work, J, H)
    return ncp.result_from_buffers(buf, options)


_STAGE2_BUFFERS = {}


def _stage2_buffers(n, options):
    """ncp.dense_buffers of a stage-2 solve of n unknowns, kept per (n, options) (a stage 2 is
    built afresh every step; making them cost ~20 us of a ~0.5 ms split step). The solver writes
    every entry it reads (step problems reuse theirs the same way: _buffers), and solve_stage2's
    result holds copies."""
    return _kept(_STAGE2_BUFFERS, (n, id(options)), options, 16, lambda: ncp.dense_buffers(n, options))[:4]


def _kept(held, key, options, limit, make):
    """held[key], made by make() (a tuple) with options appended when missing or made for other
    options (an id reused); held is emptied first when it has more than limit entries."""
    entry = held.get(key)
    if entry is None or entry[-1] is not options:
        if len(held) > limit:
            held.clear()
        entry = held[key] = make() + (options,)
    return entry


# A sparse step's Newton steps eliminate the pairs' closest-point blocks first (block_elimination.py)
# from this many unknowns. Below it the step's LU is not a material part of the step (10 bodies in a
# box, ~270 unknowns: a Newton step 0.12 ms eliminated against 0.18 ms whole, of a ~17 ms step);
# from ~450 it is (16 bodies: 0.22 against 0.37 ms; 27 superquadrics, ~720: 0.36 against 0.60 ms,
# 15 % of their contact step). Below it the whole LU also keeps the round-off that two of the
# suite's guards on the 10 bodies were measured with (tests/test_far_pairs.py counts contacts
# with p_n > 0, and one came out at 1.2e-32 N s instead of 0; tests/test_stability_cases.py's
# watch gain is 18 Newton iterations in 874, inside what a different factorisation moves).
ELIMINATE_MIN_UNKNOWNS = 500


def _solve_once(problem: StepProblem, z0, options: ncp.SolverOptions, sync: bool, stop=None) -> ncp.McpResult:
    if problem._sparse:
        problem._sync()
        blocks = closest_point_blocks(problem.layout) if problem.layout.n >= ELIMINATE_MIN_UNKNOWNS else None
        return ncp.solve_mcp(problem.fun_synced, problem.jac_synced, z0, problem.lower, problem.upper, options,
                             blocks=blocks, stop=stop)
    x0 = np.ascontiguousarray(z0, dtype=float)
    if x0.shape != problem.lower.shape or not math.isfinite(x0 @ x0) and not np.isfinite(x0).all():
        raise ValueError(f"the start of a step's solve must be a finite vector of {len(problem.lower)} entries")
    if sync:
        problem._sync()
    return _dense_solve(problem, x0, options, _NO_WEIGHT, _NO_WEIGHT)


_NO_WEIGHT = np.zeros(0)


def _solve_regularised_once(problem: StepProblem, x0, weight, centre, options: ncp.SolverOptions) -> ncp.McpResult:
    """MCP(F + weight (. - centre), l, u) from x0 on a dense problem, one compiled call
    (_solve_regularised): ncp.solve_proximal's inner solve, bit for bit the one its Python driver
    makes (tests/test_indeterminate_impulses.py). The case: the grasp study's squeezed part, whose
    proximal solves took 1-2 ms an iteration in Python against ~0.1 ms compiled."""
    return _dense_solve(problem, np.ascontiguousarray(x0, dtype=float), options,
                        np.ascontiguousarray(weight, dtype=float), np.ascontiguousarray(centre, dtype=float))


def _dense_solve(problem: StepProblem, x0, options: ncp.SolverOptions, weight, centre) -> ncp.McpResult:
    """_solve_regularised on a dense problem's tables and kept buffers (weight empty: _solve_dense's
    solve); the pairs' reports are left at the final iterate (F's: the regularisation adds none)."""
    buf, J, H, opt, _, _ = _buffers(problem, options)
    t = problem.tables
    R, p, w, vo, T, FL, JL, ws = problem._work
    _solve_regularised(t.body_i, t.body_f, t.body_jac, t.fpar, t.sk_i, t.sk_M, t.v0, t.hforce, t.pair_i, t.pair_f,
                       t.sup_i, t.sup_f, t.loc_idx, t.loc_off, t.scale, x0, problem.lower, problem.upper, opt,
                       buf.x, buf.F, buf.xt, buf.Ft, buf.Phi, buf.Phit, buf.d, buf.g, buf.da, buf.db, buf.zk, buf.Jz,
                       buf.history, buf.steps, buf.info, buf.fbuf, buf.work, J, H, problem._rep, R, p, w, vo, T, FL,
                       JL, ws, weight, centre)
    result = ncp.result_from_buffers(buf, options)
    problem._rep_at, problem._reports_np = (result.x.copy() if np.isfinite(result.residual) else None), None
    return result


def _buffers(problem: StepProblem, options: ncp.SolverOptions):
    """(ncp.Buffers, J, H, options array, options, their bundles.Solver) of one solve, kept with the
    problem per options."""
    def make():
        buf, J, H, opt = ncp.dense_buffers(problem.layout.n, options)
        bundle = bundles.solver(**{name: getattr(buf, name) for name in bundles.SOLVER_FIELDS if hasattr(buf, name)},
                                J=J, H=H, opt=opt)
        return buf, J, H, opt, bundle

    buf, J, H, opt, bundle, _ = _kept(problem.__dict__.setdefault("_solver_buffers", {}), id(options), options, 4,
                                      make)
    return buf, J, H, opt, options, bundle


def solver_bundles(problem: StepProblem, options: ncp.SolverOptions):
    """The bundles.Solver of a solve with options and of its polishing step (for
    repeat_kernels.step), and their ncp.Buffers."""
    main, polish = _buffers(problem, options), _buffers(problem, _polishing(problem, options))
    return main[5], polish[5], main[0], polish[0]


def _polishing(problem: StepProblem, options: ncp.SolverOptions) -> ncp.SolverOptions:
    """The polishing step's options (one Newton step at tol / 1000), kept with the problem."""
    held = problem.__dict__.setdefault("_polish_options", {})
    entry = held.get(id(options))
    if entry is None or entry[0] is not options:
        if len(held) > 4:
            held.clear()
        entry = held[id(options)] = (options, replace(options, tol=1e-3 * options.tol, max_iterations=1))
    return entry[1]


# the proximal weight of the impulse unknowns (solve(..., proximal=True); ncp.solve_proximal lowers it
# to the residual), in the rows' scaled units (impulses in their pair's unit s_p, rows scaled so that
# the solver's tol means the same on each). Measured with 1e-4, 1e-6, 1e-8: example-robot-data's a1
# landing on four calf boxes (t = 0.1 s, 114 unknowns) took 20, 17, 16 iterations; the four-legged
# tables of tests/test_indeterminate_impulses.py 2133, 2306, 2118 Newton iterations in 100 steps
# (mu = 1) and 4495, 3704, 3122 (mu = 0.3). No clear winner; the middle one
PROXIMAL_WEIGHT = 1e-6


def impulse_weights(problem: StepProblem, weight: float | None = None) -> np.ndarray:
    """weight (PROXIMAL_WEIGHT if None) on the contact impulses (p_n, friction, torsion) and the
    joint rows' impulses of a step problem, 0 on every other unknown (velocities, closest points,
    multipliers, sigma)."""
    weight = PROXIMAL_WEIGHT if weight is None else weight
    w = np.zeros(problem.layout.n)
    for sl in problem.layout.pairs:
        w[sl.p_n] = weight
        w[sl.p_t] = weight
        if sl.p_r >= 0:
            w[sl.p_r] = weight
    for cols in problem.layout.joint_index or ():
        w[cols] = weight
    return w


# The endgame (ncp.newton_min_map) after a solve that failed within ENDGAME_RESIDUAL of a
# solution, on problems of up to ENDGAME_MAX_UNKNOWNS unknowns (its steps are dense SVDs).
ENDGAME_RESIDUAL = 1e-4
ENDGAME_MAX_UNKNOWNS = 600


def solve(problem: StepProblem, z0, options: ncp.SolverOptions, sync: bool = True,
          proximal: bool = False, stop=None) -> ncp.McpResult:
    """The step's MCP from z0, polished (see the module docstring). sync: copy the pairs' k1 and
    tangent axes from their specs first (False: the tables already hold them). proximal: by
    ncp.solve_proximal with impulse_weights (impulses not unique: recovery.indeterminate_impulses),
    its outer steps from Python, each inner solve of a dense problem one compiled call. stop: ncp.solve_mcp's stop test, on a
    sparse problem (a dense solve is one compiled call and runs to its end); a solve it ends
    (HANDED_OVER) is returned as it is."""
    if proximal:
        inner = None
        if not problem._sparse:
            problem._sync()

            def inner(centre, weight, opts):
                return _solve_regularised_once(problem, centre, weight, centre, opts)
        result = ncp.solve_proximal(problem.fun, problem.jac, z0, problem.lower, problem.upper,
                                    impulse_weights(problem), options, inner=inner)
    else:
        result = _solve_once(problem, z0, options, sync, stop)
        if result.status is ncp.Status.HANDED_OVER:
            return result
    if not result.success and result.residual <= ENDGAME_RESIDUAL and problem.layout.n <= ENDGAME_MAX_UNKNOWNS:
        end = ncp.newton_min_map(problem.fun, problem.jac, result.x, problem.lower, problem.upper, options.tol)
        if end.success:
            result = replace(end, iterations=result.iterations + end.iterations,
                             steps=result.steps + end.steps, nfev=result.nfev + end.nfev, njev=result.njev + end.njev,
                             merit_history=result.merit_history)
    if result.success and result.residual > 1e-3 * options.tol:
        polish = _solve_once(problem, result.x, _polishing(problem, options), False)
        if polish.residual < result.residual:
            result = replace(result, x=polish.x, f=polish.f, residual=polish.residual,
                             iterations=result.iterations + polish.iterations)
        else:
            problem._rep_at = None
    return result
