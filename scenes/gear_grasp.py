"""Grasping Brost and Christiansen's lock piece with a parallel-jaw gripper ([GI] Sec. 6.4, Figs. 9-10).

What to look for: squeezed from the "sweet spot" (fingertip centre about 11 mm below the part's
centre) the jaws touch the round rim below the centre, the part slides up between them and comes to
rest held in the pockets of its outer-most teeth, jaws about 27.5 mm apart. Squeezed too high, the
jaws grip the rim nearly diametrically and the friction cone holds it there (a failure); squeezed too
low or far to the side, the part is pushed out or held by the wrong teeth.
Run: python -m scenes.gear_grasp [--x 0] [--y -11] [--mu-support 0.5] [--mu-gripper 0.5] [--plot]
The study over the 20 mm x 20 mm grid of starts is ``python -m comparisons.grasp``.

Geometry (the consistent reading of eqs 56-57, see paper/NOTES.md)
-------------------------------------------------------------------
Eq (56) prints the disc as ``(x - q1)^2 + (y - q2)^2 - 20.75 = 0`` (a radius of 4.56), while the
teeth of eq (57) are centred at ``r_i = 20.75 (cos theta_i, sin theta_i)`` and the text calls the part
"about 21 mm in diameter". The only reading in which the teeth sit on the rim is a disc of radius
R = 20.75 mm (the constant is 20.75^2; the part is then about 42 mm across, so "about 21 mm" is its
radius). Each tooth is an exponent-4 superellipse with semi-axes 2.3 mm along the radius and 1.1 mm
along the rim, centred on the rim at theta_i and turned with it (the paper's footnote: frame
transformations omitted; eq 57 as printed would lay every tooth along x). Neighbouring teeth are
0.149398 rad (3.1 mm of rim) apart and the two groups of three are mirror images about the part's
-y axis: teeth at +-17.75, +-26.31 and +-34.87 degrees from -y. Union part 0 is the disc, parts 1..6
the teeth theta_1..theta_6; tooth theta_1 (part 1) is the outer-most on the left (-x), theta_6
(part 6) the outer-most on the right.

Units: SI inside DART (metres, kg, N, s): R = 0.02075 m, so the stepper's default contact tolerance
1e-6 m is 5e-5 of the radius. Public inputs and outcomes of this module are in millimetres where
named ``*_mm``.

The 2.5D model (what dVC, Berard et al. 2007, call 2.5D)
---------------------------------------------------------
* The part moves in the plane (x, y, theta) on a PlanarJoint; gravity is along -z, out of the
  plane, so its weight M_PART g presses it on the support. Coulomb friction against the support is
  the stepper's ``set_support_friction`` (solved in the NCP with the contacts): three support points
  at 2/3 R from the centre, 120 degrees apart (at 90, 210 and 330 degrees), each carrying a third
  of the weight, as dVC's three support points.
* Each fingertip is its own single-body PlanarJoint skeleton (2D implicit shapes are refused on
  articulated skeletons). Its y and theta dofs are held at their start values by stiff, critically
  damped joint springs (K_HOLD_Y, K_HOLD_THETA), which the stepper treats implicitly as DART does
  (M + h D + h^2 K): this is dVC's "jaws force-controlled along x with y and orientation fixed"
  (measured hold error ~1e-9 m and ~3e-8 rad under the 1 N squeeze, below 1e-6 of the part's
  size; ``GraspOutcome.hold_error``).
  Its x dof is force controlled: a constant joint force F_GRIP towards the part, equal and opposite
  on the two jaws, against a joint damper D_X = F_GRIP / V_CLOSE, so a free jaw closes at
  V_CLOSE (the gripper's finite closing speed) and a stopped jaw squeezes with the full F_GRIP.
  The jaws start symmetric about the fingertip centre, just far enough apart (GAP_START beyond the
  part on the side that needs more) to clear the part, already closing at V_CLOSE: the same as a
  wider start, minus the free approach.
* Each fingertip is [GI]'s intersection of the two half-planes meeting at the vertex, eqs 58-61
  (top edge y <= y_tip, inside edge facing the part), closed by two far edges FINGER_WIDTH beyond
  the inside edge and FINGER_LENGTH below the tip, which the part never reaches. A bounded body is
  needed: the stepper grows a body's broadphase box by its speed times its size, which is infinite
  for an unbounded quadrant. The finger's origin is its vertex, so its q = (x_tip, y_tip, 0).

Closing stops and success (the test ``classify`` applies)
----------------------------------------------------------
Closing has stopped when both jaw speeds and the part's speed (|v| and |omega| R) stay below
V_STOP for STILL_STEPS consecutive steps (one: under constant forces a state the step leaves at
rest is a static equilibrium of the step, friction inside its cones, so it stays). Then the trial is a success iff, at the last step,
  (1) each jaw presses on the part with a total normal force of at least HOLD_FRACTION F_GRIP (the
      part is held, not merely touched), and
  (2) the right jaw touches the part's outer-most right tooth (theta_6, union part 6) and the left
      jaw the outer-most left tooth (theta_1, part 1) with a positive normal force, at a contact
      point on that tooth's boundary (|f_tooth| <= ID_TOL) and on its outer flank (the side away
      from the other teeth: tooth-frame coordinate along the rim > 0 for theta_6, < 0 for theta_1).
Everything else is a failure, with its reason: "held elsewhere" (stopped and held, not by the outer
teeth: e.g. gripped on the rim), "not held", "ejected" (the jaws closed past the part: separation
below SEPARATION_MIN), "not stopped" (T_MAX reached), or "step failure" (the stepper raised
StepFailure after its retries; the message is kept).

seed: the [GI]/Brost histogram counts trials "with initial conditions in that patch", so with a seed
the fingertip centre is drawn uniformly in the 1 mm x 1 mm patch centred on (x_mm, y_mm); without a
seed it is exactly (x_mm, y_mm).
"""
from __future__ import annotations

