"""Random step problems for tests and benchmarks (the stepper does not use this module).

A StepProblem needs body kinematics, Newton-Euler blocks for its moving bodies and, to probe its
rows, a point z at which every row is defined: positive multipliers and normal impulses, a
positive slip multiplier where friction rows exist, a small deflection where a quasi-rigid layer
exists. ``fm`` parameters let comparisons/bench_assembly.py build the same problems with another
version of formulation.py.
"""
from __future__ import annotations

import numpy as np

from . import formulation


def random_body(kind, dim, rng, col, h, fm=formulation):
    """(BodyKinematics, its number of velocity columns) for kind "fixed", "free" or "planar" with a
    random pose; a moving body's velocities start at column col."""
    if kind == "fixed":
        R = fm.so3_exp(np.array([0.0, 0.0, 0.3])) if dim == 3 else np.eye(3)
        return fm.BodyKinematics(fm.FIXED, dim, R, np.array([0.1, 0.2, 0.3 if dim == 3 else 0.0]), None, h, None), 0
    if kind == "free":
        R, p = fm.so3_exp(rng.normal(size=3)), rng.normal(size=3)
        return fm.BodyKinematics(fm.FREE, 3, R, p, None, h, np.arange(col, col + 6), 1.0), 6
    q0 = rng.normal(size=3)
    c, s = np.cos(q0[2]), np.sin(q0[2])
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return fm.BodyKinematics(fm.PLANAR, 2, R, np.r_[q0[:2], 0.0], q0, h, np.arange(col, col + 3), 1.0), 3


def random_pair_problem(dim, kinds, piece1, piece2, friction, rng, h, fixed2=False, fm=formulation, **spec):
    """(StepProblem, z) of one pair between random bodies of the two kinds; spec: further PairSpec
    fields (compliance, compliant_side, delta_prev, ...)."""
    bodies, nv, col = [], [], 0
    for kind in kinds:
        kin, k = random_body(kind, dim, rng, col, h, fm)
        bodies.append(kin)
        if k:
            nv.append(k)
            col += k
    o1 = fm.ContactObject(0, tuple(piece1.functions), False)
    o2 = fm.ContactObject(1, tuple(piece2.functions), fixed2)
    axis = np.array([1.0, 0.0, 0.0]) if dim == 3 else None
    pair = fm.PairSpec(("a", "b"), o1, o2, dim, friction, friction.active, 0, axis, 0.05, **spec)
    layout = fm.build_layout(nv, [pair])
    problem = fm.StepProblem(h, random_blocks(bodies, rng, fm), bodies, [pair], layout)
    return problem, random_point(layout, rng)


def random_blocks(bodies, rng, fm=formulation) -> list:
    """One SkeletonBlock per moving body: a random SPD mass matrix (eigenvalues >= its size),
    random velocity and force."""
    blocks = []
    for b, kin in enumerate(bodies):
        if kin.vindex is not None:
            k = len(kin.vindex)
            A = rng.normal(size=(k, k))
            blocks.append(fm.SkeletonBlock(A @ A.T + k * np.eye(k), rng.normal(size=k), rng.normal(size=k), b))
    return blocks


def random_point(layout, rng) -> np.ndarray:
    """z ~ 0.3 N(0, 1), then l1, l2 >= 0.5, p_n >= 0.3, sigma >= 0.2 and delta_n = 0.01 per pair,
    and sigma >= 0.2 per support block."""
    z = 0.3 * rng.normal(size=layout.n)
    for sl in layout.pairs:
        for idx in (sl.l1, sl.l2):
            z[idx] = np.abs(z[idx]) + 0.5
        z[sl.p_n] = abs(z[sl.p_n]) + 0.3
        if sl.dn >= 0:
            z[sl.dn] = 0.01
        if sl.sigma >= 0:
            z[sl.sigma] = abs(z[sl.sigma]) + 0.2
    for ss in getattr(layout, "supports", ()):      # (older layouts in bench_assembly --baseline)
        z[ss.sigma] = abs(z[ss.sigma]) + 0.2
    return z


def jacobian_error(problem, z, eps=1e-6) -> float:
    """max |J - J_fd| / max(1, |J_fd|) over all entries, J_fd by central differences of F with
    step eps (F from _assemble, the path that does not reuse a cached Jacobian evaluation)."""
    J = problem.jac(z)
    J = J.toarray() if hasattr(J, "toarray") else np.array(J)
    n = problem.layout.n
    J_fd = np.empty_like(J)
    for i in range(n):
        e = np.zeros(n)
        e[i] = eps
        J_fd[:, i] = (problem._assemble(z + e, False)[0] - problem._assemble(z - e, False)[0]) / (2 * eps)
    return float(np.max(np.abs(J - J_fd) / np.maximum(1.0, np.abs(J_fd))))


# -- small DART worlds for the tests (dartpy imported on first use) ---------------------------------
def dart_world(h, gravity=9.81):
    """An empty DART world of step h with gravity -gravity along z."""
    import dartpy as dart
    world = dart.simulation.World()
    world.setTimeStep(h)
    world.setGravity([0.0, 0.0, -gravity])
    return world


def ground_box(world, top=0.0, size=(4.0, 4.0, 0.1), mu=None):
    """A welded BoxShape ground (collision aspect; friction mu if given) whose top face is at z =
    top; returns its body node."""
    import dartpy as dart
    ground = dart.dynamics.Skeleton("ground")
    _, body = ground.createWeldJointAndBodyNodePair()
    node = body.createShapeNode(dart.dynamics.BoxShape(list(size)))
    T = dart.math.Isometry3()
    T.set_translation([0.0, 0.0, top - size[2] / 2])
    node.setRelativeTransform(T)
    node.createCollisionAspect()
    if mu is not None:
        node.createDynamicsAspect().setFrictionCoeff(mu)
    world.addSkeleton(ground)
    return body


def urdf_skeleton(text, fixed_root=True):
    """A skeleton from URDF text by DART's loader, its root welded (fixed_root) or floating."""
    import dartpy as dart
    loader = dart.utils.DartLoader()
    if fixed_root:
        opts = dart.utils.DartLoader.Options()
        opts.mDefaultRootJointType = dart.utils.DartLoader.RootJointType.FIXED
        loader.setOptions(opts)
    return loader.parseSkeletonString(text, "")


def revolute_pendulum(world, q0, mass=1.0, length=0.5, friction=0.0, limits=None, bob_radius=None):
    """A bob of mass (inertia 1e-3 about its centre) at length below a revolute axis along y at the
    origin (positive q swings it towards -x), with Coulomb joint friction, enforced limits
    (lower, upper) and a sphere of bob_radius if given; added to world at q0."""
    import dartpy as dart
    skel = dart.dynamics.Skeleton("pendulum")
    joint, body = skel.createRevoluteJointAndBodyNodePair()
    joint.setAxis([0.0, 1.0, 0.0])
    body.setMass(mass)
    body.setMomentOfInertia(1e-3, 1e-3, 1e-3)
    T = dart.math.Isometry3()
    T.set_translation([0.0, 0.0, length])
    joint.setTransformFromChildBodyNode(T)
    joint.setCoulombFriction(0, friction)
    if limits is not None:
        joint.setPositionLowerLimit(0, limits[0])
        joint.setPositionUpperLimit(0, limits[1])
        joint.setLimitEnforcement(True)
    if bob_radius is not None:
        body.createShapeNode(dart.dynamics.SphereShape(bob_radius)).createCollisionAspect()
    world.addSkeleton(skel)
    skel.setPositions([q0])
    return skel
