"""Where does the implicit stepper stop working? A matrix of stress cases against stated bounds.

Question. The [GI] scenes run at h = 0.01 s with O(1) masses, sizes and speeds. How far can one
go from there (stiffness, mass ratio, speed, time step, shape, run length, number of bodies)
before the implicit stepper fails, penetrates, gains energy or slows down, and what does DART's
own stepper (FCL + boxed LCP, ``world.step()``) do on the same case?

Every case is one frozen config (one of the ``*Case`` dataclasses below) run by one top-level
function (``stiffness_case``, ``mass_ratio_case``, ...), which builds a world, steps it and
returns a plain ``CaseRecord``. Where DART has the shapes, one builder makes one world of DART
primitives with collision aspects (SphereShape, EllipsoidShape, BoxShape, PlaneShape), and the
same builder serves both steppers (the implicit stepper maps the primitives to implicit surfaces);
shapes DART lacks (superquadrics, compliant layers) are attached with ``ic.attach`` and run only
with the implicit stepper. DART worlds use FCL with sleeping switched off, as in
comparisons.dart_native.

Measured in every run (per step; a run stops at its first exception):
  * completed, or the exception (ic.StepFailure with the solver status, or anything else);
  * min gap [m]: the most negative signed distance between bodies, from the geometry at the
    end of every step and independent of the stepper: exact for sphere/sphere and for a body
    against a plane (support point), ``closest.closest_points`` otherwise; for the implicit
    stepper also the most negative reported contact gap (``ContactReport.gap``);
  * energy: E = kinetic + gravitational (+ the quasi-rigid layers' k delta^2 / 2); "no growth"
    cases report max_k (E_{k+1} - E_k) (and, failing, the largest rise above the lowest energy
    before it, max_k (E_k - min_{j<=k} E_j): an oscillating error returns, a gain accumulates),
    "conserved" cases max_k |E_k - E_0|;
  * max residual, Newton iterations per step (mean, max; retried steps count all substeps),
    median wall time per step, any NaN in positions, velocities or reports.

Bounds (each row states its own; names below). PEN_TOL = 1e-6 m is the stepper's default
contact tolerance (its allowed penetration). Energy growth may not exceed ENERGY_REL = 1e-9 of
the run's energy scale E_ref = sum_i m_i (g * 1 m + |v_i0|^2 / 2) (1e-8 J for a 1 kg body: round-off
of E is ~1e-16 E per step). Resting bodies may not drift more than DRIFT_TOL = 1e-9 m. A
conserved kinetic energy may not change by more than KE_REL = 1e-9 relative. Impulse checks
(p_n = m g h, force chains) hold to IMPULSE_REL = 1e-6 relative. A dropped superquadric lies on
its smallest semi-axis at the end (REST_HEIGHT_TOL = 1e-3 m) when its exponent is > 2: it lands
on a face of zero curvature and stops. Exponent 2 (an ellipsoid) is exempt: after the inelastic
landing it rolls and rocks on its curved side, and rolling without slip on a fixed plane does no
work, so exact mechanics keeps that rocking energy forever (only the torsional friction e_r
resists spin about the normal); the implicit stepper damps it only at first order in h
(scenes/ellipsoid_rocking.py: 15 % of the rocking energy in 3 s). Mechanics predicts for it: no
energy growth, no penetration, and a centre never lower than the smallest semi-axis (checked for
every dropped body).

Verdicts. PASS: every bound met. FAIL: the implicit stepper missed a bound or raised (to be
fixed in the stepper). LIMIT: DART's native stepper missed a bound (the contrast, not this
package's defect), or the run was cut by the study's wall budget before its end (a measurement
limit; the bounds it reached are still checked). stability.md lists every non-PASS row with its
measured reason ("known limits").

The cases (``plan``): stiffness k = 1e3 .. 1e8 N/m with and without critical damping; mass
ratios 1e4 and 1e6; a sphere hitting a plane at 10, 20, 30 and 100 m/s with h = 0.01 s (DART:
100 m/s) and a grazing pass at tangency; h = 1e-5 .. 0.1 s on the rolling disc and on a stack of
three spheres; superquadric exponents 2 .. 10 dropped (DART: a box), a 1:100 flat ellipsoid,
1 mm and 1 km spheres, a sphere resting in the groove of two others; 1e4 steps of a resting
body and 60 s of the rolling disc; 10, 30 and 100 bodies dropped into a box (within a wall
budget, see below). The stepper's defaults throughout (retry policy, contact tolerance 1e-6 m).

Many bodies. Exponent-4 superquadrics dropped in layers into a box of five fixed half-spaces;
DART runs boxes of the same extents (its walls are thick boxes, as its ground; see _ground).
Time per step is fitted against the number of active contacts (p_n > 0; for DART the
detector's contact count) on a log-log plot, t = a n^b, over the steps solved at the first
attempt (retried steps are plotted and counted apart, see ScalingFit); the goal is b <= 1.2
and <= 50 ms per step with 100 bodies (extrapolated from the fit when 100 bodies were not run,
and then said so). Each many-body run stops after its wall budget of stepping (MANY_BODY_BUDGETS:
by default 90 s for 10 and 30 bodies and 45 s for 100, which reach only the first landings;
--quick: 10 bodies for 15 steps; --full: 900 s each), checked after every step.

Executors: a local process pool (spawn), as comparisons.energy_loss; ``--workers 0`` runs in
this process. Outputs (``--out``, default comparisons/out): stability.md (table, known limits,
scaling fit), stability.csv, stability_scaling.png, and the printed table.

Run: python -m comparisons.stability [--quick | --full] [--workers N] [--only SUBSTRING] [--out DIR]
"""
from __future__ import annotations

import argparse
import concurrent.futures
import csv
from dataclasses import dataclass, field
import math
import multiprocessing
import os
from pathlib import Path
import time

import numpy as np

G = 9.81                    # [m/s^2]
PEN_TOL = 1e-6              # [m] the stepper's default contact_tolerance: its allowed penetration
DRIFT_TOL = 1e-9            # [m] a resting body's largest displacement
ENERGY_REL = 1e-9           # energy growth bound, relative to E_ref (see the module docstring)
KE_REL = 1e-9               # conserved kinetic energy, relative change
IMPULSE_REL = 1e-6          # relative error of closed-form impulses (p_n = m g h, force chains)
VELOCITY_TOL = 1e-9         # [m/s] velocity change of a grazing pass
REST_HEIGHT_TOL = 1e-3      # [m] "lies on its smallest semi-axis" (tests/test_rigid3d.py)
SCALING_EXPONENT_GOAL = 1.2
SCALING_TIME_GOAL = 0.05    # [s] per step with 100 bodies
SCALING_BODIES_GOAL = 100
PROBE_MAX_BODIES = 12       # worlds with more bodies probe only body/half-space pairs
DEFAULT_OUT = Path(__file__).resolve().parent / "out"
MODES = ("quick", "default", "full")
# (bodies, wall budget [s] of stepping) per mode. Measured (dartpy 6.20, 2 cores, compiled rows,
# sparse Jacobian, far pairs left out; comparisons/bench_many_bodies.py): 100 bodies take ~0.04 s
# per step in free fall and ~0.2 s per step once 17-67 contacts are active (steps 10-15), more as
# the pile grows (~0.5 s at ~120 contacts, runs sharing the cores); the default's 45 s reach well
# past the first landings. The budget is checked between steps, so one retried step can overrun it.
MANY_BODY_BUDGETS = {"quick": ((10, 15.0),), "default": ((10, 90.0), (30, 90.0), (100, 45.0)),
                     "full": ((10, 900.0), (30, 900.0), (100, 900.0))}
IMPLICIT, NATIVE = "implicit", "dart_native"


# ----------------------------------------------------------------------------------------------
# configs: one frozen dataclass per family
# ----------------------------------------------------------------------------------------------
def _check_stepper(stepper):
    if stepper not in (IMPLICIT, NATIVE):
        raise ValueError(f"stepper must be {IMPLICIT!r} or {NATIVE!r}, got {stepper!r}")


@dataclass(frozen=True)
class StiffnessCase:
    """A rigid sphere (r = 0.1 m, 1 kg) dropped from 5 cm onto a compliant half-space
    ic.Compliance(k, c, delta_max = 5 cm), c = 2 sqrt(k m) (critical) or 0; h [s], duration [s]."""
    k: float
    damped: bool
    h: float = 1e-3
    duration: float = 2.0
    stepper: str = IMPLICIT

    family = "stiffness"

    @property
    def label(self):
        return f"k = {self.k:.0e} N/m, " + ("critical damping" if self.damped else "undamped")


@dataclass(frozen=True)
class MassRatioCase:
    """kind "sphere_under_ellipsoid": a 1 kg sphere (r = 0.5) on a plane under a 1e4 kg flat
    ellipsoid (2, 2, 0.1); "light_on_heavy": a 1e-3 kg sphere (r = 0.05) on a 1e3 kg box
    (1 x 1 x 0.5) on a plane. Both start resting (touching), on the vertical axis."""
    kind: str
    stepper: str = IMPLICIT
    h: float = 0.01
    duration: float = 1.0

    family = "mass ratio"

    @property
    def label(self):
        return {"sphere_under_ellipsoid": "1 kg sphere under 1e4 kg ellipsoid",
                "light_on_heavy": "1e-3 kg sphere on 1e3 kg box"}[self.kind]


