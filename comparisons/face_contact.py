"""Flat faces in contact: a seeded random campaign of boxes, cylinders and prisms on the ground.

Question: how often does the implicit stepper, with its default retry policy, fail, retry,
penetrate or gain energy when bodies with flat faces land on, slide on, tip over, spin on or
stack onto flat faces (README, "Boxes and flat faces"), and what does a step cost there?

What is run, per configuration (seed, scenario, kind, h; everything else drawn from
numpy.random.default_rng(seed)): one body, a DART BoxShape (sides 0.02-0.5 m, aspect <= 10), a
DART CylinderShape (radius 0.02-0.3 m, height 0.02-0.5 m) or a hexagonal prism (an attached
implicit polytope of 8 half-spaces, width 0.02-0.5 m, aspect <= 10), mass 0.1-10 kg with the
shape's own inertia, mu 0.1-1 (the ground's drawn too; the pair takes the smaller), on
testing.ground_box (top at z = 0). Flat placements: a box on any of its faces, a cylinder on a
cap or lying on its side (a line contact), a prism on a side face or an end. Scenarios:
  land   dropped from 1 mm-5 cm (log-uniform) face-down, face-down tilted by 1e-4-0.1 rad,
         edge-down (0.2-1.2 rad about a bottom edge; a cylinder on its rim) or randomly oriented;
         down 0-10 m/s, horizontal 0-3 m/s, spin 0-20 rad/s about a random axis;
  slide  resting flat, gap 0-1e-4 m, horizontal 0-5 m/s, spin 0-0.5 rad/s about a random axis;
  tip    resting flat, turning about a horizontal axis through a bottom edge (that edge at rest)
         at 0.5-2x the rate that just lifts the centre of mass over it;
  spin   resting flat, gap 0-1e-4 m, 0-30 rad/s about the vertical;
  stack  a second body (a box, cylinder or prism regardless of --kinds, or a welded box) resting
         flat on the ground, the first dropped onto its top (within 0.3 of its half-width of
         the centre) as in "land".
The lowest point of a body is placed at the gap above what it rests on (support functions: a box
0.5 |R| size along z, a cylinder h/2 |R22| + r |(R20, R21)|, a prism its lowest vertex), so that
nothing starts interpenetrating. h is log-uniform in [1e-4, 2e-2] and a run takes
min(ceil(0.3 / h), 150) steps of ic.ImplicitContactStepper(world) (default options), or stops at
its first ic.StepFailure (message, step and time recorded), or after the step that passes the
run's wall budget (--budget, "cut"). Each process first steps a few unrecorded runs, so that
loading the compiled kernels (about 1 s) is not timed as a step.

What is checked after every step, independently of the stepper's reports:
  penetration  coal's signed distance of every body to the ground (as coal.Halfspace z >= 0:
               exact for boxes, cylinders and convex hulls; a body cannot reach the ground box's
               sides in 0.3 s, and one that passes through the box reads its depth below z = 0)
               and, in "stack", between the two bodies (GJK/EPA, tolerances 1e-12).
               coal's EPA is not accurate to 1e-6 m for cylinders (measured: 1e-6 m of
               penetration read as 0), so a body pair closer than 1e-5 m is certified instead
               from the support functions: the signed distance of two convex bodies is the max
               over unit n of min_B n.x - max_A n.x, and every n gives a lower bound; coal's
               normal and both bodies' face normals are tried and the best is refined by
               Nelder-Mead (measured: exact to 2e-16 m on flat and crossing-edge contacts). The
               worst per run, against the stepper's contact tolerance (StepperOptions, 1e-6 m).
  energy       E~ = sum over the moving skeletons of KE + PE + (h'/2) m g.v_com, h' = h / substeps
               of the step: the quantity DART's (and the stepper's) semi-implicit Euler free flight
               keeps exactly under gravity (plain KE + PE loses m g^2 h^2 / 2 per free step, which
               would flag every resting step). For every step, each moving body's copy alone in a
               ghost world with its own stepper (no ground, no other body) is set to the real
               state at the start of the step and takes the same substeps: the free flight from
               that state (bitwise the real step while nothing is near). The excess dE~_real -
               sum dE~_free is then the work of the contact impulses at the mean velocity, <= 0
               for inelastic, dissipative contact; recorded absolute [J] and relative to max(KE at
               the step's start, sum m g rho, 1e-12 J), rho a body's bounding radius (the
               potential energy of tipping it): the worst step, the number of steps over 1e-9
               (violations), and the net (sum over the run's steps, relative to the largest scale).
               Also the worst free-flight gain dE~_free of a step, relative: DART's explicit
               gyroscopic term makes a fast-spinning body gain energy in flight, O(h^2) a step.
  cost         Newton iterations per step (StepReport.iterations: of a retried step, the sum
               over its substeps), wall time of stepper.step() alone, retried steps (substeps > 1).

Output: one row per run in comparisons/out/face_contact.csv, and a summary: clean runs (every
step done, none retried, no check violated), a table per kind and scenario (runs, clean,
retried, StepFailures, cuts, other exceptions, energy and penetration violations), the first
messages of the failures with seeds to reproduce, worst penetration, worst energy excess (step
and net), Newton iterations and time per step over all steps (a failed step's time included).
campaign(runs, seed, workers) returns the records, summary(records) the numbers.

Run: python -m comparisons.face_contact [--runs 1000] [--seed 0] [--workers 2] [--quick]
         [--only land,spin] [--kinds box,cylinder,prism] [--budget 60]
     python -m comparisons.face_contact --repro SEED,SCENARIO,KIND,H    (one run, this process)
"""
from __future__ import annotations

