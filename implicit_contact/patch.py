r"""The contact patch of two convex pieces pressed together along a normal, and its torsion radius.

A box resting on a face touches the ground along the whole face. [GI] keeps one contact point per
pair of convex pieces; on a face the step's Newton-Euler rows put it at the equivalent contact
point (ECP) of Xie & Chakraborty (SIMPAR 2016), the point inside the patch where the patch's
pressure is equivalent to a force along the normal and a moment about it alone. The friction of
the patch is a wrench at that point: a force in the tangent plane and a moment about the normal.
Its limit surface is approximated by [GI]'s ellipsoid (eq 7), whose torsion semi-axis e_r is a
length: mu N e_r is the largest friction moment of the patch. For pressure spread uniformly over
the patch, pure spin about its centroid c gives the moment

    M = mu (N / A) \int_patch |x - c| dA,     so   e_r = (1 / A) \int_patch |x - c| dA,

the rule support.py uses for a planar body's support points (Howe & Cutkosky's ellipsoidal
limit surface). Closed forms it reproduces (tests/test_patch.py): a square of side a,
e_r = a (sqrt 2 + ln(1 + sqrt 2)) / 6; a disc of radius R, 2 R / 3 (its 64-gon: 0.08 % less);
a segment of length L (a cylinder on its side, a box on an edge), L / 4; a point, 0.

The patch is the overlap, in the plane normal to n, of the two pieces' faces along n: the part of
each boundary within ``band`` of its support plane. A piece's face is spanned by its face points
(shapes' ``face_points``: a polytope's vertices, a capped cylinder's rim circles sampled) that lie
within band of the highest of them along n; a half-space's face is its whole plane; a curved
function touches in one point and has no patch (``faceted`` is False: no torsion from a patch).
Both faces are convex, so the overlap is the intersection of two convex polygons, either of which
may be a segment or a point. It is taken from the start-of-step geometry (like the tangent basis
and the support rows of support.py): friction only dissipates, whatever the e_r.

The kernels below run once per touching faceted pair and step (stepper._patch_radius); their
work arrays come from ``workspace``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ._jit import kernel

PATCH_BAND = 1e-3      # a face: the boundary within PATCH_BAND x (the pieces' size) of its plane
DEGENERATE = 1e-9      # relative area (length) below which a patch is a segment (a point)
K_POINT, K_SEGMENT, K_AREA = 0, 1, 2
KINDS = ("point", "segment", "area")


@dataclass(frozen=True)
class Patch:
    """A contact patch in the plane normal to n: kind ("point", "segment", "area"), area [m^2],
    centroid (world, 3,) and torsion radius e_r [m] (the module docstring)."""
    kind: str
    area: float
    centroid: np.ndarray
    e_r: float


def faceted(piece) -> bool:
    """Whether a piece has flat faces, so that its patch against another can be a segment or an
    area (a polytope, a capped cylinder, a half-space)."""
    pts = piece.face_points()
    return pts is None or len(pts) > 0


def band(piece1, piece2) -> float:
    """The face band of two pieces: PATCH_BAND times the smaller one's size [m]."""
    return PATCH_BAND * min(piece1.length_scale, piece2.length_scale)


def workspace(V1, V2) -> tuple:
    """Work arrays of patch_kernel for pieces with face points V1, V2 (None: a half-space)."""
    m = max(1 if V1 is None else len(V1), 1 if V2 is None else len(V2))
    return np.zeros((2 * m + 8, 2)), np.zeros((2 * m + 8, 2)), np.zeros((2 * m + 8, 2)), np.zeros(4)


