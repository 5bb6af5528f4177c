"""Collision meshes as their convex hulls, simplified to few planes (hulls.py; issue 15)."""
import os

import dartpy as dart
import numpy as np
import pytest
from scipy.optimize import minimize

import implicit_contact as ic
from implicit_contact import hulls
from implicit_contact.testing import dart_world, ground_box

DATA = os.path.join(os.path.dirname(__file__), "data")
CONTAINS_TOL = 1e-12       # every hull vertex inside the simplified hull [m]


def _ellipsoid_cloud(n=2000, seed=0):
    """Points on an ellipsoid's surface (0.3 x 0.2 x 0.1 m semi-axes): a hull of ~4000 facets."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=(n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u * np.array([0.3, 0.2, 0.1])


def _distance_to_hull(v, N, b):
    """An independent oracle: min |x - v| over {N x <= b} by SLSQP."""
    res = minimize(lambda x: 0.5 * np.sum((x - v) ** 2), v, jac=lambda x: x - v,
                   constraints=[{"type": "ineq", "fun": lambda x: b - N @ x, "jac": lambda x: -N}],
                   method="SLSQP", options={"ftol": 1e-14, "maxiter": 500})
    assert res.success, res.message
    return float(np.linalg.norm(res.x - v))


def test_simplified_hull_contains_the_mesh_and_errs_outwards_within_its_tolerance():
    P = _ellipsoid_cloud()
    hull = hulls.simplify(P)
    assert hull.tolerance == pytest.approx(max(hulls.ERROR_FLOOR, hulls.ERROR_FRACTION * 0.6), rel=1e-2)
    assert hull.exact_planes > 1000 and len(hull.normals) < hull.exact_planes / 20
    # P contains H: every mesh point satisfies every plane
    assert (P @ hull.normals.T - hull.offsets).max() <= CONTAINS_TOL
    # its outward error, at its vertices, measured by an independent oracle, is what it reports
    N_h, b_h, _ = hulls.exact_planes(P)
    from scipy.spatial import HalfspaceIntersection
    verts = HalfspaceIntersection(np.c_[hull.normals, -hull.offsets], P.mean(axis=0)).intersections
    oracle = max(_distance_to_hull(v, N_h, b_h) for v in verts)
    assert oracle <= hull.tolerance * (1 + 1e-6)
    assert oracle == pytest.approx(hull.error, rel=1e-4, abs=1e-9)


def test_obj_and_stl_vertices_are_read(tmp_path):
    V = hulls.read_vertices(os.path.join(DATA, "cube.obj"))
    assert V.shape == (8, 3) and np.allclose(np.abs(V), 0.05)
    # the same cube as a binary STL (12 triangles)
    tris = []
    with open(os.path.join(DATA, "cube.obj")) as f:
        faces = [[int(i) - 1 for i in line.split()[1:]] for line in f if line.startswith("f ")]
    for a, b, c in faces:
        tris.append(np.r_[np.zeros(3), V[a], V[b], V[c]].astype("<f4").tobytes() + b"\0\0")
    stl = tmp_path / "cube.stl"
    stl.write_bytes(b"\0" * 80 + np.uint32(len(tris)).tobytes() + b"".join(tris))
    W = hulls.read_vertices(str(stl))
    assert sorted(map(tuple, np.round(W, 6))) == sorted(map(tuple, np.round(V, 6)))


def _drop(mesh: bool, tilt: float):
    world = dart_world(1e-3)
    if mesh:
        box = dart.utils.DartLoader().parseSkeleton(os.path.join(DATA, "mesh_box.urdf"))
        assert box.getBodyNode(0).getShapeNode(0).getShape().getType() == "MeshShape"
    else:
        box = dart.dynamics.Skeleton("box")
        _, body = box.createFreeJointAndBodyNodePair()
        node = body.createShapeNode(dart.dynamics.BoxShape([0.1, 0.1, 0.1]))
        node.createCollisionAspect()
        body.setMass(0.5)
        body.setMomentOfInertia(8.333e-4, 8.333e-4, 8.333e-4)
    box.setPositions([tilt, 0.0, 0.0, 0.0, 0.0, 0.1])
    world.addSkeleton(box)
    ground_box(world, size=(2.0, 2.0, 0.1))
    stepper = ic.ImplicitContactStepper(world)
    for _ in range(500):
        stepper.step()
    return np.asarray(box.getPositions())


@pytest.mark.parametrize("tilt", [0.0, 0.3])
def test_cube_mesh_from_a_urdf_lands_like_a_dart_box(tilt):
    """The shipped URDF's cube.obj (0.1 m) dropped flat, and tilted 0.3 rad (it lands on an edge and
    tips flat): the same trajectory as a BoxShape of that size (the hull is the cube: its 14-DOP
    starting planes only touch the corners), resting at its half height."""
    q_mesh, q_box = _drop(True, tilt), _drop(False, tilt)
    np.testing.assert_allclose(q_mesh, q_box, atol=1e-12)
    assert q_mesh[5] == pytest.approx(0.05, abs=1e-9)
