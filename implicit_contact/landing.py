r"""A predictor for faces landing on faces: where the equivalent contact point and the impulse go.

A box slapping flat onto the ground (or a box onto a box) is the hard case of [GI]'s step: at
the end of the step the two faces coincide, the pair's closest points may be anywhere on the
patch, and only the Newton-Euler rows fix the equivalent contact point (ECP, Xie & Chakraborty,
SIMPAR 2016) where the patch's pressure resultant must act to stop the face's rotation. From a
warm start with p_n = 0 the moment rows do not depend on the contact point at all (r x P with
P = 0), and Newton wanders: measured on 20 random boxes resting flat and started downwards at
2-7 m/s with spin, 6 first steps failed after 6 solves of 50 iterations, at every h tried.

The predictor solves the landing with the patch's vertices instead of one point: the overlap
polygon of the two faces (patch.py, with a band wide enough for the step's rotation) gives
points x_i on the contact plane with the pair's normal n, and a velocity-level, inelastic,
frictionless LCP for their normal impulses lambda_i (Stewart & Trinkle's time-stepping with a
gap term),

    0 <= lambda  _|_  W lambda + b >= 0,     W = J M^-1 J^T,   b = J v_free + gap / h,

J_i = n . (velocity of body 2 at x_i - velocity of body 1 at x_i) over the step's velocity
unknowns, v_free = v + h M^-1 f each skeleton's free step. It is solved by projected
Gauss-Seidel (W is singular for four coplanar points; the resultant is unique where the
lambda_i are not). The resultant gives the ECP and normal impulse a warm start needs:

    P = sum lambda_i,   x_ECP = sum lambda_i x_i / P,   v+ = v_free + M^-1 J^T lambda,

and the ECP moved with body 2 to the end of the step. recovery.face_landing starts the step's
MCP from it (with these velocities and impulses and the closest points there): measured on the
same 6 failed first steps, the MCP then converges in 1-2 iterations.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from . import patch as contact_patch
from ._jit import lean_kernel

PGS_SWEEPS = 2000       # projected Gauss-Seidel sweeps at most
PGS_TOL = 1e-12         # stop when no lambda_i changes by more than this (relative to max lambda)


@dataclass
class Landing:
    """The prediction for one pair: normal impulse P [N s], ECP x (world, on the contact plane at
    l) and x_end (moved with body 2 to l+1), friction impulse (p_t, p_o) [N s] along the pair's
    tangents and its moment m_r [N m s] about the normal at the ECP, and the relative slip
    velocity (v_t, v_o) and spin w_n there at l+1."""
    P: float
    x: np.ndarray
    x_end: np.ndarray
    p_to: np.ndarray
    m_r: float
    slip: np.ndarray
    spin: float


def predict(problem, pairs, h, friction=False):
    """The landing prediction of the given pairs of a StepProblem (indices whose both pieces are
    faceted, 3D), frictionless or with each pair's Coulomb disc at every patch vertex:
    (velocities per skeleton index (only those the pairs move), per pair k its Landing or None
    when it has no patch or no impulse)."""
    blocks, lay = problem.skeletons, problem.layout
    v_free, m_inv = {}, {}
    for s, blk in enumerate(blocks):
        m_inv[s] = np.linalg.inv(blk.M)
        v_free[s] = blk.v + h * (m_inv[s] @ blk.force)
    skeleton_of = {}
    for s, vidx in enumerate(lay.v_index):
        for c in vidx:
            skeleton_of[int(c)] = s
    rows, rhs, owner, points, mus = [], [], [], [], []
    frames = {}
    for k in pairs:
        found = _pair_points(problem, k, h, v_free, skeleton_of)
        if found is None:
            continue
        X, n, gap = found
        t, o = problem._pairs_at[k][3]
        frames[k] = (n, t / np.linalg.norm(t), o / np.linalg.norm(o))
        mu = problem.specs[k].friction.mu if friction else 0.0
        for x in X:
            for axis, direction in enumerate(frames[k]):
                row = {}
                for sign, ob in ((-1.0, problem.specs[k].obj1), (1.0, problem.specs[k].obj2)):
                    kin = problem.bodies[ob.body]
                    if kin.vindex is not None:
                        s = skeleton_of[int(kin.vindex[0])]
                        row[s] = row.get(s, 0.0) + sign * _point_row(kin, x, direction)
                rows.append(row)
                rhs.append(sum(g @ v_free[s] for s, g in row.items()) + (gap / h if axis == 0 else 0.0))
            owner.append(k)
            points.append(x)
            mus.append(mu)
    if not rows:
        return {}, {}
    m = len(rows)
    W = np.zeros((m, m))
    for i in range(m):
        for j in range(i, m):
            W[i, j] = W[j, i] = sum(rows[i][s] @ m_inv[s] @ rows[j][s] for s in rows[i] if s in rows[j])
    lam = np.zeros(m)
    pgs(W, np.asarray(rhs), np.asarray(mus), lam, PGS_SWEEPS, PGS_TOL)
    moved = {}
    for i, row in enumerate(rows):
        for s, g in row.items():
            moved[s] = moved.get(s, 0.0) + lam[i] * (m_inv[s] @ g)
    velocities = {s: v_free[s] + dv for s, dv in moved.items()}
    results = {k: None for k in pairs}
    for k in frames:
        idx = [i for i in range(len(points)) if owner[i] == k]
        L = lam.reshape(-1, 3)[idx]
        X = np.array([points[i] for i in idx])
        P = float(L[:, 0].sum())
        if not P > 0.0:
            continue
        n, t, o = frames[k]
        x = L[:, 0] @ X / P
        F = L[:, 1:2] * t + L[:, 2:3] * o
        m_r = float(sum(np.cross(X[i] - x, F[i]) @ n for i in range(len(idx))))
        spec = problem.specs[k]
        twists = []
        for ob in (spec.obj1, spec.obj2):
            kin = problem.bodies[ob.body]
            v = velocities.get(skeleton_of[int(kin.vindex[0])]) if kin.vindex is not None else None
            twists.append((kin, v))
        u = [np.zeros(3) if v is None else _point_velocity(kin, v, x) for kin, v in twists]
        w = [np.zeros(3) if v is None else _twist(kin, v)[0] for kin, v in twists]
        kin2, v2 = twists[1] if twists[1][1] is not None else twists[0]
        x_end = x if v2 is None else x + h * _point_velocity(kin2, v2, x)
        rel = u[1] - u[0]
        results[k] = Landing(P, x, x_end, L[:, 1:].sum(axis=0), m_r, np.array([rel @ t, rel @ o]),
                             float((w[1] - w[0]) @ n))
    return velocities, results


def _pair_points(problem, k, h, v_free, skeleton_of):
    """(points (m, 3) of the faces' overlap on the contact plane at l, the unit normal n from
    body 1 into body 2, the gap between the faces along n) of pair k, or None without a patch."""
    spec = problem.specs[k]
    first, second = spec.objects
    a1, a2, n, _, _, _ = problem._pairs_at[k]
    n = n / np.linalg.norm(n)
    kins = [problem.bodies[o.body] for o in (spec.obj1, spec.obj2)]
    band = contact_patch.band(first.piece, second.piece)   # and how far the step's rotation tilts a face
    for o, kin in zip((first, second), kins):
        if kin.vindex is not None and o.radius is not None:
            v = v_free[skeleton_of[int(kin.vindex[0])]]
            band += h * float(np.linalg.norm(_twist(kin, v)[0])) * o.radius
    (R1, p1), (R2, p2) = [(kin.R0, kin.p0) for kin in kins]
    X = patch_points(first, second, (R1, p1), (R2, p2), n, band)
    if len(X) == 0:
        return None
    gap = _support(second, R2, p2, -n) * -1.0 - _support(first, R1, p1, n)
    return X, n, gap


def patch_points(first, second, pose1, pose2, n, band) -> np.ndarray:
    """The vertices (m, 3) of the overlap of two faceted pieces' faces (the stepper's objects, at
    poses (R, p)) on the contact plane of unit normal n (patch.overlap_polygon); m = 0 without one."""
    A, B, C, _ = contact_patch.workspace(first.face, second.face)
    origin = np.zeros(3)
    m = contact_patch.overlap_polygon(first.face, first.face_half, *pose1, second.face, second.face_half, *pose2,
                                      n, band, A, B, C, origin)
    t, o = contact_patch.plane_basis(n)
    return origin + C[:m, :1] * t + C[:m, 1:2] * o


def _support(obj, R, p, u) -> float:
    """max u . x over the piece's face points at pose (R, p); a half-space: its plane's offset."""
    if obj.face_half:
        normal, offset = obj.piece.plane()
        return float(offset + (R @ normal) @ p)
    return float(np.max((obj.face @ R.T + p) @ u))


def _twist(kin, v):
    """(omega, v_origin) of a 3D body for its skeleton's velocities v: DART's [omega; v_o] of a
    FreeJoint body, the world Jacobian times v for a link."""
    if kin.jacobian is not None:
        tw = kin.jacobian @ v
        return tw[:3], tw[3:]
    return v[:3], v[3:6]


def _point_velocity(kin, v, x):
    w, vo = _twist(kin, v)
    return vo + np.cross(w, x - kin.p0)


def _point_row(kin, x, n):
    """d (n . velocity of the body's point x) / d v over its skeleton's velocities."""
    r = x - kin.p0
    rn = np.cross(r, n)
    if kin.jacobian is not None:
        return n @ kin.jacobian[3:] + rn @ kin.jacobian[:3]
    return np.r_[rn, n]


@lean_kernel
def pgs(W, b, mu, lam, sweeps, tol):
    """Projected Gauss-Seidel on the contact points' impulses lam = (n, t, o) per point: the
    normal one in 0 <= lam_n _|_ (W lam + b)_n >= 0, the friction one (t, o) solved for
    (W lam + b)_(t, o) = 0 and projected onto the disc of radius mu lam_n (W symmetric positive
    semidefinite with a positive diagonal); returns the sweeps used."""
    m = mu.shape[0]
    for sweep in range(sweeps):
        change, top = 0.0, 0.0
        for p in range(m):
            for a in range(3):
                i = 3 * p + a
                r = b[i]
                for j in range(3 * m):
                    r += W[i, j] * lam[j]
                new = lam[i] - r / W[i, i]
                if a == 0:
                    new = max(0.0, new)
                change = max(change, abs(new - lam[i]))
                lam[i] = new
            cap = mu[p] * lam[3 * p]
            ft = math.hypot(lam[3 * p + 1], lam[3 * p + 2])
            if ft > cap:
                scale = cap / ft
                lam[3 * p + 1] *= scale
                lam[3 * p + 2] *= scale
            top = max(top, lam[3 * p])
        if change <= tol * max(top, 1e-300):
            return sweep + 1
    return sweeps


def faceted_pair(spec) -> bool:
    """Whether a pair is 3D and both its pieces (the stepper's records) have flat faces."""
    return spec.dim == 3 and len(spec.objects) == 2 and all(getattr(o, "faceted", False) for o in spec.objects)


def faceted_pairs(problem) -> list:
    """Indices of the pairs of a StepProblem that are faceted_pair."""
    return [k for k, spec in enumerate(problem.specs) if faceted_pair(spec)]


def separated_face_seed(first, second, now, pred, normal, band):
    """Closest points to seed a separated pair of faceted pieces whose faces are parallel (within
    band) at l: the static closest points are then a whole face and the solver returns any of
    them, while at l+1 the faces tilt and the closest point is the point of the faces' overlap
    that the free step brings nearest (a cylinder hovering 20 um above the ground on its cap,
    tilting at 0.2 rad/s: its rim). now, pred: the two pieces' poses (R, p) at l and after the
    free step; normal from piece 1 into piece 2. The candidates are the vertices of the overlap
    of the two faces (patch_points), each on piece 1's face (a1) and on piece 2's (a2); a vertex
    of either face alone may lie off the other piece (a small prism above a large ground box: the
    box's corner 2 m away). Returns (a1, a2) at l, or None when the faces are not parallel (a
    vertex or an edge is then the unique closest point) or do not overlap."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    X = patch_points(first, second, now[0], now[1], n, band)
    if len(X) < 2:
        return None
    top, bottom = _support(first, *now[0], n), -_support(second, *now[1], -n)
    A1 = X - (X @ n - top)[:, None] * n
    A2 = X - (X @ n - bottom)[:, None] * n
    (R1, p1), (R1p, p1p) = now[0], pred[0]
    (R2, p2), (R2p, p2p) = now[1], pred[1]
    ahead = ((A2 - p2) @ R2 @ R2p.T + p2p) @ n - ((A1 - p1) @ R1 @ R1p.T + p1p) @ n
    k = int(np.argmin(ahead))                             # the overlap point that comes nearest
    return A1[k], A2[k]


def vertex_depth(first, second, pose1, pose2) -> float:
    """How deep the deepest face point of either piece lies inside the other at the given poses
    (Pose or (R, p)); 0 if none is inside. Face points are surface points (polytope vertices,
    cylinder rim samples), so a positive depth is an overlap, never an artefact; it is not the
    penetration depth (crossing edges are not seen). The stepper refuses a solution with a
    depth beyond its contact tolerance (ImplicitContactStepper._check_solution): Newton on a
    face landing can converge to a root of the rows whose closest points sit on the far sides
    of the two pieces, a body 17 cm through the ground reported as touching."""
    poses = [(P.R, P.p) if hasattr(P, "R") else P for P in (pose1, pose2)]
    depth = 0.0
    for (obj, (R, p)), (other, (Ro, po)) in (((first, poses[0]), (second, poses[1])),
                                              ((second, poses[1]), (first, poses[0]))):
        if obj.face_half:
            continue
        X = (obj.face @ R.T + p - po) @ Ro                 # its face points in the other's frame
        values = np.max(np.stack([f.value(X) for f in other.piece.functions]), axis=0)
        depth = max(depth, float(-np.min(values)))
    return depth
