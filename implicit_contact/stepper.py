"""ImplicitContactStepper: steps a DART world with one geometrically implicit MCP per step.

One step, as a table of contents (``_one_step``; DESIGN.md, "One step, as data flows")::

    state    = self._read(h)                        # DART at l: q, v, M, forces, poses; free flight
    pairs    = self._candidates(state, keep)        # coal broadphase on grown AABBs (fat-box cache)
    pairs, far = self._far_pairs(pairs, state, keep)  # pairs that cannot touch within the step left out
    specs    = self._specs(pairs, state)            # per pair: orientation, friction, warm-start data
    result   = self._solve_step(specs, state)       # the MCP, with the ordered recoveries (recovery.py)
    missing  = self._missing_pairs(...)             # far or uncovered pairs the solution could touch
    self._commit(...)                               # write v+, integrate q+ = q (+) h v+; warm starts

``step`` wraps it in a transaction: the world is snapshotted first and restored exactly on any
failure, and the failure policy decides what follows (``on_failure``: halve h, raise, warn).

Skeletons without candidate pairs take the exact free step v+ = v + h M^{-1} force (the same
semi-implicit Euler step DART takes), and a step with no pair near builds no MCP at all.

Articulated skeletons (dart_adapter: kind ARTICULATED) take part like single bodies: every body of
the skeleton with contact shapes is a body of the step with the skeleton's velocity columns and
DART's world Jacobian at l; pairs within one skeleton are skipped (no self-collision); the write-
back is DART's setVelocities + integratePositions for every mobile skeleton, as for free bodies.
Joint springs and dampers are implicit as in DART (dart_adapter.read_dynamics); under order 2 they
take the implicit midpoint rule (rattle.py, R9-R10), and so do quasi-rigid layers (R11-R14).

Friction rows of a pair are built when the pair can be in contact in this step (it was in contact
at the last step, or its bodies are within the motion margin). A pair whose gap is open at the
solution has p_n = 0, and with the friction rows present its sigma is then undetermined; so a pair
whose rows were left out but whose solution has p_n > 0 is given its rows and the step solved again
(warm), and a pair with rows but an open gap is checked, not trusted: |p_t| <= mu p_n + tol.
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
import copy
import math
import warnings

import numpy as np

from . import bundles
from . import closest
from . import budget as step_budget
from . import dart_adapter as adapter
from . import formulation as fm
from . import joint_rows
from . import landing
from . import ncp
from . import patch as contact_patch
from . import rattle
from . import recovery
from . import shapes as shp
from . import repeat_kernels as rk_repeat
from . import step_kernels as sk
from . import step_solver
from .broadphase import Broadphase
from .memory import PairMemory, choose_axis, warm_start as memory_warm_start
from .params import Compliance, Friction
from .rows import checks as rk
from .rows import contact as rc
from .recovery import _closest_seed, _central_touch_point, _multipliers, _put_multipliers  # noqa: F401 (tests use _closest_seed)
from .support import SupportFriction, SupportSpec

# ---------------------------------------------------------------------------------------------
# options and reports
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StepperOptions:
    """contact_tolerance [m]: allowed penetration and the broadphase's extra margin (1e-9..1e-4).
    solver: options of the MCP solver (natural-residual tolerance, iterations).
    max_halvings: retry policy, how many times h may be halved (up to 2**max_halvings substeps).
    retry_iterations_factor: substeps of a retried step get this many times the solver's
        max_iterations (hard steps converge slowly rather than not at all).
    check_penetration_at_start: refuse worlds whose bodies overlap when the stepper is built.
    skip_far_pairs: leave out of the MCP the candidate pairs that cannot touch within the step (a
        known gap larger than a bound on the pieces' relative motion), checked again with the
        solved velocities (see ImplicitContactStepper._far_pairs); False keeps every candidate.
    patch_torsion: a touching pair whose friction has no e_r of its own resists spinning with
        its contact patch's torsion radius (patch.py: a box on its face, a cylinder on its cap or
        side); False leaves such pairs without torsion rows.
    order: 1 is [GI] as printed (first order); 2 the split step of rattle.py (second order in
        free flight and persistent contact; two solves per step; joint springs and dampers by
        the implicit midpoint rule, and quasi-rigid layers too, whatever Compliance.scheme says).
    max_step_iterations: the Newton iterations one call of step() may spend over all its solves,
        recoveries and halvings (budget.py); when they are spent the step fails at once, the world
        unchanged (StepFailure, or a failed report under on_failure="warn"). None: no limit.
    max_step_seconds: the same for wall time [s] (checked between solves; machine-dependent,
        so None by default: the iteration budget is the deterministic one).
    """
    contact_tolerance: float = 1e-6
    solver: ncp.SolverOptions = field(default_factory=lambda: DEFAULT_SOLVER)
    max_halvings: int = 4
    retry_iterations_factor: int = 4
    check_penetration_at_start: bool = True
    skip_far_pairs: bool = True
    patch_torsion: bool = True
    order: int = 1
    max_step_iterations: int | None = 20000
    max_step_seconds: float | None = None

    def __post_init__(self):
        if not (self.contact_tolerance > 0 and math.isfinite(self.contact_tolerance)):
            raise ValueError(f"contact_tolerance must be a positive length, got {self.contact_tolerance}")
        if not (isinstance(self.max_halvings, int) and 0 <= self.max_halvings <= 12):
            raise ValueError(f"max_halvings must be an integer in 0..12, got {self.max_halvings}")
        if not (isinstance(self.retry_iterations_factor, int) and self.retry_iterations_factor >= 1):
            raise ValueError(f"retry_iterations_factor must be an integer >= 1, got {self.retry_iterations_factor}")
        if self.max_step_iterations is not None and not (
                isinstance(self.max_step_iterations, int) and self.max_step_iterations >= 1):
            raise ValueError(f"max_step_iterations must be an integer >= 1 or None, got {self.max_step_iterations!r}")
        if self.max_step_seconds is not None and not (
                self.max_step_seconds > 0 and math.isfinite(self.max_step_seconds)):
            raise ValueError(f"max_step_seconds must be a positive number of seconds or None, got "
                             f"{self.max_step_seconds!r}")
        if self.order not in (1, 2):
            raise ValueError(f"order must be 1 ([GI]) or 2 (rattle.py), got {self.order!r}")


@dataclass(frozen=True)
class ContactReport:
    """One candidate pair at the end of the step (world frame, physical units, impulses [N s])."""
    body_a: object
    body_b: object
    a1: np.ndarray
    a2: np.ndarray
    normal: np.ndarray         # unit, from body_a into body_b
    gap: float                 # f_a(a2): algebraic distance, ~metres for normalised shapes
    p_n: float
    p_t: float
    p_o: float
    p_r: float
    sigma: float
    slip: float                # |tangential slip velocity| at l+1 [m/s]
    name_a: str = ""
    name_b: str = ""
    p_spring: float = 0.0      # quasi-rigid pairs: the layer's spring-damper impulse, eq (33)
    p_core: float = 0.0        # the rigid core's impulse (all of p_n for a rigid pair)
    deflection: float = 0.0    # normal deflection delta_n of the layer [m], eq (35)

    @property
    def active(self) -> bool:
        return self.p_n > 0.0


@dataclass(frozen=True)
class StepReport:
    success: bool
    iterations: int
    residual: float
    status: str
    contacts: tuple
    time: float
    substeps: int = 1
    message: str = ""
    unknowns: int = 0
    spent: int = 0             # Newton iterations of the whole call of step(), failed attempts included


# repeat_kernels.step's codes returned before its solve: the solver's buffers still hold the last
# step's counts, which a refused repeat charged to the step's budget and report.spent until 2026-12-07
_REFUSED_BEFORE_SOLVE = frozenset((rk_repeat.NOT_FINITE_STATE, rk_repeat.FIXED_MOVED, rk_repeat.NEED_COAL,
                                   rk_repeat.CANDIDATES, rk_repeat.FAR_CHANGED, rk_repeat.ROWS_CHANGE))


def _made_report(success, iterations, residual, status, contacts, time, substeps, message, unknowns,
                 spent) -> StepReport:
    """StepReport(...) with every field given, made by filling the new instance's dict: the
    frozen dataclass's __init__ sets its ten fields one by one through object.__setattr__
    (1.46 us against 0.61 us; the rolling disc's repeated step takes ~40 us). The same object:
    equal to the one __init__ makes (tests/test_repeat_step.py)."""
    report = object.__new__(StepReport)
    report.__dict__.update(success=success, iterations=iterations, residual=residual, status=status,
                           contacts=contacts, time=time, substeps=substeps, message=message,
                           unknowns=unknowns, spent=spent)
    return report


class StepFailure(RuntimeError):
    """The MCP of a step could not be solved; the world is exactly as before the call."""

    def __init__(self, message, report=None):
        super().__init__(message)
        self.report = report


POLICIES = ("raise", "warn", "retry")
BUDGET_EXHAUSTED = "BUDGET_EXHAUSTED"   # StepReport.status of a step that spent its budget (budget.py)

# The step's rows mix velocities, lengths and dimensionless gradients, and a position row moves
# only by h times a velocity change: near the solution a Newton step of O(1) (in scaled impulse
# units) can fix a residual of O(h^2). The solver's default descent test (rho = 1e-8) rejects such
# steps as "too long for the residual"; rho = 1e-24 still caps steps at ~1e6 for a 1e-5 residual.
DEFAULT_SOLVER = ncp.SolverOptions(tol=1e-10, max_iterations=50, descent_rho=1e-24, shorten_nonfinite=True)
_NO_AXIS = np.zeros(3)   # (rattle.start_frame of a 2D pair: no tangent axis)
_AXIS_LIMIT = 0.7   # |axis . normal| above which a pair's tangent axis is chosen anew
# [m/s] a pair's impulse unit is at least its smaller mass times this (_pair_spec). Measured on the
# face-contact campaign: with the unit m h g alone, 9 of its 11 StepFailures were at h < 3e-4 (stacks,
# slides, a landing; 21 % of its runs), where Newton at h / 16 met impacts of 1e4-1e5 units and
# stalled with friction impulses of 2e4 units; with this floor 7 of the 11 complete
IMPULSE_SPEED = 0.01
SHARE_LEVER = 1.0         # _share_patches: a contact more than this many torsion radii off a pair's axis holds its spin
_TOUCH = recovery.TOUCH   # scaled normal impulse (units of the pair's s_p) above which a pair counts as touching
# order 2's second stage solves to this fraction of the solver's tolerance: its friction rows are
# in units of e^2 mu P_n times a slip (P_n ~ 1), so the default 1e-10 left a box's spin at 2e-9
# rad/s after it stuck (tests/test_face_contact.py's spin-down); the rows are linear but for the
# friction rows and converge quadratically, so the extra digits cost about one iteration; a solve
# whose line search stalls between that and the tolerance itself (round-off of impulses ~1e4 s_p
# at a 2.4 m/s landing with h = 2e-4) is accepted at the tolerance
STAGE2_TOL = 1e-3
SPLIT_JUMP = 0.05   # order 2: a contact point moving more than this of its pieces' size in a step is unsplit
#                     (_split_jumped; measured: 0.01 also unsplit the flatter rocking ellipsoid of issue 14,
#                     whose point moves ~1.3 % of its size a step at h = 2e-3, and its energy error went
#                     from 8.1e-5 to 8.9e-2; at 0.05 the dropped superquadrics of exponent 4-8 and the
#                     1:100 ellipsoid come to rest, their per-step energy oscillation <= 7.7e-5 J at h = 0.01)
_ENERGY_GAIN = 0.01  # a solution whose impulses add more than this of the bodies' energy scale is refused:
#                    legitimate gains are O(h^2) (a box pivoting on its edge: 1.4e-3 of the campaign's
#                    scale at h = 1e-2), spurious roots of stacked bodies added 0.1-13 (comparisons.face_contact)
_FAT_SLACK = 0.25   # fat broadphase boxes: grown by this fraction of a piece's size (plus 3 motion margins)
_EVERY_PAIR_UP_TO = 128  # pieces: a world with at most this many takes every allowed pair as its fat pairs
#                        (_refresh_fat), tested exactly each step, and never asks coal again


# ---------------------------------------------------------------------------------------------
# the stepper
# ---------------------------------------------------------------------------------------------
class ImplicitContactStepper:
    """Replaces DART's collision detection + boxed LCP with the [GI] mixed NCP step.

    world: a dartpy.simulation.World; the stepper finds shapes attached with ``ic.attach`` and
    DART primitive ShapeNodes with a collision aspect.
    on_failure: "retry" (default) takes 2, 4, ... substeps of halved h (at most 2**max_halvings;
    report.substeps says how many) and raises StepFailure if those fail too; "raise" raises at
    once; "warn" warns and returns a failed report.
    In every case a failed step leaves the world exactly as it was.
    mimic: {follower joint name: (leader joint name, multiplier, offset)} for the joints DART marks
    MIMIC (dartpy does not expose their relation; ``ic.urdf_mimic_joints(urdf)`` reads a URDF's);
    like DART, a relation is applied only to a MIMIC joint with dofs.
    """

    def __init__(self, world, on_failure: str = "retry", options: StepperOptions | None = None,
                 mimic: dict | None = None):
        if on_failure not in POLICIES:
            raise ValueError(f"on_failure must be one of {POLICIES}, got {on_failure!r}")
        self.world = world
        self.on_failure = on_failure
        self.options = options or StepperOptions()
        adapter.check_free_joint_convention()
        h = world.getTimeStep()
        if not (math.isfinite(h) and h > 0):
            raise ValueError(f"the world's time step must be positive and finite, got {h}")
        self.scene = adapter.scan_world(world, mimic)
        self._objects = self._contact_objects()
        self._broadphase = Broadphase(len(self._objects))
        self._fat = None           # (lo, hi, pairs) of the last coal query (see _candidates)
        n = len(self._objects)
        self._every_pair = None if n > _EVERY_PAIR_UP_TO else np.array(
            [(i, j) for i in range(n) for j in range(i + 1, n) if self._allowed(i, j)], np.int64).reshape(-1, 2)
        self._world = _World(self.scene, self._objects)
        # the mass unit of a body's contact impulses (a scaling only): a free or planar body's own
        # mass; a link of an articulated skeleton its skeleton's, which is what a contact on it
        # moves (a link's own mass can be 0, a URDF's ee_link, or 1e-6 kg, a robot's foot frame:
        # measured, example-robot-data's hyq landing on four feet of ~1e-6 kg had its normal
        # impulses at 2.6e6 units and Newton stalled at every h down to h / 16)
        self._masses = {b.index: (b.skeleton.getMass() if b.kind == adapter.ARTICULATED else b.body_node.getMass())
                        for b in self.scene.bodies}
        self._sizes = np.array([o.piece.length_scale if math.isfinite(o.piece.length_scale) else 0.0
                                for o in self._objects])
        self._gravity_norm = 1.0
        self._pair_friction = {}
        self._pair_compliance = {}
        self._last = PairMemory()  # the last step's pairs (warm starts; memory.py)
        self._supports = {}        # body index -> SupportFriction (set_support_friction)
        self._orientation = {}     # two intersections: frozenset of object keys -> body 1's key
        self._last_support = {}    # body index -> (y, sigma, wrench) of the last step
        # skeletons with Coulomb joint friction or enforced position limits (read at construction,
        # as DART's springs): their joint rows (joint_rows.py); friction puts a skeleton in every
        # step's MCP, a limit when it is near
        self._joint_models = {}
        for s, rec in enumerate(self.scene.skeletons):
            dofs, lo, hi = rec.limits if rec.limits is not None else (np.zeros(0, np.int64), np.zeros(0), np.zeros(0))
            model = joint_rows.JointModel(rec.coulomb, dofs, lo, hi, rec.mimic)
            if not model.empty:
                self._joint_models[s] = model
        self._forced_limits = {}   # skeleton -> limit rows a solved step crossed (this step only)
        self._last_joint = {}      # skeleton index -> (its JointRows, their lambda), last step
        self._far = {}             # pairs left out of the last step -> a lower bound of their gap now
        self._all_pairs = False    # this step: leave no far pair out (after a failure with some out)
        self._left_out = False     # this step left a far pair out
        self._problems = {}        # persistent step problems, by layout signature and bodies
        self._ctx = None           # what the last step leaves for _repeat_step
        self._stage2_solver = None  # (options.solver, order 2's stage-2 options: _stage2_step)
        self._stage2_kept = None    # (the last step's rattle.Stage2, refreshed in place when it can be: _stage2)
        self._coriolis = np.empty((6, 6))   # (_stage1_tables' workspace)
        self._midpoint = None      # cache of _trapezoidal_skeletons
        self._retry_solver = None  # the solver options of retried substeps (see _solve)
        self._variants = {}        # solver options with another iteration limit or watch (_variant)
        self._retrying = False
        self._budget = None        # the budget of the step under way (step; budget.py)
        self._order1_fallback = False   # order 2 taking one step as [GI]'s (_order1_step)
        self._repeat_tried = False      # _quick_repeat tried _repeat_step on this step's state
        self._repeat_spent = None       # and the Newton iterations its solve spent (None: no solve)
        self._gravity_key = None        # the gravity _gravity_norm was computed from (a list)
        self.order1_steps = 0           # order 2: the (sub)steps of completed steps taken by that fallback
        self._check_state_finite()
        if self.options.check_penetration_at_start:
            self._check_initial_overlap()

    # -- public ----------------------------------------------------------------------------------
    def set_pair_friction(self, node_a, node_b, friction: Friction) -> None:
        """Override the friction of the pair (node_a, node_b) (default: the smaller mu)."""
        if not isinstance(friction, Friction):
            raise ValueError(f"friction must be an ic.Friction, got {type(friction).__name__}")
        ia, ib = self._body_of(node_a), self._body_of(node_b)
        self._pair_friction[frozenset((ia, ib))] = friction
        self._ctx = None

    def set_pair_compliance(self, node_a, node_b, compliance: Compliance) -> None:
        """Give the pair (node_a, node_b) a quasi-rigid layer (default: the bodies' own layers,
        in series if both have one; rigid if neither has)."""
        if not isinstance(compliance, Compliance):
            raise ValueError(f"compliance must be an ic.Compliance, got {type(compliance).__name__}")
        ia, ib = self._body_of(node_a), self._body_of(node_b)
        self._pair_compliance[frozenset((ia, ib))] = compliance
        self._ctx = self._midpoint = None

    def set_support_friction(self, node, mu: float, normal_force: float, points=((0.0, 0.0),),
                             torsion_radius: float | None = None) -> None:
        """Coulomb friction of a planar body against the surface it lies on (2.5D; see
        implicit_contact/support.py): normal_force [N] (its weight, for a horizontal support) is
        shared equally by the body-frame support points (k, 2); the friction wrench is bounded by
        the ellipsoidal limit surface with centre their centroid and torsion radius their mean
        distance from it (or torsion_radius [m]). Solved in the NCP with the contacts, every
        step. mu = 0 removes it."""
        b = self._body_of(node)
        if self.scene.bodies[b].kind != adapter.PLANAR:
            raise ValueError(f"support friction needs a body on a PlanarJoint (2.5D); "
                             f"'{self.scene.bodies[b].name}' is {self.scene.bodies[b].kind}")
        support = SupportFriction.from_points(mu, normal_force, points, torsion_radius)
        self._last_support.pop(b, None)
        self._ctx = None
        if support.mu == 0.0:
            self._supports.pop(b, None)
        else:
            self._supports[b] = support

    def joint_friction_impulse(self, skeleton) -> np.ndarray:
        """The Coulomb joint friction impulse on each dof of a skeleton in the last step [N s or
        N m s] (joint_rows.py; zeros where a dof has no friction or the skeleton did not step
        through an MCP)."""
        return self._joint_impulse(skeleton, (joint_rows.FRICTION,))

    def joint_limit_impulse(self, skeleton) -> np.ndarray:
        """The impulse of the enforced position limits on each dof of a skeleton in the last step
        [N s or N m s], signed along +q (joint_rows.py; zeros where no limit row acted)."""
        return self._joint_impulse(skeleton, (joint_rows.LOWER, joint_rows.UPPER))

    def joint_mimic_impulse(self, skeleton) -> np.ndarray:
        """The impulse of the mimic relations on each dof of a skeleton in the last step (on the
        follower and, times -multiplier, on the leader; joint_rows.py)."""
        return self._joint_impulse(skeleton, (joint_rows.MIMIC,))

    def _joint_impulse(self, skeleton, kinds):
        for s, rec in enumerate(self.scene.skeletons):
            if rec.skeleton is skeleton or rec.skeleton.getName() == skeleton.getName():
                last = self._last_joint.get(s)
                if last is None:
                    return np.zeros(rec.ndof)
                return joint_rows.impulses(last[0], last[1], kinds)
        raise ValueError(f"skeleton '{skeleton.getName()}' is not stepped by this stepper")

    def support_wrench(self, node) -> np.ndarray:
        """The support's friction impulse on a body in the last step, (p_x, p_y, moment about
        the body origin) [N s, N m s]; zeros if it has no support friction or did not step."""
        last = self._last_support.get(self._body_of(node))
        return np.zeros(3) if last is None else last[2].copy()

    def _trapezoidal_skeletons(self) -> set:
        """All mobile skeletons when any quasi-rigid layer of the world uses the "midpoint"
        scheme (ic.Compliance): the energy-consistent variant integrates every position with the
        trapezoidal rule, q+ = q + h (v + v+)/2, in flight too (exact under gravity); else none.
        None in order 2's split step (its q+ = q + h u is already the midpoint rule's, rattle.py)."""
        if self._split_stage1:
            return set()
        if self._midpoint is None:
            layers = [o.compliance for o in self._objects if o.compliance is not None]
            layers += list(self._pair_compliance.values())
            self._midpoint = (set(range(len(self.scene.skeletons))) if any(c.scheme == "midpoint" for c in layers)
                              else set())
        return self._midpoint

    def spring_energy(self) -> float:
        """Energy stored in the quasi-rigid layers at the end of the last step [J]:
        sum of k delta_n^2 / 2 over its contacts."""
        return sum(0.5 * c["k"] * c["deflection"] ** 2 for c in self._last.values() if c["k"] > 0.0)

    def step(self) -> StepReport:
        """Advance the world by world.getTimeStep(); transactional (see on_failure), within the
        step's budget (StepperOptions.max_step_iterations, max_step_seconds; budget.py)."""
        h = self.world.getTimeStep()
        if not (math.isfinite(h) and h > 0):
            raise ValueError(f"the world's time step must be positive and finite, got {h}")
        report = self._quick_repeat(h)
        if report is not None:
            return report
        snap = self._begin()
        saved = (self._last, dict(self._last_support), dict(self._far), self._ctx, self._last_joint,
                 self.order1_steps)
        self._forced_limits = {}
        budget = self._budget = step_budget.Budget(self.options.max_step_iterations, self.options.max_step_seconds)
        if self._repeat_tried and self._repeat_spent is not None:
            budget.spend(self._repeat_spent)      # the solve of _quick_repeat's failed attempt

        def attempt(n):
            """n substeps of h / n; a failed attempt leaves the world and the warm starts as before."""
            try:
                report = self._substeps(h / n, n)
            except step_budget.BudgetExhausted as exc:
                report = StepReport(False, budget.spent, math.nan, BUDGET_EXHAUSTED, (), snap.time, n,
                                    f"{exc} ({budget.elapsed():.3g} s) at t = {snap.time:.6g} s, "
                                    f"h = {h:g} in {n} substeps, without converging.")
            if report.success:
                adapter.finish_step(self.world, h, self._world.all_skeletons)
            else:
                adapter.restore(self.world, snap)
                self._world.raw_valid = False
                self._last, self._last_support, self._far = saved[0], dict(saved[1]), dict(saved[2])
                self._ctx, self._last_joint, self.order1_steps = saved[3], saved[4], saved[5]
                self._forced_limits = {}
            # (set in place: the report is this attempt's own, and dataclasses.replace cost 4.7 us
            # a step, 8 % of the rolling disc's)
            object.__setattr__(report, "spent", budget.spent)
            return report

        try:
            report = self._attempts(attempt)
        finally:
            self._budget = None
            self._repeat_tried = False
        if report.success:
            return report
        if report.status == BUDGET_EXHAUSTED:
            message = report.message + " The world is unchanged; raise the budget or lower h."
        elif self.on_failure == "retry":
            message = report.message + f" Retried with up to {2 ** self.options.max_halvings} substeps; " \
                                       "the world is unchanged."
        else:
            message = report.message + " The world is unchanged."
        if self.on_failure == "warn":
            warnings.warn(message, RuntimeWarning, stacklevel=2)
            return report
        raise StepFailure(message, report)

    def _attempts(self, attempt) -> StepReport:
        """The failure policy's attempts, in order, until one succeeds, the budget is spent or the
        policy has none left: h; h again with every candidate pair when far pairs were left out;
        under "retry" 2, 4, ... substeps."""
        self._retrying = False
        self._all_pairs = self._left_out = False
        report = attempt(1)
        if report.success or report.status == BUDGET_EXHAUSTED:
            return report
        if self._left_out:
            # the far pairs left out change the Newton path, not the solution; a failed step is
            # solved again with every candidate before anything else (measured: 30 bodies in a
            # box, a landing step that failed at h / 16 without them converged at h in 7 iterations)
            self._all_pairs = True
            report = attempt(1)
            if report.success or report.status == BUDGET_EXHAUSTED:
                return report
        if self.on_failure == "retry":
            self._retrying = True
            for k in range(1, self.options.max_halvings + 1):
                report = attempt(2 ** k)
                if report.success or report.status == BUDGET_EXHAUSTED:
                    return report
        return report

    # -- construction helpers ------------------------------------------------------------------
    def _body_of(self, node) -> int:
        for b in self.scene.bodies:
            if b.body_node is node or (b.body_node.getName() == node.getName()
                                       and b.skeleton.getName() == node.getSkeleton().getName()):
                return b.index
        raise ValueError(f"body '{node.getName()}' carries no contact shape in this world")

    def _contact_objects(self):
        objs = []
        for body in self.scene.bodies:
            for cs in body.shapes:
                pieces = cs.shape.parts if isinstance(cs.shape, shp.Union) else (cs.shape,)
                for piece in pieces:
                    funcs = tuple(piece.functions)
                    fixed_hs = (body.kind == adapter.FIXED and len(funcs) == 1
                                and isinstance(funcs[0], (shp.HalfSpace, shp.HalfPlane)))
                    label = cs.label if not cs.label.startswith(adapter.SHAPE_NODE_PREFIX) \
                        else type(cs.shape).__name__
                    objs.append(_Object(body.index, piece, funcs, fixed_hs, cs.friction,
                                        f"{body.name}:{label}#{len(objs)}", cs.compliance))
        return objs

    def _quick_repeat(self, h) -> StepReport | None:
        """The whole step when it repeats the last one's structure under order 1 (_repeat_step),
        before step() takes its snapshot and budget: that path writes DART only once its compiled
        solve has succeeded (_commit_world), so it never has anything to restore, and its one solve
        stays within max_step_iterations when that is at least the solver's max_iterations. None
        when it does not apply or the state is not as checked by _begin (step() then takes the
        step, _begin refusing a bad state; its first _gi_step does not try _repeat_step again).
        The case: the rolling disc's step took 57 us alone, about 6 of them in the snapshot, the
        budget and the calls around them (tests/test_repeat_step.py)."""
        ctx = self._ctx
        o = self.options
        if (ctx is None or ctx.h != h or ctx.problem is None or o.order != 1 or o.max_step_seconds is not None
                or (o.max_step_iterations is not None and o.max_step_iterations < o.solver.max_iterations)):
            return None
        w = self._world
        gravity = self.world.getGravity()
        if not self._gravity_ok(gravity):
            return None
        adapter.read_state(w.read_views, w.body_views)    # (checked finite by the kernel: NOT_FINITE_STATE)
        if w.all_skeletons is None or self.world.getNumSkeletons() != len(w.all_skeletons):
            return None
        w.raw_valid = True
        # (what step() and the first of _attempts set before a step's first attempt)
        self._forced_limits = {}
        self._retrying = self._all_pairs = self._left_out = False
        self._repeat_tried, self._repeat_spent = True, None
        t0 = self.world.getTime()
        w.dynamics_read = True
        try:
            report = self._repeat_step(h, t0)
        finally:
            w.dynamics_read = False
        if report is None:
            return None
        self._repeat_tried = False
        adapter.finish_step(self.world, h, w.all_skeletons, t0)
        return report               # (its spent: _repeat_step's report has it, its one solve's iterations)

    def _gravity_ok(self, gravity) -> bool:
        """Whether the world's gravity is finite; sets _gravity_norm (kept while gravity is)."""
        key = gravity.tolist()
        if key == self._gravity_key:
            return True
        gg = float(gravity @ gravity)
        if not math.isfinite(gg):
            return False
        self._gravity_norm, self._gravity_key = math.sqrt(gg), key
        return True

    def _begin(self) -> adapter.WorldSnapshot:
        """The start of a step: every mobile skeleton's q, v, joint and external forces read once
        (into the world buffers, used by the step's first read) and checked, then the world's
        snapshot for a failed step."""
        w = self._world
        if not self._gravity_ok(self.world.getGravity()):
            raise ValueError(f"the world has non-finite gravity {self.world.getGravity()}; the stepper "
                             "refuses to step it.")
        for rec, (q, v, tau, fext, dv), _, _ in w.skeleton_views:
            adapter.read_raw(rec, q, v, tau, fext, dv)
        if not sk.all_finite(w.Q, w.V, w.TAU, w.FEXT):
            self._check_state_finite()
        w.raw_valid = True
        if w.all_skeletons is None or self.world.getNumSkeletons() != len(w.all_skeletons):
            # (again if the world gained or lost skeletons since the stepper was built)
            mine = {rec.skeleton.getName() for rec in self.scene.skeletons}
            w.all_skeletons = [self.world.getSkeleton(i) for i in range(self.world.getNumSkeletons())]
            w.world_skeletons = [x for x in w.all_skeletons if x.getName() not in mine and x.getNumDofs() > 0]
        return adapter.snapshot(self.world, w.world_skeletons, w.snapshot_views)

    def _check_state_finite(self):
        """Refuse, before anything is touched, a state DART accepts but no step can use."""
        gravity = np.asarray(self.world.getGravity(), float)
        if not np.all(np.isfinite(gravity)):
            raise ValueError(f"the world has non-finite gravity {self.world.getGravity()}; the stepper "
                             "refuses to step it.")
        self._gravity_norm, self._gravity_key = float(np.linalg.norm(gravity)), None
        for s in self.scene.skeletons:
            sk = s.skeleton
            q, v = np.asarray(sk.getPositions()), np.asarray(sk.getVelocities())
            if not (np.all(np.isfinite(q)) and np.all(np.isfinite(v))):
                raise ValueError(f"skeleton '{sk.getName()}' has non-finite positions or "
                                 "velocities; the stepper refuses to step it.")
            if not (np.all(np.isfinite(sk.getForces())) and np.all(np.isfinite(sk.getExternalForces()))):
                raise ValueError(f"skeleton '{sk.getName()}' has non-finite forces (joint forces or "
                                 "external forces); the stepper refuses to step it.")

    def _check_initial_overlap(self):
        from .closest import closest_points
        tol = self.options.contact_tolerance
        poses = {b.index: adapter.body_pose(b) for b in self.scene.bodies}
        for i, j in self._pairs_at(poses, margins=np.full(len(self._objects), tol)):
            o1, o2 = self._objects[i], self._objects[j]
            if o1.fixed_halfspace and o2.fixed_halfspace:
                continue
            res = closest_points(o1.piece, _pose_dim(poses[o1.body], o1.piece.dim),
                                 o2.piece, _pose_dim(poses[o2.body], o2.piece.dim))
            if res.overlapping and res.depth > tol:
                raise ValueError(f"bodies {o1.label} and {o2.label} interpenetrate by about "
                                 f"{res.depth:.3g} at the start (tolerance {tol:g}); move them apart.")

    # -- one step --------------------------------------------------------------------------------
    def _substeps(self, h, n) -> StepReport:
        if n == 1:
            return self._one_step(h)
        total_it, worst = 0, 0.0
        report = None
        for _ in range(n):
            report = self._one_step(h)
            total_it += report.iterations
            worst = max(worst, report.residual)
            if not report.success:
                return report
        return StepReport(True, total_it, worst, report.status, report.contacts, self.world.getTime() + h * n,
                          n, report.message, report.unknowns)

    def _one_step(self, h, keep=frozenset()) -> StepReport:
        """One step of h; keep: candidate pairs the far-pair filter must not leave out."""
        if self.options.order == 2:
            return self._split_step(h, keep)
        return self._gi_step(h, keep)

    def _order1_step(self, h, keep, failed) -> StepReport:
        """Order 2's fallback: a split step whose first or second stage failed (failed: its report;
        DART is at l) is taken as [GI]'s step, whose guarantees at l+1 are the same and whose order
        is one for that step; its report, failed or not. The case: 30 superquadrics dropped into a
        box (comparisons/stability.py) raised StepFailure at t = 0.30 s under order 2 (stage 1
        MAX_ITERATIONS even at h / 16) where order 1 takes the same state in one solve; guarded by
        tests/test_rattle.py::test_order_2_falls_back_to_order_1_when_stage_1_fails (stage 2:
        _split_end)."""
        self._ctx = None                      # (_gi_step's repeat path must not take a split step's)
        self._order1_fallback = True          # (_problem: [GI]'s skeleton tables, not stage 1's)
        try:
            report = self._gi_step(h, keep)
        finally:
            self._order1_fallback = False
        self._ctx = None                      # (its structure is not a split step's)
        if report.success:
            self.order1_steps += 1
        return report

    def _gi_step(self, h, keep=frozenset()) -> StepReport:
        """One step of [GI] (order 1); keep as in _one_step."""
        t0 = self.world.getTime()
        tried, self._repeat_tried = self._repeat_tried, False
        if not keep and not tried:
            report = self._repeat_step(h, t0)
            if report is not None:
                return report
        state = self._read(h)
        candidates = self._candidates(state, keep)
        ordered = sorted(candidates)
        pairs, far = self._far_pairs(ordered, state.v_free, h, keep)
        self._ctx = None
        joints = self._joint_rows(state)
        if not pairs and not self._supports and not joints:
            report = self._free_step(state, far, keep, t0)
            if report.success and not keep:
                self._ctx = self._context(h, ordered, pairs, None, None)
            return report
        att = self._specs(pairs, state, joints)
        problem, result = self._solve_step(att, state)
        if not result.success:
            return self._failure(problem, result, t0, h)
        contacts, new_last = self._solution(problem, result.x, att.specs)
        bad = self._check_solution(problem, result.x, contacts, att.specs)
        if att.released and not bad:
            released, bad = self._released_contacts(problem, result.x, att.released)
            contacts = tuple(contacts) + tuple(released)
        if bad:
            return StepReport(False, result.iterations, result.residual, "INVALID_SOLUTION", tuple(contacts),
                              t0, 1, f"NCP solution rejected at t = {t0:.6g} s: {bad}", problem.layout.n)
        v_solved = [result.x[problem.layout.v_index[att.sk_pos[s]]] if s in att.sk_pos else state.v_free[s]
                    for s in range(len(self.scene.skeletons))]
        V_solved = self._world_vector(v_solved)
        far_next, violated = self._far_after(far, V_solved, h)
        violated |= self._uncovered(candidates, v_solved, V_solved, state)
        if violated:
            # a pair left out could touch at the solved velocities: solve the step again with it
            return self._one_step(h, keep | violated)
        if self._limits_crossed(state, joints, v_solved):
            # a limit whose row was left out is crossed at the solved velocities: again with it
            return self._one_step(h, keep)
        self._commit(state, v_solved)
        self._last = new_last
        self._far = far_next
        self._last_support = {sp.key: (result.x[ss.y].copy(), float(result.x[ss.sigma]),
                                       problem.support_wrench(result.x, s))
                              for s, (sp, ss) in enumerate(zip(problem.supports, problem.layout.supports))}
        self._last_joint = {s: (joints[s], result.x[problem.layout.joint_index[k]].copy())
                            for k, s in enumerate(att.involved) if s in joints}
        if not keep and not att.released:
            self._ctx = self._context(h, ordered, pairs, problem, att)
        return StepReport(True, result.iterations, result.residual, result.status.name, contacts,
                          t0 + h, 1, result.message, problem.layout.n)

    # -- order 2: the split step (rattle.py) ---------------------------------------------------------
    @property
    def _split_stage1(self) -> bool:
        """Whether the MCP being built is order 2's first stage (not [GI]'s step: order 1, or order
        2's fallback _order1_step)."""
        return self.options.order == 2 and not self._order1_fallback

    def _split_step(self, h, keep=frozenset()) -> StepReport:
        """One step of order 2 (rattle.py): stage 1, [GI]'s MCP for the half-step velocity u with
        the impulse R1 in the frame at l (R1)-(R4); the positions q+ = q (+) h u written to DART;
        stage 2 at the fixed geometry q+, the end velocity and total impulse (R5)-(R8)."""
        t0 = self.world.getTime()
        if not keep:
            report = self._repeat_step(h, t0)
            if report is not None:
                return report
        self._ctx = None
        state = self._read(h)
        self._stage1_tables(h)
        candidates = self._candidates(state, keep)
        ordered = sorted(candidates)
        joints = self._stage1_joints(state)
        u, first = self._stage1(state, ordered, joints, t0)
        if isinstance(first, StepReport):
            return self._order1_step(h, keep, first)
        violated = self._uncovered(candidates, u, self._world_vector(u), state)
        if violated:
            # a pair the broadphase did not see could touch at the solved velocities: again with it
            return self._split_step(h, keep | violated)
        if self._limits_crossed(state, joints, u):
            # a limit whose row was left out is crossed at the solved velocities: again with it
            return self._split_step(h, keep)
        second = self._split_end(first, u, joints, t0, h, keep)
        if isinstance(second, StepReport):
            return second
        self._last = first[5] if first is not None else PairMemory()
        self._last_support, self._far = {}, {}
        if first is not None and not keep and not joints and not any(map(landing.faceted_pair, first[1].specs)):
            self._ctx = self._context(h, ordered, ordered, first[0], first[1])     # for _split_repeat
        iterations, residual, contacts = second
        n = 0 if first is None else first[0].layout.n
        return StepReport(True, iterations, residual, "CONVERGED" if first is not None else "NO_CONTACT",
                          contacts, t0 + h, 1, "", n)

    def _stage1_joints(self, state) -> dict:
        """The joint rows of stage 1 (rattle.py, eq R1): [GI]'s, their friction bound h/2 f."""
        return {s: _friction_units(rows, 0.5) for s, rows in self._joint_rows(state).items()}

    def _stage1(self, state, pairs, joints, t0):
        """(u per skeleton, (problem, att, z, iterations, residual, memory) or None without an
        MCP, or (None, the StepReport of a failed or refused solve))."""
        h = state.h
        if not pairs and not joints:
            return self._half_kicks(h), None
        att = self._specs(pairs, state, joints)
        for spec in att.specs:
            # a face on a face takes stage 1's impulse at its equivalent contact point at q+,
            # as [GI]: with the frame at l that point would be undetermined (rattle.py)
            spec.start_frame = None if landing.faceted_pair(spec) else self._start_frame(spec, state)
        problem, result = self._solve_step(att, state)
        if result.success and self._split_jumped(problem, result.x, att.specs):
            # a contact point that moved far within the step: those pairs unsplit, solved again
            # from this solution (27 superquadrics in a box: 2 to 3 such re-solves a step)
            att.previous = (problem, result.x.copy())
            problem, result = self._solve_step(att, state)
        if not result.success and any(spec.start_frame is not None for spec in att.specs):
            # a failed split solve: every pair unsplit ([GI]'s stage 1 at half the force), from the
            # warm start; a nearly flat face rocking on the ground has the undetermined point of
            # a face on a face (a superquadric of exponent 10 dropped: MAX_ITERATIONS at h / 16)
            for spec in att.specs:
                spec.start_frame = None
            att.previous = None
            problem, result = self._solve_step(att, state)
        if not result.success:
            return None, self._failure(problem, result, t0, h)
        contacts, memory = self._solution(problem, result.x, att.specs)
        bad = self._check_solution(problem, result.x, contacts, att.specs, energy=False)
        if bad:
            return None, StepReport(False, result.iterations, result.residual, "INVALID_SOLUTION", tuple(contacts),
                                    t0, 1, f"NCP solution rejected at t = {t0:.6g} s: {bad}", problem.layout.n)
        u = self._half_kicks(h, att.involved)
        for s in att.involved:
            u[s] = result.x[problem.layout.v_index[att.sk_pos[s]]]
        return u, (problem, att, result.x, result.iterations, result.residual, memory, contacts)

    def _half_kicks(self, h, skip=()) -> list:
        """Per skeleton its free half-step velocity v + h M1^-1 FB1 (rattle.py, eq R1 without
        contact; _stage1_tables), or v for those in skip (their u comes from stage 1's MCP)."""
        w = self._world
        return [w.V[o:o + k] + np.linalg.solve(w.MB1[mo:mo + k * k].reshape(k, k), h * w.FB1[o:o + k])
                if k and s not in skip else w.V[o:o + k] for s, (o, mo, k) in enumerate(zip(w.sk_voff, w.sk_moff, w.sk_nv))]

    def _split_jumped(self, problem, z, specs) -> bool:
        """Whether a split pair's contact point on body 2 moved more than SPLIT_JUMP of the smaller
        piece's size within the step; those pairs then take stage 1's impulse at q+ (their
        start_frame is cleared). The trapezoidal rule of the split needs the point to move little:
        a superquadric of exponent 6 rocking over its nearly flat face at h = 0.01 moved its point
        0.17 m (of 0.3) in a step and gained 9e-3 J, a 1:100 ellipsoid jumped."""
        problem._evaluated_at(z)
        jumped = self._jumped_pairs(problem._rep, specs)
        for k in jumped:
            specs[k].start_frame = None
        return bool(jumped)             # (_solve_step refreshes the tables from the specs)

    def _jumped_pairs(self, rep, specs) -> list:
        """The split pairs (indices) whose contact point on body 2 at q+ (rep: the pairs' reports)
        is more than SPLIT_JUMP of the smaller piece's size from where it was at l (_split_jumped)."""
        jumped = []
        for k, spec in enumerate(specs):
            frame = spec.start_frame
            if frame is None:
                continue
            first, second = spec.objects
            p2, a2 = self._world.p_now[second.body], rep[k]
            moved = math.sqrt(sum((float(a2[rc.R_A2 + i]) - (float(p2[i]) + float(frame[12 + i]))) ** 2 for i in range(3)))
            if moved > SPLIT_JUMP * min(first.size, second.size):
                jumped.append(k)
        return jumped

    def _split_end(self, first, u, joints, t0, h, keep=frozenset()):
        """The split step after stage 1: q+ = q (+) h u, stage 2, v+ into DART; (iterations,
        residual, contacts) of the step, or the StepReport of the order-1 step taken in its place
        when stage 2 fails (_order1_step: DART back at l first; its report, failed or not)."""
        w = self._world
        v_l = w.V.copy()
        hf = self._to_end_positions(u, h)
        v_next, second = self._stage2_step(first, u, hf, joints, t0, h)
        if not isinstance(second, StepReport):
            self._write_end_velocities(v_next, v_l, h)
            return second
        # stage 2 failed: the order-1 step in its place, as when stage 1 fails. The case: go1
        # (example-robot-data) landing on the edges of its four calf boxes at t = 0.103 s, a
        # stage 2 whose Jacobian has 5 null singular values (two vertex rows a foot), stalled at
        # natural residuals 1e-10..1e-6 at every h; tests/test_rattle.py::
        # test_order_2_falls_back_to_order_1_when_stage_2_fails. (w.Q still holds q at l: stage 2's
        # forces read it there, split_end_forces.)
        for s, rec in enumerate(self.scene.skeletons):
            k, o = w.sk_nv[s], w.sk_voff[s]
            if k:
                rec.skeleton.setPositions(w.Q[o:o + k])
                rec.skeleton.setVelocities(v_l[o:o + k])
        w.raw_valid = False
        return self._order1_step(h, keep, second)

    def _to_end_positions(self, u, h):
        """q+ = q (+) h u written to DART (R2); DART's M and Coriolis and gravity forces at (q+, u)
        into the world buffers; returns h/2 f(q+, u) (R5) over the world's dofs."""
        w = self._world
        w.raw_valid = False
        for s, rec in enumerate(self.scene.skeletons):
            if w.sk_nv[s]:
                rec.skeleton.setVelocities(u[s])
                rec.skeleton.integratePositions(h)
        for rec, _, M, cg in w.skeleton_views:
            adapter.read_dynamics(rec, M, cg)
        sk.split_end_forces(w.bundle, h, self._world_vector(u), rattle.STIFF_DAMPER)   # (R9, R10)
        return 0.5 * h * w.FB

    def _stage2_step(self, first, u, hf, joints, t0, h):
        """(v+ per skeleton, (iterations, residual, contacts) of the step or the StepReport of a
        failed second stage): the free half kick for skeletons outside the MCP, stage 2 (R5)-(R8)
        for the others."""
        w = self._world

        def kicks(skip=()):
            return [u[s] + np.linalg.solve(w.MB[mo:mo + k * k].reshape(k, k), hf[o:o + k]) if k and s not in skip
                    else u[s] for s, (o, mo, k) in enumerate(zip(w.sk_voff, w.sk_moff, w.sk_nv))]
        if first is None:
            self._last_joint = {}
            return kicks(), (0, 0.0, ())
        problem, att, z, iterations, residual, _, contacts = first
        stage2, closed, jrows = self._stage2(problem, z, att, u, hf, joints)
        lam = {}
        v_next = kicks(att.involved if (closed or jrows) else ())     # (stage 2 gives theirs)
        if closed or jrows:
            if self._stage2_solver is None or self._stage2_solver[0] is not self.options.solver:
                self._stage2_solver = (self.options.solver, replace(self.options.solver,
                                                                    tol=STAGE2_TOL * self.options.solver.tol))
            res2 = stage2.solve(self._stage2_solver[1], converged_at=self.options.solver.tol, budget=self._budget)
            iterations += res2.iterations
            residual = max(residual, res2.residual)
            if not (res2.success or res2.residual <= self.options.solver.tol):   # (see STAGE2_TOL)
                return v_next, StepReport(
                    False, iterations, res2.residual, res2.status.name, tuple(contacts), t0, 1,
                    f"the second stage of the split step failed at t = {t0:.6g} s ({res2.status.name}, residual "
                    f"{res2.residual:.3g}, h = {h:g}); a smaller h or on_failure='retry' may get through.",
                    problem.layout.n)
            at = 0
            for s in att.involved:
                v_next[s] = res2.x[at:at + len(u[s])]
                at += len(u[s])
            contacts = self._split_contacts(contacts, closed, stage2, res2.x)
            lam = {(s, r): float(res2.x[c]) for (s, r), c in zip(jrows, stage2.jcol)}
        # the joint rows' total impulses, in the units of [GI]'s rows (friction h f)
        self._last_joint = {}
        for s in att.involved:
            if s in joints:
                rows = _friction_units(joints[s], 2.0)      # [GI]'s unit h f again
                self._last_joint[s] = (rows, np.array([lam.get((s, r), 0.0) for r in range(len(rows.keys))]))
        return v_next, (iterations, residual, contacts)

    def _write_end_velocities(self, v_next, v_l, h):
        """v+ into DART, and the accelerations (v+ - v) / h."""
        w = self._world
        for s, rec in enumerate(self.scene.skeletons):
            k, o = w.sk_nv[s], w.sk_voff[s]
            if k:
                rec.skeleton.setVelocities(v_next[s])
                rec.skeleton.setAccelerations((v_next[s] - v_l[o:o + k]) / h)

    def _stage1_tables(self, h):
        """Stage 1's skeleton tables (rattle.py, eqs R1, R9): MB1 = M + h/2 dc/dv at (q, v), FB1 =
        f / 2 (the rows read h FB1 = h/2 f); joint springs and dampers at the midpoint: MB1 +=
        h/2 D + h^2/4 K, FB1 = (f - K (q - q_rest + h/2 v) - D v) / 2. (MB and FB hold [GI]'s
        tables, DART's implicit springs and dampers: M + h D + h^2 K, f - K (q - q_rest + h v) -
        D v; step_kernels.assemble_forces.)"""
        w = self._world
        for s, rec in enumerate(self.scene.skeletons):
            k, o, mo = w.sk_nv[s], w.sk_voff[s], w.sk_moff[s]
            if not k:
                continue
            if rec.kind == adapter.FREE and rec.spring_damper is None:     # (MB then holds DART's M)
                sk.free_stage1_tables(w.MB[mo:mo + k * k].reshape(k, k), w.V[o:o + 3], w.FB[o:o + k], h, self._coriolis,
                                      w.MB1[mo:mo + k * k], w.FB1[o:o + k])
                continue
            C = adapter.coriolis_jacobian(rec, w.V[o:o + k])
            M1 = w.MB[mo:mo + k * k].reshape(k, k) + 0.5 * h * C
            w.FB1[o:o + k] = 0.5 * w.FB[o:o + k]
            if rec.spring_damper is not None:
                K, D, v = w.SPK[o:o + k], w.SPD[o:o + k], w.V[o:o + k]
                M1[np.diag_indices(k)] -= 0.5 * h * D + 0.75 * h * h * K
                w.FB1[o:o + k] += 0.25 * h * K * v
            w.MB1[mo:mo + k * k] = M1.ravel()

    def _start_frame(self, spec, state) -> np.ndarray | None:
        """A pair's frame at l (rattle.start_frame): its closest points at l from the last step's
        solution when it had the pair (the same way round: _pair_spec builds a persisting pair
        from that memory), else from a static solve at l; None for a pair open at l (rattle.py:
        an impact takes stage 1's impulse where it lands)."""
        self._checkpoint()
        first, second = spec.objects
        d = spec.dim
        poses = state.poses_now
        tol = self.options.contact_tolerance
        k = self._last.keys.get(spec.key)
        if k is not None:
            rep = self._last.rep[k]
            if rep[rc.R_GAP] > tol:
                return None
            a1, a2, normal = rep[rc.R_A1:rc.R_A1 + d], rep[rc.R_A2:rc.R_A2 + d], rep[rc.R_N:rc.R_N + d]
        else:
            res = _closest_seed(first.piece, _pose_dim(poses[first.body], d), second.piece,
                                _pose_dim(poses[second.body], d))
            if res.distance > tol:
                return None
            normal = np.asarray(res.normal, float)
            # touching: the point nearest the centres (a face on a face touches along a patch), as _seed_pair
            P1, P2 = (fm.Pose(*_pose_dim(poses[o.body], d), np.zeros(3)) for o in (first, second))
            a1 = a2 = _central_touch_point(spec, P1, P2, np.asarray(res.a1, float), normal / np.linalg.norm(normal), tol)
        return self._frame_at_l(spec, a1, a2, normal, poses)

    @staticmethod
    def _frame_at_l(spec, a1, a2, normal, poses) -> np.ndarray:
        """rattle.start_frame of a pair from its closest points a1, a2 and normal at l (d entries
        each) and the body poses at l; a pair without a tangent axis yet gets one."""
        first, second = spec.objects
        d = spec.dim
        if spec.tangent_axis is None and d == 3:
            spec.tangent_axis = fm._least_aligned_axis(normal / np.linalg.norm(normal))
        out = np.empty(15)
        axis = spec.tangent_axis if d == 3 else _NO_AXIS
        rattle.start_frame(a1, a2, normal, axis, poses[first.body][1], poses[second.body][1], d, out)
        return out

    def _stage2(self, problem, z, att, u, hf, joints):
        """(rattle.Stage2 of the pairs closed at q+ and the joint rows, the closed pairs (index,
        stage-2 pairs), the joint rows (skeleton, row)): DART's M at q+, the bodies' Jacobians and
        origins at q+, the pairs' frames at q+, stage 1's impulses. A limit row is kept when it is
        closed at q+ or carried an impulse; friction and mimic rows always."""
        w = self._world
        tol = self.options.contact_tolerance
        problem._evaluated_at(z)
        rep = problem._rep
        closed, cps, bodies, index = [], [], [], {}
        vcol, nv = {}, 0
        for s in att.involved:
            vcol[s] = nv
            nv += len(u[s])
        for k, spec in enumerate(att.specs):
            sl = problem.layout.pairs[k]
            p_n = float(z[sl.p_n])
            if not (rep[k, rc.R_GAP] <= tol or p_n > 0.0):
                continue
            ends = []
            for obj in (spec.obj1, spec.obj2):
                b = att.body_ids[obj.body]
                rec = self.scene.bodies[b]
                if rec.kind == adapter.FIXED:
                    ends.append(-1)
                    continue
                if b not in index:
                    p, J = adapter.origin_and_jacobian(rec)
                    index[b] = len(bodies)
                    bodies.append((vcol[rec.skeleton_index], J, p))
                ends.append(index[b])
            R1 = np.zeros(4)
            R1[0] = p_n
            R1[1:1 + len(sl.p_t)] = z[sl.p_t]
            if sl.p_r >= 0:
                R1[3] = z[sl.p_r]
            fr = spec.friction if spec.with_friction else Friction(0.0)
            n, t, o = (rep[k, c:c + 3].copy() for c in (rc.R_N, rc.R_T, rc.R_O))
            mu, e_r = (fr.mu if sl.sigma >= 0 else 0.0), (fr.e_r if sl.p_r >= 0 else 0.0)
            sigma = float(z[sl.sigma]) if sl.sigma >= 0 else 0.0
            stage1 = rattle.ClosedPair(tuple(ends), (rep[k, rc.R_A1:rc.R_A1 + 3].copy(), rep[k, rc.R_A2:rc.R_A2 + 3].copy()),
                                       n, t, o, spec.dim, mu, fr.e_t, fr.e_o, e_r, spec.impulse_scale, R1, sigma)
            layer = {}
            if spec.compliance is not None:
                # the layer's impulse over the step, twice stage 1's half, and its core (R11, R12);
                # a damper stiff for the step acts at v+ in stage 2 (R14)
                p_nr = float(z[sl.p_nr]) if sl.p_nr >= 0 else 0.0
                comp, dn = spec.compliance, float(z[sl.dn])
                layer = dict(layered=True, load=2.0 * (p_n - p_nr),
                             core_open=not (p_nr > 0.0 or comp.delta_max - dn <= tol))
                if rattle.stiff_layer(comp, problem.h, self._reduced_mass(spec)):
                    dprev = float(problem.tables.pair_f[k, rc.Q_DPREV])    # (the repeat path's too)
                    layer["load"] -= 0.5 * comp.c_n * (dn - dprev) / spec.impulse_scale
                    layer["damp"] = 0.5 * problem.h * comp.c_n / spec.impulse_scale
            X = self._patch_vertices(spec, n) if landing.faceted_pair(spec) else None
            if X is None:
                if layer:
                    stage1 = replace(stage1, start_n=0.0 if layer["core_open"] else 2.0 * p_nr, **layer)
                cps.append(stage1)
                closed.append((k, 1))
                continue
            # a face on a face: its friction point and its patch's vertices at q+ (rattle.Stage2);
            # a layered one's vertices share the layer's load (its point: their normal velocity)
            cps.append(replace(stage1, known=True, R1=np.r_[R1[0], 0.0, 0.0, 0.0]))   # its normal part
            cps.append(replace(stage1, vertices=len(X), R1=np.r_[0.0, R1[1:]], **layer))  # and its friction
            share = (layer["load"] if layer else 2.0 * p_n) / len(X)
            for x in X:
                cps.append(replace(stage1, a=(x, x), mu=0.0, e_r=0.0, R1=np.zeros(4), start_n=max(share, 0.0)))
            closed.append((k, 1 + len(X)))
        skeletons, jrows, jdata = [], [], []
        for i, s in enumerate(att.involved):
            k, o, mo = w.sk_nv[s], w.sk_voff[s], w.sk_moff[s]
            skeletons.append((w.MB[mo:mo + k * k].reshape(k, k), u[s], hf[o:o + k]))   # (Stage2 copies them)
            rows = joints.get(s)
            if rows is not None:
                lam1 = z[problem.layout.joint_index[i]]
                full = _friction_units(rows, 2.0)
                for r, (kind, _) in enumerate(rows.keys):
                    closed_limit = float(rows.G[r] @ u[s]) + rows.c[r] <= tol / problem.h
                    if kind in (joint_rows.LOWER, joint_rows.UPPER) and not (closed_limit or lam1[r] > 0.0):
                        continue
                    g = np.zeros(nv)
                    g[vcol[s]:vcol[s] + k] = rows.G[r]
                    jrows.append((s, r))
                    jdata.append((g, full.unit[r], rows.lower[r], rows.upper[r], rows.unit[r] * lam1[r]))
        kept = self._stage2_kept
        if not jdata and kept is not None and kept.refresh(skeletons, bodies, cps):
            return kept, closed, jrows
        self._stage2_kept = rattle.Stage2(skeletons, bodies, cps, jdata)
        return self._stage2_kept, closed, jrows

    def _reduced_mass(self, spec) -> float:
        """m1 m2 / (m1 + m2) of a pair's mobile bodies (one mobile body: its mass)."""
        return 1.0 / sum(1.0 / self._masses[o.body] for o in spec.objects
                         if self.scene.bodies[o.body].kind != adapter.FIXED)

    def _patch_vertices(self, spec, n):
        """The vertices (m, 3) of a faceted pair's patch at q+ (DART's poses now) on its contact
        plane of normal n, or None if it is a point."""
        first, second = spec.objects
        poses = [adapter.body_pose(self.scene.bodies[o.body]) for o in (first, second)]
        X = landing.patch_points(first, second, *poses, n, contact_patch.band(first.piece, second.piece))
        return X if len(X) >= 2 else None

    def _split_contacts(self, contacts, closed, stage2, x):
        """Stage 1's contact reports with the step's total impulses of the closed pairs (stage 2);
        lazily made (_LazyContacts) if stage 1's are, from a copy of what they read of stage2
        (the next step refreshes the kept stage 2 in place: _stage2)."""
        if isinstance(contacts, _LazyContacts):
            frozen = copy.copy(stage2)
            frozen.G = stage2.G.copy()
            contacts.pending = lambda: self._split_updates(closed, frozen, x)
            return contacts
        contacts = list(contacts)
        for k, changes in self._split_updates(closed, stage2, x).items():
            contacts[k] = replace(contacts[k], **changes)
        return tuple(contacts)

    @staticmethod
    def _split_updates(closed, stage2, x) -> dict:
        """Per closed pair index the fields of its contact report that stage 2's solution x sets:
        the total impulses, the slip at v+, the layer's and the core's shares."""
        v = x[:stage2.nv]
        P_all = stage2.impulses(x)
        cores = stage2.core_impulses(x, P_all)
        updates, at = {}, 0
        for k, count in closed:
            # the pair, or a patch's friction point (its P_n is its vertices' sum) followed by them
            cp, G, P = stage2.pairs[at], stage2.G[at], P_all[at]
            core = cores[at]
            at += count
            slip = float(np.hypot(G[1] @ v, G[2] @ v)) if cp.dim == 3 else float(abs(G[1] @ v))
            updates[k] = dict(p_n=cp.s_p * P[0], p_t=cp.s_p * P[1], p_o=cp.s_p * P[2], p_r=cp.s_p * cp.e_r * P[3],
                              slip=slip, p_spring=cp.s_p * (P[0] - core), p_core=cp.s_p * core)
        return updates

    # -- a step that repeats the last one's structure ---------------------------------------------
    def _context(self, h, candidates, pairs, problem, att) -> "_Context":
        """What a committed step leaves for _repeat_step: its candidates, which of them it solved,
        the known lower bounds of their gaps for the next far-pair test (_known_gap), its problem
        and solve-loop state, and the buffers repeat_kernels.step fills (one bundle)."""
        P = np.array(candidates, dtype=np.int64).reshape(-1, 2)
        near = set(pairs)
        mask = np.array([pair in near for pair in candidates], np.bool_)
        gaps = np.array([_nan_if_none(self._known_gap(i, j)) for i, j in candidates])
        eligible = np.array([self._gap_bound_applies(i, j) for i, j in pairs], np.bool_)
        ctx = _Context(h, P, mask, gaps, problem, att, eligible)
        if problem is not None:
            ctx.patches = [k for k, sp in enumerate(att.specs) if self._patch_applies(sp)]
            src = next(c[3] for c in self._problems.values() if c[0] is problem)
            n, npairs, nc = problem.layout.n, len(att.specs), len(P)
            ctx.sup_y = np.zeros((len(problem.supports), 4))
            ctx.bundle = bundles.context(
                cand=P, near=mask, far=np.zeros(nc, np.bool_), far_P=np.zeros((nc, 2), np.int64), far_g=np.zeros(nc),
                gaps=gaps, eligible=eligible, flags=np.zeros(npairs, np.int64), near_gaps=np.zeros(npairs),
                left=np.zeros(nc), z0=np.zeros(n), sup_y=ctx.sup_y, src=src[0], J_at=src[5], h_body=src[6],
                sk_src=src[7], identity=np.arange(npairs, dtype=np.int64))
        return ctx

    def _repeat_step(self, h, t0) -> StepReport | None:
        """The step when it repeats the last one's structure: the same candidate pairs, the same
        ones left out as far, the same rows (friction rows where they were), fixed bodies where
        they were, no recovery needed. Then everything between reading DART and writing it back
        is one compiled call (repeat_kernels.step: the kernels _one_step calls one by one, on the
        last step's problem refreshed in place) instead of being rebuilt pair by pair; the
        mathematics is _one_step's (tests/test_repeat_step.py checks the trajectories are the same
        bitwise). None when anything differs or a check of _one_step would act: _one_step then
        takes the step from the start. Order 2 has its own: _split_repeat."""
        if self.options.order == 2:
            return self._split_repeat(h, t0)
        ctx = self._ctx
        w = self._world
        if (ctx is None or ctx.h != h or self._all_pairs or self._trapezoidal_skeletons() or w.moving_unbounded
                or self._joint_models):
            return None
        if ctx.problem is None:
            return self._repeat_free_flight(ctx, h, t0)
        problem, att = ctx.problem, ctx.att
        memory = self._last
        t = problem.tables
        lay = problem.layout
        if len(memory) != len(t.pair_i) or self._fat is None or problem._sparse:
            return None           # (the kernel's solve is dense: a sparse problem takes _one_step's LU)
        for s, (sp, ss) in (enumerate(zip(problem.supports, lay.supports)) if problem.supports else ()):
            last = self._last_support.get(sp.key)
            if last is None or len(last[0]) != ss.y.stop - ss.y.start:
                return None
            ctx.sup_y[s, :len(last[0])], ctx.sup_y[s, 3] = last[0], last[1]
        for k in ctx.patches:
            # as _pair_spec would: the patch at l along the last normal; a torsion row that
            # appears or goes changes the layout
            spec = att.specs[k]
            e_r = self._patch_radius(spec.objects, memory.rep[k, rc.R_N:rc.R_N + 3])
            if (e_r > 0.0) != spec.patch:
                return None
            if spec.patch:
                spec.friction = replace(spec.friction, e_r=e_r)
                t.pair_f[k, rc.Q_ER] = e_r
        if not w.dynamics_read:
            self._read_dart()
        code, new_f, new_z, new_rep, opts, counts = self._repeat_kernel(ctx, h, w.MB, w.FB, True,
                                                                        self.options.skip_far_pairs)
        if code != rk_repeat.OK:
            return None
        self._commit_world(h)
        self._last = memory.carried_arrays(new_f, new_z, new_rep)
        if len(ctx.gaps) != len(att.specs):       # pairs left out: their bounds after the step
            far = ~ctx.near
            left = ctx.gaps[far]
            self._far = {frozenset((self._objects[i].key, self._objects[j].key)): float(g)
                         for (i, j), g in zip(ctx.candidates[far], left)}
        else:
            self._far = {}
        if problem.supports:
            self._last_support = {sp.key: (new_z[ss.y].copy(), float(new_z[ss.sigma]), problem.support_wrench(new_z, s))
                                  for s, (sp, ss) in enumerate(zip(problem.supports, lay.supports))}
        iterations, residual, first_iterations, first_residual = counts
        message = (f"Converged in {first_iterations} iterations: natural residual "
                   f"{first_residual:.3g} <= tol {opts.tol:.3g}.")
        contacts = _LazyContacts(self, problem, new_z, att.specs, new_rep)
        return _made_report(True, iterations, residual, "CONVERGED", contacts, t0 + h, 1, message, lay.n, iterations)

    def _split_repeat(self, h, t0) -> StepReport | None:
        """_repeat_step for order 2: when stage 1 repeats the last step's structure (the same
        candidate pairs, all of them in the MCP, the same rows, no faceted pair, no joint rows or
        supports, no recovery), its MCP is one compiled call (repeat_kernels.step on the last stage
        1's problem, with stage 1's tables MB1, FB1 and each pair's frame at l from the last step's
        closest points, as _stage1 and _start_frame set them); then _split_step's checks (a contact
        point that jumped, a normal that turned over, a pair the broadphase did not offer) and its
        stage 2. The mathematics is _split_step's (tests/test_repeat_step.py: bit for bit). None
        when anything differs or a check would act: _split_step then takes the step afresh."""
        ctx, w = self._ctx, self._world
        if (ctx is None or ctx.h != h or ctx.problem is None or self._all_pairs or w.moving_unbounded
                or self._joint_models or ctx.problem.supports):
            return None
        problem, att, memory = ctx.problem, ctx.att, self._last
        t, lay = problem.tables, problem.layout
        if len(memory) != len(t.pair_i) or self._fat is None or problem._sparse:
            return None           # (the kernel's solve is dense, as in _repeat_step)
        state = self._read(h)
        if w.fixed_moved:
            return None
        self._stage1_tables(h)
        for k, spec in enumerate(att.specs):
            # the frame at l from the last step's closest points: the normal and tangent axis
            # _pair_spec takes from the memory, then _start_frame
            spec.normal_l = memory.rep[k, rc.R_N:rc.R_N + spec.dim].copy()
            if spec.dim == 3:
                spec.tangent_axis = np.empty(3)
                choose_axis(memory.pair_f[k, rc.Q_AXIS:rc.Q_AXIS + 3], memory.rep[k, rc.R_N:rc.R_N + 3], _AXIS_LIMIT,
                            spec.tangent_axis)
            frame = spec.start_frame = self._start_frame(spec, state)
            t.pair_i[k, rc.P_SPLIT] = int(frame is not None)
            t.pair_f[k, rc.Q_N0:rc.NPF] = frame if frame is not None else 0.0
        # (kinematics done by _read; no far pairs left out under order 2)
        code, new_f, new_z, new_rep, opts, counts = self._repeat_kernel(ctx, h, w.MB1, w.FB1, False, False)
        if code != rk_repeat.OK or self._jumped_pairs(new_rep, att.specs):
            return None
        problem._rep_at = new_z        # (the kernel left the pairs' reports at new_z: _stage2 reads them)
        for k, spec in enumerate(att.specs):
            if new_z[lay.pairs[k].p_n] > 0.0 and float(new_rep[k, rc.R_N:rc.R_N + spec.dim] @ spec.normal_l) < 0.0:
                return None                  # a normal that turned over: _check_solution refuses it
        u = self._half_kicks(h, att.involved)
        for s in att.involved:
            u[s] = new_z[lay.v_index[att.sk_pos[s]]]
        if self._uncovered(frozenset(map(tuple, ctx.candidates.tolist())), u, self._world_vector(u), state):
            return None
        iterations, residual = counts[:2]
        new_memory = memory.carried_arrays(new_f, new_z, new_rep)
        contacts = _LazyContacts(self, problem, new_z, att.specs, new_rep)
        first = (problem, att, new_z, iterations, residual, new_memory, contacts)
        second = self._split_end(first, u, {}, t0, h)
        if isinstance(second, StepReport):
            return second
        self._last, self._last_support, self._far = new_memory, {}, {}
        iterations, residual, contacts = second
        return StepReport(True, iterations, residual, "CONVERGED", contacts, t0 + h, 1, "", lay.n)

    def _repeat_kernel(self, ctx, h, MB, FB, kin, use_far):
        """repeat_kernels.step on ctx's problem from the last step's memory, with this step's
        solver options; coal asked again once on NEED_COAL. MB, FB: the skeleton tables the rows
        read; kin: the kernel checks the state read and does the kinematics (False: _read did).
        (code, the next memory's pair parameters, solution and reports, the options, the counts of
        _repeat_counts)."""
        w, problem, memory = self._world, ctx.problem, self._last
        opts = self._solver_options()
        if self._budget is not None:
            opts = self._budget.admit(opts)
        if ctx.solver is None or ctx.solver[0] is not opts:
            ctx.solver = (opts,) + step_solver.solver_bundles(problem, opts)
            ctx.repeat = bundles.repeat(W=w.bundle, T=problem.bundle, S=ctx.solver[1], SP=ctx.solver[2],
                                        C=ctx.bundle)
        new_f, new_z, new_rep = np.empty_like(problem.tables.pair_f), np.empty(problem.layout.n), np.empty_like(problem._rep)
        args = (ctx.repeat, MB, FB)
        tail = (memory.pair_i, memory.pair_f, memory.z, memory.rep, new_f, new_z, new_rep, h,
                self.options.contact_tolerance, self.options.solver.tol, _TOUCH, _AXIS_LIMIT, use_far)
        fat = self._fat
        code = rk_repeat.step(*args, fat[0], fat[1], fat[2], fat[3], kin, *tail)
        if code == rk_repeat.NEED_COAL:
            self._refresh_fat(w.margins)
            fat = self._fat
            code = rk_repeat.step(*args, fat[0], fat[1], fat[2], fat[3], False, *tail)
        if code in _REFUSED_BEFORE_SOLVE:
            return code, None, None, None, opts, None       # (nothing solved, nothing to count)
        problem._invalidate()
        problem.h = h
        counts = self._repeat_counts(ctx, opts)
        if self._budget is not None:
            self._budget.spend(counts[0])
        else:
            self._repeat_spent = counts[0]      # (_quick_repeat: charged by step() if it failed)
        return code, new_f, new_z, new_rep, opts, counts

    @staticmethod
    def _repeat_counts(ctx, opts):
        """(Newton iterations, natural residual) of the repeat kernel's solve, its polish counted
        when it was kept (step_solver.solve's rule), then those of the solve before its polish
        (the report's message, as step_solver.solve's)."""
        buf, pbuf = ctx.solver[3], ctx.solver[4]
        iterations, residual = buf.info.item(ncp.I_ITER), buf.fbuf.item(ncp.F_RESIDUAL)
        if residual > 1e-3 * opts.tol:
            polished = pbuf.fbuf.item(ncp.F_RESIDUAL)
            if polished < residual:
                return iterations + pbuf.info.item(ncp.I_ITER), polished, iterations, residual
        return iterations, residual, iterations, residual

    def _repeat_free_flight(self, ctx, h, t0) -> StepReport | None:
        """_repeat_step when no pair was near: the same candidates, all far, and still out of reach
        at free flight: every skeleton takes its free step."""
        if self._supports:
            return None
        w = self._world
        state = self._read(h)
        if w.fixed_moved:
            return None
        tol = self.options.contact_tolerance
        P = self._candidate_array(state)
        if not np.array_equal(P, ctx.candidates):
            return None
        far = np.zeros(len(P), np.bool_)
        if self.options.skip_far_pairs:
            sk.far_test(P, ctx.gaps, w.ob_body, w.ob_radius, w.bd_kind, w.bd_sk, w.sk_voff, w.VF, h, tol, far)
        if not far.all():
            return None
        left = np.empty(len(P))
        if len(P) and sk.far_after(P, ctx.gaps, w.ob_body, w.ob_radius, w.bd_kind, w.bd_sk, w.sk_voff, w.VF, h, tol,
                                   left):
            return None
        self._commit(state, state.v_free)
        self._far = {frozenset((self._objects[i].key, self._objects[j].key)): float(g) for (i, j), g in zip(P, left)}
        ctx.gaps[:] = left
        return StepReport(True, 0, 0.0, "NO_CONTACT", (), t0 + h, 1, "no pair near", 0)

    def _read(self, h) -> "_StepState":
        """DART's state at l: each mobile skeleton's q, v, M and force (adapter.read_dynamics) and
        the poses of fixed and articulated bodies, into the world buffers; then (step_kernels) the
        free-flight velocities v + h M^-1 force, every body's pose now and after a free step, and
        each piece's motion margin for the broadphase."""
        w = self._world
        self._read_dart()
        # forces, given poses, free flight, poses, margins (step_kernels.kinematics); whether a
        # fixture moved since the last read (its unbounded pieces' boxes, _repeat_step); the
        # "midpoint" quasi-rigid scheme also needs the poses half a step on at v (see _problem)
        w.fixed_moved = sk.kinematics(w.bundle, h, 10.0 * self.options.contact_tolerance,
                                      bool(self._trapezoidal_skeletons()))
        return _StepState(h, w.states, w.v_free, w.poses_now, w.poses_pred, w.margins)

    def _read_dart(self):
        """What _read reads of DART into the world buffers (step_kernels.kinematics does the rest)."""
        scene, w = self.scene, self._world
        raw = not w.raw_valid
        for rec, (q, v, tau, fext, _), M, cg in w.skeleton_views:
            if raw:
                adapter.read_raw(rec, q, v, tau, fext)
            adapter.read_dynamics(rec, M, cg)
        for b in w.read_bodies_list:
            adapter.read_body(scene.bodies[b], w.TG[b], w.J_views.get(b))

    def _candidates(self, state, keep) -> frozenset:
        """Pairs of pieces whose boxes (now and after a free step, grown by their motion margins)
        overlap: coal's broadphase, queried on fat boxes and filtered exactly.

        Fat boxes: each piece's grown box, grown once more by three margins plus _FAT_SLACK of its size.
        While every grown box stays inside its fat box, the pairs whose grown boxes overlap are
        among the fat pairs coal returned last, so coal is not asked again; the exact closed
        overlap test of broadphase.py on the fat pairs gives the same candidates as a query on
        the grown boxes themselves."""
        pairs = {(int(a), int(b)) for a, b in self._candidate_array(state)}
        return frozenset(pairs | set(keep))

    def _candidate_array(self, state) -> np.ndarray:
        """The candidate pairs of _candidates as a sorted (n, 2) array (no kept pairs)."""
        w = self._world
        self._exact_boxes(w.R_now, w.p_now, w.R_pred, w.p_pred, w.is_mobile, settled=not w.fixed_moved)
        glo, ghi = w.glo, w.ghi
        fat = self._fat
        inside = sk.grown_boxes(w.bundle, w.no_box if fat is None else fat[0], w.no_box if fat is None else fat[1])
        if fat is None or not inside:
            self._refresh_fat(state.margins)
            fat = self._fat
        P, ok = fat[2], fat[3]
        sk.overlapping(P, glo, ghi, ok)
        return P[ok]

    def _refresh_fat(self, margins):
        """Query coal on the fat boxes of the grown boxes (see _candidates): (fat lo, fat hi, the
        pairs found (n, 2), an overlap mask buffer)."""
        w = self._world
        if self._every_pair is not None:
            # few pieces: every allowed pair is a fat pair, in boxes no piece leaves (the exact test
            # on them gives the candidates coal's query would; the rolling disc asked coal every
            # ~12 steps, 80 us each)
            flo = np.full_like(w.glo, -np.inf)
            self._fat = (flo, -flo, self._every_pair, np.empty(len(self._every_pair), np.bool_))
            return
        m = margins[:, None]
        slack = 3.0 * m + _FAT_SLACK * self._sizes[:, None]
        flo, fhi = w.glo - slack, w.ghi + slack
        found = np.array([p for p in self._broadphase.candidates(flo, fhi, 0.0) if self._allowed(*p)],
                         dtype=np.int64).reshape(-1, 2)
        self._fat = (flo, fhi, found, np.empty(len(found), np.bool_))

    def _allowed(self, i, j) -> bool:
        """Pieces that may touch: two bodies, not of one skeleton (no self-collision, DART's
        default), not both fixed."""
        oi, oj = self._objects[i], self._objects[j]
        if oi.body == oj.body:
            return False
        bi, bj = self.scene.bodies[oi.body], self.scene.bodies[oj.body]
        if bi.world_skeleton == bj.world_skeleton and bi.world_skeleton >= 0:
            return False
        return not (bi.kind == adapter.FIXED and bj.kind == adapter.FIXED)

    def _boxes(self, R1, p1, R2, p2, join):
        """World AABBs (lo, hi), (n, 3), of every piece at poses (R1, p1), joined with its box at
        (R2, p2) where join[body] (step_kernels.piece_boxes); unbounded pieces: their exact box."""
        w = self._world
        self._exact_boxes(R1, p1, R2, p2, join)
        lo, hi = np.empty((len(self._objects), 3)), np.empty((len(self._objects), 3))
        sk.piece_boxes(w.ob_body, w.ob_bounded, w.ob_dim, w.ob_centre, w.ob_half, w.exact_lo, w.exact_hi,
                       R1, p1, R2, p2, join, lo, hi)
        return lo, hi

    def _exact_boxes(self, R1, p1, R2, p2, join, settled=False):
        """The exact boxes of the unbounded pieces (exact_lo, exact_hi), where their poses changed;
        settled: the fixed bodies are where they were when their boxes were made."""
        w = self._world
        for k in w.unbounded:
            o = self._objects[k]
            if not join[o.body] and w.exact_known[k] and (settled or (np.array_equal(o._last[0], R1[o.body])
                                                                       and np.array_equal(o._last[1], p1[o.body]))):
                continue
            lo, hi = o.box((R1[o.body], p1[o.body]))
            if join[o.body]:
                l2, h2 = o.box((R2[o.body], p2[o.body]))
                lo, hi = np.minimum(lo, l2), np.maximum(hi, h2)
            w.exact_lo[k], w.exact_hi[k] = lo, hi
            w.exact_known[k] = not join[o.body]

    def _pairs_at(self, poses, margins, extra_poses=None):
        """Candidate pairs from a direct broadphase query at poses (body -> (R, p)), joined with
        extra_poses where given (the start-of-run overlap check and the end-of-step check of
        _uncovered; steps use _candidates)."""
        nb = len(self.scene.bodies)
        R1, p1 = np.zeros((nb, 3, 3)), np.zeros((nb, 3))
        R2, p2 = np.zeros((nb, 3, 3)), np.zeros((nb, 3))
        join = np.zeros(nb, np.bool_)
        for b in range(nb):
            R1[b], p1[b] = poses[b]
            if extra_poses is not None and b in extra_poses:
                R2[b], p2[b] = extra_poses[b]
                join[b] = True
        lo, hi = self._boxes(R1, p1, R2, p2, join)
        return [p for p in self._broadphase.candidates(lo, hi, margins) if self._allowed(*p)]

    def _world_vector(self, per_skeleton):
        """Per-skeleton velocities as one world vector (the layout of the world buffers)."""
        w = self._world
        out = np.empty_like(w.V)
        for s, v in enumerate(per_skeleton):
            out[w.sk_voff[s]:w.sk_voff[s] + w.sk_nv[s]] = v
        return out

    def _free_step(self, state, far, keep, t0) -> StepReport:
        """No pair can touch within the step: every skeleton takes its free-flight step."""
        far_next, violated = self._far_after(far, self._world.VF, state.h)
        if violated:
            return self._one_step(state.h, keep | violated)
        self._commit(state, state.v_free)
        self._last = PairMemory()
        self._last_support = {}
        self._far = far_next
        return StepReport(True, 0, 0.0, "NO_CONTACT", (), t0 + state.h, 1, "no pair near", 0)

    def _joint_rows(self, state) -> dict:
        """skeleton -> its joint rows for this step (joint_rows.py): friction rows, and the rows
        of the limits it is near or crossed in a solve of this step."""
        out = {}
        if not self._joint_models:
            return out
        w = self._world
        tol = self.options.contact_tolerance
        for s, model in self._joint_models.items():
            o, k = w.sk_voff[s], w.sk_nv[s]
            q, st = w.Q[o:o + k], state.states[s]
            keys = joint_rows.near(model, q, st.v, state.v_free[s], state.h, tol) | self._forced_limits.get(s, set())
            rows = joint_rows.build(model, keys, q, st.M, state.h, self._gravity_norm)
            if rows is not None:
                out[s] = rows
        return out

    def _limits_crossed(self, state, joints, v_solved) -> bool:
        """Whether the solved step crosses a limit whose row it left out (those rows are then
        forced for the rest of this step)."""
        w = self._world
        found = False
        for s, model in self._joint_models.items():
            if len(model.limited) == 0:
                continue
            o, k = w.sk_voff[s], w.sk_nv[s]
            present = set(joints[s].keys) if s in joints else set()
            new = joint_rows.crossed(model, w.Q[o:o + k], v_solved[s], state.h, self.options.contact_tolerance, present)
            if new:
                self._forced_limits[s] = self._forced_limits.get(s, set()) | new
                found = True
        return found

    def _specs(self, pairs, state, joints=None) -> recovery.Attempt:
        """The pairs' specs and the step's bodies and skeletons, as the solve loop's state."""
        scene = self.scene
        supported = sorted(self._supports)
        # skeletons that take part in the MCP (every body with support friction does, and every
        # skeleton with joint friction)
        joints = joints or {}
        involved = sorted({scene.bodies[self._objects[i].body].skeleton_index for p in pairs for i in p}
                          .union(scene.bodies[b].skeleton_index for b in supported)
                          .union(joints) - {-1})
        body_ids = sorted({self._objects[i].body for p in pairs for i in p}.union(supported))
        body_pos = {b: k for k, b in enumerate(body_ids)}
        specs = [self._pair_spec(i, j, state.h, body_pos, state.states) for i, j in pairs]
        self._share_patches(specs)
        att = recovery.Attempt(specs, list(pairs), self.options.contact_tolerance, self.options.solver.tol, state.h,
                               body_pos, state.states)
        att.involved, att.body_ids = involved, body_ids
        att.joints = [joints.get(s) for s in involved]
        att.sk_pos = {s: k for k, s in enumerate(involved)}
        att.supports = tuple(SupportSpec(body_pos[b], self._supports[b], b) for b in supported)
        att.nv = [scene.skeletons[s].ndof for s in involved]
        att.articulated = any(scene.skeletons[s].kind == adapter.ARTICULATED for s in involved)
        return att

    def _solve_step(self, att, state):
        """Solve the step's MCP; after each solve the recoveries (recovery.RECOVERIES, in order)
        may arrange another (recovery.py lists them with the cases that needed them)."""
        problem = result = None
        att.state = state
        for att.index in range(recovery.MAX_SOLVES):
            problem = self._problem(state, att)
            if att.reseeded is not None:
                z0, att.reseeded = att.reseeded, None
            elif att.previous is None:
                z0 = self._warm_start(problem, att, state)
            else:
                z0 = recovery._transfer(*att.previous, problem, att.sliding)
            att.z0 = z0
            result = recovery.watched_solve(self, att, problem, z0)
            for strategy in recovery.RECOVERIES:
                outcome = strategy(self, att, problem, result)
                if outcome is not None:
                    break
            if outcome is not recovery.RETRY:
                if outcome is not None:
                    result = outcome          # a recovery turned the solve into a failure
                break
        else:
            result = recovery.out_of_solves(att, problem, result)
        return problem, result

    def _friction_stages(self, att, fractions):
        """recovery.friction_homotopy's stages: the attempt's step solved with every pair's mu scaled
        by each fraction in turn, each from the last stage's iterate (the first from the warm start).
        Returns the last iterate (None if it is not finite); the specs' frictions are restored."""
        state = att.state
        frictions = [sp.friction for sp in att.specs]
        z = None
        try:
            for fraction in fractions:
                for sp, fr in zip(att.specs, frictions):
                    sp.friction = replace(fr, mu=fraction * fr.mu)
                problem = self._problem(state, att)
                if z is None:
                    z = self._warm_start(problem, att, state)
                z = self._solve(problem, z).x
                if not np.all(np.isfinite(z)):
                    return None
        finally:
            for sp, fr in zip(att.specs, frictions):
                sp.friction = fr
        return z

    def _solution(self, problem, z, specs):
        """(the contact reports, made when first read (_LazyContacts), the memory of the next step)
        of a solved step. The case for laziness: 100 superquadrics in a box, ~175 pairs a landing
        step, whose reports took ~3 ms of a ~78 ms step that nobody reads in a benchmark."""
        memory = PairMemory(problem, z, specs)
        # (the reports read the memory's copies of z and of the pairs' reports, as on the repeat path)
        return _LazyContacts(self, problem, memory.z, specs, memory.rep), memory

    def _commit_world(self, h):
        """_commit of the solved velocities repeat_kernels.step left in the world buffers (V_solved,
        and the accelerations (v+ - v) / h in DV; no midpoint scheme)."""
        w = self._world
        w.raw_valid = False
        for skel, v_next, dv in w.commit_views:
            skel.setVelocities(v_next)
            skel.integratePositions(h)
            skel.setAccelerations(dv)

    def _commit(self, state, velocities):
        """Write v+ and let DART integrate q+ = q (+) h v+ for every mobile skeleton."""
        self._world.raw_valid = False
        midpoint = self._trapezoidal_skeletons()
        for s, rec in enumerate(self.scene.skeletons):
            adapter.write_velocities_and_integrate(rec, velocities[s], state.states[s].v, state.h,
                                                   midpoint=s in midpoint)

    # -- pairs that cannot touch within the step -------------------------------------------------
    def _far_pairs(self, pairs, v_free, h, keep):
        """Split broadphase candidates into the pairs the MCP needs and the far ones it does not.

        A pair is far when a lower bound g of its gap at the start of the step (the gap of its last
        solution, exact for a rigid pair whose bodies moved as the formulation moves them, or the
        bound carried from the step that left it out) exceeds a bound on how much the step can close
        it (the solver's tolerance on the closest points is 10 contact tolerances off g): a point of
        piece i at distance <= rho_i from its body's origin moves by at most
        h (|v_i| + |omega_i| rho_i), so the gap shrinks by at most
            delta = h |v_i - v_j| + h (|omega_i| rho_i + |omega_j| rho_j)
        at the velocities the step ends with. Those are not known yet: the prediction uses the
        free-flight velocities plus one free step of each body's own motion (as the broadphase
        margins do, doubled), and _far_after checks the solved velocities; a pair that fails that
        check is solved with the others (the step runs again). Only rigid pairs of single-body
        free, planar or fixed skeletons integrated by backward Euler qualify. Returns (the pairs
        to solve, {pair: g} of those left out)."""
        if not self.options.skip_far_pairs or self._all_pairs or self._trapezoidal_skeletons():
            return pairs, {}
        if not pairs:
            return pairs, {}
        w = self._world
        P = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        gap = np.array([_nan_if_none(self._known_gap(i, j)) if (i, j) not in keep else math.nan for i, j in pairs])
        far = np.zeros(len(P), np.bool_)
        if sk.far_test(P, gap, w.ob_body, w.ob_radius, w.bd_kind, w.bd_sk, w.sk_voff, w.VF, h,
                       self.options.contact_tolerance, far):
            self._left_out = True
        near = [pair for pair, f in zip(pairs, far) if not f]
        return near, {pair: float(g) for pair, g, f in zip(pairs, gap, far) if f}

    def _far_after(self, far, V_solved, h):
        """({pair: lower bound of its gap after the step}, pairs whose bound the solved velocities
        (world vector) do not keep above the contact tolerance; step_kernels.far_after)."""
        if not far:
            return {}, frozenset()
        w = self._world
        pairs = list(far)
        P = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        gap = np.array([far[p] for p in pairs])
        left = np.empty(len(P))
        tol = self.options.contact_tolerance
        sk.far_after(P, gap, w.ob_body, w.ob_radius, w.bd_kind, w.bd_sk, w.sk_voff, V_solved, h, tol, left)
        bounds = {frozenset((self._objects[i].key, self._objects[j].key)): float(g) for (i, j), g in zip(pairs, left)}
        return bounds, frozenset(p for p, g in zip(pairs, left) if g <= tol)

    def _uncovered(self, candidates, v_solved, V_solved, state):
        """Pairs the broadphase did not offer that the solved step could bring into contact.

        The candidates come from the free-flight motion plus a margin (see _read). An impact can
        change a body's velocity by more than that margin covers (a ball at rest knocked into a wall
        1 cm away, measured: 3 cm deep before this check). Each object's end pose is at most
        h (|dv| + |d omega| rho) from its predicted one (dv: solved minus free-flight velocity);
        if that exceeds the margin's motion allowance, the broadphase runs again at the solved end
        poses and the pairs it finds that were not candidates are returned."""
        scene = self.scene
        h, states = state.h, state.states
        tol = self.options.contact_tolerance
        w = self._world
        if not sk.moved_beyond_margins(w.ob_body, w.ob_radius, w.ob_bounded, w.bd_kind, w.bd_sk, w.sk_voff,
                                       V_solved, w.VF, state.margins, h, tol):
            return frozenset()
        w = self._world
        midpoint = self._trapezoidal_skeletons()
        V_end = np.empty_like(w.V)
        for s in range(len(scene.skeletons)):
            o, k = w.sk_voff[s], w.sk_nv[s]
            V_end[o:o + k] = 0.5 * (states[s].v + v_solved[s]) if s in midpoint else v_solved[s]
        nb = len(scene.bodies)
        R_end, p_end, th_end = np.empty((nb, 3, 3)), np.empty((nb, 3)), np.empty(nb)
        sk.body_poses(w.bd_kind, w.bd_sk, w.bd_joff, w.sk_voff, w.sk_nv, w.Q, V_end, h, w.R_given, w.p_given, w.JB,
                      R_end, p_end, th_end)
        lo, hi = self._boxes(w.R_now, w.p_now, R_end, p_end, w.is_mobile)
        after = [p for p in self._broadphase.candidates(lo, hi, 10.0 * tol) if self._allowed(*p)]
        return frozenset(p for p in after if p not in candidates)

    def _gap_bound_applies(self, i, j) -> bool:
        """Whether pair (i, j) may be left out as far (_far_pairs): rigid, of single-body free,
        planar or fixed skeletons, with known piece radii."""
        oi, oj = self._objects[i], self._objects[j]
        if oi.compliance is not None or oj.compliance is not None:
            return False
        bi, bj = self.scene.bodies[oi.body], self.scene.bodies[oj.body]
        if any(b.kind not in (adapter.FREE, adapter.PLANAR, adapter.FIXED) for b in (bi, bj)):
            return False
        if frozenset((bi.index, bj.index)) in self._pair_compliance:
            return False
        return not any(o.radius is None and self.scene.bodies[o.body].kind != adapter.FIXED for o in (oi, oj))

    def _known_gap(self, i, j):
        """A lower bound of the gap of candidate pair (i, j) now, or None (see _far_pairs)."""
        if not self._gap_bound_applies(i, j):
            return None
        oi, oj = self._objects[i], self._objects[j]
        last = self._last.get((oi.key, oj.key)) or self._last.get((oj.key, oi.key))
        if last is not None:
            return last["distance"] - 10.0 * self.options.contact_tolerance if last["p_n"] == 0.0 else None
        return self._far.get(frozenset((oi.key, oj.key)))

    # -- pieces of a step ------------------------------------------------------------------------
    def _checkpoint(self):
        """The step's budget checked before a static closest-point solve (closest.py, plain
        Python, not counted in Newton iterations): a hexagonal prism landing (face-contact
        campaign, --repro 2099577737,land,prism,0.018837255077567443) spent 26.7 s of a step
        that took 61 Newton iterations in such solves, so only max_step_seconds bounds them."""
        if self._budget is not None:
            self._budget.admit(None)

    def _variant(self, opts, limit, watch) -> ncp.SolverOptions:
        """opts with max_iterations = limit and the given watch, kept per (opts, limit, watch):
        step_solver keeps a solve's buffers per options object."""
        key = (id(opts), limit, watch)
        held = self._variants.get(key)
        if held is None or held[0] is not opts:
            if len(self._variants) > 64:
                self._variants.clear()
            held = self._variants[key] = (opts, replace(opts, max_iterations=limit, watch=watch))
        return held[1]

    def _retry_options(self) -> ncp.SolverOptions:
        """The solver options of a retried step's substeps: they are the hard ones (measured: a box
        slapping flat onto the ground converges in ~100 LM iterations), so a larger budget."""
        if self._retry_solver is None:
            opts = self.options.solver
            self._retry_solver = replace(opts, max_iterations=self.options.retry_iterations_factor * opts.max_iterations)
        return self._retry_solver

    def _solver_options(self) -> ncp.SolverOptions:
        """The solver options of this step's solves: the retry policy's for a retried step's substeps."""
        return self._retry_options() if self._retrying else self.options.solver

    def _solve(self, problem, z0, sync=True, limit=None, watch=0, proximal=False, stop=None):
        """step_solver.solve (compiled, polished; see there), with the retry policy's budget;
        limit: at most this many iterations; watch: ncp.SolverOptions.watch (recovery.watched_solve);
        proximal: by the proximal point method (recovery.indeterminate_impulses); stop: ncp.solve_mcp's
        (recovery.row_switch_test)."""
        opts = self._solver_options()
        if limit is not None or watch:
            opts = self._variant(opts, opts.max_iterations if limit is None else limit, watch)
        budget = self._budget
        if budget is not None:
            opts = budget.admit(opts)
        try:
            result = step_solver.solve(problem, z0, opts, sync, proximal, stop)
            if budget is not None:
                budget.spend(result.iterations)
            return result
        except (ZeroDivisionError, FloatingPointError, OverflowError, ValueError) as exc:
            if isinstance(exc, ValueError) and "math domain" not in str(exc):
                raise
            # under NUMBA_DISABLE_JIT the rows are plain Python and an undefined row raises (compiled,
            # it is inf / NaN and the solver says NOT_FINITE): a failed solve like any other, never a
            # crash half-way through a step
            return ncp.McpResult(np.asarray(z0, float).copy(), np.full(len(z0), np.nan), ncp.Status.NOT_FINITE,
                                 0, math.inf, (), f"rows undefined at an iterate: {exc!r}", "", 0, 0)

    def _problem(self, state, att):
        """The step problem of the attempt's specs: kept by layout signature, bodies and h, with
        its bodies' kinematics and skeleton blocks (views of the world buffers), and refreshed
        from the world buffers (rows/tables.fill_state) and the specs."""
        scene, w = self.scene, self._world
        h = state.h
        nv, specs, involved, sk_pos = att.nv, att.specs, att.involved, att.sk_pos
        body_ids, body_pos, supports = att.body_ids, att.body_pos, att.supports
        signature = (tuple(nv), tuple((sp.key, sp.with_friction, sp.friction.torsion, sp.dim,
                                       sp.obj1.fixed_halfspace, sp.obj2.fixed_halfspace,
                                       None if sp.compliance is None else math.isfinite(sp.compliance.delta_max))
                                      for sp in specs),
                     tuple((sp.body, sp.friction.torsion) for sp in supports),
                     tuple(None if jr is None else jr.keys for jr in att.joints))
        stage1 = self._split_stage1
        key = (signature, tuple(body_ids), h, stage1)
        cached = self._problems.get(key)
        if cached is None:
            if len(self._problems) > 256:       # scenes whose pairs keep changing
                self._problems.clear()
            joints = att.joints
            layout = fm.build_layout(nv, specs, supports,
                                     tuple(None if jr is None else (jr.lower, jr.upper) for jr in joints))
            midpoint = bool(self._trapezoidal_skeletons())
            R_src, p_src, th_src = (w.R_half, w.p_half, w.th_half) if midpoint else (w.R_now, w.p_now, w.th_now)
            kins = []
            for b in body_ids:
                rec = scene.bodies[b]
                # the trapezoidal scheme starts from the pose after half a step at v (rows/tables.py)
                hk = h / 2 if (midpoint and rec.kind != adapter.FIXED) else h
                vindex = layout.v_index[sk_pos[rec.skeleton_index]] if rec.kind != adapter.FIXED else None
                q0 = np.array([p_src[b, 0], p_src[b, 1], th_src[b]]) if rec.kind == adapter.PLANAR else None
                J = None
                if rec.kind == adapter.ARTICULATED:
                    jo, k = w.bd_joff[b], w.bd_nv[b]
                    J = w.JB[jo:jo + 6 * k].reshape(6, k)
                kins.append(fm.BodyKinematics(rec.kind, rec.dim, R_src[b], p_src[b], q0, hk, vindex,
                                              self._masses[b], J))
            blocks = [fm.SkeletonBlock(state.states[s].M, state.states[s].v, state.states[s].force,
                                       next((body_pos[b] for b in scene.skeletons[s].body_indices if b in body_pos), -1),
                                       jr)
                      for s, jr in zip(involved, joints)]
            ids = np.asarray(body_ids, np.int64)
            # order 2's stage 1 reads its own skeleton tables (rattle.py, eq R1; _stage1_tables)
            MB, FB = (w.MB1, w.FB1) if stage1 else (w.MB, w.FB)
            source = (ids, R_src, p_src, th_src, w.JB, w.bd_joff[ids],
                      np.array([kin.h for kin in kins]), np.asarray(involved, np.int64), w.sk_voff, w.sk_moff,
                      w.V, MB, FB)
            problem = fm.StepProblem(h, blocks, kins, specs, layout, supports, source=source)
            cached = self._problems[key] = (problem, kins, blocks, source)
            return problem
        problem, kins, blocks, source = cached
        for block, jr in zip(blocks, att.joints):   # this step's c and units (joint_rows.build)
            block.joints = jr
        for kin, b in zip(kins, body_ids):
            if kin.kind == adapter.PLANAR:       # q0 is a copy (the planar angle is not in a buffer row)
                kin.q0[:] = (source[2][b, 0], source[2][b, 1], source[3][b])
        problem.refresh(h, blocks, kins, specs, supports, source)
        return problem

    def _impulse_speed(self, h) -> float:
        """u_p = max(h g, IMPULSE_SPEED): a pair's impulse unit is s_p = m u_p (m its lighter body)."""
        return max(h * max(self._gravity_norm, 1.0), IMPULSE_SPEED)

    def _pair_spec(self, i, j, h, body_pos, states):
        scene = self.scene
        oi, oj = self._objects[i], self._objects[j]
        # body 1 is a single function when the other side is an intersection ([GI] Sec. 4.3; two
        # intersections take the cone form, rows/contact.py); a fixed half-space (the ground) is
        # body 2, as in the paper's Example 1.
        single_i, single_j = len(oi.funcs) == 1, len(oj.funcs) == 1
        if single_i != single_j:
            first, second = (oi, oj) if single_i else (oj, oi)
        elif single_i and oi.fixed_halfspace and not oj.fixed_halfspace:
            first, second = oj, oi
        elif not single_i:
            first, second = self._orient_intersections(oi, oj)
        else:
            first, second = oi, oj
        key = (first.key, second.key)
        b1, b2 = scene.bodies[first.body], scene.bodies[second.body]
        dim = max(b1.dim, b2.dim)
        friction = self._pair_friction.get(frozenset((b1.index, b2.index)),
                                           Friction.combine(first.friction, second.friction))
        # the unit of the pair's impulse unknowns (a scaling only; masses as at construction):
        # m h g, what holds a body at rest, but at least m IMPULSE_SPEED, what stops it from a
        # slow approach (an impact at h = 1e-5 is 1e5 units of m h g otherwise)
        masses = [self._masses[b.index] for b in (b1, b2) if b.kind != adapter.FIXED]
        s_p = min(masses) * self._impulse_speed(h)
        last = self._last.get(key)
        # friction rows for pairs that touched at the last step; the others get them if they touch
        with_friction = friction.active and last is not None and last["p_n"] > _TOUCH * s_p
        axis = None
        if dim == 3 and last is not None:
            # the tangents come from Gram-Schmidt on a fixed axis; keep the axis while the normal
            # stays far from it, else take a new one (the warm start rotates the friction along)
            axis = np.empty(3)
            choose_axis(last["axis"], last["normal"], _AXIS_LIMIT, axis)
        compliance = self._pair_compliance.get(frozenset((b1.index, b2.index)),
                                               Compliance.series(first.compliance, second.compliance))
        # the deformed layer sits on the compliant body (body 2 if both or only a pair setting);
        # a compliant half-space's closest point is not on its undeformed plane: no reduction
        side = 1 if (compliance is not None and first.compliance is not None
                     and second.compliance is None) else 2
        red1 = first.fixed_halfspace and not (compliance is not None and side == 1)
        red2 = second.fixed_halfspace and not (compliance is not None and side == 2)
        o1 = fm.ContactObject(body_pos[first.body], first.funcs, red1, first.label)
        o2 = fm.ContactObject(body_pos[second.body], second.funcs, red2, second.label)
        delta_prev = last["deflection"] if last is not None else 0.0
        spec = fm.PairSpec(key, o1, o2, dim, friction, with_friction, 0, axis, s_p, (first, second),
                           compliance, side, delta_prev)
        if compliance is not None and self._split_stage1:
            spec.layer_share = 0.5      # order 2's first stage: half the layer's impulse (rattle.py, R11)
        if last is not None:
            spec.normal_l = last["normal"]
        return spec

    def _patch_applies(self, spec) -> bool:
        """Whether a pair's torsion comes from its contact patch: 3D, friction rows, no e_r of its
        own, two faceted pieces, not shared (_share_patches), options.patch_torsion."""
        return (spec.with_friction and not spec.shared and (spec.patch or spec.friction.e_r == 0.0)
                and landing.faceted_pair(spec) and self.options.patch_torsion)

    def _share_patches(self, specs, solved=None, fresh=()):
        """Patch torsion (_add_patch_torsion) for the pairs with friction rows, each along its
        normal at its contact point (the last step's a2 and normal from the memory; solved[k], a
        solve's (a2, normal), for the pairs in fresh and those the memory lacks), except a pair
        another touching pair between the same two skeletons (every fixed body counts as one, the
        world) holds against spinning about its normal by tangential friction on a lever arm over
        SHARE_LEVER times its torsion radius (spec.shared: no patch torsion, taken off if it had
        one). Decided when a step's pairs and rows are set (_specs, recovery.friction_rows) and
        kept while a step repeats them (_repeat_step).

        Such a pair's torsion row (a sticking n . w_rel = 0) repeats a constraint the other
        pair's friction holds, and where several do, the Newton matrix is singular along their
        torsion impulses. On example-robot-data's hyq landing on its four thigh hulls and four
        foot spheres, the four thighs' torsion rows all held the base's yaw (the legs have no
        vertical axis): singular values 9e-18, 1.4e-15 and 9e-13 along those impulses, every
        solve stalled at natural residuals 1.2e-6..6.6e-6 down to h / 16, and the step failed
        after 16 s; with their torsion shared away it completed 1 s. What is lost is a patch's own
        torsion moment mu p_n e_r where other contacts hold the spin on lever arms over
        SHARE_LEVER e_r: on the four-legged table of the tests, e_r / r = 3.6 % of its legs'
        spin-down moment. Kept: the torsion of a body on one patch (a box spinning down on the
        floor) and of contacts on one axis (two finger pads pinching an object, whose tangential
        friction cannot hold a spin about the pinch axis: without their torsion the object turns
        about it). Tests: tests/test_face_contact.py (the box),
        tests/test_indeterminate_impulses.py (the table landing and spinning down, the pinch),
        tests/test_face_campaign.py (a re-solve taking a shared torsion off)."""
        for sp in specs:
            sp.shared = False
        if not any(sp.with_friction and self._patch_applies(sp) for sp in specs):
            return
        bodies = self.scene.bodies

        def skeletons(sp):
            a, b = (bodies[o.body].skeleton_index for o in sp.objects)
            return (a, b) if a <= b else (b, a)

        frames, groups = {}, {}
        for k, sp in enumerate(specs):
            if not sp.with_friction:
                continue
            last = self._last.get(sp.key)
            if solved is not None and (k in fresh or last is None):
                frames[k] = solved[k]
            elif last is not None:
                frames[k] = (last["a2"], last["normal"])
            else:
                continue
            groups.setdefault(skeletons(sp), []).append(k)
        for k, (point, normal) in frames.items():
            sp = specs[k]
            self._add_patch_torsion(sp, normal)
            if not sp.patch:
                continue
            n = np.asarray(normal, float) / np.linalg.norm(normal)
            for j in groups[skeletons(sp)]:
                if j != k and _lever(np.asarray(frames[j][0], float) - point, n) > SHARE_LEVER * sp.friction.e_r:
                    sp.friction, sp.patch, sp.shared = replace(sp.friction, e_r=0.0), False, True
                    break

    def _add_patch_torsion(self, spec, normal):
        """A 3D pair with friction rows whose friction has no e_r of its own resists spinning with
        the torsion radius of its contact patch at l along normal (patch.py; options.patch_torsion);
        unchanged when the patch is a point or unknown."""
        if spec.patch or not self._patch_applies(spec):
            return
        e_r = self._patch_radius(spec.objects, normal)
        if e_r > 0.0:
            spec.friction, spec.patch = replace(spec.friction, e_r=e_r), True

    def _patch_radius(self, objects, normal) -> float:
        """The torsion radius of two faceted pieces' patch at l (DART's poses) along normal."""
        first, second = objects
        bodies = self.scene.bodies
        R1, p1 = adapter.body_pose(bodies[first.body])
        R2, p2 = adapter.body_pose(bodies[second.body])
        n = np.asarray(normal, float) / np.linalg.norm(normal)
        return contact_patch.patch_kernel(first.face, first.face_half, R1, p1, second.face, second.face_half, R2, p2,
                                          n, contact_patch.band(first.piece, second.piece),
                                          *contact_patch.workspace(first.face, second.face))

    def _orient_intersections(self, oi, oj):
        """Which of two intersections is body 1: the side whose closest point lies on one face (one
        active function), the other side taking any number of active functions. The cone form of
        eqs (28)-(32) (rows/contact.py) is valid in either order; this one makes body 1's normal a
        single face's while a box rests on a table or tips over its edge (the orientation [GI]'s
        k1 form needed, kept for its reports). Chosen from the static closest points when the
        pair appears, kept while it lasts."""
        self._checkpoint()
        pair = frozenset((oi.key, oj.key))
        known = self._orientation.get(pair)
        alive = (oi.key, oj.key) in self._last or (oj.key, oi.key) in self._last
        if known is None or not alive:
            from .closest import closest_points
            pi, pj = (_pose_dim(adapter.body_pose(self.scene.bodies[o.body]), o.piece.dim) for o in (oi, oj))
            res = closest_points(oi.piece, pi, oj.piece, pj)
            known = oi.key
            if res.success:
                tol = 10.0 * self.options.contact_tolerance
                counts = [_active_count(o.piece, P, a, tol) for o, P, a in ((oi, pi, res.a1), (oj, pj, res.a2))]
                if counts[1] < counts[0]:
                    known = oj.key
        self._orientation[pair] = known
        return (oi, oj) if known == oi.key else (oj, oi)

    def _warm_start(self, problem, att, state):
        """z0 from the last step's solution (memory.warm_start: closest points carried along,
        impulses kept); cold (att.cold): closest points the same way, but free-flight velocities
        and zero impulses. New pairs start from static closest points with zero impulses."""
        specs = att.specs
        lay = problem.layout
        t = problem.tables
        memory = self._last
        mem = np.array([memory.index(spec.key) for spec in specs], np.int64)
        seeds = self._seed_pairs(problem, specs, [k for k in range(len(specs)) if mem[k] < 0], state)
        problem._sync()
        z = np.zeros(lay.n)
        v_free = np.zeros(lay.n)
        for k, s in enumerate(att.involved):
            v_free[lay.v_index[k]] = state.v_free[s]
        if len(memory):
            memory_warm_start(t.pair_i, t.pair_f, t.body_i, t.body_f, t.body_jac, t.sk_i, t.v0, v_free, mem,
                              memory.pair_i, memory.pair_f, memory.z, memory.rep, att.cold, state.h, z)
        else:
            memory_warm_start(t.pair_i, t.pair_f, t.body_i, t.body_f, t.body_jac, t.sk_i, t.v0, v_free, mem,
                              t.pair_i[:0], t.pair_f[:0], z, problem._rep[:0], att.cold, state.h, z)
        for k, (a1, a2, l1, l2, s) in seeds.items():
            problem.pack_points(z, k, a1, a2)
            _put_multipliers(z, lay.pairs[k], l1, l2, s)
        for sp, ss in zip(problem.supports, lay.supports):
            last = self._last_support.get(sp.key)
            if last is not None and not att.cold and len(last[0]) == ss.y.stop - ss.y.start:
                z[ss.y], z[ss.sigma] = last[0], last[1]
        for k, s in enumerate(att.involved):
            last = self._last_joint.get(s)
            if last is not None and not att.cold and att.joints[k] is not None:
                carried = dict(zip(last[0].keys, last[1]))
                z[lay.joint_index[k]] = [carried.get(key, 0.0) for key in att.joints[k].keys]
        return z

    def _seed_pairs(self, problem, specs, new, state) -> dict:
        """_seed_pair of the new pairs (indices into specs): {k: (a1, a2, l1, l2, s)}. The pairs of
        two single functions apart at l by more than the contact tolerance (most new pairs where
        many bodies land) take their static closest points and gradients from one compiled call
        (closest.closest_points_batch) and their multipliers from recovery._multipliers with
        those gradients; the others, and any the batch did not solve, _seed_pair. The case: 100
        superquadrics in a box, ~40 new pairs a landing step at ~0.3 ms each, mostly Python
        around the compiled static solve (comparisons/bench_many_bodies.py)."""
        tol = self.options.contact_tolerance
        batch = [k for k in new if specs[k].dim == 3 and not landing.faceted_pair(specs[k])
                 and closest.single_batch_ready(specs[k].objects[0].piece, specs[k].objects[1].piece)]
        seeds = {}
        if len(batch) > 1:
            self._checkpoint()
            poses = state.poses_now
            firsts = [specs[k].objects[0] for k in batch]
            seconds = [specs[k].objects[1] for k in batch]
            ok, A1, A2, normals, G1, G2 = closest.closest_points_batch(
                [o.piece for o in firsts], [poses[o.body] for o in firsts],
                [o.piece for o in seconds], [poses[o.body] for o in seconds])
            for b, k in enumerate(batch):
                a1, a2 = A1[b].copy(), A2[b].copy()
                if not ok[b] or not np.linalg.norm(a2 - a1) > max(tol, 1e-12):
                    continue
                spec = specs[k]
                l1, l2, s = recovery._multipliers(spec, None, None, a1, a2, normals[b], (G1[b:b + 1], G2[b:b + 1]))
                normal = normals[b] / np.linalg.norm(normals[b])
                spec.normal_l = normal
                if spec.tangent_axis is None:
                    spec.tangent_axis = fm._least_aligned_axis(normal)
                seeds[k] = (a1, a2, l1, l2, s)
        for k in new:
            if k not in seeds:
                seeds[k] = self._seed_pair(problem, specs[k], state)
        return seeds

    def _seed_pair(self, problem, spec, state):
        """A new pair's start (a1, a2, l1, l2, s): static closest points at l (the central touch
        point if touching) and their multipliers (recovery._multipliers); sets the pair's tangent
        axis from the normal."""
        self._checkpoint()
        first, second = spec.objects
        d = spec.dim
        poses_now = state.poses_now
        res = _closest_seed(first.piece, _pose_dim(poses_now[first.body], d),
                            second.piece, _pose_dim(poses_now[second.body], d))
        a1, a2 = np.asarray(res.a1, float), np.asarray(res.a2, float)
        normal = np.asarray(res.normal, float)
        # poses at l (zero velocity), where the closest points were computed
        P1, P2 = (problem.bodies[o.body].pose(np.zeros(problem.bodies[o.body].ndof)) for o in (spec.obj1, spec.obj2))
        if res.distance <= self.options.contact_tolerance:
            a1 = a2 = _central_touch_point(spec, P1, P2, a1, normal, self.options.contact_tolerance)
        elif landing.faceted_pair(spec):
            seed = landing.separated_face_seed(first, second, (poses_now[first.body], poses_now[second.body]),
                                               (state.poses_pred.get(first.body, poses_now[first.body]),
                                                state.poses_pred.get(second.body, poses_now[second.body])),
                                               normal, contact_patch.band(first.piece, second.piece))
            if seed is not None:
                a1, a2 = seed
        l1, l2, s = _multipliers(spec, P1, P2, a1, a2, normal)
        spec.normal_l = normal / np.linalg.norm(normal)
        if spec.tangent_axis is None and d == 3:
            spec.tangent_axis = fm._least_aligned_axis(normal / np.linalg.norm(normal))
        return a1, a2, l1, l2, s

    def _contact_report(self, problem, z, k, spec, st) -> ContactReport:
        first, second = spec.objects
        b1, b2 = self.scene.bodies[first.body], self.scene.bodies[second.body]
        p_t = st.p_t
        pt = float(p_t[0]) if len(p_t) else 0.0
        po = float(p_t[1]) if len(p_t) > 1 else 0.0
        vrel = problem.relative_velocity(z, k)
        slip = float(np.linalg.norm(st.tangents @ vrel))
        sl = problem.layout.pairs[k]
        if spec.compliance is None:          # rigid: all of the normal impulse is the core's
            p_core, deflection = st.p_n, 0.0
        else:
            p_core = spec.impulse_scale * float(z[sl.p_nr]) if sl.p_nr >= 0 else 0.0
            deflection = float(z[sl.dn])
        return ContactReport(b1.body_node, b2.body_node, st.a1, st.a2, st.normal, st.gap, st.p_n, pt, po,
                             st.p_r, st.sigma, slip, b1.name, b2.name, st.p_n - p_core, p_core, deflection)

    def _check_solution(self, problem, z, contacts, specs, energy=True) -> str:
        """'' or why the solution is refused: a contact normal that turned over within the step, a
        pair of faceted pieces with a vertex inside the other (landing.vertex_depth), impulses
        adding energy beyond _ENERGY_GAIN (_contact_work), a pair penetrating beyond the contact
        tolerance or a friction impulse outside its cone (rows/checks.py's GAP and CONE)."""
        tol = self.options.contact_tolerance
        flags = problem.checks(z, tol, self.options.solver.tol, _TOUCH)
        rep, pairs = problem._rep, problem.layout.pairs        # (checks left the reports at z)
        for k, spec in enumerate(specs):
            # (what the report holds, read from the arrays: the report is made for a refused pair)
            p_n, normal = problem.specs[k].impulse_scale * z[pairs[k].p_n], rep[k, rc.R_N:rc.R_N + spec.dim]
            if spec.normal_l is not None and p_n > 0.0 and float(normal @ spec.normal_l) < 0.0:
                # the far-side root: a body through a thin one within the step (a cylinder at
                # 8.6 m/s through a 0.1 m ground box at h = 0.017, held against its underside)
                c = contacts[k]
                return (f"pair {c.name_a} / {c.name_b}: the contact normal turned over within the step "
                        f"(n . n_l = {float(c.normal @ spec.normal_l):.3g}): one body went through the other")
            if landing.faceted_pair(spec):
                poses = problem.end_poses(z, spec)
                depth = landing.vertex_depth(*spec.objects, *poses)
                # (a quasi-rigid pair's layer is pressed in by its deflection: a box landing on one)
                allowed = tol + (max(float(z[pairs[k].dn]), 0.0) if spec.compliance is not None else 0.0)
                if depth > allowed:
                    c = contacts[k]
                    return (f"pair {c.name_a} / {c.name_b}: a vertex of one lies {depth:.3g} inside the other at "
                            f"the end of the step (tolerance {allowed:g}): a spurious root of the closest-point rows")
        # (energy: the test is against [GI]'s free-flight step; order 2's stage 1 is half of one)
        gain, scale = self._contact_work(problem, z, specs) if energy else (0.0, 0.0)
        if scale > 0.0 and gain > _ENERGY_GAIN * scale:
            return (f"the contact impulses add {gain:.3g} J of energy beyond free flight ({gain / scale:.3g} of "
                    f"the bodies' energy scale {scale:.3g} J): a spurious root, not an inelastic contact")
        for k, (spec, f) in enumerate(zip(specs, flags)):
            if f & rk.GAP:
                c = contacts[k]
                return f"pair {c.name_a} / {c.name_b} penetrates by {-c.gap:.3g} (tolerance {tol:g})"
            if f & rk.CONE:
                c = contacts[k]
                ft = math.hypot(c.p_t / spec.friction.e_t, c.p_o / spec.friction.e_o)
                return (f"pair {c.name_a} / {c.name_b} friction {ft:.3g} outside the cone "
                        f"mu p_n = {spec.friction.mu * c.p_n:.3g}")
        return ""

    def _released_contacts(self, problem, z, released):
        """(reports, '' or why the solution is refused) of the pairs recovery.release_idle left out
        of the solve: each must be apart (gap >= 0) at the end poses the solution implies; reported
        with no impulse. The gap is the static closest
        points' (closest.py); where that solve stalls too (parallel faces: the closest points are
        a face), a lower bound on it certifies the pair: for any unit n, the bodies' support
        points give n . (s2(-n) - s1(n)) <= their signed distance, taken at the pair's normal at
        l and at the normal of the relaxed static solve."""
        from .closest import closest_points
        reports = []
        for spec in released.values():
            first, second = spec.objects
            b1, b2 = self.scene.bodies[first.body], self.scene.bodies[second.body]
            poses = [(P.R, P.p) for P in problem.end_poses(z, spec)]
            res = closest_points(first.piece, poses[0], second.piece, poses[1])
            if res.success:
                gap, normal = (-float(res.depth) if res.overlapping else float(res.distance)), res.normal
            else:
                res = _closest_seed(first.piece, poses[0], second.piece, poses[1])
                gap, normal = _separation_bound(first.piece, poses[0], second.piece, poses[1],
                                                (spec.normal_l, res.normal))
            if not gap >= 0.0:
                # (not merely within the tolerance: a pair closing in that is left out one step
                # within it starts the next overlapping; a spinning cylinder landing was let
                # 1e-6 m in, and coal measured 2e-6 m)
                return reports, (f"pair {b1.name} / {b2.name}, left out without impulse, is not certified apart at "
                                 f"the end of the step (gap {gap:.3g})")
            reports.append(ContactReport(b1.body_node, b2.body_node, np.asarray(res.a1, float),
                                         np.asarray(res.a2, float), np.asarray(normal, float), gap,
                                         0.0, 0.0, 0.0, 0.0, 0.0, 0.0, b1.name, b2.name))
        return reports, ""

    def _contact_work(self, problem, z, specs):
        """(the energy the step's impulses add beyond free flight [J], the bodies' energy scale
        [J]) for a step of free bodies with a pair of faceted pieces ((0, 0) otherwise). With f
        each skeleton's force at l, semi-implicit Euler's free flight keeps E~ = KE - f.x + h/2 f.v
        exactly for a constant f (a uniform field), so the impulses add
        KE(v+) - KE(v_free) - h/2 f.(v+ - v_free). The scale: the kinetic energies at l and in free
        flight, plus m |g| rho over the pairs' moving pieces (the energy of tipping them)."""
        gain = scale = 0.0
        if not any(landing.faceted_pair(spec) for spec in specs) or \
                any(b.kind not in (fm.FREE, fm.FIXED) for b in problem.bodies) or \
                any(blk.joints is not None for blk in problem.skeletons):
            return 0.0, 0.0        # (checked where it was needed: free bodies with flat faces)
        h = problem.h
        for blk, vidx in zip(problem.skeletons, problem.layout.v_index):
            v_free = blk.v + h * np.linalg.solve(blk.M, blk.force)
            v_new = z[vidx]
            gain += 0.5 * (v_new @ blk.M @ v_new - v_free @ blk.M @ v_free) - 0.5 * h * blk.force @ (v_new - v_free)
            scale += 0.5 * (blk.v @ blk.M @ blk.v + v_free @ blk.M @ v_free)
        g = max(self._gravity_norm, 1.0)
        for spec in specs:
            for o in spec.objects:
                b = self.scene.bodies[o.body]
                if b.kind != adapter.FIXED and o.radius is not None:
                    scale += self._masses[b.index] * g * o.radius
        return gain, scale

    def _failure(self, problem, result, t0, h) -> StepReport:
        """A failed step's report: the pair whose rows are worst (of the problem solved last: a
        recovery may have changed the attempt's pairs since), the status, the likely cause."""
        specs = problem.specs
        try:
            F = problem.fun(result.x)
            nat = np.abs(result.x - np.clip(result.x - F, problem.lower, problem.upper))
        except (ZeroDivisionError, FloatingPointError, OverflowError):
            nat = np.full(problem.layout.n, np.nan)
        pair_name, worst = "", -1.0
        for k, sl in enumerate(problem.layout.pairs):
            cols = sl.columns
            r = float(np.nanmax(nat[cols])) if np.any(np.isfinite(nat[cols])) else math.inf
            if r > worst:
                pair_name, worst = f"{specs[k].objects[0].label} / {specs[k].objects[1].label}", r
        if result.message.endswith(recovery.OUT_OF_SOLVES):
            cause = recovery.OUT_OF_SOLVES
        elif result.status is ncp.Status.NOT_FINITE:
            cause = ("the rows are undefined at an iterate (degenerate geometry, e.g. a contact normal "
                     "along its tangent axis or a point at a shape's centre)")
        else:
            cause = ("a hard contact transition inside one step (an impact, a face landing on a face, "
                     "a start from rest with near-zero slip); a smaller h or on_failure='retry' may get through")
        msg = (f"NCP failed at t = {t0:.6g} s ({pair_name or 'no pair'}, {result.status.name}, residual "
               f"{result.residual:.3g} after {result.iterations} iterations, h = {h:g}). Likely: {cause}.")
        return StepReport(False, result.iterations, result.residual, result.status.name, (), t0, 1, msg,
                          problem.layout.n)


