"""Work-precision: how much wall-clock time does each stepper need for a given error?

Question. For every scene with a known answer, plot the error of a run against the wall time it
took (log-log), for the implicit stepper over time steps h (and solver tolerances) and for DART's
own stepper over h, detectors and shape representations; then read off, from the data, for which
target errors the implicit stepper is cheaper than the best DART configuration, and at what wall
time, and where DART is cheaper.

Scenes, references and errors (SCENES; each error is a pure function of a run and its reference)
  disc_rolling   [GI] Example 1: the unit disc rolling (v0 = [-3, 0, 3]) over 5 s. Exact answer:
                 KE = 6.75 J, x(t) = -3 t. Errors: ke = max_t |KE - 6.75| / 6.75; x_end =
                 |x(T) + 3 T| [m].
  slide_to_roll  the same disc started sliding (v0 = [-3, 0, 0]) over 1 s. Exact answer: the slip
                 s = |v_x + omega r| falls linearly at 3 mu g and vanishes at t* = |v0| / (3 mu g) =
                 0.2548 s, then v_x = -2, omega = 2. Error: |v_x(T) + 2| + |omega(T) - 2| r +
                 |t_roll - t*| (m/s and s added, r = 1 m, T = 1 s; the sum is what matters on a
                 log axis). t_roll: the zero of the line through the last two samples whose slip
                 exceeds ROLL_SLIP_TOL (exact for any stepper whose sliding samples are exact, so
                 the event is judged to sub-step resolution rather than to the sampling h).
  sphere_on_two_spheres  [GI] Example 2 over 4 s (every event is over by 3.7 s). No closed form:
                 the reference is a fine-step implicit run of order 2 (rattle.py; REFERENCE_H =
                 5e-4 s by default: order 1 fails the first step of this scene for h <= 3e-4 s),
                 cached in --out (work_precision_reference_*.npz) with a hash of the stepper's
                 sources, so it is recomputed only when the code changes (--refresh-reference
                 forces it). Errors: events = max |t - t_ref| over "contact 1 lost" and "contact
                 2 lost" (scenes.sphere_on_two_spheres.events; for DART the same definition, a
                 contact is on while DART's contact force has a normal component above
                 FORCE_ZERO); v_rms = RMS over the run's sample times of |v - v_ref| (v = [omega;
                 v] of the ball, rad/s and m/s with r = 1 m; the reference linearly interpolated).
                 Contact 2's slide onset is printed, not scored: DART's contact 2 creeps (slip
                 1e-4..1e-2 m/s) from the start, so by the scene's ROLL_SLIP = 1e-6 m/s it
                 "slides" at once. DART also solves a different model (no torsional friction,
                 e_r = 0.3 in the scene; box friction): its error stalls at that difference.
                 The events are read at step times, so the reference's event times are good to
                 ~h_ref, and its velocities, whose error is first order near the events: errors
                 below ~ error(h) h_ref / h are not resolved.
  ellipsoid_rocking  scenes.ellipsoid_rocking over 3 s. Exact answer: the 1-dof rolling ODE
                 (scenes.ellipsoid_rocking.exact_rocking, DOP853 at 1e-12), better than a
                 fine-step run (a first-order stepper at h = 2.5e-4 s is still 1e-3 rad off).
                 Errors: tilt = max_t |theta - theta_exact| [rad]; energy = |E(T) - E0| / E0 of
                 the rocking energy (kinetic + m g (z - c)).
  quasi_rigid_drop  [GI] Example 3 (scenes.disc_on_quasi_rigid_plane, delta_max = 1 m: no core hit)
                 over 0.45 s, implicit only, orders 1 and 2 (DART has no quasi-rigid contact). Error: max |delta -
                 delta_exact| [m] of the layer's deflection during the first contact (the scene's
                 analytic_deflection). A hook: skipped with a printed note while the scene module
                 (or its simulate / analytic_deflection / analytic_events) is missing.

Steppers. "implicit": the scene's own simulate(duration, h, ...), solver tolerance 1e-10 (the
default) and, on the disc scenes, 1e-6. "dart_native": comparisons.dart_native.DartNative
(world.step(): collision detector + boxed LCP) with detectors FCL (dartpy's default) and DART;
on the disc scenes over shapes: N-gon prisms (N = 100, 1000; build_ngon_world), a CylinderShape
and a SphereShape disc (build_primitive_disc_world; a sphere's section in the plane is the disc
itself, so DART has an exact disc too); on Examples 2 and the ellipsoid the scene's own world
(SphereShapes / EllipsoidShape + PlaneShape with collision aspects).

Wall time. Sum of the time spent inside step() over the run (world building, recording and the
metrics excluded): the cost of simulating the scene's horizon. Runs share the machine's cores
(two processes on two cores by default), so wall times vary up to ~2x between invocations; the
crossovers move accordingly.

Horizons. Default: the horizons above (disc 5 s, slide 1 s, spheres 4 s, ellipsoid 3 s, drop
0.45 s); --quick: the same horizons on a coarse grid (two h per stepper, FCL only) with a
coarse sphere reference (h = 2e-3 s); a smoke run, not a measurement.

Executors: a local process pool (ProcessPoolExecutor, "spawn", --workers, default
os.cpu_count()), --workers 0 in this process, --scheduler tcp://host:8786 for Dask (the
study uploads scenes/ and comparisons/ to the cluster, see comparisons.executors). A run that
raises becomes a record with the error in its note; the command then exits with status 1.

Outputs (in --out, default comparisons/out): work_precision_<scene>.png (error vs wall time, one
panel per error; not drawn for a scene without any finite error), work_precision.csv (one row per
run and error), a printed table and reading.

Run: python -m comparisons.work_precision [--quick] [--scenes disc_rolling,slide_to_roll,...]
                                          [--workers N] [--scheduler tcp://...] [--out DIR]
                                          [--refresh-reference]
"""
from __future__ import annotations

import argparse
import csv
from dataclasses import dataclass, field, replace
import hashlib
import importlib
import importlib.util
import math
import os
from pathlib import Path
import time

