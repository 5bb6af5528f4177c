"""What a step does when its first solve is not the answer: named recoveries, in order.

A step's MCP is solved from a warm start (the last step's solution carried along). After each
solve the stepper asks the recoveries below, in this order, whether the solution must be
corrected or the solve restarted; the first that applies arranges the next solve (a new start,
or new rows) and the step is solved again, up to MAX_SOLVES solves. A converged solve that no
recovery objects to is the step's answer; a failed solve that none can restart is a failed step
(the stepper's failure policy then takes over: halving h, see ImplicitContactStepper.step), and
so, mostly, is a step whose last allowed solve a recovery still wanted to restart (out_of_solves).

    recovery             applies to   the case that needed it                           guarding test
    friction_rows        any          a touching pair without friction rows, or a pair  tests/test_disc.py (slide to roll),
                                      with rows whose gap opened (sigma undetermined);  tests/test_spheres.py,
                                      a new pair that clearly slides starts sliding     tests/test_rigid3d.py::test_a_new_
                                      (27 superquadrics dropped into a box); rows taken contact_starts_its_friction_re_...,
                                      off and given back in a step stay (a robot's hand tests/test_recovery.py
                                      cycling on/off: icub_reduced)
    passed_through       converged    a body wholly through a fixed half-space: the     tests/test_rigid3d.py::test_fast_sphere_
                                      far-side root of eqs (15)-(19) (100 m/s sphere)   does_not_tunnel_through_a_half_space
    release_idle         failed       only pairs without impulse unconverged: parallel  tests/test_face_campaign.py::test_
                                      faces hovering within the tolerance have a whole  hovering_parallel_faces_are_released_
                                      face of closest points (a cylinder sliding on its and_certified
                                      cap); left out, then certified apart at the end
    indeterminate_       failed,      redundant contacts (impulses not unique): four    tests/test_indeterminate_impulses.py,
    impulses             near a       feet sticking (torsions, warp mode), a table's    tests/test_ncp.py (solve_proximal)
                         solution     four legs landing flat: Newton and LM crawl; the
                                      proximal point method on the impulses converges
    face_landing         failed       faces landing on faces: from p_n = 0 the moment   tests/test_face_contact.py::test_box_
                                      rows do not see the contact point (a box resting  started_down_flat_with_spin_lands_in_
                                      flat, started down at 5 m/s with spin)            one_step
    restart_sliding      failed       a re-solve after friction rows were added stalls  tests/test_spheres.py::test_start_from_
                                      in the FB valley of a contact that must slide     rest_at_small_h_needs_no_retry,
                                      (sigma = 0, friction outside the cone); such a    tests/test_stability_cases.py (10 bodies,
                                      re-solve is ended after 15 iterations if a pair   and ::test_watched_resolve_...)
                                      is stuck sliding (watched_solve)
    stray_friction       failed       friction left on a pair whose p_n went to 0 (its  tests/test_indeterminate_impulses.py::
                                      friction rows then hold any impulse at sigma = 0: test_stray_friction_...
                                      a quadruped's foot after its first impact)
    cold_start           failed       the warm start carried impulses an impact made    tests/test_articulated.py::test_pendulum_
                                      wrong (a pendulum leaving the obstacle it hit)    strikes_ellipsoid_without_penetration_...
    reseed               failed       Newton stalled on a polytope vertex that is no     tests/test_rigid3d.py::test_dart_box_
                                      longer the deepest (a box slapping flat)          dropped_on_an_edge_lands_flat_...
    resume_watched       failed       a solve watched_solve ended early would have      tests/test_face_campaign.py::test_
                                      converged and the sliding start does not (a prism resume_watched_...
                                      stack of the face campaign): go on with it
    friction_homotopy    failed       every other recovery gave up and friction is      tests/test_face_campaign.py::test_
                                      strong against the motion: Newton heads for far-  friction_homotopy_...
                                      off impulses (a tumbling double pendulum, mu = 1,
                                      a box dropped on a box at h = 1.65e-4); the step
                                      solved at 1/4, 1/2, 3/4 of mu starts the real one

On a sparse step problem a solve whose answer would only have its friction rows switched ends
before it converges (row_switch_test; status HANDED_OVER), and friction_rows switches them
(tests/test_stability_cases.py::test_a_solve_whose_rows_will_switch_is_handed_over_with_...).

Each recovery is a function (stepper, attempt, problem, result) -> None (does not apply), RETRY
(solve again as arranged on the attempt) or a failed McpResult that ends the step's solves;
``Attempt`` is the solve loop's state. The helpers below them (seeds from static
closest points, transfers of a solution between layouts) are shared by several recoveries.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import nnls

from . import formulation as fm
from . import landing
from . import ncp
from .rows import checks as rk
from .rows import contact as rc

MAX_SOLVES = 12     # solves per step (the recoveries below restart at most this often in all).
# 8 ran out at example-robot-data's icub (r_hand, t = 0.972 s) and g1_29dof_with_hand (left ankle,
# t = 0.604 s) at every halving; with 12 both complete their second, and four stacks of the face
# campaign need fewer halvings (tests/test_face_campaign.py::test_a_step_whose_recoveries_need_...).
RETRY = "retry"
TOUCH = 1e-9        # scaled normal impulse (units of the pair's s_p) above which a pair counts as touching


@dataclass
class Attempt:
    """The solve loop's state within one step (ImplicitContactStepper._solve_step).

    How the next solve starts, in this precedence: ``reseeded`` (a start vector) from static
    closest points; the warm start from the last step if ``previous`` is None (``cold``: without
    its impulses); else a transfer of ``previous`` (problem, x) to the new layout, sliding
    restarts for ``sliding``."""
    specs: list
    pairs: list
    tol: float
    solver_tol: float
    h: float
    body_pos: dict                                 # the step's context, for rebuilding pair specs
    states: list
    previous: tuple | None = None
    sliding: list = field(default_factory=list)
    added: list = field(default_factory=list)      # pairs given friction rows by the last re-solve
    restarts: int = 0                              # sliding restarts from the current previous
    reseeded: np.ndarray | None = None
    cold: bool = False
    cold_tried: bool = False
    through_reseeds: int = 0                       # passed_through's reseeds
    index: int = 0                                 # solves so far
    z0: np.ndarray | None = None
    joints: list = field(default_factory=list)     # per involved skeleton its JointRows or None
    landings: set = field(default_factory=set)     # face_landing tried without (False) / with friction
    released: dict = field(default_factory=dict)   # release_idle: (i, j) -> the spec it left out
    homotopy: bool = False                         # friction_homotopy tried
    state: object = None                           # the step's state (stepper._read), for friction_homotopy
    fresh_rows: bool = False                       # friction_rows just added rows: the next solve is watched
    watched: tuple | None = None                   # (solve index, problem, iterate) of a solve watched_solve ended
    resumed: bool = False                          # resume_watched went on with it
    proximal: bool = False                         # indeterminate_impulses: the next solve is proximal
    proximal_starts: tuple | None = None           # indeterminate_impulses: (problem, its starts not yet tried)
    strays: set = field(default_factory=set)       # stray_friction: the (problem id, pairs) it restarted
    handover: tuple = ((), ())                     # row_switch_test: (on, off) of the solve it ended
    handed: set = field(default_factory=set)       # row_switch_test: the pairs it switched in this step
    taken_off: set = field(default_factory=set)    # friction_rows: the pairs (spec keys) whose rows it took off
    returned: set = field(default_factory=set)     # ... and gave back later in this step (they keep them)
    articulated: bool = False                      # an articulated skeleton takes part (no row_switch_test)


def friction_rows(stepper, att: Attempt, problem, result):
    """Friction rows for every pair that touches, none for a pair whose gap is open.

    Rows are built for the pairs that touched at the last step; a pair without rows whose
    solution touches (p_n > 0) gets them, and a pair with rows whose solution has p_n = 0 loses
    them (sigma is then undetermined: a singular Jacobian; a converged solution with an open
    gap keeps its rows and is checked, |p_t| <= mu p_n, by the stepper). Solved again from the
    current solution (a transfer): a new pair sticking, unless it clearly slides (_clearly_sliding).
    A solve row_switch_test handed over (HANDED_OVER) is switched as it found, from its iterate.

    A pair whose rows were taken off and given back in this step keeps them: a converged solve
    in which it has rows and p_n = 0 is the step's answer (the friction rows are satisfied there;
    only sigma is undetermined). The case: example-robot-data's icub_reduced at t = 0.886 s (h / 16),
    whose hand touched the ground with p_n = 2e-3 s_p without friction rows and carried 1e-11 with
    them, the other contacts' friction holding the body: its rows went off and on for ten converged
    solves, until the eleventh stalled and the step failed (tests/test_recovery.py)."""
    specs = att.specs
    handed = result.status is ncp.Status.HANDED_OVER
    if handed:
        on, off = att.handover
        att.handed.update(on + off)
    else:
        flags = problem.checks(result.x, att.tol, att.solver_tol, TOUCH)
        # (not off at a failed iterate for the pairs the last re-solve gave rows: that re-solve is
        # the other recoveries' case, and taking the rows off again cycles on/off until MAX_SOLVES;
        # a box dropped onto a prism lying on a box)
        off = [k for k in range(len(specs)) if flags[k] & rk.OFF and (result.success or k not in att.added)
               and specs[k].key not in att.returned]
        on = [k for k in range(len(specs)) if flags[k] & rk.ON] if result.success else []
    if not (on or off):
        return None
    att.returned.update(specs[k].key for k in on if specs[k].key in att.taken_off)
    att.taken_off.update(specs[k].key for k in off)
    att.previous = (problem, result.x if result.success or handed else att.z0)
    att.sliding, att.restarts = _clearly_sliding(stepper, att, problem, result.x, on), 0
    att.added = on
    att.fresh_rows = bool(on)
    for k in on + off:
        specs[k].with_friction = k in on
    # the patches' torsion (stepper._share_patches), a new contact's along its solved normal
    solved = None
    if np.all(np.isfinite(result.x)):
        problem._evaluated_at(result.x)
        solved = [(p[1], p[2]) for p in problem._pairs_at]
    stepper._share_patches(specs, solved, set(on))
    return RETRY


SLIDE_RATIO = 10.0   # _clearly_sliding's threshold: slip over what friction can take away in a step


# row_switch_test: a solve whose friction rows will switch is handed to friction_rows once its natural
# residual is below HANDOVER_RESIDUAL and a pair clearly switches: one without rows whose scaled p_n
# exceeds HANDOVER_TOUCH, or one with rows whose scaled gap row exceeds HANDOVER_GAP (p_n -> 0).
HANDOVER_RESIDUAL = 1e-4
HANDOVER_TOUCH = 1e-3
HANDOVER_GAP = 1e-3


def row_switch_test(att: Attempt, problem):
    """ncp.solve_mcp's stop test for a solve whose answer friction_rows would only re-solve with
    other rows, or None where it does not apply (a dense problem, whose solve is one compiled call;
    a step with an articulated skeleton, below; the step's last allowed solve; no pair that could
    switch).

    A converged solve in which a pair without friction rows touches, or a pair with rows has p_n = 0,
    is not the step's answer: friction_rows switches those rows and solves again from it. The
    iterations that take such a solve from a residual of 1e-4 to 1e-10 are spent on an answer that
    is thrown away, and where a pair with rows opens they are a linear tail (eq 21 reads p_t sigma
    = 0 at p_n = 0 and Newton halves p_t and sigma together each iteration). So once the residual
    is below HANDOVER_RESIDUAL and a switch is clear (module constants above), the solve ends and
    friction_rows switches the rows it found (att.handover). A pair switched so is not looked at
    again in the step (no on/off cycle). Dense problems are solved by one compiled call and have
    no handover (their solves are short; the criterion would have to be compiled into the driver).
    Nor do steps with an articulated skeleton: a robot's contacts are often redundant (impulses not
    unique), and the re-solve from an iterate instead of a solution reaches another of them. On
    example-robot-data (comparisons.real_models --duration 1, 2 workers) with the handover, 44
    models completed, 8 failed and 8 were cut, against 43, 6 and 11 in the README's run without it:
    bolt (t = 0.697 s), centauro and pr2 failed, bolt in a step whose start the handover of the
    step before had moved; not shown better, so left out there.

    Measured (2026-12-07): on comparisons.bench_step's 27 superquadrics in a box (60 steps), 38
    converged solves had added rows after 564 Newton iterations, 190 of them spent below a residual
    of 1e-4 with the new pairs touching; with the handover the run took 1227 Newton iterations
    instead of 1806, its mean step 43 ms instead of 63 ms, its median 30.9 instead of 33.0 ms. Each
    of its 38 handed-over solves, run to its end, converged (one stopped short) with the same
    switches. On comparisons.stability's box scenes (16, 20, 27, 30 bodies, seeds 0 and 1, 100
    steps each): 18055 Newton iterations in 39 s against 23727 in 48 s (20987 handing over only
    the pairs that touch). Taking rows off at an iterate is no less sure than at a solution: 13
    of 118 pairs the handover took off got them back later in the step, against 12 of 143 taken
    off at converged solves without it (rows come back when a frictionless solve lets the body
    slide into the contact)."""
    if not problem._sparse or att.articulated or att.index >= MAX_SOLVES - 1 or not HANDOVER_RESIDUAL > 0.0:
        return None
    # (pair, column of its p_n): pairs that may get rows, pairs that may lose them
    may_on, may_off = [], []
    for k, (spec, sl) in enumerate(zip(att.specs, problem.layout.pairs)):
        if k in att.handed:
            continue
        if spec.with_friction:
            may_off.append((k, sl.p_n))
        elif spec.friction.mu > 0.0:
            may_on.append((k, sl.p_n))
    if not (may_on or may_off):
        return None

    def stop(x, F, residual):
        if not residual <= HANDOVER_RESIDUAL:
            return False
        on = [k for k, i in may_on if x[i] > HANDOVER_TOUCH]
        off = [k for k, i in may_off if F[i] > HANDOVER_GAP]
        if not (on or off):
            return False
        att.handover = (on, off)
        return True
    return stop


def _clearly_sliding(stepper, att: Attempt, problem, x, on) -> list:
    """Those of the pairs ``on`` (about to get friction rows) whose re-solve should start sliding
    (_transfer's sliding start) rather than sticking: their slip |v_t| in the solution x without
    friction is more than SLIDE_RATIO times mu p_n u_p, the slip that friction at the edge of the
    cone would take from the lighter body in one step (p_n in units of s_p = m u_p, u_p =
    max(h g, IMPULSE_SPEED): stepper._pair_spec). The ratio of a contact that sticks stays below
    the inverse effective mass's factor over 1/m (a rod struck at its end: 4 per body, 8 for two),
    so 10 leaves the sticking start to every contact that might stick (a ball at rest in a groove
    slips ~1e-4 m/s without friction at h = 1e-3: ratio ~0.02). The case: 27 superquadrics dropped
    into a box (comparisons.bench_step), where a contact brushing past at 0.2-1.3 m/s with a small
    p_n (ratios 14-7700 in steps 16-36) stalled its sticking start for SLIDING_WATCH iterations
    before restart_sliding restarted it sliding. Not a decision: the solve finds stick or slip."""
    if not on:
        return []
    u_p = stepper._impulse_speed(att.h)
    out = []
    for k in on:
        sl, spec = problem.layout.pairs[k], problem.specs[k]
        if spec.friction.mu <= 0.0:
            continue
        try:
            vt = problem.unpack_pair(x, k).tangents @ problem.relative_velocity(x, k)
        except (ZeroDivisionError, FloatingPointError, OverflowError):
            continue
        slip = float(np.sqrt(vt @ vt))
        if slip > SLIDE_RATIO * spec.friction.mu * max(x[sl.p_n], 0.0) * u_p:
            out.append(k)
    return out


def passed_through(stepper, att: Attempt, problem, result):
    """A body that went wholly through a fixed half-space inside the step (see
    _passed_through): re-seeded from static closest points, twice at most, then a failure."""
    if not result.success:
        return None
    through = _passed_through(problem, result.x, att.tol)
    if not through:
        return None
    if att.through_reseeds < 2:
        att.through_reseeds += 1
        att.reseeded = _reseed(problem, result.x, att.tol)
        return RETRY
    return replace(result, status=ncp.Status.LINE_SEARCH_FAILED, message=f"pairs {through} pass through a half-space")


# [scaled rows] indeterminate_impulses applies to a solve that stopped this close to a solution (the
# stalls it is for ended at 2e-7..1.5e-5; a landing 4-legged table whose solves failed at 1e-2..1
# needed other recoveries, and the proximal re-solve only cost it 50 more iterations a step)
NEAR_SOLUTION = 1e-4


# each regularised solve of indeterminate_impulses is watched at this iteration (ncp.SolverOptions.watch):
# Newton converges on one in a few iterations where the recovery applies, and a stalled one is its
# failure (measured on example-robot-data, 60 models: without the watch its failed proximal solves
# ran to their limit of 50-200 iterations, twice per set of rows)
PROXIMAL_WATCH = 15


def indeterminate_impulses(stepper, att: Attempt, problem, result):
    """A failed solve that stopped near a solution (NEAR_SOLUTION) with two or more touching pairs
    (or one and joint rows): solve the same rows again by the proximal point method on the
    impulses (ncp.solve_proximal, step_solver.impulse_weights), first from where the solve stopped,
    then from its start; twice at most per set of rows.

    Where contacts are (nearly) redundant their impulses are not unique: four feet sticking on the
    ground fix the body's yaw through their tangential rows, so their four torsion impulses have a
    3D null space, and nearly straight legs leave the normal impulses' warp mode (+ - + -) and the
    feet's squeeze modes with singular values of 1e-9..1e-5 against rows of O(1); a leg's calf box
    and foot sphere both touching share one tangential impulse. Newton's direction then fails
    the descent test, and Levenberg-Marquardt, damped by 1e-2 ||Phi|| (~1e-8) against H^T H's
    1e-12 there, crawls: example-robot-data's a1 landing on its four calf boxes stalled at natural
    residuals 2e-7..6e-6 after 200 iterations at every h down to h / 16; the proximal re-solve from
    that solve's start converged in 3 proximal steps and 17 iterations (from where it stopped it
    stalled again). A four-legged table landing flat (tests/test_indeterminate_impulses.py): its
    frictionless solve stalled at 4e-5 with p_n = (21, 0, 0, 24) and the proximal re-solve from
    there converged in 2 proximal steps. Far from a solution the trouble is elsewhere (that
    table's solves that failed at 1e-2..1 needed the other recoveries; a proximal re-solve from
    the start cost 50 iterations each time and solved none)."""
    if result.success or not result.residual <= NEAR_SOLUTION:
        return None
    touching = sum(1 for sl in problem.layout.pairs if result.x[sl.p_n] > TOUCH)
    joint_rows = any(len(c) for c in problem.layout.joint_index or ())
    if touching + joint_rows < 2:
        return None
    if att.proximal_starts is None or att.proximal_starts[0] is not problem:
        # first from where the solve stalled, then from its start; anew for other rows
        att.proximal_starts = (problem, [result.x, att.z0])
    starts = att.proximal_starts[1]
    if not starts:
        return None
    att.proximal = True
    att.reseeded = starts.pop(0)
    return RETRY


def face_landing(stepper, att: Attempt, problem, result):
    """A failed solve with faces landing on faces: restart from the landing predictor
    (landing.py: the patch's vertices in a small LCP give the ECP, the impulse and the
    velocities; with Coulomb discs if the pair has friction rows), with the closest points at the
    ECP and their multipliers there; once without and once with friction rows. From p_n = 0 the
    moment rows do not see the contact point, and Newton wanders (a box resting flat, started
    downwards at 5 m/s with spin); with friction the impact's friction moment moves the ECP
    (a tall box landing with spin)."""
    if result.success:
        return None
    pairs = landing.faceted_pairs(problem)
    friction = any(problem.specs[k].with_friction for k in pairs)
    if not pairs or friction in att.landings:
        return None
    att.landings.add(friction)
    z0 = att.z0
    problem._evaluated_at(z0)
    velocities, predicted = landing.predict(problem, pairs, att.h, friction)
    if not any(predicted.values()):
        return None
    z = z0.copy()
    for s, v in velocities.items():
        z[problem.layout.v_index[s]] = v
    for k, found in predicted.items():
        if found is None:
            continue
        spec, sl = problem.specs[k], problem.layout.pairs[k]
        poses = problem.end_poses(z, spec)
        l1, l2, s = _multipliers(spec, poses[0], poses[1], found.x_end, found.x_end, problem._pairs_at[k][2])
        problem.pack_points(z, k, found.x_end, found.x_end)
        s_p = spec.impulse_scale
        _put_multipliers(z, sl, l1, l2, s)
        z[sl.p_n] = found.P / s_p
        if sl.sigma >= 0:
            fr = spec.friction
            z[sl.p_ts] = found.p_to / s_p
            slip = [fr.e_t * found.slip[0], fr.e_o * found.slip[1]]
            if sl.p_r >= 0:
                z[sl.p_r] = found.m_r / (s_p * fr.e_r)
                slip.append(fr.e_r * found.spin)
            z[sl.sigma] = float(np.linalg.norm(slip))
    att.reseeded = z
    return RETRY


def restart_sliding(stepper, att: Attempt, problem, result):
    """A failed solve from a frictionless solution: restart the stuck contacts sliding; if that
    finds none or fails, also the pairs that just got friction rows while slipping in the
    frictionless solution (a contact brushing past a wall at 1 m/s with a tiny p_n slides, and
    from a sticking start Newton stalls with the friction far outside the cone). Not at once: a
    ball starting from rest in a groove (Example 2 at h = 1e-3) slips ~1e-4 m/s in the
    frictionless solution but must roll. The solves it may follow are watched (watched_solve)."""
    if result.success or att.previous is None or att.restarts >= 2:
        return None
    att.restarts += 1
    more = set(att.sliding) | set(_stuck_sliding(problem, result.x))
    if more == set(att.sliding):
        more |= set(_slipping(*att.previous, att.added))
        att.restarts = 2
    if more == set(att.sliding):
        return None
    att.sliding = sorted(more)
    return RETRY


SLIDING_WATCH = 15      # the iteration at which a re-solve restart_sliding may follow is looked at
WARM_WATCH = 20         # the iteration at which the step's first solve (from the warm start) is looked at


def watched_solve(stepper, att: Attempt, problem, z0):
    """The solve of the step's MCP from z0 (stepper._solve), two of them watched
    (ncp.SolverOptions.watch: ended at a given iteration if not converged and stalled):

    * the step's first solve, from the warm start, at WARM_WATCH iterations: stalled there, it
      ends and the recoveries take over as after any failed solve (cold_start, friction_rows,
      ...); if they fail too, resume_watched goes on with it. The case: on the superquadric boxes
      of comparisons.stability (16, 20, 27 and 30 bodies, 210 steps each) warm solves that
      stalled ran to their limit of 50 iterations and then a cold start converged in 10-20:
      42377 Newton iterations and 127 s in all without the watch, 32380 and 94 s with it (15:
      36121, 30: 31846; the scenes are chaotic, so each count moves by a few thousand with any
      change). Guarded by tests/test_stability_cases.py::test_a_stalled_warm_solve_hands_over_at_the_watch.
    * the re-solve right after friction_rows added rows, which restart_sliding may follow, at
      SLIDING_WATCH iterations: not converged, stalled and with a pair stuck sliding (sigma ~ 0,
      friction outside the cone), it ends there and restart_sliding takes over (if that and the
      recoveries after it fail, resume_watched goes on with it); otherwise it goes on from its
      iterate to the iteration limit. The case: such re-solves stall in the FB valley for the
      whole limit and then restart_sliding solves the step in a few iterations. Measured on 27
      exponent-4 superquadrics dropped into a walled box (comparisons.bench_step's scene), 60
      steps: 28 solves ran to their limit of 50 iterations, 1700 of the 3237 Newton iterations.
      With the watch, comparisons.stability's box scenes (16, 20, 27 and 30 superquadrics, 210
      steps) took 8544 Newton iterations instead of 10808 (the face campaign's counts did not
      change). Guarded by
      tests/test_stability_cases.py::test_watched_resolve_hands_a_stalled_sticking_start_to_restart_sliding_sooner."""
    fresh, att.fresh_rows = att.fresh_rows, False
    if att.proximal:
        att.proximal = False
        return stepper._solve(problem, z0, watch=PROXIMAL_WATCH, proximal=True)
    stop = row_switch_test(att, problem)
    limit = stepper._solver_options().max_iterations
    if att.index == 0 and not fresh and att.watched is None and not att.resumed and 0 < WARM_WATCH < limit:
        result = stepper._solve(problem, z0, watch=WARM_WATCH, stop=stop)
        if result.status is ncp.Status.MAX_ITERATIONS and result.iterations == WARM_WATCH:
            att.watched = (att.index, problem, result.x)
        return result
    # (one re-solve is watched a step; a watched first solve gives way to it in att.watched)
    if not fresh or (att.watched is not None and att.watched[0] > 0) or att.resumed or SLIDING_WATCH <= 0:
        return stepper._solve(problem, z0, stop=stop)
    result = stepper._solve(problem, z0, watch=SLIDING_WATCH, stop=stop)
    if not (result.status is ncp.Status.MAX_ITERATIONS and result.iterations == SLIDING_WATCH < limit):
        return result
    if _stuck_sliding(problem, result.x):
        att.watched = (att.index, problem, result.x)
        return result
    # stalled with no pair stuck sliding: restart_sliding has nothing to restart, go on
    rest = stepper._solve(problem, result.x, sync=False, limit=limit - result.iterations, stop=stop)
    return replace(rest, iterations=result.iterations + rest.iterations)


def resume_watched(stepper, att: Attempt, problem, result):
    """A step whose solve watched_solve ended early, and that restart_sliding, cold_start and reseed
    could not solve either: go on from the watched solve's iterate, unwatched, with no more sliding
    restarts. The case: the face campaign's prism stack 4105566614 (its first step fails without
    it), whose stalled sticking start converges within the iteration limit and whose sliding start
    does not. Late in the order: placed right after restart_sliding, it made comparisons.stability's
    box scenes take 13708 Newton iterations instead of 8694 (measured with a looser stall test),
    where cold_start and reseed get through sooner. Guarded by
    tests/test_face_campaign.py::test_resume_watched_goes_on_with_a_solve_the_watch_ended."""
    if result.success or att.watched is None or att.watched[0] == att.index:
        return None
    _, watched_problem, x = att.watched
    att.watched, att.resumed = None, True
    att.previous, att.sliding, att.restarts = (watched_problem, x), [], 2
    return RETRY


def out_of_solves(att: Attempt, problem, result):
    """The step's answer when every one of its MAX_SOLVES solves ended with a recovery asking for
    another. A converged last solve stands if the attempt still has the problem's pairs: the
    recoveries that object to a converged solve switch friction rows (friction_rows: a pair whose
    p_n flips between 0 and > 0 from one solve to the next cycles until the solves run out;
    example-robot-data's icub_reduced at t = 0.877 s) or re-seed a body that passed through a
    half-space (passed_through, which fails on its own after two). Otherwise the step fails: the
    last solve did not converge, or a recovery changed the pairs after it (icub at t = 0.927 s:
    release_idle left pairs out after the last solve, and the failure report then indexed the
    attempt's shorter pair list with the problem's pairs: IndexError)."""
    if result.success and [sp.key for sp in att.specs] == [sp.key for sp in problem.specs]:
        return result
    status = ncp.Status.MAX_ITERATIONS if result.success else result.status
    return replace(result, status=status, message=f"{result.message} {OUT_OF_SOLVES}")


OUT_OF_SOLVES = (f"the recoveries asked for more than {MAX_SOLVES} solves in this step (each changed the rows "
                 "or the start, none gave an answer they accept)")


def cold_start(stepper, att: Attempt, problem, result):
    """The warm start carried last step's impulses; after an impact they can be far from this
    step's (a pendulum stopped by an obstacle leaves it again: p_n = 0) and Newton stalls. Start
    once more as new contacts do: free-flight velocities, zero impulses, no friction rows (they
    come back for the pairs that touch)."""
    if result.success or att.cold_tried:
        return None
    if not any(sp.key in stepper._last and stepper._last[sp.key]["p_n"] > 0.0 for sp in att.specs):
        return None
    att.cold = att.cold_tried = True
    att.previous, att.sliding, att.restarts = None, [], 0
    for sp in att.specs:
        sp.with_friction = False
    return RETRY


def release_idle(stepper, att: Attempt, problem, result):
    """A failed solve in which every row has converged except the closest-point rows of pairs
    that carry no impulse: leave those pairs out and solve again.

    The closest points of a pair without impulse do not enter the dynamics, and when two flat
    faces hover parallel within the contact tolerance they are a whole face: the KKT Jacobian is
    singular and Newton can stall on them for good (example-robot-data's laikago: a calf box's end
    face 1e-6 m over the ground box, natural residual 8e-8 on its points after 1000 iterations
    while every other row was at 2e-11; the step failed at every h the retry policy tried). The
    re-solve must keep each released pair apart: at its end poses the static closest points
    (closest.py, a convex problem) must find it apart (gap >= 0), else the step fails
    (ImplicitContactStepper._released_contacts). Once per step, order 1 only (order 2's first
    stage has no such check)."""
    if result.success or att.released or not _gi_step(stepper):
        return None
    idle = _idle_stalled(problem, result, att.solver_tol)
    if not idle:
        return None
    keep = [k for k in range(len(att.specs)) if k not in idle]
    att.released = {att.pairs[k]: att.specs[k] for k in idle}
    att.previous = (problem, result.x)
    att.specs, att.pairs = [att.specs[k] for k in keep], [att.pairs[k] for k in keep]
    att.sliding, att.restarts, att.added = [], 0, []
    return RETRY


def reseed(stepper, att: Attempt, problem, result):
    """Restart from exact closest points at the poses the failed iterate implies: Newton on the
    KKT rows of a polytope can stall on a vertex that is no longer the deepest one (a box
    slapping flat turns its contact point over to the far edge within one step); the static
    problem is convex and its solver finds the right vertex, face or deepest point. At most in
    the first five solves."""
    if result.success or att.index >= 5:
        return None
    att.reseeded = _reseed(problem, result.x, att.tol)
    return RETRY


def _gi_step(stepper) -> bool:
    """Whether the step being solved is [GI]'s (order 1, or order 2's fallback to it): the
    recoveries that re-solve without or around the step's rows apply only there."""
    return stepper.options.order == 1 or stepper._order1_fallback


