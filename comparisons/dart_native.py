"""DART's own stepper on the rolling-disc scene, and the exact rolling N-gon it should approach.

[GI] Sec. 1 (Fig. 1) and Sec. 6.1: a unit disc (m = 1, I_c = 0.5, q = [0, 1, 0], v = [-3, 0, 3],
mu = 0.4) rolls on the ground and keeps KE = 6.75 J forever; a polygonal disc in a geometrically
explicit time-stepper loses energy. This module builds that scene for DART's native stepper
(collision detector + boxed LCP) and provides the exact reference line of a rolling polygon.

DART scene (what `build_ngon_world` builds)
------------------------------------------
* The disc is a regular N-gon prism (circumradius r, thickness along z, one vertex pointing down,
  -y, at zero rotation) loaded as a MeshShape: no dartpy call builds a MeshShape from vertices, so
  the prism is written as an OBJ (`ngon_prism_mesh_path`) and loaded through a one-link URDF with
  `dart.utils.DartLoader().parseSkeletonString`. Caps are fans from vertex 0 (2N vertices, no cap
  centre); ODE's contact set depends on the triangulation and this one reproduces the measured
  reference table (`/work/shared/reference/dart_native.md`).
* PlanarJoint in the XY plane (dofs [x, y, theta]), gravity -9.81 along y, mass 1 and Izz = 0.5
  set by hand (the MeshShape's volume is its bounding box's, so DART's own mass properties are
  wrong for it), Ixx = Iyy = m (3 r^2 + t^2) / 12 (a solid disc; irrelevant in the plane).
* Collision and dynamics aspects on both shapes, friction mu on each (a pair uses the smaller),
  restitution 0; sleeping (deactivation, on by default in dartpy 6.20) switched off.
* Ground: a WeldJoint box, top face y = 0, size GROUND_SIZE. Its depth along z (10 m) matters:
  DART's own detector lets the prism sink through a ground only 1-2 m deep in z (measured: KE
  loss 75-85 %, disc centre below y = 0), and gives the reference numbers with 10 m.

Exact rolling N-gon (`exact_ngon_rolling`, `exact_ngon_kinetic_energy`)
----------------------------------------------------------------------
A rigid regular polygon (circumradius r, central angle alpha = 2 pi / N, half-angle
beta = pi / N, mass m, central inertia I_c, I_P = I_c + m r^2 about a vertex) rolls to the left
(omega > 0) without slip and without bouncing. Between impacts it pivots on its lowest vertex P.
Let phi be the angle of the segment P -> centre from the upward vertical (c - P = r (-sin phi,
cos phi)); a pivot runs from phi = -beta to +beta. Angular momentum about P gives an inverted
pendulum

    I_P phi'' = m g r sin phi,   so   phi'^2 = w_s^2 + 2 k^2 (cos beta - cos phi),  k^2 = m g r / I_P,

where w_s is the speed at phi = -beta. The pivot ends at +beta with the same speed (cos is even),
and its duration is T(w_s) = int_{-beta}^{beta} dphi / phi'(phi) (Gauss-Legendre, checked against
half the nodes). The kinetic energy is rotation about P: KE = I_P phi'^2 / 2.
At phi = +beta the next vertex Q lands. A perfectly inelastic impact without slip conserves the
angular momentum about Q, H_Q = I_c w + m (c - Q) x v_c, which gives the per-impact ratio

    w+ = lambda w-,   lambda = (I_c + m r^2 cos alpha) / (I_c + m r^2),

so the k-th full pivot starts at w_s,k = lambda^k w_e,0 (w_e,0 the speed at the end of the first,
partial pivot) and KE drops by lambda^2 at every impact.
Conditions for this to be the motion (checked, reported in `NgonRolling.required_mu`):
  * no slip and no lift-off while pivoting: the ground force F = m c'' + m g e_y has
    F_n = m g - m r (sin phi phi'' + cos phi phi'^2) > 0 and |F_t| <= mu F_n with
    F_t = m r (sin phi phi'^2 - cos phi phi''); worst at phi = +-beta of the fastest pivot;
  * no slip at the impact: the impulse m (v+ - v-) has |P_t| / P_n = (1 - lambda) / (1 + lambda)
    cot beta <= mu;
  * the polygon gets over each vertex: phi'^2 > 0 at phi = 0, i.e. w_s^2 > 2 k^2 (1 - cos beta);
    otherwise it rocks back and the rolling reference ends.
For the paper's disc (r = 1, m = 1, I_c = 0.5, omega = 3, g = 9.81) r omega^2 = 9 is close to
g = 9.81: a 10-gon needs |F_t| / F_n of about 66 at the end of its first pivot (F_n nearly 0, it
is about to hop), so its reference is not applicable with mu = 0.4 (the table's "n/a"); a 100-gon
needs about 0.1, a 1000-gon about 0.01.
Initial condition: the paper's state q = [0, 1, 0], v = [-3, 0, 3] is EXACTLY a pivot about the
lowest vertex (phi = 0, centre r above it, v_c = omega x (c - P) = [-3, 0]), so no mapping is
needed: omega and KE0 = 6.75 J are both kept. A state that is not a pure pivot about the lowest
vertex (vertex off the ground, or v_c != omega x (c - P)) is refused with a ValueError rather than
mapped, since any mapping (equal KE or equal omega) would change the other.
Exact values (this module): 100-gon KE loss 11.39 % at 1 s, 42.15 % at 5 s; 1000-gon 1.245 % /
6.000 %; 10000-gon 0.1255 % / 0.6254 %.
"""
from __future__ import annotations