def patch(piece1, pose1, piece2, pose2, normal, band) -> Patch | None:
    """The Patch of two pieces at poses (R, p) pressed along the unit normal n (from piece 1 into
    piece 2); None when either piece is not faceted or both are half-spaces."""
    V1, V2 = piece1.face_points(), piece2.face_points()
    if (V1 is not None and len(V1) == 0) or (V2 is not None and len(V2) == 0) or (V1 is None and V2 is None):
        return None
    n = np.asarray(normal, float)
    n = n / np.linalg.norm(n)
    W = workspace(V1, V2)
    args = [(np.zeros((1, 3)), True) if V is None else (np.asarray(V, float), False) for V in (V1, V2)]
    (R1, p1), (R2, p2) = pose1, pose2
    e_r = patch_kernel(args[0][0], args[0][1], np.asarray(R1, float), np.asarray(p1, float), args[1][0],
                       args[1][1], np.asarray(R2, float), np.asarray(p2, float), n, float(band), *W)
    out = W[3]
    t, o = plane_basis(n)
    anchor = _anchor(args, (pose1, pose2), n, band)
    centroid = anchor + out[2] * t + out[3] * o
    return Patch(KINDS[int(out[0])], float(out[1]), centroid, float(e_r))


def _anchor(args, poses, n, band):
    """The world origin the kernel measured the patch's plane coordinates from."""
    V, unbounded = args[0] if not args[0][1] else args[1]
    R, p = poses[0] if not args[0][1] else poses[1]
    W = V @ np.asarray(R, float).T + p
    sign = 1.0 if not args[0][1] else -1.0
    heights = sign * (W @ n)
    return W[int(np.flatnonzero(heights >= heights.max() - band)[0])]


@kernel
def plane_basis(n):
    """Unit tangents (t, o) of the plane normal to the unit n, t from the least aligned axis."""
    a = np.zeros(3)
    k = 0
    for i in range(3):
        if abs(n[i]) < abs(n[k]):
            k = i
    a[k] = 1.0
    t = np.cross(n, a)
    t /= np.linalg.norm(t)
    return t, np.cross(n, t)


@kernel
def patch_kernel(V1, half1, R1, p1, V2, half2, R2, p2, n, band, A, B, C, out):
    """e_r of the patch of two pieces (face points V (k, 3) in their body frames, or half=True for
    a half-space) at poses (R, p) along the unit normal n from piece 1 into piece 2. out: (kind,
    area, centroid's plane coordinates) about the first face point of a bounded piece on its
    face; A, B, C: work arrays (workspace)."""
    origin = np.zeros(3)
    m = overlap_polygon(V1, half1, R1, p1, V2, half2, R2, p2, n, band, A, B, C, origin)
    return moments(C, m, out)


@kernel
def overlap_polygon(V1, half1, R1, p1, V2, half2, R2, p2, n, band, A, B, C, origin):
    """The overlap of the two pieces' faces (patch_kernel's arguments) into C[:m], counter-
    clockwise in the coordinates (t, o) of plane_basis(n) about origin (set to the first face
    point of a bounded piece on its face); returns m."""
    t, o = plane_basis(n)
    found = False
    na = 0
    nb = 0
    if not half1:
        na = _face2(V1, R1, p1, n, 1.0, band, t, o, origin, found, A)
        found = True
    if not half2:
        nb = _face2(V2, R2, p2, n, -1.0, band, t, o, origin, found, B)
        found = True
    if half1:
        return hull2(B, nb, C)
    if half2:
        return hull2(A, na, C)
    na = hull2(A, na, C)
    A[:na] = C[:na]
    nb = hull2(B, nb, C)
    B[:nb] = C[:nb]
    return overlap(A, na, B, nb, C)


@kernel
def _face2(V, R, p, n, sign, band, t, o, origin, have_origin, out):
    """Plane coordinates (about origin) of the world face points within band of the highest along
    sign n; sets origin to the first of them unless have_origin. Returns their count."""
    k = V.shape[0]
    hmax = -np.inf
    for i in range(k):
        h = 0.0
        for a in range(3):
            w = p[a] + R[a, 0] * V[i, 0] + R[a, 1] * V[i, 1] + R[a, 2] * V[i, 2]
            h += sign * n[a] * w
        hmax = max(hmax, h)
    m = 0
    for i in range(k):
        w = np.empty(3)
        h = 0.0
        for a in range(3):
            w[a] = p[a] + R[a, 0] * V[i, 0] + R[a, 1] * V[i, 1] + R[a, 2] * V[i, 2]
            h += sign * n[a] * w[a]
        if h < hmax - band:
            continue
        if not have_origin and m == 0:
            origin[:] = w
        d = w - origin
        out[m, 0] = d @ t
        out[m, 1] = d @ o
        m += 1
    return m


