"""A plain record of a simulation, shared by scenes, tests and comparisons.

``simulate(world, stepper, duration)`` steps any stepper with a ``step()`` method (the implicit
stepper or ``comparisons.dart_native.DartNative``) and records the same quantities for both, so
one metric function serves every comparison.
"""
from __future__ import annotations

from dataclasses import dataclass, field
import time

import numpy as np


@dataclass
class Trajectory:
    """Per recorded instant: time, q and v of every mobile skeleton, kinetic energy, and per step
    the stepper's report (contacts, iterations, residual) and wall time."""
    times: list = field(default_factory=list)
    q: list = field(default_factory=list)
    v: list = field(default_factory=list)
    kinetic: list = field(default_factory=list)
    reports: list = field(default_factory=list)
    wall: list = field(default_factory=list)

    def arrays(self):
        return (np.asarray(self.times), np.asarray(self.q), np.asarray(self.v),
                np.asarray(self.kinetic))

    @property
    def iterations(self) -> np.ndarray:
        return np.array([getattr(r, "iterations", 0) for r in self.reports])

    @property
    def step_seconds(self) -> np.ndarray:
        return np.asarray(self.wall)


def kinetic_energy(world) -> float:
    total = 0.0
    for s in range(world.getNumSkeletons()):
        sk = world.getSkeleton(s)
        if sk.getNumDofs() == 0:
            continue
        v = np.asarray(sk.getVelocities(), float)
        total += 0.5 * float(v @ np.asarray(sk.getMassMatrix(), float) @ v)
    return total


def _record_state(world, traj: Trajectory) -> None:
    qs, vs = [], []
    for s in range(world.getNumSkeletons()):
        sk = world.getSkeleton(s)
        if sk.getNumDofs() == 0:
            continue
        qs.append(np.asarray(sk.getPositions(), float))
        vs.append(np.asarray(sk.getVelocities(), float))
    traj.times.append(world.getTime())
    traj.q.append(np.concatenate(qs) if qs else np.zeros(0))
    traj.v.append(np.concatenate(vs) if vs else np.zeros(0))
    traj.kinetic.append(kinetic_energy(world))


def simulate(world, stepper, duration: float, before_step=None) -> Trajectory:
    """Step ``stepper`` until ``duration`` seconds have passed; record every step.

    before_step(world, t): optional hook to apply forces (DART clears them after each step)."""
    h = world.getTimeStep()
    n = int(round(duration / h))
    traj = Trajectory()
    _record_state(world, traj)
    for _ in range(n):
        if before_step is not None:
            before_step(world, world.getTime())
        t0 = time.perf_counter()
        report = stepper.step()
        traj.wall.append(time.perf_counter() - t0)
        traj.reports.append(report)
        _record_state(world, traj)
    return traj