# ---------------------------------------------------------------------------------------------
# helpers
# ---------------------------------------------------------------------------------------------
class _World:
    """The world tables of step_kernels (skeletons, bodies, pieces) and the buffers each step
    fills (one set per stepper: a step's re-solve with more pairs re-reads the same state)."""

    def __init__(self, scene, objects):
        kinds = {adapter.FIXED: sk.FIXED, adapter.FREE: sk.FREE, adapter.PLANAR: sk.PLANAR,
                 adapter.ARTICULATED: sk.ARTICULATED}
        nv = [s.ndof for s in scene.skeletons]
        self.sk_nv = np.array(nv, np.int64)
        self.sk_voff = np.cumsum([0] + nv)[:-1].astype(np.int64)
        self.sk_moff = np.cumsum([0] + [k * k for k in nv])[:-1].astype(np.int64)
        nvw, nM = sum(nv), sum(k * k for k in nv)
        bodies = scene.bodies
        nb = len(bodies)
        self.bd_kind = np.array([kinds[b.kind] for b in bodies], np.int64)
        self.bd_sk = np.array([b.skeleton_index for b in bodies], np.int64)
        self.bd_nv = np.array([nv[b.skeleton_index] if b.skeleton_index >= 0 else 0 for b in bodies], np.int64)
        joff, at = [], 0
        for b in bodies:
            joff.append(at)
            if b.kind == adapter.ARTICULATED:
                at += 6 * nv[b.skeleton_index]
        self.bd_joff = np.array(joff, np.int64)
        self.read_bodies_list = [b.index for b in bodies if b.kind in (adapter.FIXED, adapter.ARTICULATED)]
        self.read_bodies = np.array(self.read_bodies_list, np.int64)
        self.mobile = [b.index for b in bodies if b.kind != adapter.FIXED]
        self.is_mobile = np.array([b.kind != adapter.FIXED for b in bodies], np.bool_)
        no = len(objects)
        self.ob_body = np.array([o.body for o in objects], np.int64)
        self.ob_bounded = np.array([o.local_box is not None for o in objects], np.bool_)
        self.ob_dim = np.array([o.piece.dim for o in objects], np.int64)
        self.ob_centre = np.array([o.local_box[0] if o.local_box is not None else np.zeros(3) for o in objects]).reshape(no, 3)
        self.ob_half = np.array([o.local_box[1] if o.local_box is not None else np.zeros(3) for o in objects]).reshape(no, 3)
        reach = []
        for o in objects:
            r = o.piece.length_scale
            if bodies[o.body].kind == adapter.ARTICULATED:
                r += o.offset          # the piece may sit far from the body origin
            reach.append(r)
        self.ob_reach = np.array(reach, float)
        self.unbounded = [k for k, o in enumerate(objects) if o.local_box is None]
        self.moving_unbounded = any(bodies[objects[k].body].kind != adapter.FIXED for k in self.unbounded)
        self.fixed = np.array([b.index for b in bodies if b.kind == adapter.FIXED], np.int64)
        self.R_fixed, self.p_fixed = np.full((len(self.fixed), 3, 3), np.nan), np.full((len(self.fixed), 3), np.nan)
        self.fixed_moved = True
        self.ob_radius = np.array([o.radius if o.radius is not None else 0.0 for o in objects], float)
        self.exact_lo, self.exact_hi = np.zeros((no, 3)), np.zeros((no, 3))
        self.exact_known = np.zeros(no, np.bool_)     # exact_lo/hi hold the box at the piece's last pose
        self.glo, self.ghi = np.zeros((no, 3)), np.zeros((no, 3))   # the grown boxes of the step
        self.no_box = np.zeros((0, 3))
        self.Q, self.V, self.FB, self.VF = np.zeros(nvw), np.zeros(nvw), np.zeros(nvw), np.zeros(nvw)
        self.CG, self.V_solved, self.DV_solved = np.zeros(nvw), np.zeros(nvw), np.zeros(nvw)
        # joint springs and dampers per dof (zero where none; dart_adapter._spring_damper)
        self.SPK, self.SPD, self.SPQ0 = np.zeros(nvw), np.zeros(nvw), np.zeros(nvw)
        for s, rec in enumerate(scene.skeletons):
            if rec.spring_damper is not None:
                o, k = self.sk_voff[s], nv[s]
                self.SPK[o:o + k], self.SPD[o:o + k], self.SPQ0[o:o + k] = rec.spring_damper
        self.TAU, self.FEXT, self.DV = np.zeros(nvw), np.zeros(nvw), np.zeros(nvw)
        self.raw_valid = False      # Q, V, TAU, FEXT hold the world as it is now (read by _begin)
        self.all_skeletons = None   # the world's skeletons (_begin)
        self.world_skeletons = None  # the world's other skeletons with dofs (for snapshots)
        self.MB = np.zeros(max(nM, 1))
        self.MB1, self.FB1 = np.zeros(max(nM, 1)), np.zeros(nvw)   # order 2's stage 1 (_stage1_tables)
        self.JB = np.zeros(max(at, 1))
        self.R_given, self.p_given = np.zeros((nb, 3, 3)), np.zeros((nb, 3))
        self.TG = np.zeros((nb, 4, 4))
        self.R_now, self.p_now, self.th_now = np.zeros((nb, 3, 3)), np.zeros((nb, 3)), np.zeros(nb)
        self.R_pred, self.p_pred, self.th_pred = np.zeros((nb, 3, 3)), np.zeros((nb, 3)), np.zeros(nb)
        self.R_half, self.p_half, self.th_half = np.zeros((nb, 3, 3)), np.zeros((nb, 3)), np.zeros(nb)
        self.margins = np.zeros(no)
        # the step state's views of these buffers (_StepState), made once
        self.states, self.v_free = [], []
        for s, rec in enumerate(scene.skeletons):
            o, k, mo = self.sk_voff[s], self.sk_nv[s], self.sk_moff[s]
            first = rec.body_index
            arts = {b: (self.R_now[b], self.p_now[b], self.JB[self.bd_joff[b]:self.bd_joff[b] + 6 * k].reshape(6, k))
                    for b in rec.body_indices} if rec.kind == adapter.ARTICULATED else {}
            self.states.append(adapter.SkeletonState(
                self.Q[o:o + k], self.V[o:o + k], self.MB[mo:mo + k * k].reshape(k, k), self.FB[o:o + k],
                self.R_now[first] if first >= 0 else None, self.p_now[first] if first >= 0 else None, arts))
            self.v_free.append(self.VF[o:o + k])
        self.poses_now = {b: (self.R_now[b], self.p_now[b]) for b in range(nb)}
        self.poses_pred = {b: (self.R_pred[b], self.p_pred[b]) for b in self.mobile}
        self.skeleton_views = [(rec, tuple(a[o:o + k] for a in (self.Q, self.V, self.TAU, self.FEXT, self.DV)),
                                self.MB[mo:mo + k * k].reshape(k, k), self.CG[o:o + k])
                               for rec, o, mo, k in zip(scene.skeletons, self.sk_voff, self.sk_moff, nv)]
        self.snapshot_views = [(rec.skeleton, q, v, dv, tau) for rec, (q, v, tau, _, dv), _, _ in self.skeleton_views]
        self.read_views = [(rec.skeleton, q, v, tau, fext, M, cg) for rec, (q, v, tau, fext, _), M, cg in self.skeleton_views]
        self.commit_views = [(rec.skeleton, self.V_solved[o:o + k], self.DV_solved[o:o + k])
                             for rec, o, k in zip(scene.skeletons, self.sk_voff, nv)]
        self.J_views = {b.index: self.JB[self.bd_joff[b.index]:self.bd_joff[b.index] + 6 * nv[b.skeleton_index]]
                        .reshape(6, nv[b.skeleton_index]) for b in bodies if b.kind == adapter.ARTICULATED}
        self.body_views = [(bodies[b], self.TG[b], self.J_views.get(b)) for b in self.read_bodies_list]
        self.dynamics_read = False   # _quick_repeat read all of DART's state at l (adapter.read_state)
        self.bundle = bundles.world(**{name: getattr(self, name) for name in bundles.WORLD_FIELDS})