# the fractions of every pair's mu at which friction_homotopy solves the step before solving it
HOMOTOPY = (0.25, 0.5, 0.75)


def friction_homotopy(stepper, att: Attempt, problem, result):
    """The last resort of a failed solve with friction: solve the step with every pair's mu scaled
    by 1/4, 1/2 and 3/4 in turn, each stage from the last one's iterate (the first from the warm
    start), and start the step's own solve from the last stage.

    Where friction is strong against the motion, Newton from the warm start can head for far-off
    impulses and stall there. example-robot-data's double_pendulum (free base, tumbling on the
    ground at 9.7 rad/s, mu = 1): one step after link 2 hit the ground, the iterates held normal
    impulses of 250-440 h m g with the friction on its cone and sigma = 0, natural residual 2.75, at
    every h the retry policy tried; the same run with mu = 0.3 completes. At a quarter of mu the
    step converges, and each stage starts the next within Newton's reach; a stage that fails
    still hands on its last iterate (measured: the stages at 1/4 and 1/2 of mu failed and the one
    at 3/4 converged from there, then the step itself in one iteration). The stages are solves
    like any other (the step's iteration budget counts them) and only their start is kept: the
    step's answer is the step's own solve, judged as always. Once per step, when a solve remains,
    order 1 only (order 2's first stage keeps its own policy)."""
    if result.success or att.homotopy or att.index >= MAX_SOLVES - 1 or not _gi_step(stepper):
        return None
    if not any(sp.with_friction and sp.friction.mu > 0.0 for sp in att.specs):
        return None
    att.homotopy = True
    z = stepper._friction_stages(att, HOMOTOPY)
    if z is None:
        return None
    att.reseeded = z
    return RETRY