import argparse
from dataclasses import dataclass, field
import functools
import math
import time

import dartpy as dart
import numpy as np

import implicit_contact as ic
from implicit_contact import shapes as shp

# 1. Parameters (SI units)
R = 0.02075                               # [m] disc radius, eq (56) read as 20.75^2 (see above)
TOOTH_SEMI_AXES = (0.0023, 0.0011)        # [m] along the radius, along the rim, eq (57)
TOOTH_EXPONENT = 4.0
THETAS = (4.103727, 4.253125, 4.402522, 5.022255, 5.171653, 5.321051)   # [rad] eq (57)
LEFT_OUTER, RIGHT_OUTER = 1, 6            # union part indices of the outer-most teeth
M_PART = 0.030                            # [kg] a ~42 mm steel piece about 3 mm thick
I_PART = 0.5 * M_PART * R**2              # [kg m^2] the disc's (teeth neglected)
G = 9.81                                  # [m/s^2] along -z: the weight presses on the support
SUPPORT_POINTS = tuple((2.0 / 3.0 * R * math.cos(a), 2.0 / 3.0 * R * math.sin(a))
                       for a in np.radians((90.0, 210.0, 330.0)))          # [m] body frame
M_FINGER, I_FINGER = 0.010, 1e-6          # [kg], [kg m^2] each fingertip body
F_GRIP = 1.0                              # [N] squeeze force on each jaw (~3.4 M_PART g)
V_CLOSE = 0.05                            # [m/s] free closing speed of each jaw
D_X = F_GRIP / V_CLOSE                    # [N s/m] jaw damper giving that speed
K_HOLD_Y = 1e8                            # [N/m] y hold: 1 N moves a jaw 1e-8 m (5e-7 R)
K_HOLD_THETA = 1e5                        # [N m/rad] orientation hold
D_HOLD_Y = 2.0 * math.sqrt(K_HOLD_Y * M_FINGER)             # critical damping
D_HOLD_THETA = 2.0 * math.sqrt(K_HOLD_THETA * I_FINGER)
FINGER_WIDTH, FINGER_LENGTH = 0.025, 0.040  # [m] far edges of the bounded fingertip
GAP_START = 5e-4                          # [m] clearance of the first jaw at the start
H = 2e-3                                  # [s] time step (see comparisons/grasp.py on h = 1e-3)
V_STOP = 1e-3                             # [m/s] "closing stopped" below this speed ...
STILL_STEPS = 1                           # ... for this many consecutive steps (see above)
T_EXTRA = 0.6                             # [s] T_MAX = free-closing time of the start opening + this
SEPARATION_MIN = 0.010                    # [m] jaws closer than this have no part between them
HOLD_FRACTION = 0.5                       # of F_GRIP, per jaw, for "held"
ID_TOL = 1e-5                             # [m] a contact point this close to a part's surface is on it
PATCH = 1.0                               # [mm] side of the patch a seeded start is drawn from