@dataclass
class _Context:
    """What a committed step leaves for the next one's _repeat_step (see _context)."""
    h: float
    candidates: np.ndarray     # (nc, 2) candidate piece pairs, sorted
    near: np.ndarray           # which of them the step solved (the others were far)
    gaps: np.ndarray           # per candidate: a known lower bound of its gap now (NaN: none)
    problem: object            # the step's StepProblem (None: no pair was near)
    att: object                # its solve loop's state (specs, skeletons, bodies)
    eligible: np.ndarray       # per solved pair: whether a known gap can leave it out (_gap_bound_applies)
    bundle: object = None      # the arrays repeat_kernels.step compares and fills (bundles.Context)
    solver: tuple = None       # (options, their solver bundles and buffers: step_solver.solver_bundles)
    repeat: object = None      # the bundles repeat_kernels.step reads, in one (bundles.Repeat; with solver)
    sup_y: np.ndarray = None   # the support blocks' warm starts (y, sigma) it is given
    patches: list = ()         # solved pairs whose torsion radius is their patch's (_patch_applies)


class _LazyContacts(Sequence):
    """A step's contact reports, made when first read (a step that nobody inspects pays nothing)
    from its solution z and its pairs' reports rep (copies, kept), with the problem's spec list
    of the step (a cached problem is refreshed with another list by a later step)."""

    def __init__(self, stepper, problem, z, specs, rep):
        self._args = (stepper, problem, z, specs, problem.specs)
        self._items = None
        self._rep = rep
        self.pending = None    # () -> per pair index, fields that replace the report's (order 2's stage 2)

    def _made(self):
        if self._items is None:
            stepper, problem, z, specs, step_specs = self._args
            saved = problem._rep.copy(), problem._rep_at, problem._reports_np, problem.specs
            problem._rep[:] = self._rep          # the reports of this step's solution
            problem._rep_at, problem._reports_np, problem.specs = z, None, step_specs
            try:
                made = [stepper._contact_report(problem, z, k, spec, problem.unpack_pair(z, k))
                        for k, spec in enumerate(specs)]
                for k, changes in (self.pending() if self.pending is not None else {}).items():
                    made[k] = replace(made[k], **changes)
                self._items = tuple(made)
            finally:
                problem._rep[:], problem._rep_at, problem._reports_np, problem.specs = saved
            self._args = self.pending = None
        return self._items

    def __getitem__(self, k):
        return self._made()[k]

    def __len__(self):
        return len(self._rep)

    def __eq__(self, other):
        return tuple(self._made()) == (tuple(other) if isinstance(other, (tuple, list, Sequence)) else other)

    def __repr__(self):
        return repr(self._made())