import numpy as np

from comparisons import dart_native
from implicit_contact.trajectory import simulate as simulate_stepper
from comparisons.executors import completed

DEFAULT_OUT = Path(os.path.abspath(__file__)).parent / "out"
REPO = Path(os.path.abspath(__file__)).parent.parent
STEPPERS = ("implicit", "dart_native", "reference")
DEFAULT_TOL = 1e-10           # the stepper's default natural-residual tolerance (stepper.DEFAULT_SOLVER)
ERROR_FLOOR = 1e-16           # errors below this (round-off, or exactly 0) are drawn at it
# Disc scenes ([GI] Example 1)
KE0 = 6.75                    # [J] 0.5 m |v0|^2 + 0.5 I omega0^2
ROLL_SPEED = 3.0              # [m/s] x(t) = -3 t
MU, G = 0.4, 9.81
SLIDE_V0 = (-3.0, 0.0, 0.0)
T_STAR = 3.0 / (3.0 * MU * G)  # [s] end of slip, |v0| / (3 mu g) = 0.2548 s
ROLLING_V, ROLLING_OMEGA = -2.0, 2.0
ROLL_SLIP_TOL = 1e-2          # [m/s] slip below this counts as rolling (1/300 of the initial slip;
                              # DART's rolling creep on a cylinder is up to ~1.5e-3 m/s)
# Example 2
REFERENCE_H = 5e-4            # [s] fine-step implicit reference of Example 2: the stepper fails its first
                              # step for h <= 3e-4 (NCP at its iteration cap, measured), so 5e-4
EVENT_KEYS = ("contact1_lost", "contact2_lost")   # scored; contact2_slides printed only
SPHERE_CONTACT_SLACK = 0.05   # [m] a DART contact point within this of a fixed sphere's surface is its
QUASI_DELTA_MAX = 1.0         # [m] Example 3 without a core hit (Fig. 8): the deflection has a closed form


# ----------------------------------------------------------------------------------------------
# scenes
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SceneSpec:
    """A scene of the study: the question (the figure's title), its errors (key, axis label),
    the module it needs, whether DART runs it, and what the reference is."""
    name: str
    question: str
    metrics: tuple
    module: str
    reference: str
    requires: tuple = ()
    dart: bool = True


SCENES = {
    "disc_rolling": SceneSpec(
        "disc_rolling", "Rolling disc (Ex. 1): wall time for a given energy / position error?",
        (("ke", "max |KE - 6.75 J| / 6.75 J over the run [-]"), ("x_end", "|x(T) + 3 T| at the end [m]")),
        "scenes.disc_rolling", "exact: KE = 6.75 J, x = -3 t"),
    "slide_to_roll": SceneSpec(
        "slide_to_roll", "Slide-to-roll (disc, v0 = [-3, 0, 0]): wall time for a given error?",
        (("slide", "|v_x(1 s) + 2| + |omega(1 s) - 2| + |t_roll - t*|  [m/s, rad/s, s]"),),
        "scenes.disc_rolling", f"exact: t* = {T_STAR:.4f} s, then v_x = -2, omega = 2"),
    "sphere_on_two_spheres": SceneSpec(
        "sphere_on_two_spheres", "Sphere on two spheres (Ex. 2): wall time for given event / velocity errors?",
        (("events", "max |t - t_ref| of the contact-loss events [s]"),
         ("v_rms", "RMS over time of |v - v_ref| [m/s, rad/s]")),
        "scenes.sphere_on_two_spheres", "fine-step implicit run"),
    "ellipsoid_rocking": SceneSpec(
        "ellipsoid_rocking", "Rocking ellipsoid: wall time for a given tilt / energy error?",
        (("tilt", "max |tilt - exact| over the run [rad]"), ("energy", "|E(T) - E0| / E0, rocking energy [-]")),
        "scenes.ellipsoid_rocking", "exact: the 1-dof rolling ODE (DOP853, 1e-12)"),
    "quasi_rigid_drop": SceneSpec(
        "quasi_rigid_drop", "Disc dropped on a quasi-rigid plane (Ex. 3): wall time for a given deflection error?",
        (("deflection", "max |delta - delta_exact| in the first contact [m]"),),
        "scenes.disc_on_quasi_rigid_plane", "analytic deflection (delta_max = 1 m, no core hit)",
        requires=("simulate", "analytic_deflection", "analytic_events"), dart=False),
}


def scene_available(name: str) -> tuple[bool, str]:
    """(True, "") if the scene's module (and what the study calls in it) exists, else (False, why)."""
    spec = SCENES[name]
    if importlib.util.find_spec(spec.module) is None:
        return False, (f"skipped {name}: {spec.module} does not exist yet; the hook runs it once the "
                       f"module exists with {', '.join(spec.requires) or 'simulate'}")
    if spec.requires:
        module = importlib.import_module(spec.module)
        missing = [f for f in spec.requires if not hasattr(module, f)]
        if missing:
            return False, f"skipped {name}: {spec.module} has no {', '.join(missing)} yet"
    return True, ""