from dataclasses import dataclass
import math
import os
import tempfile

import dartpy as dart
import numpy as np
from numpy.polynomial.legendre import leggauss

GRAVITY = 9.81  # [m/s^2], along -y
GROUND_SIZE = (1000.0, 1.0, 10.0)  # [m] x (rolling room), y (top face at 0), z (see docstring)
DETECTORS = ("fcl", "dart", "bullet", "ode")
PRIMITIVE_SHAPES = ("cylinder", "sphere", "ellipsoid", "flat_ellipsoid")
PAPER_Q0 = (0.0, 1.0, 0.0)  # [m, m, rad]
PAPER_V0 = (-3.0, 0.0, 3.0)  # [m/s, m/s, rad/s]

# Gauss-Legendre nodes for a pivot's duration; the same integral with half the nodes must agree
# to QUADRATURE_RTOL, else the pivot is too close to stopping on a vertex to be trusted.
_QUADRATURE_NODES = 48
_QUADRATURE_RTOL = 1e-11
_FORCE_SAMPLES = 33  # phi samples per pivot for the no-slip / no-lift-off check (ends included)
_PHI_TOL = 1e-13  # Newton stop for the pivot angle, relative to beta (rounding floor ~1e-16)
_STATE_TOL = 1e-9  # relative tolerance of "the initial state is a pure pivot" checks