@dataclass
class _StepState:
    """DART's state at the start of one step of h (ImplicitContactStepper._read)."""
    h: float
    states: list               # adapter.SkeletonState per mobile skeleton
    v_free: list               # free-flight velocities v + h M^-1 force per skeleton
    poses_now: dict            # body index -> (R, p) at l
    poses_pred: dict           # mobile body index -> (R, p) after a free step
    margins: np.ndarray        # per piece: the broadphase's motion margin [m]


class _Object:
    """One convex piece of one body. Its world box for the broadphase (step_kernels.piece_boxes):
    for a bounded piece the world AABB of its rotated body-frame box ``local_box`` (centre,
    half extents), centre R c + p and half extents |R| e (tight for a disc or an axis-aligned
    body, at most sqrt(3) wider otherwise); for an unbounded piece its exact AABB (``box``,
    recomputed only when the pose changes)."""

    def __init__(self, body, piece, funcs, fixed_halfspace, friction, label, compliance=None):
        self.body, self.piece, self.funcs = body, piece, funcs
        self.fixed_halfspace, self.friction, self.label = fixed_halfspace, friction, label
        self.compliance = compliance
        self.key = label
        self.size = float(piece.length_scale)    # (a property computed afresh, ~8 us a call)
        # flat faces (a polytope, a capped cylinder, a plane): its contact patch can be an area
        face = piece.face_points() if piece.dim == 3 else np.empty((0, 2))
        self.faceted = piece.dim == 3 and contact_patch.faceted(piece)
        self.face_half = face is None
        self.face = np.zeros((1, 3)) if face is None else np.ascontiguousarray(face, float)
        d = piece.dim
        self.local_box = None
        self.offset = 0.0          # distance of its body-frame box centre from the body origin
        if piece.bounded:
            lo, hi = (np.asarray(v, float) for v in piece.aabb(np.eye(d), np.zeros(d)))
            centre = np.zeros(3)
            centre[:d] = 0.5 * (lo + hi)
            half = np.zeros(3)
            half[:d] = 0.5 * (hi - lo)
            self.local_box = (centre, half)
            self.offset = float(np.linalg.norm(centre))
        # the farthest any point of the piece is from its body's origin (None: unbounded)
        self.radius = self.offset + float(np.linalg.norm(self.local_box[1])) if piece.bounded else None
        self._last = None

    def box(self, pose):
        """The exact world AABB of an unbounded piece at pose (R, p)."""
        R, p = pose
        if self._last is not None and np.array_equal(self._last[0], R) and np.array_equal(self._last[1], p):
            return self._last[2]
        out = _aabb3(self.piece, pose)
        self._last = (np.array(R), np.array(p), out)
        return out