def stray_friction(stepper, att: Attempt, problem, result):
    """A failed solve that left friction on a pair without normal impulse (p_n <= TOUCH, its
    friction outside the cone at sigma ~ 0: _stuck_sliding): restart from that iterate with those
    pairs' friction impulses zeroed and sigma at their slip, once per such set of pairs and rows.

    With p_n = 0 a pair's friction rows e^2 mu p_n (t . v_rel) + p_t sigma = 0 hold for any
    friction impulse at sigma = 0, and only the cone row, quadratic in p_t, pulls it back: Newton
    crawls. p_t = 0 with sigma at the slip is the sliding state such a pair has at p_n = 0. The
    case: example-robot-data's anymal-kinova at t = 0.106 s, a foot that touched in the
    frictionless solve got friction rows (friction_rows), and its re-solve lowered the foot's p_n
    to 0 with a scaled friction impulse of 3.6e-3 left: every recovery and halving stalled at
    natural residuals 1e-3..5e-4, and the step failed; from that iterate with the foot's friction
    zeroed the solve converged in 11 iterations."""
    if result.success or not np.all(np.isfinite(result.x)):
        return None
    x = result.x
    stray = tuple(k for k in _stuck_sliding(problem, x) if x[problem.layout.pairs[k].p_n] <= TOUCH)
    if not stray or (id(problem), stray) in att.strays:
        return None
    att.strays.add((id(problem), stray))
    z = x.copy()
    for k in stray:
        sl = problem.layout.pairs[k]
        try:
            z[sl.sigma] = _slip(problem, x, k, problem.specs[k].friction, sl.p_r >= 0)[3]
        except (ZeroDivisionError, FloatingPointError, OverflowError):
            return None
        z[sl.p_t] = 0.0
        if sl.p_r >= 0:
            z[sl.p_r] = 0.0
    att.reseeded = z
    return RETRY