# ----------------------------------------------------------------------------------------------
# geometry and worlds
# ----------------------------------------------------------------------------------------------
def ngon_prism_mesh_path(n: int, circumradius: float = 1.0, thickness: float = 0.2, cache_dir=None) -> str:
    """Path of an OBJ of a regular n-gon prism (axis z, vertex k at angle -pi/2 + 2 pi k / n).

    2n vertices (bottom ring z = -t/2, then top ring z = +t/2), outward-wound triangles: caps as
    fans from vertex 0, sides as two triangles per edge. Written once per (n, r, t) into cache_dir
    (default: <system temp>/implicit_contact_meshes), atomically, so parallel runs can share it.
    """
    n = _integer_at_least(n, 3, "n (the number of polygon vertices)")
    circumradius = _positive(circumradius, "circumradius")
    thickness = _positive(thickness, "thickness")
    cache_dir = os.path.join(tempfile.gettempdir(), "implicit_contact_meshes") if cache_dir is None else str(cache_dir)
    os.makedirs(cache_dir, exist_ok=True)
    path = os.path.join(cache_dir, f"ngon_{n}_r{circumradius!r}_t{thickness!r}.obj")
    if os.path.exists(path):
        return path
    angles = -0.5 * math.pi + 2.0 * math.pi * np.arange(n) / n
    x, y = circumradius * np.cos(angles), circumradius * np.sin(angles)
    lines = [f"# regular {n}-gon prism, circumradius {circumradius!r}, thickness {thickness!r}"]
    for z in (-0.5 * thickness, 0.5 * thickness):
        lines += [f"v {xi:.17g} {yi:.17g} {z:.17g}" for xi, yi in zip(x, y)]
    bottom = np.arange(1, n + 1)  # OBJ indices are 1-based
    top = bottom + n
    for k in range(1, n - 1):
        lines.append(f"f {bottom[0]} {bottom[k + 1]} {bottom[k]}")  # normal -z
        lines.append(f"f {top[0]} {top[k]} {top[k + 1]}")  # normal +z
    for k in range(n):
        a, b = k, (k + 1) % n
        lines.append(f"f {bottom[a]} {bottom[b]} {top[b]}")
        lines.append(f"f {bottom[a]} {top[b]} {top[a]}")
    partial = f"{path}.{os.getpid()}.partial"
    with open(partial, "w") as handle:
        handle.write("\n".join(lines) + "\n")
    os.replace(partial, path)
    return path


def build_ngon_world(
    n: int,
    h: float = 0.01,
    detector: str = "fcl",
    mu: float = 0.4,
    q0=PAPER_Q0,
    v0=PAPER_V0,
    circumradius: float = 1.0,
    thickness: float = 0.2,
    cache_dir=None,
):
    """The [GI] Fig. 1 scene in DART: an n-gon prism disc on a PlanarJoint on a box ground.

    Returns (world, disc_skeleton). Mass 1, Izz 0.5 (see the module docstring), friction mu on
    both shapes, restitution 0, sleeping off, detector in DETECTORS, time step h [s].
    """
    mesh = _load_mesh_shape(ngon_prism_mesh_path(n, circumradius, thickness, cache_dir))
    inertia = _disc_inertia(radius=circumradius, thickness=thickness)
    return _planar_disc_world(mesh, inertia, h, detector, mu, q0, v0)


def build_primitive_disc_world(
    shape: str = "cylinder",
    h: float = 0.01,
    detector: str = "fcl",
    mu: float = 0.4,
    q0=PAPER_Q0,
    v0=PAPER_V0,
    radius: float = 1.0,
    thickness: float = 0.2,
):
    """The same scene with a DART primitive disc: shape in PRIMITIVE_SHAPES.

    cylinder: CylinderShape(radius, thickness), axis z; sphere: SphereShape(radius);
    ellipsoid: EllipsoidShape with three equal radii (DART's detector treats it as a sphere);
    flat_ellipsoid: radii (radius, radius, thickness / 2). Mass 1 and Izz 0.5 as for the prism.
    """
    if shape not in PRIMITIVE_SHAPES:
        raise ValueError(f"shape must be one of {PRIMITIVE_SHAPES}, got {shape!r}")
    radius = _positive(radius, "radius")
    thickness = _positive(thickness, "thickness")
    if shape == "cylinder":
        dart_shape = dart.dynamics.CylinderShape(radius, thickness)
    elif shape == "sphere":
        dart_shape = dart.dynamics.SphereShape(radius)
    elif shape == "ellipsoid":
        dart_shape = dart.dynamics.EllipsoidShape(np.full(3, 2.0 * radius))  # takes diameters
    else:
        dart_shape = dart.dynamics.EllipsoidShape(np.array([2.0 * radius, 2.0 * radius, thickness]))
    return _planar_disc_world(dart_shape, _disc_inertia(radius, thickness), h, detector, mu, q0, v0)


def make_detector(name: str):
    """A fresh DART collision detector by name (one of DETECTORS)."""
    factories = {
        "fcl": dart.collision.FCLCollisionDetector,
        "dart": dart.collision.DARTCollisionDetector,
        "bullet": dart.collision.BulletCollisionDetector,
        "ode": dart.collision.OdeCollisionDetector,
    }
    if name not in factories:
        raise ValueError(f"detector must be one of {DETECTORS}, got {name!r}")
    return factories[name]()