_ZERO3 = np.zeros(3)


def _active_count(piece, pose, a, tol) -> int:
    """How many of a piece's functions vanish (to tol) at the world point a."""
    R, p = pose
    xi = R.T @ (np.asarray(a, float) - p)
    return sum(abs(float(f.value(xi))) <= tol for f in piece.functions)


def _separation_bound(piece1, pose1, piece2, pose2, normals):
    """(the largest lower bound on the signed distance of two convex pieces over the given
    directions, that direction): n . (s2(-n) - s1(n)) with s_i the pieces' world support points;
    -inf where no direction has closed-form supports."""
    best, best_n = -math.inf, None
    for n in normals:
        if n is None or not np.all(np.isfinite(n)) or not np.any(n):
            continue
        n = np.asarray(n, float) / np.linalg.norm(n)
        try:
            (R1, p1), (R2, p2) = pose1, pose2
            s1 = R1 @ piece1.support(R1.T @ n) + p1
            s2 = R2 @ piece2.support(R2.T @ -n) + p2
        except (NotImplementedError, ValueError):
            continue
        bound = float(n @ (s2 - s1))
        if bound > best:
            best, best_n = bound, n
    return best, best_n


def _nan_if_none(value):
    return math.nan if value is None else value


def _friction_units(rows, factor):
    """A skeleton's joint rows with their Coulomb friction rows' unit h f scaled by factor (order
    2's stage 1 bounds friction by h/2 f, rattle.py eq R1)."""
    return replace(rows, unit=np.array([factor * u if kind == joint_rows.FRICTION else u
                                        for u, (kind, _) in zip(rows.unit, rows.keys)]))