RECOVERIES = (friction_rows, passed_through, release_idle, indeterminate_impulses, face_landing, restart_sliding,
              stray_friction, cold_start, reseed, resume_watched, friction_homotopy)


# ---------------------------------------------------------------------------------------------
# seeds and transfers
# ---------------------------------------------------------------------------------------------
def _multipliers(spec, P1, P2, a1, a2, normal, gradients=None):
    """KKT multipliers of eqs (15)-(16)/(28n)-(29n) consistent with given closest points:
    (l1, l2, s), s the scaled distance of a cone-form pair (rows/contact.py), else None.

    hat-l (eqs 24-25) by non-negative least squares on the gradients, then scaled: body 1 one
    function, the paper's l1 = hat-l (eq 15); an intersection, the cone form's l_i = hat-l_i /
    sum hat-l and s = sum hat-l. Touching points use the normal instead of a2 - a1.
    gradients: the functions' world gradients (G1 (m1, d), G2 (m2, d)) at a1 and a2 if known
    (ImplicitContactStepper._seed_pairs), else evaluated at the poses P1, P2."""
    if gradients is None:
        _, G1 = fm.eval_functions(spec.obj1.functions, P1, a1)
        _, G2 = fm.eval_functions(spec.obj2.functions, P2, a2)
    else:
        G1, G2 = gradients
    d = a2 - a1
    touching = np.linalg.norm(d) <= 1e-12
    if spec.cone_form:
        lam, _ = nnls(G1.T, normal if touching else d)
        total = float(lam.sum())
        if total <= 0.0:         # no cone combination: the function nearest to active
            f1, _ = fm.eval_functions(spec.obj1.functions, P1, a1)
            lam, total = np.zeros(len(G1)), 1.0
            lam[int(np.argmax(f1))] = 1.0
        l1 = lam / total
        s = 0.0 if touching else total
    else:                        # one function: N1 = grad f(a1), l1 = hat-l (0 when touching)
        l1 = np.zeros(1) if touching else nnls(G1.T, d)[0]
        s = None
    N1 = G1[0] if s is None else l1 @ G1
    l2, _ = nnls(G2.T, -N1)
    if spec.obj1.fixed_halfspace:
        l1 = np.array([float(np.linalg.norm(d))])
    if spec.obj2.fixed_halfspace:
        l2 = np.array([float(np.linalg.norm(N1) / np.linalg.norm(G2[0]))])
    return l1, l2, s