def _planar_disc_world(shape, inertia: np.ndarray, h, detector, mu, q0, v0):
    h = _positive(h, "time step h")
    mu = _non_negative(mu, "mu")
    q0 = _vector3(q0, "q0")
    v0 = _vector3(v0, "v0")
    collision_detector = make_detector(detector)
    world = dart.simulation.World()
    world.setGravity([0.0, -GRAVITY, 0.0])
    world.setTimeStep(h)
    deactivation = world.getDeactivationOptions()
    deactivation.mEnabled = False  # a slowly rolling polygon must never be put to sleep
    world.setDeactivationOptions(deactivation)

    disc = dart.dynamics.Skeleton("disc")
    joint, body = disc.createPlanarJointAndBodyNodePair(None)
    joint.setXYPlane()
    _add_contact_shape(body, shape, mu)
    body.setInertia(dart.dynamics.Inertia(1.0, np.zeros(3), inertia))

    ground = dart.dynamics.Skeleton("ground")
    _, ground_body = ground.createWeldJointAndBodyNodePair(None)
    ground_node = _add_contact_shape(ground_body, dart.dynamics.BoxShape(np.array(GROUND_SIZE)), mu)
    placement = dart.math.Isometry3()
    placement.set_translation([0.0, -0.5 * GROUND_SIZE[1], 0.0])
    ground_node.setRelativeTransform(placement)

    world.addSkeleton(disc)
    world.addSkeleton(ground)
    world.setCollisionDetector(collision_detector)
    disc.setPositions(q0)
    disc.setVelocities(v0)
    return world, disc


def _add_contact_shape(body, shape, mu: float):
    node = body.createShapeNode(shape)
    node.createVisualAspect()
    node.createCollisionAspect()  # without it DART's detector ignores the shape
    dynamics = node.createDynamicsAspect()
    dynamics.setFrictionCoeff(mu)
    dynamics.setRestitutionCoeff(0.0)
    return node


def _disc_inertia(radius: float, thickness: float) -> np.ndarray:
    """Izz = 0.5 (the paper's disc, m = 1, r = 1); Ixx = Iyy of a solid disc of mass 1."""
    transverse = (3.0 * radius**2 + thickness**2) / 12.0
    return np.diag([transverse, transverse, 0.5])


def _load_mesh_shape(path: str):
    urdf = (
        '<robot name="ngon_loader"><link name="ngon"><collision><geometry>'
        f'<mesh filename="file://{path}"/></geometry></collision></link></robot>'
    )
    loaded = dart.utils.DartLoader().parseSkeletonString(urdf, dart.common.Uri(f"file://{os.path.dirname(path)}/"))
    if loaded is None or loaded.getNumBodyNodes() != 1 or loaded.getBodyNode(0).getNumShapeNodes() != 1:
        raise ValueError(f"DART could not load the mesh {path} through its URDF loader")
    return loaded.getBodyNode(0).getShapeNode(0).getShape()


# ----------------------------------------------------------------------------------------------
# energies
# ----------------------------------------------------------------------------------------------
def kinetic_energy(skel) -> float:
    """0.5 v^T M(q) v [J] of one skeleton."""
    v = np.asarray(skel.getVelocities(), dtype=float)
    return 0.5 * float(v @ np.asarray(skel.getMassMatrix(), dtype=float) @ v)


def mechanical_energy(skel, g: float = GRAVITY, reference_height: float = 0.0) -> float:
    """Kinetic plus gravitational energy m g (y_com - reference_height) [J], gravity g along -y.

    A relative loss depends on the zero of the potential: reference/dart_native.md's "Emech loss %"
    measures it from the initial height (so it divides the loss by KE0 = 6.75 J).
    """
    height = float(np.asarray(skel.getCOM())[1]) - reference_height
    return kinetic_energy(skel) + float(skel.getMass()) * g * height