# 2. Geometry
def tooth(i: int) -> shp.Superellipse:
    """Tooth i (0..5) of eq (57): centred on the rim at THETAS[i], long axis along the radius."""
    th = THETAS[i]
    return shp.Superellipse(TOOTH_SEMI_AXES, TOOTH_EXPONENT, center=(R * math.cos(th), R * math.sin(th)),
                            rotation=th)


@functools.lru_cache(maxsize=1)
def lock_piece() -> shp.Union:
    """The part: disc (part 0) and the six teeth (parts 1..6), body frame at the disc centre."""
    return shp.Union([shp.Disc(R)] + [tooth(i) for i in range(6)])


@functools.lru_cache(maxsize=2)
def fingertip(side: str) -> shp.Intersection:
    """A jaw's fingertip in its body frame, origin at the vertex: eqs 58-61's top edge y <= 0 and
    inside edge (x >= 0 on the right jaw, x <= 0 on the left), then the two far edges."""
    s = _sign(side)
    return shp.Intersection([shp.HalfPlane((0.0, 1.0), 0.0), shp.HalfPlane((-s, 0.0), 0.0),
                             shp.HalfPlane((s, 0.0), FINGER_WIDTH), shp.HalfPlane((0.0, -1.0), FINGER_LENGTH)])


def _sign(side: str) -> float:
    if side not in ("right", "left"):
        raise ValueError(f"side must be 'right' or 'left', got {side!r}")
    return 1.0 if side == "right" else -1.0


@functools.lru_cache(maxsize=1)
def _outline(samples: int = 4000) -> np.ndarray:
    """Boundary points of every union part, body frame [m] (points inside other parts included:
    only extents are taken from them)."""
    t = np.linspace(0.0, 2.0 * np.pi, samples, endpoint=False)
    c, s = np.cos(t), np.sin(t)
    pts = [R * np.c_[c, s]]
    a, b = TOOTH_SEMI_AXES
    p = 2.0 / TOOTH_EXPONENT
    local = np.c_[a * np.sign(c) * np.abs(c) ** p, b * np.sign(s) * np.abs(s) ** p]
    for i in range(6):
        th = THETAS[i]
        rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
        pts.append(local @ rot.T + R * np.array([math.cos(th), math.sin(th)]))
    return np.vstack(pts)


def extent_below(y: float) -> tuple[float, float]:
    """(min x, max x) [m] of the part (at the origin, unrotated) over its points with y' <= y."""
    P = _outline()
    P = P[P[:, 1] <= y]
    if len(P) == 0:
        return 0.0, 0.0
    return float(P[:, 0].min()), float(P[:, 0].max())


def start_opening(x_tip: float, y_tip: float) -> float:
    """Half the jaw separation at the start [m]: the jaw that must travel less clears the part by
    GAP_START (symmetric jaws about x_tip)."""
    lo, hi = extent_below(y_tip)
    return max(hi - x_tip, x_tip - lo, 0.0) + GAP_START