def _put_multipliers(z, sl, l1, l2, s):
    """A pair's multipliers (and a cone-form pair's scaled distance s) into z at its slots sl."""
    z[sl.l1s] = l1
    z[sl.l2s] = l2
    if sl.s >= 0:
        z[sl.s] = s


def _static_seed(problem, x, spec, tol, always=False):
    """(a1, a2, l1, l2, s) of pair ``spec`` from the static closest points at the poses the
    iterate x of ``problem`` implies (touching pieces: the central touch point; a body through a
    fixed half-space: its point below the plane); None if the static solve fails, unless always
    (then _closest_seed's fallbacks)."""
    from .closest import closest_points
    P = problem.end_poses(x, spec)
    first, second = spec.objects
    res = (_closest_seed if always else closest_points)(first.piece, (P[0].R, P[0].p), second.piece, (P[1].R, P[1].p))
    if not res.success and not always:
        return None
    a1, a2 = np.asarray(res.a1, float), np.asarray(res.a2, float)
    normal = np.asarray(res.normal, float)
    if res.overlapping or res.distance <= tol:
        a1 = a2 = _central_touch_point(spec, P[0], P[1], a1, normal, tol)
    deepest = _below_plane_seed(spec, P) if res.overlapping else None
    if deepest is not None:
        a1, a2, normal = deepest
    return (a1, a2) + _multipliers(spec, P[0], P[1], a1, a2, normal)