# ----------------------------------------------------------------------------------------------
# the exact rolling polygon
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NgonRolling:
    """Event record of an exactly rolling polygon up to t_end (see the module docstring).

    impact_times [s]: vertex impacts in (0, t_end]; omega_start [rad/s]: the speed at the start of
    each pivot (entry 0: the initial omega at phi0); pivot_starts [s]: start time of each pivot.
    required_mu: the smallest friction coefficient that keeps every pivot and impact up to t_end
    (the pivot in progress at t_end included) from slipping, inf if the polygon would lift off.
    applicable: required_mu <= mu and no rock-back before t_end; reason: one sentence when not.
    lam: the per-impact ratio of omega; inertia_pivot = I_c + m r^2; k2 = m g r / inertia_pivot.
    """

    n: int
    mu: float
    t_end: float
    lam: float
    phi0: float
    pivot_starts: np.ndarray
    omega_start: np.ndarray
    impact_times: np.ndarray
    required_mu: float
    applicable: bool
    reason: str
    inertia_pivot: float
    k2: float


def exact_ngon_rolling(
    n: int,
    t_end: float,
    mu: float = 0.4,
    r: float = 1.0,
    m: float = 1.0,
    I_c: float = 0.5,
    q0=PAPER_Q0,
    v0=PAPER_V0,
    g: float = GRAVITY,
) -> NgonRolling:
    """Pivots and impacts of the rigid, perfectly inelastic, non-slipping rolling n-gon to t_end.

    Never raises for a polygon that would slip, hop or rock back: it reports that in
    `applicable` / `reason` / `required_mu` (the "n/a" of the reference table).
    """
    n = _integer_at_least(n, 3, "n (the number of polygon vertices)")
    t_end = _non_negative(t_end, "t_end")
    mu = _non_negative(mu, "mu")
    r, m, I_c, g = (_positive(value, name) for value, name in ((r, "r"), (m, "m"), (I_c, "I_c"), (g, "g")))
    phi0, omega0 = _pivot_state(n, r, _vector3(q0, "q0"), _vector3(v0, "v0"))

    beta = math.pi / n
    alpha = 2.0 * beta
    inertia_pivot = I_c + m * r * r
    k2 = m * g * r / inertia_pivot
    lam = (I_c + m * r * r * math.cos(alpha)) / inertia_pivot

    # Speeds at phi = -beta of every pivot, the first one extended backwards from phi0.
    top_barrier = 2.0 * k2 * (1.0 - math.cos(beta))  # w_s^2 needed to get over the vertex
    w_first = math.sqrt(omega0**2 + 2.0 * k2 * (math.cos(phi0) - math.cos(beta)))
    t_first, trusted = _pivot_time(np.array([w_first]), np.array([phi0]), np.array([beta]), beta, k2)
    starts = [0.0]  # start of every pivot, then the end of the last one computed
    speeds = []
    stop = ""  # why the rolling reference ends: "" (it does not), "rocks back", "nearly stops"
    if phi0 < 0.0 and w_first**2 <= top_barrier:
        stop = "rocks back"
    elif not trusted[0]:
        stop = "nearly stops"
    else:
        starts.append(float(t_first[0]))
        speeds.append(w_first)
    # Each full pivot lasts at least 2 beta / w_first (speeds only decrease): a batch this long
    # usually reaches t_end at once.
    batch = int(t_end * w_first / (2.0 * beta)) + 2
    while not stop and starts[-1] <= t_end:
        w = speeds[-1] * lam ** np.arange(1, batch + 1)
        clears = w**2 > top_barrier
        if not clears.all():
            w = w[: int(np.argmin(clears))]
            stop = "rocks back"
        durations, trusted = _pivot_time(w, np.full(w.size, -beta), np.full(w.size, beta), beta, k2)
        if not trusted.all():
            keep = int(np.argmin(trusted))
            w, durations = w[:keep], durations[:keep]
            stop = "nearly stops"
        starts.extend((starts[-1] + np.cumsum(durations)).tolist())
        speeds.extend(w.tolist())
    starts = np.array(starts)
    speeds = np.array(speeds)
    # The pivots that begin by t_end; starts[-1] is where the last computed one ends.
    n_pivots = int(np.searchsorted(starts[:-1], t_end, side="right")) if speeds.size else 0
    pivot_starts = starts[:n_pivots]
    omega_start = speeds[:n_pivots].copy()
    if n_pivots:
        omega_start[0] = omega0
    impact_times = starts[1:n_pivots]
    ends_early = bool(stop) and starts[-1] <= t_end

    required_mu = _required_mu(speeds[:n_pivots], phi0, beta, k2, m, r, g, lam, has_impacts=impact_times.size > 0)
    if not n_pivots:
        required_mu = 0.0  # nothing rolls: the rock-back reason below says why
    reason = ""
    if math.isinf(required_mu):
        reason = f"the exact {n}-gon reference would lift off the ground (hop) before t = {t_end:g} s"
    elif required_mu > mu:
        reason = (
            f"the exact {n}-gon reference needs mu >= {required_mu:.3g} to roll without slipping or "
            f"hopping up to t = {t_end:g} s, but mu = {mu:g}"
        )
    elif ends_early and stop == "nearly stops":
        reason = (
            f"the {n}-gon nearly stops on top of a vertex at t = {starts[-1]:.4g} s, where the "
            "rolling reference is not trusted"
        )
    elif ends_early:
        reason = f"the {n}-gon cannot get over a vertex at t = {starts[-1]:.4g} s: it rocks back"
    return NgonRolling(
        n=n,
        mu=mu,
        t_end=t_end,
        lam=lam,
        phi0=phi0,
        pivot_starts=pivot_starts,
        omega_start=omega_start,
        impact_times=impact_times,
        required_mu=required_mu,
        applicable=not reason,
        reason=reason,
        inertia_pivot=inertia_pivot,
        k2=k2,
    )


