r"""Collision meshes as convex implicit bodies: the convex hull, simplified to few planes with a
bounded outward error.

MuJoCo's convention is followed: a collision mesh stands for its convex hull. An exact hull is an
Intersection of one half-space per facet plane, hundreds to thousands of them on robot meshes, and
[GI] carries one multiplier per function of an intersection, so the hull is simplified first:

    H  = {x : n_i . x <= b_i, i = 1..m}       the exact hull (coplanar facets merged)
    P  = {x : n_j . x <= b_j, j in S}         S: 14 supporting planes (the k-DOP of the axes and
                                              diagonals), then hull planes added greedily

P contains H for any S (every plane supports the points), so P only errs outwards; its outward
error is the Hausdorff distance max_{x in P} dist(x, H), attained at a vertex of P (dist(., H) is
convex). The greedy loop takes the vertex of P farthest outside H and adds the hull plane it
violates most, until that distance is within the tolerance. Distances are exact: dist(v, H) is
the least-squares distance from v to the convex combinations of the hull's vertices (scipy's
NNLS with the sum-to-one row weighted in).

Meshes are read for their vertices only: OBJ and STL (ASCII and binary) here, other formats
(COLLADA .dae, ...) through trimesh when it is installed (`pip install implicit_contact[models]`).
"""
from __future__ import annotations

from dataclasses import dataclass
import os
import struct

import numpy as np
from scipy.optimize import nnls
from scipy.spatial import ConvexHull, HalfspaceIntersection

# the starting planes: axes and diagonals (a 14-DOP), supporting the points
_KDOP = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1],
                  [1, 1, 1], [1, 1, -1], [1, -1, 1], [1, -1, -1],
                  [-1, 1, 1], [-1, 1, -1], [-1, -1, 1], [-1, -1, -1]], float)
_KDOP /= np.linalg.norm(_KDOP, axis=1, keepdims=True)
ERROR_FLOOR = 1e-3         # m: the outward error allowed on any mesh ...
ERROR_FRACTION = 0.01      # ... or this fraction of its largest extent, whichever is larger
_SUM_WEIGHT = 1e4          # weight of the sum-to-one row in the NNLS distance (relative to size)


@dataclass(frozen=True)
class SimplifiedHull:
    normals: np.ndarray        # (m, 3) unit outward normals of P
    offsets: np.ndarray        # (m,): P = {x : normals @ x <= offsets}
    error: float               # outward error of P against the exact hull [m] (measured)
    tolerance: float           # what it was built to
    exact_planes: int          # distinct facet planes of the exact hull
    vertices: int              # the mesh's vertices


def exact_planes(points: np.ndarray, merge: float = 1e-9):
    """(normals, offsets, hull vertices) of the convex hull of points, coplanar facets merged."""
    hull = ConvexHull(points)
    eq = hull.equations                          # n . x + d <= 0 inside
    scale = max(float(np.ptp(points, axis=0).max()), 1e-12)
    key = np.round(np.c_[eq[:, :3], eq[:, 3] / scale] / merge).astype(np.int64)
    _, first = np.unique(key, axis=0, return_index=True)
    eq = eq[np.sort(first)]
    return eq[:, :3], -eq[:, 3], points[hull.vertices]


def _distance(v, V, scale):
    """Euclidean distance from v to conv(V) (V: (k, 3))."""
    w = _SUM_WEIGHT * scale
    A = np.vstack([V.T, np.full((1, len(V)), w)])
    _, r = nnls(A, np.r_[v, w], maxiter=50 * len(V))
    return float(r)


def simplify(points, tolerance: float | None = None, max_planes: int = 256) -> SimplifiedHull:
    """The simplified hull P of the module docstring; tolerance defaults to max(1 mm, 1 % of
    the largest extent). Stops at max_planes even if the error is still above the tolerance (the
    result's error says so). Raises ValueError for fewer than 4 affinely independent points."""
    P = np.asarray(points, float).reshape(-1, 3)
    if len(P) < 4 or not np.isfinite(P).all():
        raise ValueError("a collision mesh needs at least 4 finite vertices spanning a volume")
    extent = float(np.ptp(P, axis=0).max())
    tol = float(tolerance) if tolerance is not None else max(ERROR_FLOOR, ERROR_FRACTION * extent)
    try:
        N_h, b_h, V_h = exact_planes(P)
    except Exception as exc:      # qhull: flat or degenerate point sets
        raise ValueError(f"the collision mesh spans no volume (its convex hull failed: {exc})") from None
    N = list(_KDOP)
    b = list((V_h @ _KDOP.T).max(axis=0))
    centre = V_h.mean(axis=0)
    while True:
        A = np.asarray(N)
        hs = HalfspaceIntersection(np.c_[A, -np.asarray(b)], centre)
        verts = hs.intersections
        viol = verts @ N_h.T - b_h                # (k, m): how far each vertex is past each plane
        worst = int(np.argmax(viol.max(axis=1)))
        if viol[worst].max() <= tol or len(N) >= max_planes:
            # the plane test passed (or the cap): measure the true outward error
            dists = [_distance(v, V_h, extent) for v in verts[viol.max(axis=1) > 0.0]]
            error = max(dists, default=0.0)
            if error <= tol or len(N) >= max_planes:
                break
            far = verts[viol.max(axis=1) > 0.0][int(np.argmax(dists))]
            j = int(np.argmax(N_h @ far - b_h))
        else:
            j = int(np.argmax(viol[worst]))
        N.append(N_h[j])
        b.append(b_h[j])
    return SimplifiedHull(np.asarray(N), np.asarray(b), error, tol, len(N_h), len(P))


# -- reading meshes ---------------------------------------------------------------------------
def read_vertices(path: str) -> np.ndarray:
    """A mesh file's vertices (n, 3): OBJ and STL here, other formats through trimesh."""
    ext = os.path.splitext(path)[1].lower()
    if ext == ".obj":
        rows = []
        with open(path) as f:
            for line in f:
                if line.startswith("v "):
                    rows.append([float(x) for x in line.split()[1:4]])
        return np.asarray(rows, float)
    if ext == ".stl":
        with open(path, "rb") as f:
            data = f.read()
        if len(data) >= 84:
            (count,) = struct.unpack_from("<I", data, 80)
            if len(data) == 84 + 50 * count:          # binary STL
                tri = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]),
                                    count=count, offset=84)
                return np.unique(tri["v"].reshape(-1, 3).astype(float), axis=0)
        rows = [[float(x) for x in line.split()[1:4]] for line in data.decode(errors="replace").splitlines()
                if line.strip().startswith("vertex")]
        return np.unique(np.asarray(rows, float), axis=0)
    try:
        import trimesh
    except ImportError:
        raise ValueError(f"mesh '{path}': reading {ext} files needs trimesh (pip install "
                         "'implicit_contact[models]'); OBJ and STL are read without it.") from None
    mesh = trimesh.load(path, force="mesh")
    return np.asarray(mesh.vertices, float)


_CACHE: dict = {}


def mesh_hull(path: str, scale) -> SimplifiedHull:
    """The simplified hull of a mesh file scaled by scale (3,), cached per (path, scale, mtime)."""
    scale = tuple(float(s) for s in np.asarray(scale, float).reshape(3))
    key = (os.path.abspath(path), scale, os.path.getmtime(path))
    hull = _CACHE.get(key)
    if hull is None:
        hull = _CACHE[key] = simplify(read_vertices(path) * np.asarray(scale))
    return hull