def _swap_into(old, x, new, z, seeds, src=None):
    """The pairs in seeds (k -> (a1, a2, l1, l2, s) in the new frame) swapped bodies 1 and 2
    between old and new: their points and multipliers from the seeds, their impulses mapped.
    With n' = -n the Gram-Schmidt tangents are t' = t, o' = -o, and the impulse on the new body 2
    is minus the old one on body 2: p_n' = p_n, p_t' = -p_t, p_o' = p_o, p_r' = p_r; sigma is
    unchanged."""
    for k, (a1, a2, l1, l2, s) in seeds.items():
        ko = k if src is None else src[k]
        so, sn = old.layout.pairs[ko], new.layout.pairs[k]
        new.pack_points(z, k, a1, a2)
        if sn.s >= 0 and s is None:          # a cone-form pair: s from the points (a start only)
            s = float(np.linalg.norm(np.asarray(a2) - np.asarray(a1)))
        _put_multipliers(z, sn, l1, l2, s)
        z[sn.p_n] = x[so.p_n] * old.specs[ko].impulse_scale / new.specs[k].impulse_scale
        if sn.sigma >= 0 and so.sigma >= 0:
            flip = np.array([-1.0, 1.0][: len(sn.p_t)])
            z[sn.p_t] = flip * x[so.p_t] * old.specs[ko].impulse_scale / new.specs[k].impulse_scale
            if sn.p_r >= 0 and so.p_r >= 0:
                z[sn.p_r] = x[so.p_r]
            z[sn.sigma] = x[so.sigma]