# ----------------------------------------------------------------------------------------------
# one run
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class RunConfig:
    """One independent simulation (hashable, picklable).

    scene: a key of SCENES; stepper: "implicit", "dart_native" or "reference" (the fine implicit
    run of a scene without a closed form); shape: DART's disc representation on the disc scenes
    ("ngon100", "ngon1000", "cylinder", "sphere"), "" else; detector: DART's collision detector,
    "" for the implicit stepper; h [s]; tol: the implicit solver's tolerance (None for DART);
    duration [s]; order: the implicit stepper's StepperOptions.order (1 for DART runs).
    """
    scene: str
    stepper: str
    shape: str
    detector: str
    h: float
    tol: float | None
    duration: float
    order: int = 1

    def __post_init__(self):
        if self.scene not in SCENES:
            raise ValueError(f"scene must be one of {tuple(SCENES)}, got {self.scene!r}")
        if self.stepper not in STEPPERS:
            raise ValueError(f"stepper must be one of {STEPPERS}, got {self.stepper!r}")
        native = self.stepper == "dart_native"
        if native and self.detector not in dart_native.DETECTORS:
            raise ValueError(f"detector must be one of {dart_native.DETECTORS}, got {self.detector!r}")
        if not native and (self.detector or self.shape):
            raise ValueError(f"only DART runs have a detector and shape, got {self.detector!r}, {self.shape!r}")
        disc = self.scene in ("disc_rolling", "slide_to_roll")
        if native and disc and self.shape not in DISC_SHAPES:
            raise ValueError(f"a DART disc shape must be one of {DISC_SHAPES}, got {self.shape!r}")
        if native and not disc and self.shape:
            raise ValueError(f"{self.scene} runs DART on the scene's own world: shape must be '', got {self.shape!r}")
        if native != (self.tol is None):
            raise ValueError(f"tol must be None exactly for DART runs, got {self.tol!r} for {self.stepper}")
        if not native and self.tol != DEFAULT_TOL and self.scene not in TOLERANCE_SCENES:
            raise ValueError(f"{self.scene} runs the implicit stepper at its default tolerance only")
        if self.order not in (1, 2) or (self.order == 2 and (self.stepper == "dart_native" or self.scene not in ORDER2_SCENES)):
            raise ValueError(f"order 2 runs the implicit stepper on {ORDER2_SCENES} only, got order {self.order!r} "
                             f"for {self.stepper} on {self.scene}")
        if not (math.isfinite(self.h) and self.h > 0):
            raise ValueError(f"h must be a finite time step > 0 [s], got {self.h!r}")
        if not (math.isfinite(self.duration) and self.duration >= self.h):
            raise ValueError(f"duration must be >= h [s], got {self.duration!r}")

    @property
    def steps(self) -> int:
        return int(round(self.duration / self.h))

    @property
    def series(self) -> str:
        """The curve this run belongs to (one line per series in the figure)."""
        if self.stepper == "dart_native":
            shape = {"ngon100": "100-gon", "ngon1000": "1000-gon", "cylinder": "cylinder", "sphere": "sphere"}.get(
                self.shape, "")
            return f"DART/{self.detector.upper()}" + (f" {shape}" if shape else "")
        if self.stepper == "reference":
            return "reference (fine implicit" + (", order 2)" if self.order == 2 else ")")
        return "implicit" + (" order 2" if self.order == 2 else "") + ("" if self.tol == DEFAULT_TOL else f", tol {self.tol:g}")

    @property
    def label(self) -> str:
        return f"{self.series}, h = {self.h:g} s"


DISC_SHAPES = ("ngon100", "ngon1000", "cylinder", "sphere")
TOLERANCE_SCENES = ("disc_rolling", "slide_to_roll", "ellipsoid_rocking")
ORDER2_SCENES = ("disc_rolling", "slide_to_roll", "sphere_on_two_spheres", "ellipsoid_rocking", "quasi_rigid_drop")


@dataclass(frozen=True, eq=False)
class RunRecord:
    """What a run returns: sample times [s], the scene's series (arrays by name), its events
    (Example 2), the wall time inside step() [s] and per step [us], and a note (why it failed:
    then ok is False and the arrays are empty)."""
    config: RunConfig
    times: np.ndarray
    series: dict
    wall_s: float
    events: dict = field(default_factory=dict)
    ok: bool = True
    note: str = ""

    @property
    def us_per_step(self) -> float:
        return 1e6 * self.wall_s / self.config.steps if self.ok else math.nan


def run(config: RunConfig) -> RunRecord:
    """Simulate one configuration (a pure function of config: pool and Dask workers call it)."""
    if config.scene in ("disc_rolling", "slide_to_roll"):
        return _run_disc(config)
    if config.scene == "sphere_on_two_spheres":
        return _run_spheres(config)
    if config.scene == "ellipsoid_rocking":
        return _run_ellipsoid(config)
    return _run_quasi_rigid(config)


def _stepper_options(tol: float, order: int = 1):
    from implicit_contact import stepper

    return stepper.StepperOptions(solver=replace(stepper.DEFAULT_SOLVER, tol=tol), order=order)


def _run_disc(config: RunConfig) -> RunRecord:
    v0 = dart_native.PAPER_V0 if config.scene == "disc_rolling" else SLIDE_V0
    if config.stepper == "dart_native":
        if config.shape.startswith("ngon"):
            world, _ = dart_native.build_ngon_world(int(config.shape[4:]), h=config.h, detector=config.detector, v0=v0)
        else:
            world, _ = dart_native.build_primitive_disc_world(config.shape, h=config.h, detector=config.detector, v0=v0)
        traj = simulate_stepper(world, dart_native.DartNative(world), config.duration)
    else:
        from scenes import disc_rolling

        traj = disc_rolling.simulate(config.duration, config.h, v0=v0, stepper_options=_stepper_options(config.tol, config.order))
    t, q, v, ke = traj.arrays()
    series = {"x": q[:, 0], "v_x": v[:, 0], "omega": v[:, 2], "ke": ke}
    return RunRecord(config, t, series, float(np.sum(traj.step_seconds)))


def _run_spheres(config: RunConfig) -> RunRecord:
    from scenes import sphere_on_two_spheres as scene

    if config.stepper == "dart_native":
        world = scene.build_world(config.h)
        world.setCollisionDetector(dart_native.make_detector(config.detector))
        forces = []

        def before_step(w, t):
            # the contact forces of the step just taken, read outside the timed step()
            if w.getTime() > 0:
                forces.append(_dart_sphere_forces(w, scene))
            scene.push(w, t)

        traj = simulate_stepper(world, dart_native.DartNative(world), config.duration, before_step=before_step)
        forces.append(_dart_sphere_forces(world, scene))
        t, q, v, _ = traj.arrays()
        forces = np.array(forces)
        events = _native_sphere_events(t[1:], forces, _slip_on(q[1:], v[1:], scene.SMALL, scene.RADIUS), scene)
    else:
        traj = scene.simulate(config.duration, config.h, on_failure="retry",
                              stepper_options=_stepper_options(config.tol, config.order))
        t, q, v, _ = traj.arrays()
        events = scene.events(traj)
    return RunRecord(config, t, {"v": v}, float(np.sum(traj.step_seconds)), events=events)