# 3. Build the DART world
def build_world(x_tip: float, y_tip: float, h: float = H):
    """The part at the origin and two jaws with vertices at (x_tip -+ opening, y_tip) [m].

    Returns (world, part_skeleton, {"right": skeleton, "left": skeleton})."""
    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity([0.0, 0.0, -G])       # out of the plane: loads the support only

    part = dart.dynamics.Skeleton("lock_piece")
    joint, body = part.createPlanarJointAndBodyNodePair()
    joint.setXYPlane()
    body.setName("lock_piece")
    body.setMass(M_PART)
    body.setMomentOfInertia(I_PART / 2, I_PART / 2, I_PART)
    ic.attach(body, lock_piece())
    world.addSkeleton(part)

    d = start_opening(x_tip, y_tip)
    jaws = {}
    for side in ("right", "left"):
        s = _sign(side)
        sk = dart.dynamics.Skeleton(side + "_jaw")
        jj, bj = sk.createPlanarJointAndBodyNodePair()
        jj.setXYPlane()
        bj.setName(side + "_jaw")
        bj.setMass(M_FINGER)
        bj.setMomentOfInertia(I_FINGER, I_FINGER, I_FINGER)
        ic.attach(bj, fingertip(side))
        q0 = np.array([x_tip + s * d, y_tip, 0.0])
        for i, (k, c) in enumerate(((0.0, D_X), (K_HOLD_Y, D_HOLD_Y), (K_HOLD_THETA, D_HOLD_THETA))):
            jj.setSpringStiffness(i, k)
            jj.setDampingCoefficient(i, c)
            jj.setRestPosition(i, q0[i])
        sk.setPositions(q0)
        sk.setVelocities([-s * V_CLOSE, 0.0, 0.0])
        world.addSkeleton(sk)
        jaws[side] = sk
    return world, part, jaws


def make_stepper(world, part, jaws, mu_support: float, mu_gripper: float):
    """The implicit stepper with gripper friction on both jaw/part pairs and support friction."""
    stepper = ic.ImplicitContactStepper(world, on_failure="retry")
    node = part.getBodyNode(0)
    for sk in jaws.values():
        stepper.set_pair_friction(sk.getBodyNode(0), node, ic.Friction(mu=mu_gripper))
    stepper.set_support_friction(node, mu_support, M_PART * G, SUPPORT_POINTS)
    return stepper


def squeeze(jaws) -> None:
    """The force control: F_GRIP on each jaw towards the part (DART clears forces every step)."""
    for side, sk in jaws.items():
        sk.setForces([-_sign(side) * F_GRIP, 0.0, 0.0])


# 4. One trial and its success test
@dataclass(frozen=True)
class JawContact:
    """A jaw/part contact at the end: union parts whose surface holds the point (0 disc, 1..6 the
    teeth), the point in the part frame [mm], the normal force [N], and for the jaw's outer tooth
    the point's coordinate along that tooth's rim axis [mm] (NaN if not on it)."""
    parts: tuple
    point_mm: tuple
    force: float
    outer_flank_mm: float


@dataclass(frozen=True)
class GraspOutcome:
    """One grasp trial. Positions in mm relative to the part's start (its centre at the origin).

    x_mm, y_mm: the requested fingertip centre; x0_mm, y0_mm: the one used (seeded patch draw).
    success / reason: the test of the module docstring ("held by the outer teeth" on success).
    part_mm_rad: the part's final (x, y, theta); jaws_mm: final vertex x of the right and left jaw;
    separation_mm: their distance; contacts: {"right": (JawContact, ...), "left": (...)};
    time_s / steps: simulated time and steps; wall_s: wall time of the trial;
    hold_error: the largest |y - y0| [m] and |theta| [rad] of the jaws over the trial;
    step_failure: the stepper raised (message in reason)."""
    x_mm: float
    y_mm: float
    x0_mm: float
    y0_mm: float
    mu_support: float
    mu_gripper: float
    success: bool
    reason: str
    part_mm_rad: tuple
    jaws_mm: tuple
    separation_mm: float
    contacts: dict
    time_s: float
    steps: int
    wall_s: float
    hold_error: tuple
    step_failure: bool = False