import argparse
import collections
import csv
import functools
import math
import os
import time
from dataclasses import dataclass

import coal
import dartpy as dart
import numpy as np
from scipy.optimize import minimize

import implicit_contact as ic
from implicit_contact.testing import dart_world, ground_box

from . import executors

OUT = os.path.join(os.path.dirname(__file__), "out")
KINDS = ("box", "cylinder", "prism")
SCENARIOS = ("land", "slide", "tip", "spin", "stack")
ORIENTATIONS = ("face", "tilt", "edge", "random")
LOWER = ("welded",) + KINDS   # what a dropped body lands on in "stack"
G = 9.81
DURATION, MAX_STEPS = 0.3, 150
H_RANGE = (1e-4, 2e-2)
BUDGET = 60.0            # wall seconds per run
ENERGY_TOL = 1e-9        # relative energy excess over free flight counted as a violation
WARM_SEED = 1
NEAR = 1e-5              # body pairs closer than this [m] get the support-function certificate
CSV_FIELDS = ("seed", "scenario", "kind", "h", "lower", "placement", "orientation", "status",
              "steps_planned", "steps", "retried", "max_substeps", "fail_step", "fail_time",
              "worst_distance", "worst_pair", "worst_step", "energy_excess", "energy_excess_rel",
              "energy_over", "energy_net", "energy_net_rel", "free_gain_rel", "it_median", "it_max", "ms_median",
              "ms_max", "wall_s", "message")


@dataclass(frozen=True)
class Config:
    seed: int
    scenario: str
    kind: str
    h: float
    budget: float = BUDGET

    @property
    def steps(self) -> int:
        return min(math.ceil(DURATION / self.h - 1e-9), MAX_STEPS)

    @property
    def repro(self) -> str:
        return f"{self.seed},{self.scenario},{self.kind},{self.h!r}"


@dataclass
class Body:
    """A body's geometry (box: full sides; cylinder: radius, height; prism: apothem, half length
    along its y axis), mass, mu, placement label and initial state (R, centre c, omega, v; world)."""
    kind: str
    dims: tuple
    mass: float
    mu: float
    placement: str = ""
    R: np.ndarray = None
    c: np.ndarray = None
    w: np.ndarray = None
    v: np.ndarray = None


# -- geometry -----------------------------------------------------------------------------------
_PRISM_ANGLES = np.pi / 2 + np.arange(6) * np.pi / 3     # side normals in the xz plane, one up