def _dart_sphere_forces(world, scene) -> tuple[float, float]:
    """Normal components [N] of DART's contact forces on the r10 and r9 spheres, last step."""
    out = [0.0, 0.0]
    for contact in world.getLastCollisionResult().getContacts():
        point = np.asarray(contact.point)
        for k, (radius, centre) in enumerate((scene.BIG, scene.SMALL)):
            if abs(np.linalg.norm(point - np.asarray(centre)) - radius) < SPHERE_CONTACT_SLACK:
                out[k] += abs(float(np.asarray(contact.force) @ np.asarray(contact.normal)))
    return tuple(out)


def _slip_on(q, v, sphere, radius) -> np.ndarray:
    """Tangential slip speed [m/s] of the ball's surface point facing a fixed sphere (FreeJoint
    q = [rotvec, origin], v = [omega; v], world frame)."""
    centre = np.asarray(sphere[1], float)
    towards = centre - q[:, 3:]
    n = towards / np.linalg.norm(towards, axis=1, keepdims=True)
    u = v[:, 3:] + np.cross(v[:, :3], radius * n)
    return np.linalg.norm(u - np.sum(u * n, axis=1, keepdims=True) * n, axis=1)


def _native_sphere_events(t, forces, slip2, scene) -> dict:
    """scenes.sphere_on_two_spheres.events with DART's contact forces (same thresholds)."""
    out = {}
    for name, column in (("contact1_lost", 0), ("contact2_lost", 1)):
        on = np.nonzero(forces[:, column] > scene.FORCE_ZERO)[0]
        out[name] = float(t[on[-1]]) if len(on) else math.nan
    sliding = np.nonzero((forces[:, 1] > scene.FORCE_ZERO) & (slip2 > scene.ROLL_SLIP))[0]
    out["contact2_slides"] = float(t[sliding[0]]) if len(sliding) else math.nan
    return out


def _run_ellipsoid(config: RunConfig) -> RunRecord:
    from scenes import ellipsoid_rocking as scene

    if config.stepper == "dart_native":
        world = scene.build_world(config.h)
        world.setCollisionDetector(dart_native.make_detector(config.detector))
        traj = simulate_stepper(world, dart_native.DartNative(world), config.duration)
    else:
        traj = scene.simulate(config.duration, config.h, stepper_options=_stepper_options(config.tol, config.order))
    t, q, _, _ = traj.arrays()
    series = {"tilt": scene.tilt_angle(q), "energy": scene.rocking_energy(traj)}
    return RunRecord(config, t, series, float(np.sum(traj.step_seconds)))


def _run_quasi_rigid(config: RunConfig) -> RunRecord:
    scene = importlib.import_module(SCENES["quasi_rigid_drop"].module)
    record = scene.simulate(QUASI_DELTA_MAX, config.duration, config.h, order=config.order)
    return RunRecord(config, np.asarray(record.t), {"deflection": np.asarray(record.deflection)},
                     float(np.sum(record.traj.step_seconds)))


def _failed(config: RunConfig, error: BaseException) -> RunRecord:
    return RunRecord(config, np.zeros(0), {}, math.nan, ok=False, note=f"run failed: {type(error).__name__}: {error}")


# ----------------------------------------------------------------------------------------------
# references and errors (pure functions)
# ----------------------------------------------------------------------------------------------
def slide_exact(t) -> tuple[np.ndarray, np.ndarray]:
    """(v_x [m/s], omega [rad/s]) of the sliding disc: slip until T_STAR, then rolling."""
    t = np.minimum(np.asarray(t, float), T_STAR)
    return -3.0 + MU * G * t, 2.0 * MU * G * t        # omega' = mu m g r / I, I = m r^2 / 2


def roll_time(t, slip) -> float:
    """When the slip ends [s]: the zero of the line through the last two samples with slip above
    ROLL_SLIP_TOL before the first sample below it (NaN if it never falls below)."""
    t, slip = np.asarray(t, float), np.abs(np.asarray(slip, float))
    below = np.nonzero(slip <= ROLL_SLIP_TOL)[0]
    if not len(below):
        return math.nan
    m = int(below[0])
    if m < 2:
        return float(t[m])
    a, b = slip[m - 2], slip[m - 1]
    if a <= b:  # not decreasing: no line to extend
        return float(t[m])
    return float(t[m - 1] + b * (t[m - 1] - t[m - 2]) / (a - b))


def errors(record: RunRecord, reference: RunRecord | None = None) -> dict:
    """The scene's errors of one run (NaN when the run failed or the error is undefined)."""
    spec = SCENES[record.config.scene]
    if not record.ok:
        return {key: math.nan for key, _ in spec.metrics}
    t, s = record.times, record.series
    scene = record.config.scene
    if scene == "disc_rolling":
        return {"ke": float(np.max(np.abs(s["ke"] - KE0)) / KE0),
                "x_end": float(abs(s["x"][-1] + ROLL_SPEED * t[-1]))}
    if scene == "slide_to_roll":
        v_exact, w_exact = slide_exact(t[-1])
        t_roll = roll_time(t, s["v_x"] + s["omega"])   # r = 1 m
        return {"slide": float(abs(s["v_x"][-1] - v_exact) + abs(s["omega"][-1] - w_exact) + abs(t_roll - T_STAR))}
    if scene == "sphere_on_two_spheres":
        if reference is None or not reference.ok:
            return {"events": math.nan, "v_rms": math.nan}
        dt = [abs(record.events[k] - reference.events[k]) for k in EVENT_KEYS]
        v_ref = np.column_stack([np.interp(t, reference.times, reference.series["v"][:, j]) for j in range(6)])
        rms = float(np.sqrt(np.mean(np.sum((s["v"] - v_ref) ** 2, axis=1))))
        return {"events": float(max(dt)), "v_rms": rms}
    if scene == "ellipsoid_rocking":
        from scenes import ellipsoid_rocking

        exact, _ = ellipsoid_rocking.exact_rocking(t)
        e0 = ellipsoid_rocking.exact_energy()
        return {"tilt": float(np.max(np.abs(s["tilt"] - exact))), "energy": float(abs(s["energy"][-1] - e0) / e0)}
    quasi = importlib.import_module(SCENES["quasi_rigid_drop"].module)
    events = quasi.analytic_events(QUASI_DELTA_MAX)
    first = (t >= events["contact"]) & (t <= events["release"])
    exact = np.asarray(quasi.analytic_deflection(t[first]), float)
    return {"deflection": float(np.max(np.abs(s["deflection"][first] - exact))) if first.any() else math.nan}