def simulate_grasp(x_mm: float, y_mm: float, mu_support: float, mu_gripper: float, seed=None,
                   h: float = H) -> GraspOutcome:
    """Close the jaws from fingertip centre (x_mm, y_mm) [mm] until closing stops; classify."""
    for name, v in (("x_mm", x_mm), ("y_mm", y_mm), ("mu_support", mu_support), ("mu_gripper", mu_gripper)):
        if not math.isfinite(v):
            raise ValueError(f"{name} must be finite, got {v!r}")
    if mu_support < 0 or mu_gripper < 0:
        raise ValueError(f"friction coefficients must be >= 0, got {mu_support}, {mu_gripper}")
    x0, y0 = float(x_mm), float(y_mm)
    if seed is not None:
        jitter = np.random.default_rng(seed).uniform(-0.5 * PATCH, 0.5 * PATCH, 2)
        x0, y0 = x0 + float(jitter[0]), y0 + float(jitter[1])
    wall0 = time.perf_counter()
    world, part, jaws = build_world(1e-3 * x0, 1e-3 * y0, h)
    stepper = make_stepper(world, part, jaws, mu_support, mu_gripper)
    t_max = start_opening(1e-3 * x0, 1e-3 * y0) / V_CLOSE + T_EXTRA
    still, steps, report, reason = 0, 0, None, ""
    hold_y = hold_th = 0.0
    failed = False
    while True:
        squeeze(jaws)
        try:
            report = stepper.step()
        except ic.StepFailure as error:
            reason, failed = f"step failure: {error}", True
            break
        steps += 1
        qr, ql = jaws["right"].getPositions(), jaws["left"].getPositions()
        hold_y = max(hold_y, abs(qr[1] - 1e-3 * y0), abs(ql[1] - 1e-3 * y0))
        hold_th = max(hold_th, abs(qr[2]), abs(ql[2]))
        vr, vl = jaws["right"].getVelocities()[0], jaws["left"].getVelocities()[0]
        vp = part.getVelocities()
        speed = max(abs(vr), abs(vl), math.hypot(vp[0], vp[1]), abs(vp[2]) * R)
        still = still + 1 if speed < V_STOP else 0
        if qr[0] - ql[0] < SEPARATION_MIN:
            reason = "ejected"
            break
        if still >= STILL_STEPS:
            break
        if world.getTime() >= t_max:
            reason = "not stopped"
            break
    contacts = jaw_contacts(part, report, h) if report is not None and not failed else {"right": (), "left": ()}
    success = False
    if not reason:
        success, reason = classify(contacts)
    qp = part.getPositions()
    qr, ql = jaws["right"].getPositions(), jaws["left"].getPositions()
    return GraspOutcome(float(x_mm), float(y_mm), x0, y0, float(mu_support), float(mu_gripper), success, reason,
                        (1e3 * qp[0], 1e3 * qp[1], float(qp[2])), (1e3 * qr[0], 1e3 * ql[0]),
                        1e3 * (qr[0] - ql[0]), contacts, world.getTime(), steps,
                        time.perf_counter() - wall0, (hold_y, hold_th), failed)


def jaw_contacts(part, report, h: float) -> dict:
    """The jaw/part contacts of the last step with p_n > 0, per jaw, as JawContact records.
    A retried step reports the contacts of its last substep, whose impulses span h / substeps."""
    h_last = h / max(int(getattr(report, "substeps", 1)), 1)
    qp = part.getPositions()
    c, s = math.cos(qp[2]), math.sin(qp[2])
    rot = np.array([[c, -s], [s, c]])
    pieces = lock_piece().parts
    out = {"right": [], "left": []}
    for con in report.contacts:
        names = (con.name_a, con.name_b)
        if con.p_n <= 0.0 or not any("lock_piece" in n for n in names):
            continue
        side = "right" if any("right_jaw" in n for n in names) else "left" if any("left_jaw" in n for n in names) else None
        if side is None:
            continue
        a = np.asarray(con.a1 if "lock_piece" in con.name_a else con.a2, float)[:2]
        p = rot.T @ (a - qp[:2])
        on = tuple(k for k, piece in enumerate(pieces) if abs(float(piece.value(p))) <= ID_TOL)
        outer = RIGHT_OUTER if side == "right" else LEFT_OUTER
        flank = math.nan
        if outer in on:
            th = THETAS[outer - 1]
            flank = 1e3 * float((p - R * np.array([math.cos(th), math.sin(th)])) @ (-math.sin(th), math.cos(th)))
        out[side].append(JawContact(on, (1e3 * p[0], 1e3 * p[1]), con.p_n / h_last, flank))
    return {k: tuple(v) for k, v in out.items()}