def prism_planes(apothem, half_length):
    normals = [[math.cos(a), 0.0, math.sin(a)] for a in _PRISM_ANGLES] + [[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]
    return np.array(normals), np.array([apothem] * 6 + [half_length] * 2)


def prism_vertices(apothem, half_length):
    rc = apothem / math.cos(math.pi / 6)
    return np.array([[rc * math.cos(a + math.pi / 6), s * half_length, rc * math.sin(a + math.pi / 6)]
                     for s in (-1.0, 1.0) for a in _PRISM_ANGLES])


def support_point(body, R, c, n):
    """The point of the body at pose (R, c) farthest along the world direction n."""
    m = R.T @ n
    if body.kind == "box":
        local = np.sign(m) * 0.5 * np.asarray(body.dims)
    elif body.kind == "cylinder":
        r, height = body.dims
        radial = math.hypot(m[0], m[1])
        local = np.array([0.0, 0.0, math.copysign(0.5 * height, m[2])])
        if radial > 0.0:
            local[:2] = r * m[:2] / radial
    else:
        V = prism_vertices(*body.dims)
        local = V[int(np.argmax(V @ m))]
    return c + R @ local


def lowest(body, R):
    """How far the body's lowest point lies below its centre at orientation R."""
    return -support_point(body, R, np.zeros(3), np.array([0.0, 0.0, -1.0]))[2]


def face_normals(body):
    """(label, outward body-frame normal) of the flat placements of the body."""
    e = np.eye(3)
    if body.kind == "box":
        return [(f"face{s}{'xyz'[i]}", sign * e[i]) for i in range(3) for s, sign in (("+", 1.0), ("-", -1.0))]
    if body.kind == "cylinder":
        return [("cap+", e[2]), ("cap-", -e[2]), ("side", e[0])]
    normals, _ = prism_planes(*body.dims)
    return [(f"side{k}", normals[k]) for k in range(6)] + [("end+", normals[6]), ("end-", normals[7])]


def inertia(body):
    """Principal moments about the centre (body axes) of the uniform solid."""
    m = body.mass
    if body.kind == "box":
        x, y, z = body.dims
        return m * (y * y + z * z) / 12, m * (x * x + z * z) / 12, m * (x * x + y * y) / 12
    if body.kind == "cylinder":
        r, height = body.dims
        side = m * (3 * r * r + height * height) / 12
        return side, side, m * r * r / 2
    a, half_length = body.dims                 # regular hexagon: second moment / area = 5 a^2 / 18
    across = m * (5 * a * a / 18 + (2 * half_length) ** 2 / 12)
    return across, m * 5 * a * a / 9, across


def bounding_radius(body):
    if body.kind == "box":
        return 0.5 * float(np.linalg.norm(body.dims))
    if body.kind == "cylinder":
        return math.hypot(body.dims[0], 0.5 * body.dims[1])
    return float(np.linalg.norm(prism_vertices(*body.dims)[0]))


def rotation(axis, angle):
    """Rodrigues' rotation about a unit axis."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * K @ K


def flat_rotation(nb):
    """A rotation taking the body-frame normal nb to -z, and the first body axis (y, x, z order)
    perpendicular to nb to +x: the bottom face's edge along x (exact for axis normals)."""
    r3 = -np.asarray(nb, float)
    axis = next(e for e in (np.eye(3)[1], np.eye(3)[0], np.eye(3)[2]) if abs(e @ r3) < 1e-12)
    return np.array([axis, np.cross(r3, axis), r3])


def yaw(angle):
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def random_rotation(rng):
    q = rng.normal(size=4)
    w, x, y, z = q / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def unit(rng, horizontal=False):
    u = rng.normal(size=3)
    if horizontal:
        u[2] = 0.0
    return u / np.linalg.norm(u)


def loguniform(rng, lo, hi):
    return math.exp(rng.uniform(math.log(lo), math.log(hi)))


# -- drawing a run ------------------------------------------------------------------------------
def draw_body(rng, kind):
    if kind == "box":
        base = loguniform(rng, 0.02, 0.5)
        dims = tuple(float(np.clip(base * 10 ** rng.uniform(-0.5, 0.5), 0.02, 0.5)) for _ in range(3))
    elif kind == "cylinder":
        dims = (loguniform(rng, 0.02, 0.3), loguniform(rng, 0.02, 0.5))
    else:
        apothem = loguniform(rng, 0.01, 0.25)
        dims = (apothem, float(np.clip(apothem * 10 ** rng.uniform(-1.0, 1.0), 0.01, 0.25)))
    return Body(kind, dims, loguniform(rng, 0.1, 10.0), float(rng.uniform(0.1, 1.0)))


def lay_flat(rng, body):
    """A random flat placement (body.placement) with a random yaw; returns R."""
    faces = face_normals(body)
    body.placement, nb = faces[int(rng.integers(len(faces)))]
    return yaw(rng.uniform(0.0, 2 * math.pi)) @ flat_rotation(nb)


def orient(rng, body, mode):
    if mode == "random":
        body.placement = "random"
        return random_rotation(rng)
    flat = lay_flat(rng, body)
    turn = rng.uniform(0.0, 2 * math.pi)
    if mode == "tilt":
        return yaw(turn) @ rotation(unit(rng, True), loguniform(rng, 1e-4, 0.1)) @ flat
    if mode == "edge":
        return yaw(turn) @ rotation(np.array([1.0, 0.0, 0.0]), rng.uniform(0.2, 1.2)) @ flat
    return yaw(turn) @ flat


def drop(rng, body, floor):
    """The "land" state above the height floor; returns the orientation mode."""
    mode = ORIENTATIONS[int(rng.integers(len(ORIENTATIONS)))]
    body.R = orient(rng, body, mode)
    body.c = np.array([0.0, 0.0, floor + loguniform(rng, 1e-3, 5e-2) + lowest(body, body.R)])
    body.v = rng.uniform(0.0, 3.0) * unit(rng, True) - np.array([0.0, 0.0, rng.uniform(0.0, 10.0)])
    body.w = rng.uniform(0.0, 20.0) * unit(rng)
    return mode


def rest(rng, body, gap=0.0):
    body.R = lay_flat(rng, body)
    body.c = np.array([0.0, 0.0, gap + lowest(body, body.R)])
    body.w, body.v = np.zeros(3), np.zeros(3)


def tip(rng, body):
    """Resting flat, turning about a bottom edge (held at rest) at 0.5-2x the rate that lifts the
    centre over it: 1/2 I_edge w^2 = m g (|c - P| - c_z)."""
    rest(rng, body)
    u = unit(rng, True)
    s = np.cross([0.0, 0.0, 1.0], u)
    P = support_point(body, body.R, body.c, np.array([0.0, 0.0, -1.0]) + 1e-3 * s)
    arm = body.c - P
    I = body.R @ np.diag(inertia(body)) @ body.R.T
    rise = float(np.linalg.norm(arm)) - arm[2]
    critical = math.sqrt(2 * body.mass * G * rise / (u @ I @ u + body.mass * (arm @ arm - (u @ arm) ** 2)))
    body.w = -loguniform(rng, 0.5, 2.0) * critical * u      # towards s: the centre rises over P
    body.v = np.cross(body.w, arm)


def draw(config):
    """(moving bodies, welded base or None, ground mu, orientation mode, lower label) of a run."""
    rng = np.random.default_rng(config.seed)
    body = draw_body(rng, config.kind)
    ground_mu, mode = float(rng.uniform(0.1, 1.0)), "face"
    if config.scenario == "land":
        mode = drop(rng, body, 0.0)
    elif config.scenario == "slide":
        rest(rng, body, rng.uniform(0.0, 1e-4))
        body.v = rng.uniform(0.0, 5.0) * unit(rng, True)
        body.w = rng.uniform(0.0, 0.5) * unit(rng)
    elif config.scenario == "tip":
        tip(rng, body)
    elif config.scenario == "spin":
        rest(rng, body, rng.uniform(0.0, 1e-4))
        body.w = np.array([0.0, 0.0, rng.uniform(0.0, 30.0)])
    else:
        choice = LOWER[int(rng.integers(len(LOWER)))]
        lower = draw_body(rng, "box" if choice == "welded" else choice)
        rest(rng, lower)
        mode = drop(rng, body, support_point(lower, lower.R, lower.c, np.array([0.0, 0.0, 1.0]))[2])
        halfwidth = min(support_point(lower, lower.R, np.zeros(3), n)[i] for i, n in enumerate(np.eye(3)[:2]))
        body.c[:2] = 0.3 * halfwidth * rng.uniform(-1.0, 1.0, 2)
        label = f"{choice}:{lower.placement}"
        if choice == "welded":
            return [body], lower, ground_mu, mode, label
        return [body, lower], None, ground_mu, mode, label
    return [body], None, ground_mu, mode, ""


# -- the DART scene -----------------------------------------------------------------------------
def add_body(world, body, name, welded=False):
    """The body as a skeleton of world (a FreeJoint at its state, or welded there) with its
    contact shape; returns (skeleton, the frame whose world transform places the shape)."""
    skel = dart.dynamics.Skeleton(name)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = body.R, body.c
    if welded:
        joint, node = skel.createWeldJointAndBodyNodePair()
        joint.setTransformFromParentBodyNode(dart.math.Isometry3(T))
    else:
        joint, node = skel.createFreeJointAndBodyNodePair()
        joint.setTransform(dart.math.Isometry3(T))
        skel.setVelocities(np.r_[body.w, body.v])
    node.setMass(body.mass)
    node.setMomentOfInertia(*inertia(body))
    world.addSkeleton(skel)
    if body.kind == "prism":
        ic.attach(node, ic.shapes.Intersection.polytope(*prism_planes(*body.dims)), friction=ic.Friction(mu=body.mu))
        return skel, node
    shape = dart.dynamics.BoxShape(list(body.dims)) if body.kind == "box" else dart.dynamics.CylinderShape(*body.dims)
    shape_node = node.createShapeNode(shape)
    shape_node.createCollisionAspect()
    shape_node.createDynamicsAspect().setFrictionCoeff(body.mu)
    return skel, shape_node


ORDER_ENV = "IMPLICIT_CONTACT_CAMPAIGN_ORDER"   # --order, seen by the worker processes too


def _stepper(world):
    """The stepper of a run and of its ghosts: default options, of the order --order chose."""
    return ic.ImplicitContactStepper(world, options=ic.StepperOptions(order=int(os.environ.get(ORDER_ENV, "1"))))


@dataclass
class Ghost:
    """A moving body's copy alone in a world of its own: its free flight from any state."""
    world: object
    skel: object
    stepper: object

    @classmethod
    def of(cls, body, h):
        world = dart_world(h, G)
        skel, _ = add_body(world, body, "ghost")
        return cls(world, skel, _stepper(world))

    def change(self, q, v, h, substeps):
        """dE~ of `substeps` free steps of h from (q, v)."""
        self.skel.setPositions(q)
        self.skel.setVelocities(v)
        self.world.setTimeStep(h)
        before = modified_energy([self.skel], h)
        for _ in range(substeps):
            self.stepper.step()
        return modified_energy([self.skel], h) - before


def energy_parts(skels):
    """(KE + PE, sum m g.v_com, KE) of the skeletons: E~ = first + h/2 second."""
    e = p = k = 0.0
    for skel in skels:
        kinetic = skel.computeKineticEnergy()
        e += kinetic + skel.computePotentialEnergy()
        p += skel.getMass() * float(np.asarray(skel.getGravity()) @ np.asarray(skel.getCOMLinearVelocity()))
        k += kinetic
    return e, p, k


def modified_energy(skels, h):
    e, p, _ = energy_parts(skels)
    return e + 0.5 * h * p


# -- independent penetration check --------------------------------------------------------------
@dataclass
class Solid:
    """A body's geometry for the checks: its coal shape, posed by a DART frame."""
    body: Body
    frame: object
    shape: object

    @classmethod
    def of(cls, body, frame):
        if body.kind == "box":
            shape = coal.Box(*body.dims)
        elif body.kind == "cylinder":
            shape = coal.Cylinder(*body.dims)
        else:
            points = coal.StdVec_Vec3s()
            for vertex in prism_vertices(*body.dims):
                points.append(vertex)
            shape = coal.Convex.convexHull(points, False, "")
        return cls(body, frame, shape)

    def pose(self):
        T = self.frame.getWorldTransform().matrix()
        return T[:3, :3], T[:3, 3]

    def transform(self):
        return coal.Transform3s(*self.pose())


def _request():
    request = coal.DistanceRequest()
    request.enable_signed_distance = True
    request.gjk_tolerance = request.epa_tolerance = 1e-12
    return request


def ground_distance(solid):
    """Signed distance to the ground's top half-space z >= 0 (coal's exact half-space solvers)."""
    plane = coal.Halfspace(np.array([0.0, 0.0, 1.0]), 0.0)
    return coal.distance(solid.shape, solid.transform(), plane, coal.Transform3s(), _request(), coal.DistanceResult())


def pair_distance(a, b):
    """Signed distance of two bodies: coal's, certified by the support functions when near."""
    result = coal.DistanceResult()
    d = coal.distance(a.shape, a.transform(), b.shape, b.transform(), _request(), result)
    return d if d > NEAR else certified_distance(a, b, np.asarray(result.normal, float))


def certified_distance(a, b, normal):
    """max over the tried unit n (a to b) of min_B n.x - max_A n.x: a lower bound of the signed
    distance, exact at the maximising n. Tried: coal's normal, a's outward and b's inward face
    normals; the best refined by Nelder-Mead in its tangent plane."""
    (Ra, ca), (Rb, cb) = a.pose(), b.pose()

    def gap(n):
        n = n / np.linalg.norm(n)
        return float(n @ (support_point(b.body, Rb, cb, -n) - support_point(a.body, Ra, ca, n)))

    tried = [normal] + [Ra @ n for _, n in face_normals(a.body)] + [-(Rb @ n) for _, n in face_normals(b.body)]
    best = max((n / np.linalg.norm(n) for n in tried if np.linalg.norm(n) > 0.0), key=gap)
    t1 = np.cross(best, np.eye(3)[int(np.argmin(np.abs(best)))])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(best, t1)
    refined = minimize(lambda x: -gap(best + x[0] * t1 + x[1] * t2), np.zeros(2), method="Nelder-Mead",
                       options={"xatol": 1e-12, "fatol": 1e-16, "initial_simplex": [[0, 0], [1e-3, 0], [0, 1e-3]]})
    return max(gap(best), -float(refined.fun))


# -- one run ------------------------------------------------------------------------------------
def run(config) -> dict:
    """One configuration stepped and checked (module docstring); returns its record."""
    _warm_up()
    return _run(config)


def _run(config):
    start = time.perf_counter()
    movers, base, ground_mu, mode, lower = draw(config)
    world = dart_world(config.h, G)
    ground_box(world, mu=ground_mu)
    moving = [add_body(world, b, f"body{i}") for i, b in enumerate(movers)]
    skels = [skel for skel, _ in moving]
    solids = [Solid.of(b, frame) for b, (_, frame) in zip(movers, moving)]
    if base is not None:
        solids.append(Solid.of(base, add_body(world, base, "base", welded=True)[1]))
    ghosts = [Ghost.of(b, config.h) for b in movers]
    stepper = _stepper(world)
    scale_floor = sum(b.mass * G * bounding_radius(b) for b in movers)
    rec = _record(config, status="ok", lower=lower, placement=movers[0].placement, orientation=mode)
    iterations, times, excess = [], [], []
    for step in range(config.steps):
        state = [(skel.getPositions(), skel.getVelocities()) for skel in skels]
        e0, p0, k0 = energy_parts(skels)
        t, t0 = world.getTime(), time.perf_counter()
        try:
            report = stepper.step()
        except ic.StepFailure as failure:
            times.append(time.perf_counter() - t0)
            rec.update(status="failure", message=str(failure), fail_step=step, fail_time=t)
            break
        times.append(time.perf_counter() - t0)
        iterations.append(report.iterations)
        rec["steps"] += 1
        rec["retried"] += int(report.substeps > 1)
        rec["max_substeps"] = max(rec["max_substeps"], report.substeps)
        h = config.h / report.substeps
        e1, p1, _ = energy_parts(skels)
        free = sum(g.change(q, v, h, report.substeps) for g, (q, v) in zip(ghosts, state))
        excess.append((e1 + 0.5 * h * p1 - e0 - 0.5 * h * p0 - free, max(k0, scale_floor, 1e-12), free))
        _penetration(rec, solids, len(movers), step)
        if time.perf_counter() - start > config.budget:
            rec.update(status="cut", message=f"wall budget {config.budget:g} s passed after step {step}")
            break
    if excess:
        worst = max(excess, key=lambda e: e[0] / e[1])
        net = sum(e[0] for e in excess)
        rec.update(energy_excess=worst[0], energy_excess_rel=worst[0] / worst[1],
                   energy_over=sum(1 for e in excess if e[0] > ENERGY_TOL * e[1]),
                   energy_net=net, energy_net_rel=net / max(e[1] for e in excess),
                   free_gain_rel=max(e[2] / e[1] for e in excess))
    if iterations:
        rec.update(it_median=float(np.median(iterations)), it_max=int(max(iterations)))
    if times:
        rec.update(ms_median=1e3 * float(np.median(times)), ms_max=1e3 * float(max(times)))
    rec.update(iterations=iterations, times=times, wall_s=time.perf_counter() - start)
    return rec


@functools.cache
def _warm_up():
    """Once per process, unrecorded runs of each kind landing on another, so that loading the
    compiled kernels (about 1 s) is not timed as a step of the first run."""
    for kind in KINDS:
        _run(Config(WARM_SEED, "stack", kind, 5e-3, budget=10.0))


def _penetration(rec, solids, n_moving, step):
    """The signed distances after a step: every moving body to the ground, the two bodies."""
    pairs = [(f"body{i}/ground", ground_distance(solids[i])) for i in range(n_moving)]
    if len(solids) == 2:
        pairs.append(("body0/" + ("body1" if n_moving == 2 else "base"), pair_distance(solids[0], solids[1])))
    name, d = min(pairs, key=lambda p: p[1])
    if d < rec["worst_distance"]:
        rec.update(worst_distance=d, worst_pair=name, worst_step=step)


def _record(config, **fields):
    rec = {"seed": config.seed, "scenario": config.scenario, "kind": config.kind, "h": config.h, "lower": "",
           "placement": "", "orientation": "", "status": "", "steps_planned": config.steps, "steps": 0,
           "retried": 0, "max_substeps": 0, "fail_step": -1, "fail_time": math.nan, "worst_distance": math.inf,
           "worst_pair": "", "worst_step": -1, "energy_excess": math.nan, "energy_excess_rel": math.nan,
           "energy_over": 0, "energy_net": math.nan, "energy_net_rel": math.nan, "free_gain_rel": math.nan,
           "it_median": math.nan,
           "it_max": 0, "ms_median": math.nan, "ms_max": math.nan, "wall_s": math.nan, "message": "",
           "iterations": [], "times": []}
    rec.update(fields)
    return rec


def failed(config, error) -> dict:
    """The record of a run that raised anything but StepFailure (a defect, reported)."""
    return _record(config, status="error", message=f"{type(error).__name__}: {error}")


# -- the campaign -------------------------------------------------------------------------------
def configs(runs, seed, scenarios=SCENARIOS, kinds=KINDS, budget=BUDGET):
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(runs):
        scenario = scenarios[int(rng.integers(len(scenarios)))]
        kind = kinds[int(rng.integers(len(kinds)))]
        out.append(Config(int(rng.integers(2 ** 32)), scenario, kind, loguniform(rng, *H_RANGE), budget))
    return out


def campaign(runs, seed=0, workers=2, scenarios=SCENARIOS, kinds=KINDS, budget=BUDGET, progress=None):
    """The records of `runs` seeded configurations, in their order; progress(record) as each ends."""
    todo = configs(runs, seed, scenarios, kinds, budget)
    done = {}
    for config, rec in executors.completed(run, todo, failed, max_workers=workers):
        done[config] = rec
        if progress is not None:
            progress(rec)
    return [done[c] for c in todo]


def clean(rec) -> bool:
    return (rec["status"] == "ok" and rec["retried"] == 0 and rec["energy_over"] == 0
            and rec["worst_distance"] >= -ic.StepperOptions().contact_tolerance)


def summary(records) -> dict:
    """The campaign's numbers (module docstring, Output); "table" counts per "kind scenario"."""
    tol = ic.StepperOptions().contact_tolerance
    groups = collections.defaultdict(list)
    for rec in records:
        groups[f"{rec['kind']} {rec['scenario']}"].append(rec)
    its = np.concatenate([np.asarray(r["iterations"], float) for r in records] + [np.zeros(0)])
    times = np.concatenate([np.asarray(r["times"], float) for r in records] + [np.zeros(0)])
    measured = [r for r in records if math.isfinite(r["energy_excess_rel"])]
    out = {
        "runs": len(records), "clean": sum(map(clean, records)),
        "status": dict(collections.Counter(r["status"] for r in records)),
        "runs_retried": sum(1 for r in records if r["retried"] > 0),
        "steps": int(len(its)), "steps_retried": sum(r["retried"] for r in records),
        "table": {key: _counts(rs, tol) for key, rs in sorted(groups.items())},
        "not_ok": {f"{status} {key}": {"runs": len(rs), "seeds": [_repro(r) for r in rs[:3]],
                                       "first": _short(rs[0]["message"])}
                   for key, group in sorted(groups.items()) for status in ("failure", "cut", "error")
                   for rs in [[r for r in group if r["status"] == status]] if rs},
        "tolerance": tol, "energy_tol": ENERGY_TOL,
        "worst_distance": min((r["worst_distance"] for r in records), default=math.nan),
        "runs_beyond_tolerance": sum(1 for r in records if r["worst_distance"] < -tol),
        "runs_energy_over": sum(1 for r in records if r["energy_over"] > 0),
        "runs_net_gain": sum(1 for r in measured if r["energy_net_rel"] > ENERGY_TOL),
    }
    if measured:
        worst = max(measured, key=lambda r: r["energy_excess_rel"])
        net = max(measured, key=lambda r: r["energy_net_rel"])
        free = max(measured, key=lambda r: r["free_gain_rel"])
        out.update(worst_energy_rel=worst["energy_excess_rel"], worst_energy_abs=worst["energy_excess"],
                   worst_energy_run=_repro(worst), worst_net_rel=net["energy_net_rel"], worst_net_run=_repro(net),
                   worst_free_gain_rel=free["free_gain_rel"], worst_free_gain_run=_repro(free),
                   runs_free_gain=sum(1 for r in measured if r["free_gain_rel"] > ENERGY_TOL))
    if len(its):
        out.update(it_median=float(np.median(its)), it_p99=float(np.percentile(its, 99)), it_max=float(its.max()))
    if len(times):
        out.update(ms_median=1e3 * float(np.median(times)), ms_p99=1e3 * float(np.percentile(times, 99)),
                   ms_max=1e3 * float(times.max()), p99_over_median=float(np.percentile(times, 99) / np.median(times)))
    return out


def _counts(records, tol):
    return {"runs": len(records), "clean": sum(map(clean, records)),
            "retried": sum(1 for r in records if r["retried"] > 0),
            **{status: sum(1 for r in records if r["status"] == status) for status in ("failure", "cut", "error")},
            "energy": sum(1 for r in records if r["energy_over"] > 0),
            "penetration": sum(1 for r in records if r["worst_distance"] < -tol)}


def _repro(rec):
    return Config(rec["seed"], rec["scenario"], rec["kind"], rec["h"]).repro


def _short(message, n=160):
    message = " ".join(str(message).split())
    return message if len(message) <= n else message[:n - 3] + "..."


def print_summary(s):
    print(f"\n{s['runs']} runs, {s['clean']} clean (all steps, none retried, no check violated); "
          f"status {s['status']}; {s['runs_retried']} runs with retried steps "
          f"({s['steps_retried']} of {s['steps']} steps)")
    columns = ("runs", "clean", "retried", "failure", "cut", "error", "energy", "penetration")
    print(f"  {'':16s}" + "".join(f"{c:>12s}" for c in columns))
    for key, row in s["table"].items():
        print(f"  {key:16s}" + "".join(f"{row[c]:12d}" for c in columns))
    for key, row in s["not_ok"].items():
        print(f"  {key:24s} {row['runs']:4d}, e.g. --repro {' / '.join(row['seeds'])}\n      {row['first']}")
    print(f"worst signed distance {s['worst_distance']:.3g} m; runs beyond the contact tolerance "
          f"{s['tolerance']:g} m: {s['runs_beyond_tolerance']}")
    if "worst_energy_rel" in s:
        print(f"energy over free flight: worst step {s['worst_energy_rel']:.3g} relative "
              f"({s['worst_energy_abs']:.3g} J, --repro {s['worst_energy_run']}); "
              f"runs with a step over {s['energy_tol']:g}: {s['runs_energy_over']}; "
              f"worst net over a run {s['worst_net_rel']:.3g} (--repro {s['worst_net_run']}), runs with a net gain "
              f"over {s['energy_tol']:g}: {s['runs_net_gain']}")
        print(f"free flight itself (the ghosts): worst gain of a step {s['worst_free_gain_rel']:.3g} relative "
              f"(--repro {s['worst_free_gain_run']}), runs with a step over {s['energy_tol']:g}: {s['runs_free_gain']}")
    if "it_median" in s:
        print(f"Newton iterations per step: median {s['it_median']:.0f}, p99 {s['it_p99']:.0f}, max {s['it_max']:.0f}")
    if "ms_median" in s:
        print(f"time per step: median {s['ms_median']:.3g} ms, p99 {s['ms_p99']:.3g} ms, max {s['ms_max']:.4g} ms, "
              f"p99/median {s['p99_over_median']:.3g}")


def write_csv(records, path):
    os.makedirs(os.path.dirname(path), exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_FIELDS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(records)


def _progress(total):
    count = [0]

    def show(rec):
        count[0] += 1
        if not clean(rec):
            print(f"[{count[0]}/{total}] {rec['status']:7s} {rec['kind']:8s} {rec['scenario']:5s} "
                  f"--repro {_repro(rec)}  "
                  f"steps {rec['steps']}/{rec['steps_planned']} retried {rec['retried']} "
                  f"d {rec['worst_distance']:.2g} dE {rec['energy_excess_rel']:.2g} {_short(rec['message'], 90)}",
                  flush=True)
    return show


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=1000)
    parser.add_argument("--quick", action="store_true", help="40 runs")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--workers", type=int, default=2, help="processes (0: this one)")
    parser.add_argument("--only", default=",".join(SCENARIOS), help="comma-separated scenarios")
    parser.add_argument("--kinds", default=",".join(KINDS), help="comma-separated body kinds")
    parser.add_argument("--budget", type=float, default=BUDGET, help="wall seconds per run")
    parser.add_argument("--repro", help="SEED,SCENARIO,KIND,H: one run in this process, its record printed")
    parser.add_argument("--order", type=int, choices=(1, 2), default=1, help="StepperOptions.order of the runs")
    args = parser.parse_args(argv)
    os.environ[ORDER_ENV] = str(args.order)
    if args.repro:
        seed, scenario, kind, h = args.repro.split(",")
        rec = run(Config(int(seed), scenario, kind, float(h), args.budget))
        for key in CSV_FIELDS:
            print(f"{key:18s} {rec[key]}")
        return
    scenarios, kinds = tuple(args.only.split(",")), tuple(args.kinds.split(","))
    unknown = set(scenarios) - set(SCENARIOS) | set(kinds) - set(KINDS)
    if unknown:
        parser.error(f"unknown scenarios or kinds {sorted(unknown)}; choose from {SCENARIOS} and {KINDS}")
    runs = 40 if args.quick else args.runs
    t0 = time.perf_counter()
    records = campaign(runs, args.seed, args.workers, scenarios, kinds, args.budget, _progress(runs))
    wall = time.perf_counter() - t0
    write_csv(records, os.path.join(OUT, "face_contact.csv"))
    print_summary(summary(records))
    print(f"campaign wall time {wall:.1f} s on {args.workers} workers "
          f"(run wall time: median {np.nanmedian([r['wall_s'] for r in records]):.2f} s, "
          f"max {np.nanmax([r['wall_s'] for r in records]):.1f} s); comparisons/out/face_contact.csv")


if __name__ == "__main__":
    main()