# ----------------------------------------------------------------------------------------------
# the reference cache (Example 2)
# ----------------------------------------------------------------------------------------------
def source_hash(scene: str) -> str:
    """sha256 of the stepper's sources and the scene: a cached reference is valid while it matches."""
    digest = hashlib.sha256()
    files = sorted((REPO / "implicit_contact").glob("**/*.py")) + [REPO / (SCENES[scene].module.replace(".", "/") + ".py")]
    for path in files:
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:16]


def reference_path(config: RunConfig, out: Path) -> Path:
    order = f"_order{config.order}" if config.order != 1 else ""
    return Path(out) / f"work_precision_reference_{config.scene}_h{config.h:g}_T{config.duration:g}{order}.npz"


def load_reference(config: RunConfig, out: Path) -> RunRecord | None:
    """The cached reference run of config, or None if absent or made by other sources."""
    path = reference_path(config, out)
    if not path.exists():
        return None
    with np.load(path, allow_pickle=False) as data:
        if str(data["source_hash"]) != source_hash(config.scene):
            return None
        events = {k: float(v) for k, v in zip(data["event_names"], data["event_times"])}
        return RunRecord(config, data["times"], {"v": data["v"]}, float(data["wall_s"]), events=events,
                         note=f"cached in {path.name}")


def save_reference(record: RunRecord, out: Path) -> Path:
    path = reference_path(record.config, out)
    names = sorted(record.events)
    np.savez_compressed(path, times=record.times, v=record.series["v"], wall_s=record.wall_s,
                        event_names=np.array(names), event_times=np.array([record.events[k] for k in names]),
                        source_hash=source_hash(record.config.scene))
    return path


# ----------------------------------------------------------------------------------------------
# the grid of runs
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ScenePlan:
    """What to run for one scene: horizon [s]; implicit time steps [s] and solver tolerances;
    DART time steps [s], shapes (disc scenes; ("",) for a scene's own world) and detectors;
    reference_h [s] of a fine-step reference (scenes without a closed form)."""
    scene: str
    horizon: float
    implicit_steps: tuple
    tolerances: tuple = (DEFAULT_TOL,)
    dart_steps: tuple = ()
    dart_shapes: tuple = ("",)
    detectors: tuple = ("fcl", "dart")
    reference_h: float | None = None
    orders: tuple = (1,)          # the implicit stepper's orders (order 2 at the default tolerance)

    def __post_init__(self):
        if self.scene not in SCENES:
            raise ValueError(f"scene must be one of {tuple(SCENES)}, got {self.scene!r}")
        if self.scene == "sphere_on_two_spheres" and self.reference_h is None:
            raise ValueError("sphere_on_two_spheres needs reference_h (it has no closed form)")


_IMPLICIT_H = (0.02, 0.01, 0.005, 0.002, 0.001, 0.0005)
_DART_H = (0.02, 0.01, 0.005, 0.002, 0.001, 0.0005, 0.0002, 0.0001)
DEFAULT_PLANS = (
    ScenePlan("disc_rolling", 5.0, _IMPLICIT_H, (DEFAULT_TOL, 1e-6), _DART_H, DISC_SHAPES, orders=(1, 2)),
    ScenePlan("slide_to_roll", 1.0, _IMPLICIT_H, (DEFAULT_TOL, 1e-6), _DART_H, DISC_SHAPES, orders=(1, 2)),
    ScenePlan("sphere_on_two_spheres", 4.0, _IMPLICIT_H[:4], dart_steps=_DART_H, reference_h=REFERENCE_H, orders=(1, 2)),
    ScenePlan("ellipsoid_rocking", 3.0, _IMPLICIT_H[:-1], dart_steps=_DART_H, orders=(1, 2)),
    ScenePlan("quasi_rigid_drop", 0.45, (1e-3, 5e-4, 2e-4, 1e-4), orders=(1, 2)),
)
QUICK_PLANS = (
    ScenePlan("disc_rolling", 5.0, (0.02, 0.01), dart_steps=(0.01, 0.001), dart_shapes=("ngon1000", "cylinder", "sphere"),
              detectors=("fcl",)),
    ScenePlan("slide_to_roll", 1.0, (0.02, 0.005), dart_steps=(0.01, 0.001), dart_shapes=("ngon1000", "cylinder", "sphere"),
              detectors=("fcl",)),
    ScenePlan("sphere_on_two_spheres", 4.0, (0.02, 0.01), dart_steps=(0.01, 0.001), detectors=("fcl",), reference_h=2e-3),
    ScenePlan("ellipsoid_rocking", 3.0, (0.02, 0.01), dart_steps=(0.01, 0.001), detectors=("fcl",), orders=(1, 2)),
    ScenePlan("quasi_rigid_drop", 0.45, (1e-3, 5e-4), orders=(1, 2)),
)


def plan(plans) -> tuple[RunConfig, ...]:
    """Every run of the plans (references included), each once."""
    configs = []
    for p in plans:
        configs += [RunConfig(p.scene, "implicit", "", "", h, tol, p.horizon) for tol in p.tolerances
                    for h in p.implicit_steps]
        configs += [RunConfig(p.scene, "implicit", "", "", h, DEFAULT_TOL, p.horizon, order)
                    for order in p.orders if order != 1 for h in p.implicit_steps]
        if SCENES[p.scene].dart:
            configs += [RunConfig(p.scene, "dart_native", shape, det, h, None, p.horizon)
                        for shape in p.dart_shapes for det in p.detectors for h in p.dart_steps]
        if p.reference_h is not None:
            configs.append(RunConfig(p.scene, "reference", "", "", p.reference_h, DEFAULT_TOL, p.horizon,
                                     2 if p.scene in ORDER2_SCENES else 1))
    return tuple(dict.fromkeys(configs))