def _transfer(old, x, new, sliding=()) -> np.ndarray:
    """Warm start of a re-solve whose pairs gained or lost friction rows: copy what both layouts
    share. New friction rows start at zero impulse and zero slip multiplier, except for the pairs
    in ``sliding``, which start at the sliding solution that the old solution's slip implies
    (p_f = -mu p_n E^2 v_t / sigma, sigma = |E v_t|). Measured on Example 2: from the wrong one of
    the two starts the FB merit crawls along a non-solution valley (a sliding contact held at
    sigma = 0 with its friction outside the cone), from the right one Newton converges at once.
    A pair whose bodies are in the other order in new gets old's points, multipliers and
    impulses in the swapped frame (_swap_into); measured: example-robot-data's solo.urdf, a
    46-plane foot hull against the ground box, raised a shape mismatch here when a friction
    re-solve followed a swap (the recovery that swapped the bodies of two intersections, for
    [GI]'s k1, is gone with the cone form; the transfer keeps the case)."""
    z = np.zeros(new.layout.n)
    index = {key: k for k, key in enumerate(old.keys)}
    src, swapped = {}, {}             # new pair -> old pair (release_idle leaves pairs out)
    for k, kn in enumerate(new.keys):
        if kn in index:
            src[k] = index[kn]
        elif kn[::-1] in index:
            src[k] = index[kn[::-1]]
            st = old.unpack_pair(x, src[k])
            swapped[k] = (st.a2, st.a1, st.l2, st.l1, None)
    for a, b in zip(old.layout.v_index, new.layout.v_index):
        z[b] = x[a]
    for so, sn in zip(old.layout.supports, new.layout.supports):
        z[sn.rows] = x[so.rows]
    for a, b in zip(old.layout.joint_index, new.layout.joint_index):
        z[b] = x[a]
    for k, sn in enumerate(new.layout.pairs):
        if k in swapped or k not in src:
            continue
        ko = src[k]
        so = old.layout.pairs[ko]
        for name in ("a1", "a2", "l1", "l2"):
            z[getattr(sn, name)] = x[getattr(so, name)]
        z[sn.p_n] = x[so.p_n]
        for name in ("dbar", "dn", "p_nr", "s"):
            if getattr(sn, name) >= 0 and getattr(so, name) >= 0:
                z[getattr(sn, name)] = x[getattr(so, name)]
        if sn.sigma < 0:
            continue
        if so.sigma >= 0 and k not in sliding:   # both layouts have this pair's friction rows
            z[sn.p_t], z[sn.sigma] = x[so.p_t], x[so.sigma]
            if sn.p_r >= 0 and so.p_r >= 0:      # (a shared pair's patch torsion comes and goes)
                z[sn.p_r] = x[so.p_r]
            continue
        if k not in sliding:
            continue
        spec = new.specs[k]
        e, vt, spin, sigma = _slip(old, x, ko, spec.friction, sn.p_r >= 0)
        if sigma > 0.0:
            z[sn.p_t] = -spec.friction.mu * x[so.p_n] * e**2 * vt / sigma
            if sn.p_r >= 0:
                z[sn.p_r] = -spec.friction.mu * x[so.p_n] * spin / sigma
        z[sn.sigma] = sigma
    _swap_into(old, x, new, z, swapped, src)
    return z


def _slip(problem, x, k, friction, torsion):
    """Pair k's slip at x: (e, v_t, spin, sigma), e its friction ellipse's (d-1) semi-axes, v_t the
    tangential relative velocity, spin = e_r (n . w_rel) with torsion rows (else 0), and sigma
    = |(e v_t, spin)|, the slip multiplier of a sliding contact (eq 21)."""
    st = problem.unpack_pair(x, k)
    vt = st.tangents @ problem.relative_velocity(x, k)
    e = np.array([friction.e_t, friction.e_o][: st.normal.shape[0] - 1])
    spin = friction.e_r * float(st.normal @ problem._rep[k, rc.R_WREL:rc.R_WREL + 3]) if torsion else 0.0
    return e, vt, spin, float(np.sqrt(np.sum((e * vt) ** 2) + spin * spin))


def _idle_stalled(problem, result, tol) -> list:
    """Pairs without impulse (p_n <= TOUCH) holding all of a failed iterate's natural residual
    above tol: every row outside them is converged, and at least one of theirs is not, but not
    their gap row (p_n = 0 with a gap below -tol is a contact the iterate has not found yet)."""
    x, F = result.x, result.f
    if not np.all(np.isfinite(F)):
        return []
    nat = np.abs(x - np.clip(x - F, problem.lower, problem.upper))
    inside = np.zeros(len(x), bool)
    stalled = []
    for k, sl in enumerate(problem.layout.pairs):
        if x[sl.p_n] > TOUCH or problem.specs[k].compliance is not None or nat[sl.p_n] > tol:
            continue
        rows = sl.columns
        inside[rows] = True
        if nat[rows].max() > tol:
            stalled.append(k)
    if not stalled or nat[~inside].max(initial=0.0) > tol:
        return []
    return stalled


def _stuck_sliding(problem, x) -> list:
    """Pairs held at sigma ~ 0 with their friction outside the cone: the FB valley of a contact
    that must slide (see _transfer). No pairs at an iterate where the rows are undefined (a failed
    solve that raised inside the rows returns its start)."""
    try:
        F = problem.fun(x)
    except (ZeroDivisionError, FloatingPointError, OverflowError):
        return []
    out = []
    for k, sl in enumerate(problem.layout.pairs):
        if sl.sigma >= 0 and F[sl.sigma] < 0.0 and x[sl.sigma] < -F[sl.sigma]:
            out.append(k)
    return out


def _slipping(problem, x, pairs) -> list:
    """Those of ``pairs`` whose tangential relative velocity at x is not zero."""
    out = []
    for k in pairs:
        try:
            vt = problem.unpack_pair(x, k).tangents @ problem.relative_velocity(x, k)
        except (ZeroDivisionError, FloatingPointError, OverflowError):
            continue
        if np.any(vt != 0.0):
            out.append(k)
    return out


# closest points that only seed a step's MCP (which polishes them) need not meet the static
# solver's own tolerance (1e-12 L); 1e-9 L is a seed well inside Newton's quadratic basin
_SEED_TOL = 1e-9