def exact_ngon_kinetic_energy(
    n: int,
    times,
    mu: float = 0.4,
    r: float = 1.0,
    m: float = 1.0,
    I_c: float = 0.5,
    q0=PAPER_Q0,
    v0=PAPER_V0,
    g: float = GRAVITY,
) -> np.ndarray:
    """KE(t) [J] of the exactly rolling n-gon at the given times [s] (after the impact at an
    impact instant). Raises ValueError when the reference does not apply (it would slip, hop or
    rock back before max(times); see `exact_ngon_rolling` for the record without raising)."""
    times = np.asarray(times, dtype=float)
    if times.ndim != 1 or times.size == 0 or not np.all(np.isfinite(times)) or np.any(times < 0):
        raise ValueError("times must be a non-empty 1D array of finite times >= 0 [s]")
    rolling = exact_ngon_rolling(n, float(times.max()), mu, r, m, I_c, q0, v0, g)
    if not rolling.applicable:
        raise ValueError(rolling.reason)
    beta = math.pi / rolling.n
    k = np.searchsorted(rolling.pivot_starts, times, side="right") - 1
    speed_at_minus_beta = rolling.omega_start.copy()
    # omega_start[0] is the speed at phi0; the pivot formulas want the speed at -beta.
    speed_at_minus_beta[0] = math.sqrt(
        rolling.omega_start[0] ** 2 + 2.0 * rolling.k2 * (math.cos(rolling.phi0) - math.cos(beta))
    )
    w_s = speed_at_minus_beta[k]
    phi_start = np.where(k == 0, rolling.phi0, -beta)
    phi = _phi_at(times - rolling.pivot_starts[k], w_s, phi_start, beta, rolling.k2)
    rate2 = w_s**2 + 2.0 * rolling.k2 * (math.cos(beta) - np.cos(phi))
    return 0.5 * rolling.inertia_pivot * rate2


