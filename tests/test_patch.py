"""Contact patches (implicit_contact/patch.py): their area, centroid and torsion radius against
closed forms and against an independent grid integration of the overlap of two faces."""
import math

import numpy as np
import pytest
from scipy.optimize import linprog
from scipy.spatial import ConvexHull, HalfspaceIntersection

from implicit_contact import patch as cp
from implicit_contact import shapes
from implicit_contact.formulation import so3_exp

I3 = np.eye(3)
DOWN = np.array([0.0, 0.0, -1.0])      # from the upper piece (piece 1) into the lower one
BAND = 1e-6
SQUARE = (math.sqrt(2.0) + math.log(1.0 + math.sqrt(2.0))) / 6.0   # e_r / side of a square
EXACT = 1e-12                          # closed forms evaluated by the kernel: round-off only
POLYGON = 2e-3                         # a cap's 64-gon against its disc (area 0.16 % smaller)
HULL = 1e-9                            # the oracle's Qhull vertices: round-off
GRID = 1e-3                            # the oracle's mean distance on 800 x 800 cells


def _ground():
    return shapes.HalfSpace([0.0, 0.0, 1.0], 0.0), (I3, np.zeros(3))


def test_box_face_on_the_ground_is_a_square_with_its_closed_form_torsion_radius():
    a = 0.5
    box = shapes.Intersection.box([a / 2, a / 2, 0.05])
    ground, pose = _ground()
    p = cp.patch(box, (I3, np.array([0.3, -0.2, 0.05])), ground, pose, DOWN, BAND)
    assert p.kind == "area"
    assert p.area == pytest.approx(a * a, rel=EXACT)
    np.testing.assert_allclose(p.centroid, [0.3, -0.2, 0.0], atol=EXACT)
    assert p.e_r == pytest.approx(SQUARE * a, rel=EXACT)


def test_cylinder_on_its_cap_is_a_disc_and_on_its_side_a_segment():
    r, half = 0.3, 0.2
    cyl = shapes.Intersection.capped_cylinder(r, half)
    ground, pose = _ground()
    cap = cp.patch(cyl, (I3, np.array([0.0, 0.0, half])), ground, pose, DOWN, BAND)
    assert cap.kind == "area"
    assert cap.area == pytest.approx(math.pi * r * r, rel=POLYGON)
    assert cap.e_r == pytest.approx(2.0 * r / 3.0, rel=POLYGON)
    lying = so3_exp(np.array([math.pi / 2, 0.0, 0.0]))            # axis along y
    side = cp.patch(cyl, (lying, np.array([0.0, 0.0, r])), ground, pose, DOWN, BAND)
    assert side.kind == "segment"
    assert side.e_r == pytest.approx(2.0 * half / 4.0, rel=EXACT)   # L / 4


def test_box_on_an_edge_is_a_segment_and_a_sphere_has_no_patch():
    box = shapes.Intersection.box([0.2, 0.1, 0.05])
    ground, pose = _ground()
    R = so3_exp(np.array([0.3, 0.0, 0.0]))                          # tilted about x: the long edge
    low = -min((R @ np.array(c))[2] for c in np.array(np.meshgrid([-.2, .2], [-.1, .1], [-.05, .05])).T.reshape(-1, 3))
    edge = cp.patch(box, (R, np.array([0.0, 0.0, low])), ground, pose, DOWN, BAND)
    assert edge.kind == "segment" and edge.e_r == pytest.approx(0.4 / 4.0, rel=EXACT)
    assert cp.patch(shapes.Sphere(0.1), (I3, np.array([0, 0, 0.1])), ground, pose, DOWN, BAND) is None
    assert not cp.faceted(shapes.Sphere(0.1)) and not cp.faceted(shapes.Superquadric([0.1, 0.1, 0.1], 4.0))
    assert cp.faceted(box) and cp.faceted(ground)


def _oracle(rects, n=800):
    """Area, centroid and mean distance from the centroid of the intersection of rectangles
    (centre, half extents, angle) in the plane, independently of patch.py: its vertices by
    scipy's half-space intersection, area and centroid from their hull (Qhull), the mean distance
    by cell midpoints of an n x n grid over its bounding box."""
    A, b = [], []
    for (cx, cy), (hx, hy), ang in rects:
        u, v = np.array([math.cos(ang), math.sin(ang)]), np.array([-math.sin(ang), math.cos(ang)])
        for d, half in ((u, hx), (-u, hx), (v, hy), (-v, hy)):
            A.append(d)
            b.append(half + d @ np.array([cx, cy]))
    A, b = np.array(A), np.array(b)
    res = linprog(np.r_[0.0, 0.0, -1.0], A_ub=np.c_[A, np.ones(len(b))], b_ub=b, bounds=[(None, None)] * 2 + [(0, 1)])
    V = HalfspaceIntersection(np.c_[A, -b], res.x[:2]).intersections
    hull = ConvexHull(V)
    P = V[hull.vertices]
    tri = [(P[0], P[k], P[k + 1]) for k in range(1, len(P) - 1)]
    areas = np.array([abs((q - p)[0] * (r - p)[1] - (q - p)[1] * (r - p)[0]) / 2 for p, q, r in tri])
    centroid = sum(a * (p + q + r) / 3 for a, (p, q, r) in zip(areas, tri)) / areas.sum()
    lo, hi = P.min(axis=0), P.max(axis=0)
    X, Y = np.meshgrid(*[(np.arange(n) + 0.5) / n * (hi[k] - lo[k]) + lo[k] for k in range(2)])
    inside = np.all(A @ np.array([X.ravel(), Y.ravel()]) <= b[:, None], axis=0)
    mean = float(np.hypot(X.ravel()[inside] - centroid[0], Y.ravel()[inside] - centroid[1]).mean())
    return hull.volume, centroid, mean


@pytest.mark.parametrize("seed", range(4))
def test_box_on_a_box_patch_is_the_overlap_of_their_faces_by_an_independent_grid(seed):
    rng = np.random.default_rng(seed)
    halves = [rng.uniform(0.15, 0.5, 2) for _ in range(2)]
    centres = [np.zeros(2), rng.uniform(-0.3, 0.3, 2)]
    angles = [0.0, rng.uniform(0.0, math.pi)]
    lower = shapes.Intersection.box([*halves[0], 0.1])
    upper = shapes.Intersection.box([*halves[1], 0.05])
    R_up = so3_exp(np.array([0.0, 0.0, angles[1]]))
    p = cp.patch(upper, (R_up, np.r_[centres[1], 0.05]), lower, (I3, np.array([0.0, 0.0, -0.1])), DOWN, BAND)
    area, centroid, mean = _oracle(list(zip(centres, halves, angles)))
    assert p.kind == "area"
    assert p.area == pytest.approx(area, rel=HULL)
    np.testing.assert_allclose(p.centroid[:2], centroid, atol=HULL)
    assert p.e_r == pytest.approx(mean, rel=GRID)


def test_disjoint_faces_have_no_area():
    box = shapes.Intersection.box([0.1, 0.1, 0.05])
    p = cp.patch(box, (I3, np.array([0.0, 0.0, 0.05])), box, (I3, np.array([1.0, 0.0, -0.05])), DOWN, BAND)
    assert p is None or p.e_r == 0.0