def _cost(config: RunConfig) -> float:
    """Rough seconds of a run (measured magnitudes), only to start the longest runs first."""
    if config.stepper == "dart_native":
        per_step = 2e-4 if config.shape.startswith("ngon") else 2e-5
    else:
        per_step = {"sphere_on_two_spheres": 7e-3, "ellipsoid_rocking": 3e-3}.get(config.scene, 1e-3)
    return config.steps * per_step


# ----------------------------------------------------------------------------------------------
# executors (the pattern of comparisons.energy_loss)
# ----------------------------------------------------------------------------------------------
def execute(configs, scheduler: str | None = None, max_workers: int | None = None,
            progress: bool = True) -> dict:
    """Run every config once; {config: record}. A local process pool of max_workers processes
    (default os.cpu_count(); 0 runs here) or a Dask scheduler address. A run that raises becomes
    a failed record. One tqdm bar per scene."""
    from tqdm import tqdm

    configs = sorted(configs, key=_cost, reverse=True)
    scenes = list(dict.fromkeys(c.scene for c in configs))
    bars = {s: tqdm(total=sum(c.scene == s for c in configs), desc=s, unit="run", position=i,
                    disable=not progress) for i, s in enumerate(scenes)}
    records = {}
    try:
        for config, record in completed(run, configs, _failed, scheduler, max_workers):
            records[config] = record
            bars[config.scene].update()
    finally:
        for bar in bars.values():
            bar.close()
    return records


# ----------------------------------------------------------------------------------------------
# table, CSV
# ----------------------------------------------------------------------------------------------
CSV_FIELDS = ("scene", "metric", "error", "stepper", "series", "shape", "detector", "h", "solver_tol",
              "duration_s", "steps", "wall_s", "us_per_step", "note")


def rows(records: dict, references: dict) -> list[dict]:
    """One row per (run, error) of every non-reference run, as CSV_FIELDS."""
    table = []
    for config, record in records.items():
        if config.stepper == "reference":
            continue
        values = errors(record, references.get(config.scene))
        for metric, _ in SCENES[config.scene].metrics:
            table.append({
                "scene": config.scene, "metric": metric, "error": values[metric], "stepper": config.stepper,
                "series": config.series, "shape": config.shape, "detector": config.detector, "h": config.h,
                "solver_tol": config.tol, "duration_s": config.duration, "steps": config.steps,
                "wall_s": record.wall_s, "us_per_step": record.us_per_step, "note": _note(record, values),
            })
    return table


def _note(record: RunRecord, values: dict) -> str:
    if not record.ok:
        return record.note
    if record.config.scene == "slide_to_roll" and math.isnan(values["slide"]):
        return f"never rolls: slip above {ROLL_SLIP_TOL:g} m/s at every sample"
    if record.events:
        return "events " + ", ".join(f"{k} {v:.3f}" for k, v in record.events.items())
    return ""


def write_csv(table: list[dict], path: Path) -> None:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=CSV_FIELDS)
        writer.writeheader()
        for row in table:
            writer.writerow({k: _csv_value(row[k]) for k in CSV_FIELDS})


def _csv_value(value):
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return ""
    return f"{value:.6g}" if isinstance(value, float) else value


def format_table(table: list[dict], references: dict) -> str:
    """Per scene: one line per run with its errors, wall time [s] and time per step [us]."""
    lines = []
    for name, spec in SCENES.items():
        chosen = [r for r in table if r["scene"] == name]
        if not chosen:
            continue
        keys = [k for k, _ in spec.metrics]
        lines.append(f"\n{name}: {spec.question}  (reference: {spec.reference}"
                     + (f", h = {references[name].config.h:g} s" if name in references else "") + ")")
        header = (f"{'series':<24} {'h [s]':>7} {'steps':>6} {'wall [s]':>9} {'us/step':>8} "
                  + " ".join(f"{k:>10}" for k in keys) + "  note")
        lines += [header, "-" * len(header)]
        runs = {}
        for r in chosen:
            runs.setdefault((r["series"], r["h"]), {})[r["metric"]] = r
        for (series, h), by_metric in sorted(runs.items(), key=lambda kv: (_series_order(kv[0][0]), -kv[0][1])):
            r = next(iter(by_metric.values()))
            cells = " ".join(f"{_cell(by_metric[k]['error']):>10}" for k in keys)
            lines.append(f"{series:<24} {h:>7g} {r['steps']:>6} {_cell(r['wall_s'], '.3f'):>9} "
                         f"{_cell(r['us_per_step'], '.0f'):>8} {cells}  {r['note']}")
    return "\n".join(lines)


def _series_order(series: str):
    return (0 if series.startswith("implicit") else 1, series)


def _cell(value, spec=".2e") -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


# ----------------------------------------------------------------------------------------------
# the reading: who is cheaper for a given error (computed from the table)
# ----------------------------------------------------------------------------------------------
def cheapest(points, target: float):
    """The point (error, wall_s, label) with the smallest wall time whose error <= target, or None."""
    good = [p for p in points if p[0] <= target]
    return min(good, key=lambda p: p[1]) if good else None


def compare(implicit, dart) -> list[dict]:
    """For every achieved error level (descending), the cheapest implicit and DART run reaching it
    and the winner: "implicit", "dart" or "none". points: (error, wall_s, label) with finite error."""
    levels = sorted({max(p[0], ERROR_FLOOR) for p in implicit + dart}, reverse=True)
    out = []
    for target in levels:
        i, d = cheapest(implicit, target), cheapest(dart, target)
        winner = "none" if not (i or d) else "implicit" if not d else "dart" if not i else \
            ("implicit" if i[1] < d[1] else "dart")
        out.append({"target": target, "implicit": i, "dart": d, "winner": winner})
    return out