def _lever(offset, n) -> float:
    """The distance of a point at offset from an axis along the unit vector n (2D: n x offset)."""
    if len(n) == 2:
        return abs(n[0] * offset[1] - n[1] * offset[0])
    return float(np.linalg.norm(np.cross(n, offset)))


def _pose_dim(pose, dim):
    R, p = pose
    return (R[:dim, :dim], p[:dim])


def _aabb3(piece, pose):
    R, p = pose
    d = piece.dim
    lo, hi = piece.aabb(R[:d, :d], p[:d])
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    if d == 2:
        lo, hi = np.append(lo, 0.0), np.append(hi, 0.0)
    return lo, hi


def _contact_shift(b1, b2, states, h, gap_vector, d, a1=None, a2=None):
    """Warm start: how far the last closest points a1, a2 travel in one step.

    Each point moves with its own body's translation; the point on a fixed body also slides
    along its surface with the other body's tangential translation (the contact point of a
    rolling disc travels along the ground; a falling body's target point stays put). Exact for
    steady rolling on flat ground. A point of an articulated body moves with its material velocity
    v_o + omega x (a - p) (a link's origin may sit at a joint that does not move)."""
    def velocity(b, a):
        if b.kind == adapter.FIXED:
            return np.zeros(d)
        st = states[b.skeleton_index]
        v = st.v
        if b.kind == adapter.ARTICULATED:
            R, p, J = st.bodies[b.index]
            w, vo = J[:3] @ v, J[3:] @ v
            return vo if a is None else vo + np.cross(w, np.asarray(a, float) - p)
        return np.array([v[0], v[1]]) if b.kind == adapter.PLANAR else v[3:6].copy()
    v1, v2 = velocity(b1, a1), velocity(b2, a2)
    norm = np.linalg.norm(gap_vector)
    n = gap_vector / norm if norm > 1e-12 else None
    tangential = (lambda v: v - (v @ n) * n) if n is not None else (lambda v: v)
    s1 = h * (v1 + (tangential(v2) if b1.kind == adapter.FIXED else 0.0))
    s2 = h * (v2 + (tangential(v1) if b2.kind == adapter.FIXED else 0.0))
    return s1, s2