def _closest_seed(piece1, pose1, piece2, pose2):
    """Static closest points as a seed of a new pair, never NaN.

    closest_points at its default tolerance; if that fails, again at _SEED_TOL; if that fails
    too, the support points along the line between the pieces' interior points (the normal
    along that line). Measured (comparisons.stability, 10 bodies in a box): two exponent-4
    superquadrics lying flat side by side, 4 cm apart, whose equators are coplanar to round-off
    (both rest exactly on the floor): the surfaces have zero curvature there, the KKT Jacobian is
    singular and Newton stops at a natural residual 3.5e-10 L > 1e-12 L; the seed was NaN and the
    step raised in nnls. At 1e-9 the same solve is accepted and the step's MCP converges."""
    from .closest import ClosestPointOptions, closest_points
    res = closest_points(piece1, pose1, piece2, pose2)
    if res.success:
        return res
    relaxed = ClosestPointOptions(solver=ncp.SolverOptions(tol=_SEED_TOL, max_iterations=60))
    res = closest_points(piece1, pose1, piece2, pose2, relaxed)
    if res.success:
        return res
    (R1, p1), (R2, p2) = pose1, pose2
    c1, c2 = R1 @ piece1.interior_point + p1, R2 @ piece2.interior_point + p2
    d = c2 - c1
    d = d / np.linalg.norm(d) if np.any(d) else np.eye(len(d))[0]
    points = []
    for piece, (R, p), c, u in ((piece1, pose1, c1, d), (piece2, pose2, c2, -d)):
        try:
            points.append(R @ piece.support(R.T @ u) + p)
        except (NotImplementedError, ValueError):
            points.append(c)
    # a flat face towards the other piece: the other's support point projected onto it (the
    # support point of a box along a direction a little off its face normal is a corner: a
    # cylinder lying 50 um above a ground box was seeded at the ground's corner 2.9 m away)
    for k, (piece, pose, u) in enumerate(((piece1, pose1, d), (piece2, pose2, -d))):
        face = _face_projection(piece, pose, u, points[1 - k])
        if face is not None:
            points[k] = face[0]
            d = face[1] if k == 0 else -face[1]
            break
    return replace(res, a1=points[0], a2=points[1], normal=d,
                   distance=float(np.linalg.norm(points[1] - points[0])))


def _face_projection(piece, pose, u, x):
    """(x projected onto the piece's half-space face whose world normal is nearest u, that
    normal), if the projection lies on the piece (to 1e-9 of its size); else None."""
    R, p = pose
    best = None
    for f in piece.functions:
        if hasattr(f, "plane") and f.dim == len(u):
            normal, offset = f.plane()
            nw = R @ normal
            if best is None or nw @ u > best[0] @ u:
                best = (nw, offset + nw @ p)
    if best is None:
        return None
    nw, off = best
    y = x - (x @ nw - off) * nw
    values, _ = fm.eval_functions(piece.functions, fm.Pose(R, p, np.zeros(3)), y)
    scale = piece.length_scale if np.isfinite(piece.length_scale) else 1.0
    return (y, nw) if np.max(values) <= 1e-9 * scale else None


def _central_touch_point(spec, P1, P2, a, normal, tol):
    """Warm start of a touching pair: the touching point nearest the bodies' centres.

    Flat on flat (a box on the ground) touches along a whole face and the static solver returns
    any point of it, often a corner; Newton then has to walk the point across the face through a
    nearly singular system. The point where the dynamics will put it is near the projection of the
    moving body's centre onto the tangent plane, so that projection is used when it lies on both
    surfaces (to tol); otherwise the static solution is kept."""
    centres = [P.p for P, body in ((P2, spec.obj2), (P1, spec.obj1)) if not body.fixed_halfspace]
    if len(centres) == 2:
        centres.append(0.5 * (centres[0] + centres[1]))
    for c in centres:
        x = c - ((c - a) @ normal) * normal
        f1, _ = fm.eval_functions(spec.obj1.functions, P1, x)
        f2, _ = fm.eval_functions(spec.obj2.functions, P2, x)
        if abs(np.max(f1)) <= tol and abs(np.max(f2)) <= tol:
            return x
    return a


def _passed_through(problem, x, tol) -> list:
    """Pairs against a fixed half-space whose free multiplier l2 is not positive.

    With a fixed half-space's point reduced onto its plane, the pair 0 <= l2 _|_ -g(a2) is
    trivial and l2 is free ([GI] Example 1). A body that passes wholly through the half-space in
    one step then has a spurious solution: a1 on its far side (grad f along +n, l2 = -|grad f|),
    a2 its projection on the plane, gap >= 0 and no impulse: tunnelling. A valid contact has
    grad f(a1) along -n, i.e. l2 > 0. (A fixed half-space as body 1 needs no check: body 2's
    multipliers are bounded and its point must then face the plane, and the gap row keeps it
    above.) The test is rows/checks.py's THROUGH."""
    flags = problem.checks(x, tol, 0.0, TOUCH)
    return [k for k in range(len(flags)) if flags[k] & rk.THROUGH]


def _below_plane_seed(spec, P):
    """Seed (a1, a2, normal) of a body overlapping a fixed half-space: its support point along
    -n (its deepest point below the plane) and that point's projection on the plane; None when
    neither side is a fixed half-space or the body has no closed-form support point.

    For an overlap closest_points returns a deepest common point in the algebraic sense, which
    for a body wholly below the plane (a 100 m/s sphere at h = 0.01 s passes through it within
    one step) is the body's centre: grad f = 0 there, the pair's normal is undefined and the
    rows divide by zero. Eqs (15)-(18) want a1 on body 1's surface facing the plane (l2 > 0,
    see _passed_through); the support point is that, at any depth."""
    first, second = spec.objects
    for plane, other, P_plane, P_other, plane_is_1 in ((second, first, P[1], P[0], False),
                                                       (first, second, P[0], P[1], True)):
        if not plane.fixed_halfspace:
            continue
        n_b, d_b = plane.funcs[0].plane()
        n = P_plane.R @ n_b
        d = d_b + float(n @ P_plane.p)
        try:
            deep = P_other.R @ other.piece.support(P_other.R.T @ (-n)) + P_other.p
        except NotImplementedError:
            return None
        on_plane = deep - (float(n @ deep) - d) * n
        return (on_plane, deep, n) if plane_is_1 else (deep, on_plane, -n)
    return None


def _reseed(problem, x, tol):
    """A warm start for a failed solve: keep the velocities and impulses of the failed iterate and
    replace every pair's closest points and multipliers by the static solution (closest.py) at
    the poses those velocities imply.

    Newton on the KKT rows of a polytope can stall on a vertex that is no longer the deepest one
    (a box slapping flat turns its contact point over to the far edge within one step); the
    static problem is convex and its solver finds the right vertex, face or deepest point."""
    z = x.copy()
    for k, spec in enumerate(problem.specs):
        seed = _static_seed(problem, x, spec, tol)
        if seed is None:
            continue
        a1, a2, l1, l2, s = seed
        sl = problem.layout.pairs[k]
        problem.pack_points(z, k, a1, a2)
        _put_multipliers(z, sl, l1, l2, s)
    return z