def reading(table: list[dict], skipped: dict, references: dict) -> list[str]:
    """Per scene and error: where the implicit stepper is cheaper than the best DART configuration,
    at what wall time, and where DART is cheaper (nothing here is hard-coded)."""
    lines = [f"{note}" for note in skipped.values()]
    for name, spec in SCENES.items():
        chosen = [r for r in table if r["scene"] == name]
        if not chosen:
            continue
        for r in chosen:
            if r["note"].startswith("run failed") and r["metric"] == spec.metrics[0][0]:
                lines.append(f"{name}: FAILED {r['series']} h = {r['h']:g}: {r['note']}")
        for metric, label in spec.metrics:
            rows_ = [r for r in chosen if r["metric"] == metric and math.isfinite(r["error"])]
            points = {kind: [(max(r["error"], ERROR_FLOOR), r["wall_s"], f"{r['series']}, h = {r['h']:g} s")
                             for r in rows_ if (r["stepper"] == "implicit") == (kind == "implicit")]
                      for kind in ("implicit", "dart")}
            lines.append(_scene_reading(name, metric, points["implicit"], points["dart"], spec.dart))
        if name == "sphere_on_two_spheres" and name in references:
            lines.append(_reference_floor(chosen, references[name]))
    return lines


def _scene_reading(name, metric, implicit, dart, dart_runs: bool) -> str:
    head = f"{name} [{metric}]: "
    if not implicit:
        return head + "no implicit run gave a finite error."
    best_i = min(implicit, key=lambda p: (p[0], p[1]))
    text = head + f"implicit best {_fmt_error(best_i[0])} ({best_i[2]}, {best_i[1]:.3g} s)"
    if not dart:
        return text + ("; no DART configuration gave a finite error." if dart_runs else
                       "; DART has no counterpart (implicit only).")
    best_d = min(dart, key=lambda p: (p[0], p[1]))
    text += f"; DART best {_fmt_error(best_d[0])} ({best_d[2]}, {best_d[1]:.3g} s)."
    intervals = winner_intervals(compare(implicit, dart))
    return text + " " + " ".join(_interval_sentence(iv, k == 0) for k, iv in enumerate(intervals))


def winner_intervals(levels) -> list[dict]:
    """Group compare()'s levels, ascending, into intervals of target errors [low, high) with one
    winner; high is None for the last. Each carries its levels, ascending, and the one at its top
    (the cheapest runs that reach its least demanding target)."""
    ascending = [lv for lv in reversed(levels) if lv["winner"] != "none"]
    out = []
    for k, level in enumerate(ascending):
        if out and out[-1]["winner"] == level["winner"]:
            out[-1]["top"] = level
            out[-1]["levels"].append(level)
        else:
            if out:
                out[-1]["high"] = level["target"]
            out.append({"winner": level["winner"], "low": level["target"], "high": None, "levels": [level],
                        "top": level})
    return out


def _interval_sentence(iv, first: bool) -> str:
    """An implicit interval is read at its least demanding target (from what wall time on the
    implicit stepper wins), a DART interval at its most demanding target that both reach (the
    narrowest margin)."""
    i, d = iv["top"]["implicit"], iv["top"]["dart"]
    if iv["high"] is None:
        span = "every target error reached in this grid" if first else f"target errors from {_fmt_error(iv['low'])} up"
    elif first:
        span = f"target errors below {_fmt_error(iv['high'])}"
    else:
        span = f"target errors from {_fmt_error(iv['low'])} to below {_fmt_error(iv['high'])}"
    if iv["winner"] == "implicit":
        return (f"For {span} the implicit stepper beats every DART configuration: it gets there from "
                f"{i[1]:.3g} s of wall time on ({i[2]}), " + (f"the cheapest DART run that good takes {d[1]:.3g} s "
                                                             f"({d[2]}, {d[1] / i[1]:.2g}x)." if d else
                                                             "no DART run gets there."))
    both = [lv for lv in iv["levels"] if lv["implicit"] and lv["dart"]]
    if not both:
        return f"For {span} DART is cheaper: no implicit run gets there."
    level = both[0]
    i, d = level["implicit"], level["dart"]
    return (f"For {span} DART is cheaper; at {_fmt_error(level['target'])} it takes {d[1]:.3g} s ({d[2]}) "
            f"against {i[1]:.3g} s for the implicit stepper ({i[2]}, {i[1] / d[1]:.2g}x).")


def _fmt_error(value: float) -> str:
    return f"<= {ERROR_FLOOR:.0e} (round-off)" if value <= ERROR_FLOOR else f"{value:.3g}"


def _reference_floor(chosen, reference: RunRecord) -> str:
    if not reference.ok:
        return (f"sphere_on_two_spheres: the reference run (implicit, h = {reference.config.h:g} s) failed, so "
                f"no errors: {reference.note}")
    finest = min((r for r in chosen if r["stepper"] == "implicit" and r["metric"] == "v_rms"
                  and math.isfinite(r["error"])), key=lambda r: r["h"], default=None)
    text = (f"sphere_on_two_spheres: reference = implicit run of order {reference.config.order} at h = {reference.config.h:g} s "
            f"(events: " + ", ".join(f"{k} {v:.4f} s" for k, v in reference.events.items()) + ")")
    if finest:
        floor = finest["error"] * reference.config.h / finest["h"]
        text += (f"; its velocities are first order near the events, so v_rms errors below ~{floor:.1g} (the h = {finest['h']:g} s "
                 "error scaled to the reference's h) are not resolved. DART's errors include the model "
                 "difference (no torsional friction, box friction cone), not only its discretisation")
    return text + "."