@dataclass(frozen=True)
class ImpactCase:
    """A sphere (r = 0.1, 1 kg) 0.45 m above a plane hitting it at ``speed`` [m/s] with h [s]."""
    speed: float = 100.0
    stepper: str = IMPLICIT
    h: float = 0.01
    duration: float = 0.5

    family = "speed"

    @property
    def label(self):
        return f"sphere hits plane at {self.speed:g} m/s, h = {self.h:g} s"


@dataclass(frozen=True)
class GrazingCase:
    """No gravity: a sphere (r = 0.5, 1 kg, 1 m/s along x) skims past a free resting sphere
    (r = 1, 1 kg) on the line whose distance to its centre is exactly r1 + r2 (tangency)."""
    stepper: str = IMPLICIT
    h: float = 0.01
    duration: float = 2.0

    family = "speed"

    @property
    def label(self):
        return "grazing pass at tangency, 1 m/s"


@dataclass(frozen=True)
class TimeStepCase:
    """scene "disc": the rolling disc of [GI] Example 1 (scenes.disc_rolling; DART: a cylinder);
    "stack": three spheres (r = 0.1, 1 kg) stacked on a plane, resting; h [s], steps."""
    scene: str
    h: float
    steps: int
    stepper: str = IMPLICIT

    family = "time step"

    @property
    def label(self):
        return ("rolling disc" if self.scene == "disc" else "stack of 3 spheres") + f", h = {self.h:g} s"


@dataclass(frozen=True)
class ShapeCase:
    """kind "superquadric": semi-axes (0.3, 0.2, 0.15), exponent ``param``, dropped from
    z = 0.3 tilted 0.3 rad (as tests/test_rigid3d.py); exponents > 2 land on a face of zero
    curvature and must lie at rest on their smallest semi-axis at the end; exponent 2 (an
    ellipsoid) keeps rocking (see the module docstring) and must only never sink below it;
    "box": the same drop of a DART box of
    those extents (the exponent -> inf limit; DART has no superquadric); "flat_ellipsoid":
    semi-axes (1, 1, 0.01) dropped the same way; "tiny" / "huge": a sphere of radius ``param``
    [m] (density 1000) dropped from a gap min(r/2, 0.1 m); "held": a unit-mass sphere (r = 0.5)
    resting in the groove between two fixed spheres (r = 1, centres 2 m apart)."""
    kind: str
    param: float = 0.0
    stepper: str = IMPLICIT
    h: float = 0.01
    duration: float = 3.0

    family = "geometry"

    @property
    def label(self):
        return {"superquadric": f"superquadric exponent {self.param:g}, dropped",
                "box": "box (exponent -> inf), dropped",
                "flat_ellipsoid": "flat ellipsoid 1:100, dropped",
                "tiny": f"tiny sphere r = {self.param:g} m, dropped",
                "huge": f"huge sphere r = {self.param:g} m, dropped",
                "held": "sphere held between two spheres"}[self.kind]


@dataclass(frozen=True)
class LongRunCase:
    """kind "resting": an exponent-4 superquadric (0.3, 0.2, 0.15) (DART: a box of those extents)
    lying on a plane for ``steps`` steps of h; "disc": the rolling disc for steps * h seconds."""
    kind: str
    steps: int
    stepper: str = IMPLICIT
    h: float = 0.01

    family = "long run"

    @property
    def label(self):
        if self.kind == "resting":
            return f"body resting, {self.steps} steps"
        return f"disc rolling {self.steps * self.h:g} s"


@dataclass(frozen=True)
class ManyBodiesCase:
    """n exponent-4 superquadrics (0.1, 0.08, 0.06), 0.5 kg (DART: boxes of those extents)
    dropped in layers into a box of five fixed half-spaces, random tilts (seed 0); stepped to
    ``duration`` [s] or until ``wall_budget`` [s] of stepping."""
    n: int
    stepper: str = IMPLICIT
    h: float = 0.01
    duration: float = 1.0
    wall_budget: float = 60.0

    family = "many bodies"

    @property
    def label(self):
        return f"{self.n} bodies dropped into a box"


CASE_TYPES = (StiffnessCase, MassRatioCase, ImpactCase, GrazingCase, TimeStepCase, ShapeCase, LongRunCase,
              ManyBodiesCase)


# ----------------------------------------------------------------------------------------------
# the record
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Check:
    """One bound: ``value <= bound`` (NaN never passes). text names it with its unit."""
    text: str
    value: float
    bound: float

    @property
    def ok(self) -> bool:
        return bool(self.value <= self.bound)

    def describe(self) -> str:
        return f"{self.text} = {_num(self.value)} > {_num(self.bound)}"


@dataclass(frozen=True, eq=False)
class CaseRecord:
    """What a case returns (plain data, picklable). energy_rule: "no growth" (energy_drift is
    max_k E_{k+1} - E_k [J]), "conserved" (max_k |E_k - E_0| [J]) or "" (not checked). key: the
    case's own measurement, one short string. steps_wall [s], steps_contacts (active contacts;
    DART: the detector's contacts), steps_substeps (1, or the substeps of a retried step): per step."""
    config: object
    completed: bool
    error: str
    steps_done: int
    steps_planned: int
    min_gap: float
    min_report_gap: float
    energy_rule: str
    energy_drift: float
    max_residual: float
    iterations_mean: float
    iterations_max: int
    step_median_s: float
    any_nan: bool
    checks: tuple
    key: str
    budget_stopped: bool = False
    steps_wall: np.ndarray = field(default_factory=lambda: np.zeros(0))
    steps_contacts: np.ndarray = field(default_factory=lambda: np.zeros(0))
    steps_substeps: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def failed_checks(self) -> list:
        return [c for c in self.checks if not c.ok]

    @property
    def verdict(self) -> str:
        if not self.completed and not self.budget_stopped:
            return "LIMIT" if self.config.stepper == NATIVE else "FAIL"
        if self.any_nan or self.failed_checks:
            return "LIMIT" if self.config.stepper == NATIVE else "FAIL"
        return "LIMIT" if self.budget_stopped else "PASS"

    @property
    def reason(self) -> str:
        parts = []
        if self.error:
            parts.append(f"raised at step {self.steps_done + 1}: {self.error}")
        if self.budget_stopped:
            parts.append(f"stopped by the wall budget after {self.steps_done} of {self.steps_planned} steps")
        if self.any_nan:
            parts.append("NaN in the state or a report")
        parts += [c.describe() for c in self.failed_checks]
        if parts and self.key:
            parts.append(f"measured: {self.key}")
        return "; ".join(parts)


# ----------------------------------------------------------------------------------------------
# worlds
# ----------------------------------------------------------------------------------------------
def _world(h, gravity=(0.0, 0.0, -G)):
    import dartpy as dart
    from comparisons import dart_native

    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity(list(gravity))
    deactivation = world.getDeactivationOptions()
    deactivation.mEnabled = False        # DART would put resting bodies to sleep (zero drift by fiat)
    world.setDeactivationOptions(deactivation)
    world.setCollisionDetector(dart_native.make_detector("fcl"))
    return world


def _free_body(world, name, mass, inertia, position, rotation=(0.0, 0.0, 0.0), velocity=None):
    import dartpy as dart

    skel = dart.dynamics.Skeleton(name)
    _, body = skel.createFreeJointAndBodyNodePair()
    body.setName(name)
    body.setMass(float(mass))
    body.setMomentOfInertia(*[float(x) for x in np.diag(np.asarray(inertia, float))])
    skel.setPositions(np.r_[np.asarray(rotation, float), np.asarray(position, float)])
    if velocity is not None:
        skel.setVelocities(np.asarray(velocity, float))
    world.addSkeleton(skel)
    return skel, body


def _fixed_body(world, name):
    import dartpy as dart

    skel = dart.dynamics.Skeleton(name)
    _, body = skel.createWeldJointAndBodyNodePair()
    body.setName(name)
    world.addSkeleton(skel)
    return body


def _primitive(body, shape, mu=0.5, center=None):
    """A DART primitive with collision and dynamics aspects (both steppers see it)."""
    import dartpy as dart

    node = body.createShapeNode(shape)
    if center is not None:
        T = dart.math.Isometry3()
        T.set_translation(np.asarray(center, float))
        node.setRelativeTransform(T)
    node.createVisualAspect()
    node.createCollisionAspect()
    dynamics = node.createDynamicsAspect()
    dynamics.setFrictionCoeff(mu)
    dynamics.setRestitutionCoeff(0.0)
    return node


def _sphere(r):
    import dartpy as dart
    return dart.dynamics.SphereShape(float(r))


def _box(size):
    import dartpy as dart
    return dart.dynamics.BoxShape(np.asarray(size, float))


def _ellipsoid(semi_axes):
    import dartpy as dart
    return dart.dynamics.EllipsoidShape(2.0 * np.asarray(semi_axes, float))   # DART takes diameters


def _plane(normal=(0.0, 0.0, 1.0), offset=0.0):
    import dartpy as dart
    return dart.dynamics.PlaneShape(np.asarray(normal, float), float(offset))


GROUND_BOX = (100.0, 100.0, 10.0)   # [m] DART's ground: FCL lets boxes sink through a PlaneShape