def _pivot_state(n: int, r: float, q0: np.ndarray, v0: np.ndarray) -> tuple[float, float]:
    """(phi0, omega0) of a state pivoting on its lowest vertex, mirrored to roll left (omega > 0)."""
    alpha = 2.0 * math.pi / n
    theta, omega = q0[2], v0[2]
    if omega == 0.0:
        raise ValueError("v0[2] (omega) must be non-zero: the exact polygon reference needs a rolling start")
    # The lowest vertex; on an edge, the leading one (the one the polygon pivots on next).
    if omega > 0:
        phi0 = theta - alpha * math.floor(theta / alpha + 0.5)
    else:
        phi0 = theta - alpha * math.ceil(theta / alpha - 0.5)
    centre_height = r * math.cos(phi0)
    pivot_velocity = omega * r * np.array([-math.cos(phi0), -math.sin(phi0)])
    if abs(q0[1] - centre_height) > _STATE_TOL * r or np.abs(v0[:2] - pivot_velocity).max() > _STATE_TOL * max(
        1.0, abs(omega) * r
    ):
        raise ValueError(
            "q0, v0 must pivot on the lowest vertex (centre height r cos(phi0), centre velocity "
            f"omega x (c - P)); expected y = {centre_height:.12g}, v = {pivot_velocity.round(12).tolist()}"
        )
    return (phi0, omega) if omega > 0 else (-phi0, -omega)


