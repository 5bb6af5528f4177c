r"""Coulomb friction of a planar body against the surface it lies on (the 2.5D support).

A planar body (PlanarJoint in XY, v = [v_x, v_y, omega]) that rests on a horizontal support
under its weight N slides on it with Coulomb friction. The support's friction wrench on the body,
(p_x, p_y) at a centre of pressure c and a moment tau about it, is bounded by the support's limit
surface, which this module approximates by an ellipsoid (Goyal, Ruina & Papadopoulos' limit
surface; Howe & Cutkosky's ellipsoidal fit), the same law as [GI]'s friction with torsion (eq 7):

    (p_x^2 + p_y^2) / (mu P)^2 + tau^2 / (e_r mu P)^2 <= 1,      P = N h  (impulses of one step)

with e_r the torsion radius: mu N e_r is the largest friction moment about c. For pressure
shared equally by support points s_i the ellipsoid is exact for pure translation (mu N) and for
pure spin about their centroid c (mu N mean |s_i - c|), which is how ``e_r`` is chosen from
points; a uniform disc of radius R has mu N (2/3) R, i.e. e_r = 2R/3.

Maximum dissipation at l+1 ([GI] eq 21-22 with a known normal impulse). Scaled unknowns
y = (p_x, p_y, tau / e_r) / (mu P) (dimensionless, in the unit ball) and sigma >= 0:

    u + sigma y_xy = 0              u = v_xy + omega x r      (velocity of c at l+1)
    e_r omega + sigma y_3 = 0       (dropped, with y_3, when e_r = 0: a point support)
    0 <= sigma  _|_  1 - |y|^2 >= 0

r = R(theta^l) c is the lever arm of c at the start of the step (friction only dissipates: a
start-of-step lever arm keeps these rows linear in v). Sticking: sigma = 0 and u = 0, omega = 0,
y inside the ball; sliding: |y| = 1 and y opposes (u, e_r omega). The body's Newton-Euler rows
receive the generalized impulse mu P (y_x, y_y, e_r y_3 + r x (y_x, y_y)).

Rows are in velocity units (the Newton-Euler rows are scaled by the problem), sigma's row is
unit-free; their kernel is rows/support.py. tests/test_support.py checks the Jacobian by
differences and the motion against closed forms (deceleration mu g, spin-down mu N e_r / I,
static hold below mu N).
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np


@dataclass(frozen=True)
class SupportFriction:
    """Support friction of one planar body: coefficient mu, total normal force [N], centre of
    pressure (body frame, 2,) and torsion radius e_r [m] (see the module docstring)."""
    mu: float
    normal_force: float
    centre: tuple = (0.0, 0.0)
    e_r: float = 0.0

    def __post_init__(self):
        if not (math.isfinite(self.mu) and self.mu >= 0.0):
            raise ValueError(f"support friction mu must be finite and >= 0, got {self.mu}")
        if not (math.isfinite(self.normal_force) and self.normal_force > 0.0):
            raise ValueError(f"the support's normal force must be finite and > 0 [N], got {self.normal_force}")
        c = np.asarray(self.centre, float)
        if c.shape != (2,) or not np.all(np.isfinite(c)):
            raise ValueError(f"the centre of pressure must be a finite (x, y), got {self.centre}")
        if not (math.isfinite(self.e_r) and self.e_r >= 0.0):
            raise ValueError(f"the torsion radius e_r must be finite and >= 0 [m], got {self.e_r}")

    @classmethod
    def from_points(cls, mu, normal_force, points, torsion_radius=None) -> "SupportFriction":
        """Pressure shared equally by body-frame support points (k, 2): centre = their centroid,
        e_r = their mean distance from it (unless torsion_radius is given)."""
        pts = np.asarray(points, float)
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0 or not np.all(np.isfinite(pts)):
            raise ValueError(f"support points must be a finite (k, 2) array with k >= 1, got {points!r}")
        c = pts.mean(axis=0)
        e_r = float(np.mean(np.linalg.norm(pts - c, axis=1))) if torsion_radius is None else float(torsion_radius)
        return cls(float(mu), float(normal_force), (float(c[0]), float(c[1])), e_r)

    @property
    def torsion(self) -> bool:
        return self.e_r > 0.0


@dataclass
class SupportSpec:
    """A support block of a step: the body (index into the problem's bodies) and its friction."""
    body: int
    friction: SupportFriction
    key: object = None         # the stepper's body index (warm starts)


@dataclass
class SupportSlots:
    """Columns (= rows) of one support block in z: y (2 or 3, free), then sigma (>= 0)."""
    y: slice
    sigma: int

    @property
    def rows(self) -> slice:
        return slice(self.y.start, self.sigma + 1)


def allocate(col: int, supports: list, lower: list, upper: list):
    """Append the support blocks' unknowns at column col; returns (slots, next column)."""
    slots = []
    for sp in supports:
        ny = 3 if sp.friction.torsion else 2
        slots.append(SupportSlots(slice(col, col + ny), col + ny))
        lower += [-math.inf] * ny + [0.0]
        upper += [math.inf] * (ny + 1)
        col += ny + 1
    return slots, col