def _ground(world, stepper, mu=0.5):
    """The plane z = 0: a PlaneShape (a half-space) for the implicit stepper; for DART a thick box
    with its top face at z = 0 (measured: with FCL a box dropped on a PlaneShape sinks through it
    within 3 s, on a box it rests), so that each stepper gets its best ground."""
    body = _fixed_body(world, "ground")
    if stepper == IMPLICIT:
        _primitive(body, _plane(), mu)
    else:
        _primitive(body, _box(GROUND_BOX), mu, center=[0.0, 0.0, -GROUND_BOX[2] / 2])
    return body


def _solid_sphere_inertia(m, r):
    return np.eye(3) * 0.4 * m * r * r


def _shape_inertia(shape, m):
    mp = shape.mass_properties(1.0)
    return np.asarray(mp.inertia, float) * m / mp.mass


def _box_inertia(m, size):
    a, b, c = size
    return np.diag([m * (b * b + c * c), m * (a * a + c * c), m * (a * a + b * b)]) / 12.0


ORDER_ENV = "IMPLICIT_CONTACT_STABILITY_ORDER"   # --order, seen by the worker processes too


def _make_stepper(world, stepper, options=None):
    if stepper == IMPLICIT:
        import implicit_contact as ic
        from dataclasses import replace
        order = int(os.environ.get(ORDER_ENV, "1"))
        options = replace(options or ic.StepperOptions(), order=order)
        return ic.ImplicitContactStepper(world, options=options)
    from comparisons.dart_native import DartNative
    return DartNative(world)


# ----------------------------------------------------------------------------------------------
# geometry probe: signed distances independent of the stepper
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Frame:
    """The world frame as a fixed 3D "body" for the probe's planes."""
    index: int = -1
    dim: int = 3


_WORLD_FRAME = _Frame()
GROUND_PLANE = (((0.0, 0.0, 1.0), 0.0),)


def _ground_probe(world, stepper, **kwargs):
    """A probe that measures against the plane z = 0 for either ground (see _ground)."""
    if stepper == IMPLICIT:
        return _GapProbe(world, **kwargs)
    return _GapProbe(world, planes=GROUND_PLANE, skip=("ground",), **kwargs)


class _GapProbe:
    """Min signed distance [m] over body pairs (not both fixed) from the geometry of the world.

    Shapes come from implicit_contact.dart_adapter.scan_world, which maps DART primitives and
    reads attached implicit shapes. Exact for sphere/sphere and for any body with a closed-form
    support point against a plane; closest_points otherwise (-depth when overlapping, which is
    the algebraic depth of normalised functions, ~metres). planes: ((normal, offset), ...) solid
    half-spaces {normal . x <= offset} that stand for the fixed bodies named in ``skip`` (DART's
    box grounds and walls, whose tops are those planes). halfspaces_only: skip body/body pairs
    (many-body worlds). Pairs that need closest_points are solved last, in the order of a lower
    bound of their distance (bounding spheres about the body origins, world AABBs), and skipped
    once that bound reaches the smallest distance found: the minimum is unchanged, and a pile of
    10 bodies solves only neighbours whose boxes overlap instead of all 45 pairs (measured: 0.45
    s per step before, 0.02-0.04 s after)."""

    def __init__(self, world, halfspaces_only=False, planes=(), skip=()):
        from implicit_contact import dart_adapter as adapter
        from implicit_contact import shapes as shp

        self._adapter, self._shp = adapter, shp
        scene = adapter.scan_world(world)
        bodies = [b for b in scene.bodies if b.body_node.getName() not in skip]
        self.pairs = []
        for b in bodies:
            if b.kind != adapter.FIXED:
                for sb in b.shapes:
                    for normal, offset in planes:
                        self.pairs.append((_WORLD_FRAME, shp.HalfSpace(normal, offset), b, sb.shape))
        for i, a in enumerate(bodies):
            for b in bodies[i + 1:]:
                if a.kind == adapter.FIXED and b.kind == adapter.FIXED:
                    continue
                for sa in a.shapes:
                    for sb in b.shapes:
                        half = isinstance(sa.shape, shp._HalfSpaceBase) or isinstance(sb.shape, shp._HalfSpaceBase)
                        if halfspaces_only and not half:
                            continue
                        self.pairs.append((a, sa.shape, b, sb.shape))
        self.failures = 0

    @staticmethod
    def _reach(shape) -> float:
        """Radius [m] of a ball about the body origin that holds the shape (inf if unbounded)."""
        if not shape.bounded:
            return math.inf
        lo, hi = (np.asarray(x, float) for x in shape.aabb(np.eye(shape.dim), np.zeros(shape.dim)))
        return float(np.linalg.norm(np.maximum(np.abs(lo), np.abs(hi))))

    def __call__(self) -> float:
        poses = {}
        for a, _, b, _ in self.pairs:
            for body in (a, b):
                if body.index not in poses:
                    R, p = (np.eye(3), np.zeros(3)) if body is _WORLD_FRAME else self._adapter.body_pose(body)
                    poses[body.index] = (R[:body.dim, :body.dim], p[:body.dim])
        best = math.inf
        solves = []
        for a, sa, b, sb in self.pairs:
            if self._needs_solve(sa, sb):
                solves.append((self._lower_bound(sa, poses[a.index], sb, poses[b.index]), a, sa, b, sb))
                continue
            d = self._distance(sa, poses[a.index], sb, poses[b.index])
            if math.isnan(d):
                self.failures += 1
            else:
                best = min(best, d)
        for lower, a, sa, b, sb in sorted(solves, key=lambda x: x[0]):
            if lower >= best:
                break
            d = self._distance(sa, poses[a.index], sb, poses[b.index])
            if math.isnan(d):
                self.failures += 1
            else:
                best = min(best, d)
        return best

    def _lower_bound(self, s1, P1, s2, P2) -> float:
        """A lower bound [m] of the distance: the larger of the bounding spheres' and the world
        AABBs' separations (negative, or -inf for the boxes, when they overlap)."""
        spheres = float(np.linalg.norm(P1[1] - P2[1])) - self._reach(s1) - self._reach(s2)
        lo1, hi1 = (np.asarray(x, float) for x in s1.aabb(*P1))
        lo2, hi2 = (np.asarray(x, float) for x in s2.aabb(*P2))
        gap = np.maximum(0.0, np.maximum(lo2 - hi1, lo1 - hi2))
        boxes = float(np.linalg.norm(gap)) if np.any(gap > 0.0) else -math.inf
        return max(spheres, boxes)

    def _needs_solve(self, s1, s2) -> bool:
        """Whether _distance falls back to closest_points (both shapes bounded, not two balls)."""
        shp = self._shp
        if isinstance(s1, shp._HalfSpaceBase) or isinstance(s2, shp._HalfSpaceBase):
            return False
        return not (isinstance(s1, shp._Ball) and isinstance(s2, shp._Ball)) and s1.bounded and s2.bounded

    def _distance(self, s1, P1, s2, P2):
        shp = self._shp
        if isinstance(s2, shp._HalfSpaceBase):
            s1, P1, s2, P2 = s2, P2, s1, P1
        if isinstance(s1, shp._HalfSpaceBase):
            n_b, d_b = s1.plane()
            R1, p1 = P1
            n = R1 @ n_b
            d = d_b + float(n @ p1)
            R2, p2 = P2
            try:
                point = R2 @ s2.support(R2.T @ (-n)) + p2
            except NotImplementedError:
                return self._closest(s1, P1, s2, P2)
            return float(n @ point) - d
        if isinstance(s1, shp._Ball) and isinstance(s2, shp._Ball):
            c1 = P1[0] @ s1.center + P1[1]
            c2 = P2[0] @ s2.center + P2[1]
            return float(np.linalg.norm(c1 - c2)) - s1.radius - s2.radius
        return self._closest(s1, P1, s2, P2)

    @staticmethod
    def _closest(s1, P1, s2, P2):
        from implicit_contact.closest import closest_points

        res = closest_points(s1, P1, s2, P2)
        if not res.success:
            return math.nan
        return -float(res.depth) if res.overlapping else float(res.distance)


# ----------------------------------------------------------------------------------------------
# stepping and measuring
# ----------------------------------------------------------------------------------------------
def _energy(world, stepper) -> float:
    """Kinetic + gravitational (+ quasi-rigid spring) energy [J] of every mobile skeleton."""
    g = np.asarray(world.getGravity(), float)
    total = 0.0
    for s in range(world.getNumSkeletons()):
        sk = world.getSkeleton(s)
        if sk.getNumDofs() == 0 or not sk.isMobile():
            continue
        v = np.asarray(sk.getVelocities(), float)
        total += 0.5 * float(v @ np.asarray(sk.getMassMatrix(), float) @ v)
        total -= float(sk.getMass()) * float(g @ np.asarray(sk.getCOM(), float))
    spring = getattr(stepper, "spring_energy", None)
    return total + (spring() if spring is not None else 0.0)


def _energy_scale(world) -> float:
    """E_ref = sum m (g * 1 m + |v0|^2 / 2) [J] (the energy bound's scale)."""
    total = 0.0
    for s in range(world.getNumSkeletons()):
        sk = world.getSkeleton(s)
        if sk.getNumDofs() == 0 or not sk.isMobile():
            continue
        v = np.asarray(sk.getVelocities(), float)
        total += float(sk.getMass()) * G * 1.0 + 0.5 * float(v @ np.asarray(sk.getMassMatrix(), float) @ v)
    return total


def _finite_state(world) -> bool:
    for s in range(world.getNumSkeletons()):
        sk = world.getSkeleton(s)
        if not (np.all(np.isfinite(sk.getPositions())) and np.all(np.isfinite(sk.getVelocities()))):
            return False
    return True