def _pivot_time(w_s, phi_a, phi_b, beta, k2):
    """Time to pivot from phi_a to phi_b at speed w_s at phi = -beta, and whether the quadrature
    with half the nodes agrees (False when the pivot nearly stops on top)."""
    fine = _gauss_legendre_time(w_s, phi_a, phi_b, beta, k2, _QUADRATURE_NODES)
    coarse = _gauss_legendre_time(w_s, phi_a, phi_b, beta, k2, _QUADRATURE_NODES // 2)
    trusted = np.abs(fine - coarse) <= _QUADRATURE_RTOL * np.maximum(np.abs(fine), 1e-300)
    return fine, trusted


def _gauss_legendre_time(w_s, phi_a, phi_b, beta, k2, nodes):
    x, weights = leggauss(nodes)
    half_width = 0.5 * (phi_b - phi_a)
    phi = 0.5 * (phi_a + phi_b)[..., None] + half_width[..., None] * x
    rate = np.sqrt(w_s[..., None] ** 2 + 2.0 * k2 * (math.cos(beta) - np.cos(phi)))
    return half_width * np.sum(weights / rate, axis=-1)


def _phi_at(tau, w_s, phi_start, beta, k2):
    """phi after a time tau into a pivot: Newton on t(phi) = tau, t' = 1 / phi' > 0 (t is convex
    or concave only mildly, the start phi_start + tau w_s is within O(beta^3) of the answer)."""
    phi = phi_start + tau * w_s
    for _ in range(50):
        elapsed = _gauss_legendre_time(w_s, phi_start, phi, beta, k2, _QUADRATURE_NODES)
        rate = np.sqrt(w_s**2 + 2.0 * k2 * (math.cos(beta) - np.cos(phi)))
        step = (elapsed - tau) * rate
        phi = np.clip(phi - step, -beta, beta)
        if np.abs(step).max() <= _PHI_TOL * beta:
            return phi
    raise ArithmeticError("the pivot angle did not converge; this is a bug in the reference, not an input error")


def _required_mu(w_s, phi0, beta, k2, m, r, g, lam, has_impacts: bool) -> float:
    """Smallest mu without slip: pivots (sampled in phi, ends included) and impacts."""
    if w_s.size == 0:
        return 0.0
    phi = np.linspace(-beta, beta, _FORCE_SAMPLES)
    # The first pivot starts at phi0: only its part phi >= phi0 happens.
    active = np.ones((w_s.size, phi.size), dtype=bool)
    active[0] = phi >= phi0 - 1e-15
    active[0, -1] = True
    rate2 = w_s[:, None] ** 2 + 2.0 * k2 * (math.cos(beta) - np.cos(phi))
    accel = k2 * np.sin(phi)
    normal = m * g - m * r * (np.sin(phi) * accel + np.cos(phi) * rate2)
    tangential = m * r * (np.sin(phi) * rate2 - np.cos(phi) * accel)
    if np.any(normal[active] <= 0.0):
        return math.inf
    need = float(np.max(np.abs(tangential[active]) / normal[active]))
    if has_impacts:
        need = max(need, (1.0 - lam) / (1.0 + lam) / math.tan(beta))
    return need


# ----------------------------------------------------------------------------------------------
# DART's own stepper behind the stepper interface
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class NativeContact:
    """One contact DART's detector reported for the last step (world frame)."""

    point: np.ndarray
    normal: np.ndarray
    depth: float


@dataclass(frozen=True)
class NativeStepReport:
    """What one `World.step()` tells: DART never reports a failure, its LCP iterations or residual
    (residual is NaN: not known, not zero). num_contacts: contacts of the last collision check."""

    success: bool
    time: float
    num_contacts: int
    contacts: tuple = ()
    iterations: int = 0
    residual: float = math.nan
    status: str = "dart_native"
    substeps: int = 1
    message: str = ""
    unknowns: int = 0


class DartNative:
    """DART's native stepper (collision detector + boxed LCP) with the stepper interface:
    `DartNative(world).step()` advances one `world.getTimeStep()` and returns a NativeStepReport.

    record_contacts: also copy every contact point into the report (costs a few us per contact,
    which the wall-time benchmarks would count; the number of contacts is always reported).
    """

    def __init__(self, world, record_contacts: bool = False):
        if not isinstance(world, dart.simulation.World):
            raise ValueError(f"DartNative needs a dartpy.simulation.World, got {type(world).__name__}")
        self.world = world
        self.record_contacts = bool(record_contacts)

    @property
    def h(self) -> float:
        return float(self.world.getTimeStep())

    def step(self) -> NativeStepReport:
        self.world.step()
        result = self.world.getLastCollisionResult()
        contacts = ()
        if self.record_contacts:
            contacts = tuple(
                NativeContact(np.array(c.point), np.array(c.normal), float(c.penetrationDepth))
                for c in result.getContacts()
            )
        return NativeStepReport(success=True, time=float(self.world.getTime()), num_contacts=int(result.getNumContacts()),
                                contacts=contacts)


# ----------------------------------------------------------------------------------------------
# input checks
# ----------------------------------------------------------------------------------------------
def _integer_at_least(value, lowest: int, name: str) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < lowest:
        raise ValueError(f"{name} must be an integer >= {lowest}, got {value!r}")
    return int(value)


def _positive(value, name: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value > 0.0):
        raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
    return value


def _non_negative(value, name: str) -> float:
    value = float(value)
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
    return value


def _vector3(value, name: str) -> np.ndarray:
    vector = np.asarray(value, dtype=float)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise ValueError(f"{name} must be 3 finite numbers [x, y, theta] (or their rates), got {value!r}")
    return vector


def ke_loss_percent(kinetic: np.ndarray) -> np.ndarray:
    """Relative kinetic-energy loss (KE0 - KE) / KE0 in % of a KE series (entry 0 is KE0)."""
    kinetic = np.asarray(kinetic, dtype=float)
    return 100.0 * (kinetic[0] - kinetic) / kinetic[0]


def main() -> None:
    """Print the reference check: KE loss % at 1 s / 5 s, h = 0.01, N = 100 and 1000, all detectors."""
    h, duration = 0.01, 5.0
    sample_steps = (int(round(1.0 / h)), int(round(duration / h)))
    print("N     exact          " + "  ".join(f"{name:>16s}" for name in DETECTORS))
    for n in (100, 1000):
        exact = ke_loss_percent(exact_ngon_kinetic_energy(n, [0.0, 1.0, duration]))
        cells = []
        for name in DETECTORS:
            world, disc = build_ngon_world(n, h=h, detector=name)
            stepper = DartNative(world)
            energies = [kinetic_energy(disc)]
            for step in range(1, sample_steps[-1] + 1):
                stepper.step()
                if step in sample_steps:
                    energies.append(kinetic_energy(disc))
            loss = ke_loss_percent(energies)
            cells.append(f"{loss[1]:6.3g} / {loss[2]:6.3g}")
        print(f"{n:<5d} {exact[1]:5.3g} / {exact[2]:5.3g}  " + "  ".join(f"{c:>16s}" for c in cells))


if __name__ == "__main__":
    main()