@kernel
def _cross(ax, ay, bx, by, cx, cy):
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@kernel
def hull2(P, k, out):
    """Counter-clockwise convex hull of the first k 2D points of P into out (Andrew's monotone
    chain, collinear and repeated points dropped: a segment is its 2 ends, a point 1 point);
    P's first k rows are sorted in place. Returns the hull's count."""
    for i in range(1, k):                          # insertion sort by (x, y): k is small
        x, y = P[i, 0], P[i, 1]
        j = i - 1
        while j >= 0 and (P[j, 0] > x or (P[j, 0] == x and P[j, 1] > y)):
            P[j + 1] = P[j]
            j -= 1
        P[j + 1, 0], P[j + 1, 1] = x, y
    if k == 0:
        return 0
    m = 0
    for i in range(k):                             # lower chain
        while m >= 2 and _cross(out[m - 2, 0], out[m - 2, 1], out[m - 1, 0], out[m - 1, 1], P[i, 0], P[i, 1]) <= 0.0:
            m -= 1
        out[m] = P[i]
        m += 1
    lower = m
    for i in range(k - 2, -1, -1):                 # upper chain
        while m > lower and _cross(out[m - 2, 0], out[m - 2, 1], out[m - 1, 0], out[m - 1, 1], P[i, 0], P[i, 1]) <= 0.0:
            m -= 1
        out[m] = P[i]
        m += 1
    return max(m - 1, 1)                           # (the first point closed the chain)


@kernel
def overlap(A, na, B, nb, out):
    """The intersection of two convex 2D sets given as counter-clockwise hulls (polygons,
    segments or points) into out: the one with fewer points clipped by each edge of the other
    (Sutherland-Hodgman; a segment or a point clipped as an open chain). Returns its count."""
    if na < nb:
        return _overlap_ordered(B, nb, A, na, out)
    return _overlap_ordered(A, na, B, nb, out)


@kernel
def _overlap_ordered(A, na, B, nb, out):
    """overlap with na >= nb."""
    if na < 3:
        return _segments(A, na, B, nb, out)
    scale = 0.0
    for i in range(na):
        for a in range(2):
            scale = max(scale, abs(A[i, a] - A[0, a]))
    tol = DEGENERATE * scale * scale
    work = np.empty((na + nb + 4, 2))
    m = nb
    work[:m] = B[:m]
    closed = nb >= 3
    for i in range(na):
        j = (i + 1) % na
        m = _clip(work, m, A[i, 0], A[i, 1], A[j, 0], A[j, 1], closed, tol, out)
        work[:m] = out[:m]
        if m == 0:
            return 0
    return hull2(work, m, out)


@kernel
def _clip(P, k, ax, ay, bx, by, closed, tol, out):
    """The points of the chain P[:k] (closed polygon or open chain) left of the line a -> b."""
    m = 0
    edges = k if closed else k - 1
    if k == 1:
        if _cross(ax, ay, bx, by, P[0, 0], P[0, 1]) >= -tol:
            out[0] = P[0]
            return 1
        return 0
    for i in range(edges):
        q = (i + 1) % k
        dp = _cross(ax, ay, bx, by, P[i, 0], P[i, 1])
        dq = _cross(ax, ay, bx, by, P[q, 0], P[q, 1])
        if dp >= -tol:
            out[m] = P[i]
            m += 1
        if (dp >= -tol) != (dq >= -tol):
            s = dp / (dp - dq)
            out[m, 0] = P[i, 0] + s * (P[q, 0] - P[i, 0])
            out[m, 1] = P[i, 1] + s * (P[q, 1] - P[i, 1])
            m += 1
    if not closed and _cross(ax, ay, bx, by, P[k - 1, 0], P[k - 1, 1]) >= -tol:
        out[m] = P[k - 1]
        m += 1
    return m