@dataclass
class _Run:
    """Per-step series of one run (see _drive)."""
    energy: list = field(default_factory=list)
    gaps: list = field(default_factory=list)
    report_gaps: list = field(default_factory=list)
    wall: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    residual: list = field(default_factory=list)
    contacts: list = field(default_factory=list)
    substeps: list = field(default_factory=list)
    reports: list = field(default_factory=list)
    error: str = ""
    nan: bool = False
    budget_stopped: bool = False
    steps: int = 0
    e_ref: float = 0.0


def _drive(world, stepper, steps, probe=None, wall_budget=math.inf, before_step=None, keep_reports=False,
           on_step=None) -> _Run:
    """Step ``steps`` times (or until an exception, or ``wall_budget`` seconds of stepping);
    record energy, gaps, wall time, iterations, residual and contacts after every step."""
    from implicit_contact import ImplicitContactStepper

    implicit = isinstance(stepper, ImplicitContactStepper)
    run = _Run(e_ref=_energy_scale(world))
    run.energy.append(_energy(world, stepper))
    if probe is not None:
        run.gaps.append(probe())
    spent = 0.0
    for _ in range(steps):
        if before_step is not None:
            before_step(world)
        t0 = time.perf_counter()
        try:
            report = stepper.step()
        except Exception as error:   # the record says what was raised; the run ends here
            run.error = f"{type(error).__name__}: {_first_sentence(str(error))}"
            break
        dt = time.perf_counter() - t0
        spent += dt
        run.wall.append(dt)
        run.steps += 1
        if implicit:
            run.iterations.append(report.iterations)
            run.residual.append(report.residual)
            run.substeps.append(report.substeps)
            run.contacts.append(sum(1 for c in report.contacts if c.p_n > 0.0))
            gaps = [c.gap for c in report.contacts]
            run.report_gaps.append(min(gaps) if gaps else math.inf)
            values = [report.residual] + [x for c in report.contacts for x in (c.p_n, c.gap)]
            if not np.all(np.isfinite(values)):
                run.nan = True
            if not report.success:
                run.error = f"step returned success = False ({report.status}): {_first_sentence(report.message)}"
                break
        else:
            run.contacts.append(report.num_contacts)
            run.substeps.append(1)
        if not _finite_state(world):
            run.nan = True
        run.energy.append(_energy(world, stepper))
        if probe is not None:
            run.gaps.append(probe())
        if keep_reports:
            run.reports.append(report)
        if on_step is not None:
            on_step(report)
        if run.nan:
            break
        if spent > wall_budget and run.steps < steps:
            run.budget_stopped = True
            break
    return run