# ----------------------------------------------------------------------------------------------
# figures
# ----------------------------------------------------------------------------------------------
def plot_scene(name: str, table: list[dict], path: Path, reference_note: str = "") -> None:
    """Error against wall time (log-log), one panel per error, one line per series over h."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    spec = SCENES[name]
    chosen = [r for r in table if r["scene"] == name]
    series = sorted({r["series"] for r in chosen}, key=_series_order)
    dart_series = [s for s in series if s.startswith("DART")]
    colours = dict(zip(dart_series, plt.get_cmap("tab10")(np.arange(len(dart_series)) % 10)))
    fig, axes = plt.subplots(1, len(spec.metrics), figsize=(6.2 * len(spec.metrics), 4.8), squeeze=False,
                             layout="constrained")
    for ax, (metric, label) in zip(axes[0], spec.metrics):
        for s in series:
            pts = sorted(((r["h"], r["wall_s"], max(r["error"], ERROR_FLOOR)) for r in chosen
                          if r["series"] == s and r["metric"] == metric and math.isfinite(r["error"])),
                         reverse=True)
            if not pts:
                continue
            h, wall, err = map(np.array, zip(*pts))
            if s.startswith("implicit"):
                style = dict(color="black", marker="o", lw=2.0, ls="-" if s == "implicit" else "--", zorder=3)
            else:
                style = dict(color=colours[s], marker="s" if "FCL" in s else "^", lw=1.0, ms=4,
                             ls="-" if "FCL" in s else ":")
            ax.plot(wall, err, label=s, **style)
            for k in (0, len(h) - 1) if len(h) > 1 else (0,):
                ax.annotate(f"{h[k]:g}", (wall[k], err[k]), textcoords="offset points", xytext=(3, 3),
                            fontsize=6, color=style["color"])
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time to simulate the run [s] (time in step() only)")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3, which="both")
        if any(r["error"] <= 100 * ERROR_FLOOR for r in chosen if r["metric"] == metric):
            ax.axhline(ERROR_FLOOR, color="0.6", lw=0.8, ls=":")
            ax.text(ax.get_xlim()[0], ERROR_FLOOR, f" round-off: errors < {ERROR_FLOOR:.0e} drawn at it",
                    fontsize=6, color="0.4", va="bottom")
    horizon = chosen[0]["duration_s"] if chosen else math.nan
    fig.suptitle(f"{spec.question}\nhorizon {horizon:g} s; reference: {spec.reference}{reference_note}; "
                 "point labels: largest and smallest h [s]", fontsize=9)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=4, fontsize=7)
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ----------------------------------------------------------------------------------------------
# the study
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class StudyResult:
    table: list = field(default_factory=list)
    records: dict = field(default_factory=dict)
    references: dict = field(default_factory=dict)
    paths: dict = field(default_factory=dict)
    reading: list = field(default_factory=list)
    skipped: dict = field(default_factory=dict)
    seconds: float = 0.0


def study(plans=DEFAULT_PLANS, out: Path | str = DEFAULT_OUT, scheduler: str | None = None,
          max_workers: int | None = None, progress: bool = True, refresh_reference: bool = False) -> StudyResult:
    """Run the plans (scenes whose module is missing are skipped with a note), write
    work_precision.csv and one work_precision_<scene>.png into out, return everything."""
    start = time.perf_counter()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    skipped, chosen = {}, []
    for p in plans:
        available, why = scene_available(p.scene)
        if available:
            chosen.append(p)
        else:
            skipped[p.scene] = why
    configs = plan(chosen)
    references = {}
    for config in configs:
        if config.stepper == "reference" and not refresh_reference:
            cached = load_reference(config, out)
            if cached is not None:
                references[config.scene] = cached
    todo = [c for c in configs if not (c.stepper == "reference" and c.scene in references)]
    records = execute(todo, scheduler=scheduler, max_workers=max_workers, progress=progress)
    for config, record in records.items():
        if config.stepper == "reference":
            references[config.scene] = record
            if record.ok:
                save_reference(record, out)
    table = rows({c: r for c, r in records.items() if c.stepper != "reference"}, references)
    paths = {"csv": out / "work_precision.csv"}
    write_csv(table, paths["csv"])
    for p in chosen:
        if any(r["scene"] == p.scene and math.isfinite(r["error"]) for r in table):
            paths[p.scene] = out / f"work_precision_{p.scene}.png"
            note = f", h = {references[p.scene].config.h:g} s" if p.scene in references else ""
            plot_scene(p.scene, table, paths[p.scene], note)
    return StudyResult(table, records, references, paths, reading(table, skipped, references), skipped,
                       time.perf_counter() - start)


def parse_args(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="smoke run: two h per stepper, FCL only, coarse reference")
    parser.add_argument("--scenes", default=",".join(SCENES), help=f"comma-separated subset of {','.join(SCENES)}")
    parser.add_argument("--workers", type=int, default=None,
                        help="local processes (default: os.cpu_count(); 0 = run in this process)")
    parser.add_argument("--scheduler", default=None, help="Dask scheduler address, e.g. tcp://host:8786")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help=f"output directory (default: {DEFAULT_OUT})")
    parser.add_argument("--refresh-reference", action="store_true", help="recompute cached references")
    args = parser.parse_args(argv)
    wanted = [s.strip() for s in args.scenes.split(",") if s.strip()]
    unknown = [s for s in wanted if s not in SCENES]
    if unknown or not wanted:
        parser.error(f"--scenes must be a non-empty subset of {','.join(SCENES)}, got {args.scenes!r}")
    plans = tuple(p for p in (QUICK_PLANS if args.quick else DEFAULT_PLANS) if p.scene in wanted)
    return args, plans


def main(argv=None) -> StudyResult:
    args, plans = parse_args(argv)
    result = study(plans, args.out, scheduler=args.scheduler, max_workers=args.workers,
                   refresh_reference=args.refresh_reference)
    print(format_table(result.table, result.references))
    print("\nReading:")
    for line in result.reading:
        print(f"  * {line}")
    print("\nwrote " + ", ".join(str(p) for p in result.paths.values()))
    print(f"total wall time {result.seconds:.1f} s")
    return result


if __name__ == "__main__":
    # Run the imported module rather than __main__, so that pickled configs and `run` are named
    # comparisons.work_precision, which pool and Dask workers can import.
    from comparisons.work_precision import main as _main

    raise SystemExit(1 if any(r["note"].startswith("run failed") for r in _main().table) else 0)