@kernel
def _segments(A, na, B, nb, out):
    """Two sets of at most 2 points each: their common part if collinear segments, else one
    point (crossing segments, or a point: where it sits does not change e_r = 0)."""
    if nb == 1 or na == 1:
        out[0] = B[0] if nb == 1 else A[0]
        return 1
    dx, dy = A[1, 0] - A[0, 0], A[1, 1] - A[0, 1]
    L = math.hypot(dx, dy)
    ux, uy = dx / L, dy / L
    off = max(abs(_cross(A[0, 0], A[0, 1], A[1, 0], A[1, 1], B[0, 0], B[0, 1])),
              abs(_cross(A[0, 0], A[0, 1], A[1, 0], A[1, 1], B[1, 0], B[1, 1]))) / L
    if off > DEGENERATE * L:
        out[0] = A[0]
        return 1
    s0 = (B[0, 0] - A[0, 0]) * ux + (B[0, 1] - A[0, 1]) * uy
    s1 = (B[1, 0] - A[0, 0]) * ux + (B[1, 1] - A[0, 1]) * uy
    lo, hi = max(0.0, min(s0, s1)), min(L, max(s0, s1))
    if hi < lo:
        return 0
    out[0, 0], out[0, 1] = A[0, 0] + lo * ux, A[0, 1] + lo * uy
    out[1, 0], out[1, 1] = A[0, 0] + hi * ux, A[0, 1] + hi * uy
    return 2 if hi > lo else 1


@kernel
def moments(P, m, out):
    """e_r of a convex polygon, segment or point P[:m] (counter-clockwise); out: (kind, area,
    centroid x, y)."""
    out[:] = 0.0
    if m == 0:
        return 0.0
    if m >= 3:
        area = 0.0
        cx = 0.0
        cy = 0.0
        size = 0.0
        for i in range(m):
            j = (i + 1) % m
            cr = P[i, 0] * P[j, 1] - P[j, 0] * P[i, 1]
            area += 0.5 * cr
            cx += (P[i, 0] + P[j, 0]) * cr
            cy += (P[i, 1] + P[j, 1]) * cr
            for a in range(2):
                size = max(size, abs(P[i, a] - P[0, a]))
        if area > DEGENERATE * size * size:
            cx /= 6.0 * area
            cy /= 6.0 * area
            out[0], out[1], out[2], out[3] = K_AREA, area, cx, cy
            return _mean_distance(P, m, cx, cy) / area
        far = 0                                    # a sliver: its longest extent as a segment
        for i in range(m):
            if math.hypot(P[i, 0] - P[0, 0], P[i, 1] - P[0, 1]) > math.hypot(P[far, 0] - P[0, 0], P[far, 1] - P[0, 1]):
                far = i
        P[1] = P[far]
        m = 2
    if m == 2:
        L = math.hypot(P[1, 0] - P[0, 0], P[1, 1] - P[0, 1])
        out[2], out[3] = 0.5 * (P[0, 0] + P[1, 0]), 0.5 * (P[0, 1] + P[1, 1])
        if L > 0.0:
            out[0] = K_SEGMENT
            return L / 4.0
    out[0], out[2], out[3] = K_POINT, P[0, 0], P[0, 1]
    return 0.0


@kernel
def _mean_distance(P, m, cx, cy):
    r"""\int |x - c| dA over a convex polygon P[:m] (counter-clockwise) that contains c: the sum
    over its edges of the triangle (c, a, b), in polar coordinates about the edge's foot at
    distance d: \int r(phi)^3 / 3 dphi = [d rho s / 6 + d^3 asinh(s / d) / 6] between the edge's
    ends, s the signed position along the edge and rho = sqrt(d^2 + s^2)."""
    total = 0.0
    for i in range(m):
        j = (i + 1) % m
        ax, ay = P[i, 0] - cx, P[i, 1] - cy
        ex, ey = P[j, 0] - P[i, 0], P[j, 1] - P[i, 1]
        L = math.hypot(ex, ey)
        if L == 0.0:
            continue
        ux, uy = ex / L, ey / L
        d = abs(ax * uy - ay * ux)
        sa = ax * ux + ay * uy
        total += _edge_integral(d, sa + L) - _edge_integral(d, sa)
    return total


@kernel
def _edge_integral(d, s):
    rho = math.hypot(d, s)
    value = d * rho * s / 6.0
    if d > 0.0:
        value += d ** 3 * math.asinh(s / d) / 6.0
    return value