def _first_sentence(text: str, limit: int = 300) -> str:
    text = " ".join(text.split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _record(config, run: _Run, checks, key, energy_rule="no growth", steps_planned=None) -> CaseRecord:
    """Common checks (completion is the verdict's; NaN; penetration; energy) plus the case's own."""
    energy = np.asarray(run.energy, float)
    if energy_rule == "no growth":
        drift = float(np.max(np.diff(energy))) if len(energy) > 1 else 0.0
    elif energy_rule == "conserved":
        drift = float(np.max(np.abs(energy - energy[0])))
    else:
        drift = math.nan
    common = []
    min_gap = float(np.min(run.gaps)) if run.gaps else math.nan
    min_report_gap = float(np.min(run.report_gaps)) if run.report_gaps else math.nan
    if run.gaps:
        common.append(Check("penetration [m] (geometry)", -min_gap, PEN_TOL))
    if run.report_gaps:
        common.append(Check("penetration [m] (reported gap)", -min_report_gap, PEN_TOL))
    if energy_rule == "no growth":
        common.append(Check("energy growth per step [J]", drift, ENERGY_REL * run.e_ref))
        if not common[-1].ok:
            # a growing step may be a gain or the return of an oscillation (order 2's energy error
            # is not monotone): the largest rise above the lowest energy before it tells them apart
            rise = float(np.max(energy - np.minimum.accumulate(energy)))
            key += f"; largest rise above the lowest energy before it {rise:.2e} J"
    elif energy_rule == "conserved":
        common.append(Check("|E - E0| [J]", drift, KE_REL * max(abs(energy[0]), run.e_ref)))
    iterations = np.asarray(run.iterations, float)
    return CaseRecord(
        config=config, completed=not run.error and not run.budget_stopped, error=run.error,
        steps_done=run.steps, steps_planned=steps_planned if steps_planned is not None else run.steps,
        min_gap=min_gap, min_report_gap=min_report_gap, energy_rule=energy_rule, energy_drift=drift,
        max_residual=float(np.max(run.residual)) if run.residual else math.nan,
        iterations_mean=float(iterations.mean()) if len(iterations) else math.nan,
        iterations_max=int(iterations.max()) if len(iterations) else -1,
        step_median_s=float(np.median(run.wall)) if run.wall else math.nan,
        any_nan=run.nan, checks=tuple(common + list(checks)), key=key, budget_stopped=run.budget_stopped,
        steps_wall=np.asarray(run.wall, float), steps_contacts=np.asarray(run.contacts, float),
        steps_substeps=np.asarray(run.substeps, int))


def _steps(duration, h) -> int:
    return int(round(duration / h))


def _drift(series) -> float:
    """max_k |x_k - x_0| over rows of (steps, dims) positions [m]."""
    x = np.asarray(series, float)
    return float(np.max(np.linalg.norm(x - x[0], axis=1))) if len(x) else math.nan


def _rel(value, expected) -> float:
    return abs(value - expected) / abs(expected) if expected else abs(value)


# ----------------------------------------------------------------------------------------------
# the cases
# ----------------------------------------------------------------------------------------------
def stiffness_case(c: StiffnessCase) -> CaseRecord:
    """Drop on a quasi-rigid layer; a damped layer must come to rest at deflection m g / k."""
    import implicit_contact as ic

    m, r, gap0, delta_max = 1.0, 0.1, 0.05, 0.05
    world = _world(c.h)
    skel, body = _free_body(world, "ball", m, _solid_sphere_inertia(m, r), [0.0, 0.0, r + gap0])
    ic.attach(body, ic.shapes.Sphere(r), friction=ic.Friction(mu=0.5))
    ground = _fixed_body(world, "ground")
    damping = 2.0 * math.sqrt(c.k * m) if c.damped else 0.0
    ic.attach(ground, ic.shapes.HalfSpace([0.0, 0.0, 1.0], 0.0), friction=ic.Friction(mu=0.5),
              compliance=ic.Compliance(c.k, damping, delta_max))
    stepper = _make_stepper(world, c.stepper)
    deflections = []
    on_step = (lambda rep: deflections.append(max([x.deflection for x in rep.contacts], default=0.0)))
    steps = _steps(c.duration, c.h)
    run = _drive(world, stepper, steps, on_step=on_step)
    static = m * G / c.k
    final = deflections[-1] if deflections else math.nan
    ratio = final / static
    checks = [Check("deflection / delta_max", max(deflections, default=math.nan) / delta_max, 1.0 + PEN_TOL / delta_max)]
    if c.damped:
        checks.append(Check("|final deflection / (m g / k) - 1|", abs(ratio - 1.0), IMPULSE_REL))
    key = f"final deflection / (m g/k) - 1 = {ratio - 1.0:+.1e}" + ("" if c.damped else " (undamped: not required at rest)")
    return _record(c, run, checks, key, steps_planned=steps)


def _mass_ratio_world(kind, h, stepper):
    world = _world(h)
    _ground(world, stepper)
    if kind == "sphere_under_ellipsoid":
        r, m, axes, M = 0.5, 1.0, (2.0, 2.0, 0.1), 1e4
        s1, b1 = _free_body(world, "sphere", m, _solid_sphere_inertia(m, r), [0.0, 0.0, r])
        _primitive(b1, _sphere(r))
        a, b, cz = axes
        inertia = np.diag([b * b + cz * cz, a * a + cz * cz, a * a + b * b]) * M / 5.0
        s2, b2 = _free_body(world, "ellipsoid", M, inertia, [0.0, 0.0, 2 * r + cz])
        _primitive(b2, _ellipsoid(axes))
        return world, (s1, s2), (m, M)
    size, M, r, m = (1.0, 1.0, 0.5), 1e3, 0.05, 1e-3
    s1, b1 = _free_body(world, "heavy_box", M, _box_inertia(M, size), [0.0, 0.0, size[2] / 2])
    _primitive(b1, _box(size))
    s2, b2 = _free_body(world, "light_sphere", m, _solid_sphere_inertia(m, r), [0.0, 0.0, size[2] + r])
    _primitive(b2, _sphere(r))
    return world, (s1, s2), (M, m)


def mass_ratio_case(c: MassRatioCase) -> CaseRecord:
    """Two bodies resting in a column on a plane: nothing may move; the ground carries both."""
    world, (lower, upper), (m_lower, m_upper) = _mass_ratio_world(c.kind, c.h, c.stepper)
    stepper = _make_stepper(world, c.stepper)
    positions = [np.r_[lower.getPositions()[3:], upper.getPositions()[3:]]]
    steps = _steps(c.duration, c.h)
    run = _drive(world, stepper, steps, probe=_ground_probe(world, c.stepper), keep_reports=True,
                 on_step=lambda rep: positions.append(np.r_[lower.getPositions()[3:], upper.getPositions()[3:]]))
    drift = _drift(positions)
    checks = [Check("drift [m]", drift, DRIFT_TOL)]
    key = f"drift {drift:.2e} m"
    if c.stepper == IMPLICIT and run.reports:
        ground_pn = sum(x.p_n for x in run.reports[-1].contacts if "ground" in (x.name_a + x.name_b))
        err = _rel(ground_pn, (m_lower + m_upper) * G * c.h)
        checks.append(Check("|ground p_n / ((m1 + m2) g h) - 1|", err, IMPULSE_REL))
        key += f"; ground p_n error {err:.1e}"
    return _record(c, run, checks, key, steps_planned=steps)


def impact_case(c: ImpactCase) -> CaseRecord:
    """A fast sphere must stop on the plane, not inside or below it."""
    r, m, z0 = 0.1, 1.0, 0.55
    world = _world(c.h)
    _ground(world, c.stepper)
    skel, body = _free_body(world, "ball", m, _solid_sphere_inertia(m, r), [0.0, 0.0, z0],
                            velocity=[0, 0, 0, 0, 0, -c.speed])
    _primitive(body, _sphere(r))
    stepper = _make_stepper(world, c.stepper)
    steps = _steps(c.duration, c.h)
    run = _drive(world, stepper, steps, probe=_ground_probe(world, c.stepper))
    final = float(skel.getPositions()[5]) - r
    checks = [Check("final centre height below r [m]", -final, PEN_TOL)]
    return _record(c, run, checks, f"final height - r = {final:.2e} m", steps_planned=steps)


def grazing_case(c: GrazingCase) -> CaseRecord:
    """A pass at exact tangency: no impulse, no velocity change, no penetration."""
    r1, r2, m = 1.0, 0.5, 1.0
    world = _world(c.h, gravity=(0.0, 0.0, 0.0))
    big, b1 = _free_body(world, "big", m, _solid_sphere_inertia(m, r1), [0.0, 0.0, 0.0])
    _primitive(b1, _sphere(r1))
    v0 = np.array([0.0, 0.0, 0.0, 1.0, 0.0, 0.0])
    x0 = -0.5 * c.duration * v0[3]
    small, b2 = _free_body(world, "small", m, _solid_sphere_inertia(m, r2), [x0, 0.0, r1 + r2], velocity=v0)
    _primitive(b2, _sphere(r2))
    stepper = _make_stepper(world, c.stepper)
    steps = _steps(c.duration, c.h)
    run = _drive(world, stepper, steps, probe=_GapProbe(world))
    dv = max(float(np.max(np.abs(big.getVelocities()))), float(np.max(np.abs(small.getVelocities() - v0))))
    checks = [Check("velocity change [m/s, rad/s]", dv, VELOCITY_TOL)]
    return _record(c, run, checks, f"max velocity change {dv:.1e}", energy_rule="conserved", steps_planned=steps)


def _stack_world(h, stepper, n=3, r=0.1, m=1.0):
    world = _world(h)
    _ground(world, stepper)
    skels = []
    for k in range(n):
        skel, body = _free_body(world, f"sphere{k}", m, _solid_sphere_inertia(m, r), [0.0, 0.0, (2 * k + 1) * r])
        _primitive(body, _sphere(r))
        skels.append(skel)
    return world, skels


def time_step_case(c: TimeStepCase) -> CaseRecord:
    """The rolling disc keeps its kinetic energy and height; the stack does not move; any h."""
    if c.scene == "disc":
        return _disc_run(c, c.h, c.steps)
    world, skels = _stack_world(c.h, c.stepper)
    stepper = _make_stepper(world, c.stepper)
    positions = [np.concatenate([s.getPositions()[3:] for s in skels])]
    run = _drive(world, stepper, c.steps, probe=_ground_probe(world, c.stepper), keep_reports=True,
                 on_step=lambda rep: positions.append(np.concatenate([s.getPositions()[3:] for s in skels])))
    drift = _drift(positions)
    checks = [Check("drift [m]", drift, DRIFT_TOL)]
    key = f"drift {drift:.2e} m"
    if c.stepper == IMPLICIT and run.reports:
        pn = sum(x.p_n for x in run.reports[-1].contacts if "ground" in (x.name_a + x.name_b))
        err = _rel(pn, 3 * 1.0 * G * c.h)
        checks.append(Check("|ground p_n / (3 m g h) - 1|", err, IMPULSE_REL))
        key += f"; ground p_n error {err:.1e}"
    return _record(c, run, checks, key, steps_planned=c.steps)


def _disc_run(c, h, steps) -> CaseRecord:
    """The [GI] Example 1 disc for ``steps`` steps of h: KE conserved, centre height kept."""
    from scenes import disc_rolling

    if c.stepper == IMPLICIT:
        world = disc_rolling.build_world(h)
    else:
        from comparisons import dart_native
        world, _ = dart_native.build_primitive_disc_world("cylinder", h=h)
    disc = world.getSkeleton("disc")
    stepper = _make_stepper(world, c.stepper)
    heights = [disc.getPositions()[1]]
    run = _drive(world, stepper, steps, on_step=lambda rep: heights.append(disc.getPositions()[1]))
    y = np.asarray(heights) - disc_rolling.RADIUS
    # the ground is flat: the disc's lowest point is y - r, exactly
    run.gaps = list(y)
    ke0 = 6.75
    v = disc.getVelocities()
    ke = 0.5 * disc_rolling.MASS * (v[0] ** 2 + v[1] ** 2) + 0.5 * disc_rolling.INERTIA * v[2] ** 2
    drift = float(np.max(np.abs(y - y[0])))
    checks = [Check("|y - y0| [m]", drift, DRIFT_TOL)]
    key = f"KE {ke:.9g} J (KE0 {ke0} J); height drift {drift:.1e} m"
    return _record(c, run, checks, key, energy_rule="conserved", steps_planned=steps)


def shape_case(c: ShapeCase) -> CaseRecord:
    import implicit_contact as ic

    world = _world(c.h)
    if c.kind in ("superquadric", "box", "flat_ellipsoid"):
        m = 1.0
        axes = (1.0, 1.0, 0.01) if c.kind == "flat_ellipsoid" else (0.3, 0.2, 0.15)
        if c.kind == "superquadric":
            shape = ic.shapes.Superquadric(axes, c.param)
            inertia = _shape_inertia(shape, m)
        elif c.kind == "box":
            inertia = _box_inertia(m, 2 * np.asarray(axes))
        else:
            inertia = _shape_inertia(ic.shapes.Ellipsoid(axes), m)
        skel, body = _free_body(world, c.kind, m, inertia, [0.0, 0.0, 0.3], rotation=[0.3, 0.0, 0.0])
        heights = [0.3]
        if c.kind == "superquadric":
            ic.attach(body, shape, friction=ic.Friction(mu=0.5, e_r=0.02))
            ground = _fixed_body(world, "ground")
            ic.attach(ground, ic.shapes.HalfSpace([0.0, 0.0, 1.0], 0.0), friction=ic.Friction(mu=0.5, e_r=0.02))
        else:
            _primitive(body, _box(2 * np.asarray(axes)) if c.kind == "box" else _ellipsoid(axes))
            _ground(world, c.stepper)
        stepper = _make_stepper(world, c.stepper)
        steps = _steps(c.duration, c.h)
        run = _drive(world, stepper, steps, probe=_ground_probe(world, c.stepper),
                     on_step=lambda rep: heights.append(float(skel.getPositions()[5])))
        z = float(skel.getPositions()[5])
        v = skel.getVelocities()
        ke = 0.5 * float(v @ skel.getMassMatrix() @ v)
        checks = []
        if c.kind != "flat_ellipsoid":
            # no orientation puts the centre lower than the smallest semi-axis above the plane
            checks.append(Check("centre below smallest semi-axis [m]", axes[2] - min(heights), PEN_TOL))
        if c.kind == "box" or (c.kind == "superquadric" and c.param > 2.0):
            checks.append(Check("|final height - smallest semi-axis| [m]", abs(z - axes[2]), REST_HEIGHT_TOL))
        key = f"final height {z:.6f} m (smallest semi-axis {axes[2]:g}), KE {ke:.1e} J"
        if c.kind == "superquadric" and c.param <= 2.0:
            key += " (an ellipsoid rocks: not required at rest)"
        return _record(c, run, checks, key, steps_planned=steps)
    if c.kind in ("tiny", "huge"):
        r = c.param
        m = 1000.0 * 4.0 / 3.0 * math.pi * r ** 3
        gap0 = min(0.5 * r, 0.1)
        skel, body = _free_body(world, "ball", m, _solid_sphere_inertia(m, r), [0.0, 0.0, r + gap0])
        _primitive(body, _sphere(r))
        _ground(world, c.stepper)
        stepper = _make_stepper(world, c.stepper)
        steps = _steps(c.duration, c.h)
        run = _drive(world, stepper, steps, probe=_ground_probe(world, c.stepper))
        z = float(skel.getPositions()[5]) - r
        speed = float(np.max(np.abs(skel.getVelocities())))
        checks = [Check("|final height - r| [m]", abs(z), PEN_TOL), Check("final speed [m/s]", speed, 1e-6)]
        return _record(c, run, checks, f"final height - r = {z:.2e} m, speed {speed:.1e}", steps_planned=steps)
    if c.kind == "held":
        R, r, m = 1.0, 0.5, 1.0
        fixed = _fixed_body(world, "holders")
        _primitive(fixed, _sphere(R), center=[-1.0, 0.0, 0.0])
        fixed2 = _fixed_body(world, "holders2")
        _primitive(fixed2, _sphere(R), center=[1.0, 0.0, 0.0])
        z0 = math.sqrt((R + r) ** 2 - 1.0)
        skel, body = _free_body(world, "ball", m, _solid_sphere_inertia(m, r), [0.0, 0.0, z0])
        _primitive(body, _sphere(r))
        stepper = _make_stepper(world, c.stepper)
        positions = [skel.getPositions()[3:].copy()]
        steps = _steps(c.duration, c.h)
        run = _drive(world, stepper, steps, probe=_GapProbe(world), keep_reports=True,
                     on_step=lambda rep: positions.append(skel.getPositions()[3:].copy()))
        drift = _drift(positions)
        checks = [Check("drift [m]", drift, DRIFT_TOL)]
        key = f"drift {drift:.2e} m"
        if c.stepper == IMPLICIT and run.reports:
            expected = m * G * c.h / (2.0 * z0 / (R + r))
            err = max((_rel(x.p_n, expected) for x in run.reports[-1].contacts), default=math.nan)
            checks.append(Check("|p_n / (m g h / (2 cos theta)) - 1|", err, IMPULSE_REL))
            key += f"; p_n error {err:.1e}"
        return _record(c, run, checks, key, steps_planned=steps)
    raise ValueError(f"unknown shape case {c.kind!r}")


def long_run_case(c: LongRunCase) -> CaseRecord:
    import implicit_contact as ic

    if c.kind == "disc":
        return _disc_run(c, c.h, c.steps)
    axes, m = (0.3, 0.2, 0.15), 1.0
    world = _world(c.h)
    if c.stepper == IMPLICIT:
        shape = ic.shapes.Superquadric(axes, 4.0)
        skel, body = _free_body(world, "body", m, _shape_inertia(shape, m), [0.0, 0.0, axes[2]])
        ic.attach(body, shape, friction=ic.Friction(mu=0.5, e_r=0.02))
        ground = _fixed_body(world, "ground")
        ic.attach(ground, ic.shapes.HalfSpace([0.0, 0.0, 1.0], 0.0), friction=ic.Friction(mu=0.5, e_r=0.02))
    else:
        skel, body = _free_body(world, "body", m, _box_inertia(m, 2 * np.asarray(axes)), [0.0, 0.0, axes[2]])
        _primitive(body, _box(2 * np.asarray(axes)))
        _ground(world, c.stepper)
    stepper = _make_stepper(world, c.stepper)
    q = [skel.getPositions().copy()]
    run = _drive(world, stepper, c.steps, probe=_ground_probe(world, c.stepper), keep_reports=False,
                 on_step=lambda rep: q.append(skel.getPositions().copy()))
    q = np.asarray(q)
    drift = _drift(q[:, 3:])
    turn = _drift(q[:, :3])
    checks = [Check("drift [m]", drift, DRIFT_TOL), Check("rotation drift [rad]", turn, DRIFT_TOL)]
    return _record(c, run, checks, f"drift {drift:.2e} m, rotation {turn:.1e} rad", steps_planned=c.steps)


def _box_planes(half):
    """The solid half-spaces {normal . x <= offset} of the open box: floor z <= 0, walls |x|, |y| >= half."""
    return (((0.0, 0.0, 1.0), 0.0), ((1.0, 0.0, 0.0), -half), ((-1.0, 0.0, 0.0), -half),
            ((0.0, 1.0, 0.0), -half), ((0.0, -1.0, 0.0), -half))


def _box_half_width(n, spacing=0.25):
    """Half width [m] of the box for n bodies: a square grid of side ceil(sqrt(n / 2)) per layer."""
    return max(2, math.ceil(math.sqrt(n / 2))) * spacing / 2


def many_bodies_world(n, h, stepper, seed=0):
    import implicit_contact as ic

    world = _world(h)
    side = max(2, math.ceil(math.sqrt(n / 2)))
    spacing = 0.25
    half = _box_half_width(n)
    walls = _fixed_body(world, "box")
    planes = _box_planes(half)
    for normal, offset in planes:
        if stepper == IMPLICIT:
            ic.attach(walls, ic.shapes.HalfSpace(normal, offset), friction=ic.Friction(mu=0.5))
        else:
            # DART: a 1 m thick box behind each plane (see _ground), walls 3 m high
            normal = np.asarray(normal)
            floor = normal[2] != 0.0
            size = np.where(normal != 0.0, 1.0, 2.0 * half + 2.0)
            size[2] = 1.0 if floor else 3.0
            centre = (offset - 0.5) * normal + (0.0 if floor else np.array([0.0, 0.0, 1.5]))
            _primitive(walls, _box(size), center=centre)
    axes, m = (0.1, 0.08, 0.06), 0.5
    shape = ic.shapes.Superquadric(axes, 4.0)
    inertia = _shape_inertia(shape, m) if stepper == IMPLICIT else _box_inertia(m, 2 * np.asarray(axes))
    rng = np.random.default_rng(seed)
    for k in range(n):
        i, j, layer = k % side, (k // side) % side, k // (side * side)
        position = [-half + spacing * (i + 0.5), -half + spacing * (j + 0.5), 0.15 + 0.25 * layer]
        skel, body = _free_body(world, f"b{k}", m, inertia, position, rotation=rng.uniform(-0.5, 0.5, 3))
        if stepper == IMPLICIT:
            ic.attach(body, shape, friction=ic.Friction(mu=0.5))
        else:
            _primitive(body, _box(2 * np.asarray(axes)))
    return world


def many_bodies_case(c: ManyBodiesCase) -> CaseRecord:
    world = many_bodies_world(c.n, c.h, c.stepper)
    stepper = _make_stepper(world, c.stepper)
    steps = _steps(c.duration, c.h)
    if c.stepper == IMPLICIT:
        probe = _GapProbe(world, halfspaces_only=c.n > PROBE_MAX_BODIES)
    else:
        probe = _GapProbe(world, halfspaces_only=c.n > PROBE_MAX_BODIES, planes=_box_planes(_box_half_width(c.n)),
                          skip=("box",))
    run = _drive(world, stepper, steps, probe=probe, wall_budget=c.wall_budget)
    contacts = np.asarray(run.contacts, float)
    key = (f"{run.steps} steps, median {1e3 * np.median(run.wall):.1f} ms/step, "
           f"up to {int(contacts.max()) if len(contacts) else 0} contacts") if run.wall else "no step"
    return _record(c, run, [], key, steps_planned=steps)


RUNNERS = {StiffnessCase: stiffness_case, MassRatioCase: mass_ratio_case, ImpactCase: impact_case,
           GrazingCase: grazing_case, TimeStepCase: time_step_case, ShapeCase: shape_case,
           LongRunCase: long_run_case, ManyBodiesCase: many_bodies_case}


def run(config) -> CaseRecord:
    """Run one case (a pure function of its config: pool workers call it)."""
    _check_stepper(config.stepper)
    return RUNNERS[type(config)](config)


def _crashed(config, error: BaseException) -> CaseRecord:
    """A case whose own code raised (not the stepper: _drive catches those)."""
    return CaseRecord(config, False, f"case raised {type(error).__name__}: {_first_sentence(str(error))}", 0, 0,
                      math.nan, math.nan, "", math.nan, math.nan, math.nan, -1, math.nan, False, (), "")


# ----------------------------------------------------------------------------------------------
# the matrix
# ----------------------------------------------------------------------------------------------
def plan(mode: str = "default") -> tuple:
    """Every case of the study, implicit and (where DART has the case) native."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    quick = mode == "quick"
    both = (IMPLICIT, NATIVE)
    cases = []
    ks = (1e3, 1e8) if quick else (1e3, 1e4, 1e6, 1e8)
    cases += [StiffnessCase(k, damped) for k in ks for damped in (True, False)]
    cases += [MassRatioCase(kind, s, duration=0.3 if quick else 1.0)
              for kind in ("sphere_under_ellipsoid", "light_on_heavy") for s in both]
    speeds = (100.0,) if quick else (10.0, 20.0, 30.0, 100.0)   # where tunnelling starts, if it does
    cases += [ImpactCase(v, IMPLICIT) for v in speeds] + [ImpactCase(100.0, NATIVE)]
    cases += [GrazingCase(stepper=s) for s in both]
    hs = (1e-3, 1e-1) if quick else (1e-5, 1e-4, 1e-3, 1e-2, 1e-1)
    n = 100 if quick else 500
    cases += [TimeStepCase(scene, h, n, s) for scene in ("disc", "stack") for h in hs for s in both]
    exponents = (4.0, 10.0) if quick else (2.0, 4.0, 6.0, 8.0, 10.0)
    duration = 3.0
    cases += [ShapeCase("superquadric", e, duration=duration) for e in exponents]
    cases += [ShapeCase("box", 0.0, NATIVE, duration=duration)]
    cases += [ShapeCase("flat_ellipsoid", 0.0, s, duration=duration) for s in both]
    cases += [ShapeCase(kind, r, s, duration=1.0) for kind, r in (("tiny", 1e-3), ("huge", 1e3)) for s in both]
    cases += [ShapeCase("held", 0.0, s, duration=duration) for s in both]
    rest_steps = 1000 if quick else 10_000
    disc_steps = 1000 if quick else 6000
    cases += [LongRunCase("resting", rest_steps, s) for s in both]
    cases += [LongRunCase("disc", disc_steps, s) for s in both]
    budgets = MANY_BODY_BUDGETS[mode]
    duration = 0.15 if quick else 1.0      # quick: the first landings only
    cases += [ManyBodiesCase(n_, s, duration=duration, wall_budget=b) for n_, b in budgets for s in both]
    return tuple(cases)


def _cost(config) -> float:
    """Rough seconds of a case (measured magnitudes), only to start the longest ones first."""
    if isinstance(config, ManyBodiesCase):
        return config.wall_budget if config.stepper == IMPLICIT else 1.0
    per_step = 1.5e-3 if config.stepper == IMPLICIT else 1e-4
    steps = getattr(config, "steps", None) or _steps(config.duration, config.h)
    return steps * per_step


def execute(configs, max_workers: int | None = None, progress: bool = True) -> dict:
    """Run every config once on a local process pool (0: in this process); {config: record}."""
    from tqdm import tqdm

    configs = sorted(configs, key=_cost, reverse=True)
    workers = (os.cpu_count() or 1) if max_workers is None else int(max_workers)
    if workers < 0:
        raise ValueError(f"max_workers must be >= 0 (0: run in this process), got {max_workers!r}")
    records = {}
    with tqdm(total=len(configs), desc="stability cases", unit="case", disable=not progress) as bar:
        if workers == 0:
            for config in configs:
                records[config] = _guarded(config)
                bar.update()
        else:
            context = multiprocessing.get_context("spawn")
            with concurrent.futures.ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
                futures = {pool.submit(run, config): config for config in configs}
                for future in concurrent.futures.as_completed(futures):
                    config = futures[future]
                    try:
                        records[config] = future.result()
                    except Exception as error:   # one broken case must not discard the others
                        records[config] = _crashed(config, error)
                    bar.update()
    return records


def _guarded(config) -> CaseRecord:
    try:
        return run(config)
    except Exception as error:
        return _crashed(config, error)


# ----------------------------------------------------------------------------------------------
# scaling
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ScalingFit:
    """t = a n^b fitted (least squares in log-log) over the steps with n >= 1 active contacts that
    were solved at the first attempt (retried steps, which take up to 2 + 4 + 8 + 16 solves, are
    counted and plotted but not fitted: they measure robustness, not the cost of a solve).
    t_goal [s]: time per step with SCALING_BODIES_GOAL bodies, measured (median over that run's
    first-attempt steps with contacts; contacts_goal their median contacts) if it has such steps,
    else the fit at contacts_goal = (the most contacts per body any run reached) x
    SCALING_BODIES_GOAL; extrapolated says which. retried: steps left out;
    retried_seconds: their median wall time."""
    stepper: str
    a: float
    b: float
    points: int
    t_goal: float
    extrapolated: bool
    contacts_goal: float
    retried: int = 0
    retried_seconds: float = math.nan

    @property
    def meets_goal(self) -> bool:
        return self.b <= SCALING_EXPONENT_GOAL and self.t_goal <= SCALING_TIME_GOAL


def fit_scaling(records: dict, stepper: str) -> ScalingFit | None:
    runs = [r for c, r in records.items() if isinstance(c, ManyBodiesCase) and c.stepper == stepper and r.steps_done]
    if not runs:
        return None
    n = np.concatenate([r.steps_contacts for r in runs])
    t = np.concatenate([r.steps_wall for r in runs])
    first = np.concatenate([r.steps_substeps for r in runs]) == 1
    keep = (n >= 1) & first
    if keep.sum() < 2 or len(np.unique(n[keep])) < 2:
        return None
    b, log_a = np.polyfit(np.log(n[keep]), np.log(t[keep]), 1)
    a = math.exp(log_a)
    retried = int(np.sum(~first))
    retried_seconds = float(np.median(t[~first])) if retried else math.nan
    goal = next((r for r in runs if r.config.n == SCALING_BODIES_GOAL), None)
    # a settled pile: the most contacts per body any run reached, times the goal's bodies
    contacts_goal = max(float(r.steps_contacts.max()) / r.config.n for r in runs) * SCALING_BODIES_GOAL
    measured = goal.steps_contacts >= 1 if goal is not None else None
    if goal is not None and np.any(measured & (goal.steps_substeps == 1)):
        once = measured & (goal.steps_substeps == 1)
        return ScalingFit(stepper, a, float(b), int(keep.sum()), float(np.median(goal.steps_wall[once])), False,
                          float(np.median(goal.steps_contacts[once])), retried, retried_seconds)
    return ScalingFit(stepper, a, float(b), int(keep.sum()), a * contacts_goal ** b, True, contacts_goal, retried,
                      retried_seconds)


def plot_scaling(records: dict, fits: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.5, 6.4), layout="constrained")
    markers = {IMPLICIT: "o", NATIVE: "^"}
    colours = plt.get_cmap("viridis")
    sizes = sorted({c.n for c in records if isinstance(c, ManyBodiesCase)})
    many = [(c, r) for c, r in records.items() if isinstance(c, ManyBodiesCase) and r.steps_done]
    for config, record in sorted(many, key=lambda cr: (cr[0].stepper, cr[0].n)):
        keep = (record.steps_contacts >= 1) & (record.steps_substeps == 1)
        colour = colours(0.85 * sizes.index(config.n) / max(1, len(sizes) - 1))
        name = "implicit" if config.stepper == IMPLICIT else "DART native (boxes)"
        ax.loglog(record.steps_contacts[keep], record.steps_wall[keep], markers[config.stepper], ms=3.5,
                  alpha=0.5, color=colour, mfc="none" if config.stepper == NATIVE else colour,
                  label=f"{name}, {config.n} bodies")
        retried = (record.steps_contacts >= 1) & (record.steps_substeps > 1)
        if retried.any():
            ax.loglog(record.steps_contacts[retried], record.steps_wall[retried], "x", ms=6, color=colour,
                      label=f"{name}, {config.n} bodies: retried steps (not fitted)")
    for stepper, fit in fits.items():
        if fit is None:
            continue
        n = np.geomspace(1, max(fit.contacts_goal, 2.0) * 1.3, 50)
        ax.loglog(n, fit.a * n ** fit.b, "-" if stepper == IMPLICIT else "--", color="black" if stepper == IMPLICIT else "0.5",
                  label=f"fit {'implicit' if stepper == IMPLICIT else 'DART'}: t = {fit.a:.2g} n^{fit.b:.2f}")
        if stepper == IMPLICIT:
            ax.loglog([fit.contacts_goal], [fit.t_goal], "*", ms=12, color="crimson",
                      label=f"{SCALING_BODIES_GOAL} bodies ({'extrapolated' if fit.extrapolated else 'measured'}): "
                            f"{1e3 * fit.t_goal:.0f} ms")
    ax.axhline(SCALING_TIME_GOAL, color="crimson", lw=0.8, ls=":", label=f"goal {1e3 * SCALING_TIME_GOAL:.0f} ms per step")
    ax.set_xlabel("active contacts in the step")
    ax.set_ylabel("wall time per step [s]")
    ax.set_title("How does the time per step grow with the number of contacts?")
    ax.grid(alpha=0.3, which="both")
    fig.legend(*ax.get_legend_handles_labels(), loc="outside lower center", ncols=2, fontsize=7)
    fig.savefig(path, dpi=120)
    plt.close(fig)


# ----------------------------------------------------------------------------------------------
# table and report
# ----------------------------------------------------------------------------------------------
COLUMNS = ("family", "case", "stepper", "bounds", "done", "min gap [m]", "energy drift [J]", "max residual",
           "iters mean/max", "median step [ms]", "NaN", "measured", "verdict")


def _num(x, spec=".2e") -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "-"
    if isinstance(x, float) and math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return format(x, spec)


def _bounds_text(record: CaseRecord) -> str:
    return "; ".join(f"{c.text} <= {_num(c.bound, '.0e')}" for c in record.checks) or "completes"


def rows(records: dict) -> list[dict]:
    order = {t: k for k, t in enumerate(CASE_TYPES)}
    out = []
    for config, r in sorted(records.items(), key=lambda kv: (order[type(kv[0])], str(kv[0]))):
        if r.energy_rule == "no growth":
            energy = f"+{_num(r.energy_drift)}" if r.energy_drift > 0 else _num(r.energy_drift)
        elif r.energy_rule == "conserved":
            energy = f"±{_num(r.energy_drift)}"
        else:
            energy = "-"
        done = "yes" if r.completed else (f"{r.steps_done}/{r.steps_planned} (budget)" if r.budget_stopped
                                           else f"no ({r.steps_done}/{r.steps_planned})")
        gap = _num(r.min_gap)
        if not math.isnan(r.min_report_gap):
            gap += f" (rep. {_num(r.min_report_gap)})"
        out.append({
            "family": config.family, "case": config.label, "stepper": config.stepper, "bounds": _bounds_text(r),
            "done": done, "min gap [m]": gap, "energy drift [J]": energy, "max residual": _num(r.max_residual),
            "iters mean/max": "-" if math.isnan(r.iterations_mean) else f"{r.iterations_mean:.1f}/{r.iterations_max}",
            "median step [ms]": _num(1e3 * r.step_median_s, ".3g"), "NaN": "yes" if r.any_nan else "no",
            "measured": r.key, "verdict": r.verdict, "reason": r.reason,
        })
    return out


# why the scaling goal is out of reach (measured with comparisons/bench_many_bodies.py and cProfile)
SCALING_LIMIT_WHY = ("why: the pair rows are compiled (~4 us per pair for F and J), but a landing step of 100 "
                     "bodies (~2200 unknowns) takes ~2-3 solves (friction rows switched on) of ~10 Newton "
                     "iterations, each iteration two compiled assemblies of F and J (~0.7 ms each for ~175 pairs, "
                     "the line search's trial and the new iterate) and one Newton step with each pair's "
                     "closest-point block eliminated first (block_elimination.py: ~1.1 ms, ~880 unknowns left, "
                     "0.36 ms to form them and 0.24 ms their LU), ~85 ms a step; the other ~50 ms are Python "
                     "around the solves: layouts rebuilt while pairs keep changing, the static closest points "
                     "of new pairs, the checks. 50 ms needs fewer iterations and that Python compiled, not "
                     "faster rows")


def goal_row(fit: ScalingFit | None) -> dict:
    if fit is None:
        return {"family": "many bodies", "case": "scaling goal", "stepper": IMPLICIT, "verdict": "FAIL",
                "reason": "no many-body run completed a step with contacts"}
    how = "extrapolated from the fit" if fit.extrapolated else "measured"
    reasons = []
    if fit.b > SCALING_EXPONENT_GOAL:
        reasons.append(f"exponent {fit.b:.3f} > {SCALING_EXPONENT_GOAL}")
    if fit.t_goal > SCALING_TIME_GOAL:
        reasons.append(f"{SCALING_BODIES_GOAL} bodies: {1e3 * fit.t_goal:.0f} ms per step ({how}, "
                       f"~{fit.contacts_goal:.0f} contacts) > {1e3 * SCALING_TIME_GOAL:.0f} ms")
    if reasons:
        reasons.append(SCALING_LIMIT_WHY)
    return {"family": "many bodies", "case": f"scaling: t = a n^b, {SCALING_BODIES_GOAL} bodies",
            "stepper": IMPLICIT,
            "bounds": f"b <= {SCALING_EXPONENT_GOAL}; t({SCALING_BODIES_GOAL} bodies) <= {1e3 * SCALING_TIME_GOAL:.0f} ms",
            "done": "yes", "min gap [m]": "-", "energy drift [J]": "-", "max residual": "-", "iters mean/max": "-",
            "median step [ms]": _num(1e3 * fit.t_goal, ".3g"), "NaN": "-",
            "measured": f"b = {fit.b:.3f}, a = {fit.a:.2e} s ({fit.points} first-attempt steps); "
                        f"{SCALING_BODIES_GOAL} bodies {1e3 * fit.t_goal:.0f} ms ({how}); {fit.retried} retried steps, "
                        f"median {_num(fit.retried_seconds, '.3g')} s",
            "verdict": "PASS" if fit.meets_goal else "FAIL", "reason": "; ".join(reasons)}


def markdown_table(table: list[dict]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    for r in table:
        lines.append("| " + " | ".join(str(r.get(k, "-")).replace("|", "\\|") for k in COLUMNS) + " |")
    return "\n".join(lines)


def text_table(table: list[dict]) -> str:
    widths = {"family": 11, "case": 44, "stepper": 11, "done": 14, "min gap [m]": 30, "energy drift [J]": 10,
              "iters mean/max": 8, "median step [ms]": 8, "verdict": 7}
    head = " ".join(f"{k[:widths[k]]:<{widths[k]}}" for k in widths)
    lines = [head, "-" * len(head)]
    for r in table:
        lines.append(" ".join(f"{str(r.get(k, '-'))[:widths[k]]:<{widths[k]}}" for k in widths))
    return "\n".join(lines)


def write_csv(table: list[dict], path: Path) -> None:
    fields = list(COLUMNS) + ["reason"]
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields)
        writer.writeheader()
        for r in table:
            writer.writerow({k: r.get(k, "") for k in fields})


def write_markdown(table, fits, mode, seconds, path: Path) -> None:
    import dartpy as dart

    known = sorted((r for r in table if r["verdict"] != "PASS"), key=lambda r: r["verdict"] != "FAIL")
    counts = {v: sum(r["verdict"] == v for r in table) for v in ("PASS", "FAIL", "LIMIT")}
    lines = [
        "# Stability matrix of the implicit stepper (and DART's native stepper)",
        "",
        "Generated by `python -m comparisons.stability" + ("" if mode == "default" else f" --{mode}") +
        f"` (dartpy {getattr(dart, '__version__', '?')}, {os.cpu_count()} cores, {seconds:.0f} s wall). "
        "Definitions, bounds and verdicts: the module docstring of `comparisons/stability.py`.",
        "",
        f"PASS {counts['PASS']}, FAIL {counts['FAIL']}, LIMIT {counts['LIMIT']}. "
        "FAIL: the implicit stepper missed a bound or raised. LIMIT: DART's native stepper missed a bound "
        "(contrast), or the run was cut by the study's wall budget. min gap: most negative signed distance from "
        "the geometry (rep.: the stepper's reported contact gap). energy drift: `+x` largest growth in one step "
        "(no-growth cases), `±x` largest |E - E0| (conserved cases). Wall times are for runs sharing the cores.",
        "",
        markdown_table(table),
        "",
        "## Known limits",
        "",
    ]
    if not known:
        lines.append("None: every case met its bounds.")
    for r in known:
        lines.append(f"- **{r['verdict']}** {r['family']} / {r['case']} / {r['stepper']}: {r['reason']}")
    lines += ["", "## Scaling", ""]
    for stepper, fit in fits.items():
        if fit is None:
            lines.append(f"- {stepper}: no fit (no many-body steps with contacts).")
            continue
        lines.append(f"- {stepper}: t = {fit.a:.3g} s x n^{fit.b:.3f} over {fit.points} first-attempt steps "
                     f"(n = active contacts); {SCALING_BODIES_GOAL} bodies (~{fit.contacts_goal:.0f} contacts): "
                     f"{1e3 * fit.t_goal:.1f} ms per step ({'extrapolated from the fit' if fit.extrapolated else 'measured'}); "
                     f"{fit.retried} retried steps left out of the fit (median {_num(fit.retried_seconds, '.3g')} s each).")
    lines += ["", "![time per step against contacts](stability_scaling.png)", ""]
    path.write_text("\n".join(lines))


@dataclass(frozen=True)
class StudyResult:
    table: list
    records: dict
    fits: dict
    paths: dict
    seconds: float


def study(mode: str = "default", out: Path | str = DEFAULT_OUT, max_workers: int | None = None,
          progress: bool = True, only: str = "") -> StudyResult:
    start = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    configs = [c for c in plan(mode) if only.lower() in f"{c.family} {c.label} {c.stepper}".lower()]
    records = execute(configs, max_workers=max_workers, progress=progress)
    fits = {s: fit_scaling(records, s) for s in (IMPLICIT, NATIVE)}
    table = rows(records)
    if any(isinstance(c, ManyBodiesCase) and c.stepper == IMPLICIT for c in records):
        table.append(goal_row(fits[IMPLICIT]))
    seconds = time.perf_counter() - start
    paths = {"md": out / "stability.md", "csv": out / "stability.csv"}
    write_csv(table, paths["csv"])
    if any(isinstance(c, ManyBodiesCase) for c in records):
        paths["scaling"] = out / "stability_scaling.png"
        plot_scaling(records, fits, paths["scaling"])
    write_markdown(table, fits, mode, seconds, paths["md"])
    return StudyResult(table, records, fits, paths, seconds)


def main(argv=None) -> StudyResult:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--quick", action="store_true", help="a subset in under a minute on 2 cores")
    group.add_argument("--full", action="store_true", help="a 900 s wall budget per many-body run (default 45-90 s)")
    parser.add_argument("--workers", type=int, default=None, help="local processes (default os.cpu_count(); 0 = here)")
    parser.add_argument("--only", default="", help="run only cases whose 'family label stepper' contains this")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default {DEFAULT_OUT})")
    parser.add_argument("--order", type=int, choices=(1, 2), default=1,
                        help="the implicit stepper's StepperOptions.order (2: rattle.py)")
    args = parser.parse_args(argv)
    os.environ[ORDER_ENV] = str(args.order)
    mode = "quick" if args.quick else "full" if args.full else "default"
    result = study(mode, args.out, max_workers=args.workers, only=args.only)
    print(text_table(result.table))
    known = sorted((r for r in result.table if r["verdict"] != "PASS"), key=lambda r: r["verdict"] != "FAIL")
    if known:
        print("\nKnown limits:")
        for r in known:
            print(f"  * {r['verdict']} {r['family']} / {r['case']} / {r['stepper']}: {r['reason']}")
    for stepper, fit in result.fits.items():
        if fit is not None:
            print(f"scaling {stepper}: t = {fit.a:.3g} s n^{fit.b:.3f}; {SCALING_BODIES_GOAL} bodies "
                  f"{1e3 * fit.t_goal:.1f} ms ({'extrapolated' if fit.extrapolated else 'measured'})")
    print("wrote " + ", ".join(str(p) for p in result.paths.values()))
    print(f"total wall time {result.seconds:.1f} s")
    return result


if __name__ == "__main__":
    # run the imported module, so that pickled configs name comparisons.stability
    from comparisons.stability import main as _main

    _main()