def classify(contacts: dict) -> tuple[bool, str]:
    """The success test (module docstring) on the stopped state's jaw contacts."""
    for side in ("right", "left"):
        if sum(jc.force for jc in contacts[side]) < HOLD_FRACTION * F_GRIP:
            return False, "not held"
    for side, outer, sign in (("right", RIGHT_OUTER, 1.0), ("left", LEFT_OUTER, -1.0)):
        if not any(outer in jc.parts and jc.force > 0.0 and sign * jc.outer_flank_mm > 0.0
                   for jc in contacts[side]):
            touched = sorted({k for jc in contacts[side] for k in jc.parts})
            return False, f"held elsewhere ({side} jaw on parts {touched})"
    return True, "held by the outer teeth"


# 5. Run one trial, print what happened
def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--x", type=float, default=0.0, help="fingertip centre x [mm]")
    ap.add_argument("--y", type=float, default=-11.0, help="fingertip centre y [mm]")
    ap.add_argument("--mu-support", type=float, default=0.5)
    ap.add_argument("--mu-gripper", type=float, default=0.5)
    ap.add_argument("--h", type=float, default=H)
    ap.add_argument("--plot", action="store_true", help="write scenes/out/gear_grasp.png (final state)")
    args = ap.parse_args(argv)
    out = simulate_grasp(args.x, args.y, args.mu_support, args.mu_gripper, h=args.h)
    print(f"grasp from ({out.x0_mm:g}, {out.y0_mm:g}) mm, mu_support {out.mu_support:g}, "
          f"mu_gripper {out.mu_gripper:g}: {'SUCCESS' if out.success else 'failure'} ({out.reason})")
    px, py, pth = out.part_mm_rad
    print(f"  part moved to ({px:.2f}, {py:.2f}) mm, turned {math.degrees(pth):.2f} deg; jaws at "
          f"{out.jaws_mm[0]:.2f} / {out.jaws_mm[1]:.2f} mm, separation {out.separation_mm:.2f} mm "
          "(outer-teeth grasp: ~27.5)")
    for side in ("right", "left"):
        for jc in out.contacts[side]:
            print(f"  {side:5s} jaw on parts {list(jc.parts)} at ({jc.point_mm[0]:.2f}, {jc.point_mm[1]:.2f}) mm, "
                  f"{jc.force:.3f} N")
    print(f"  {out.steps} steps, {out.time_s:.3f} s simulated, {out.wall_s:.2f} s wall; jaw hold error "
          f"{out.hold_error[0]:.1e} m, {out.hold_error[1]:.1e} rad")
    if args.plot:
        plot_outcome(out, "scenes/out/gear_grasp.png")


def plot_outcome(out: GraspOutcome, path: str) -> None:
    """The final state: part outline (its frame moved to its final pose) and the two fingertips."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    px, py, th = out.part_mm_rad
    rot = np.array([[math.cos(th), -math.sin(th)], [math.sin(th), math.cos(th)]])
    P = 1e3 * _outline() @ rot.T + (px, py)
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.plot(P[:, 0], P[:, 1], ",", color="0.3")
    for x, s in zip(out.jaws_mm, (1.0, -1.0)):
        w, l = 1e3 * FINGER_WIDTH, 1e3 * FINGER_LENGTH
        ax.add_patch(plt.Rectangle((x if s > 0 else x - w, out.y0_mm - l), w, l, alpha=0.4, color="C0"))
    ax.set_xlim(-40, 40), ax.set_ylim(-40, 30), ax.set_aspect("equal")
    ax.set_xlabel("x [mm]"), ax.set_ylabel("y [mm]")
    ax.set_title(f"start ({out.x0_mm:g}, {out.y0_mm:g}) mm: {out.reason}")
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


if __name__ == "__main__":
    main()
