"""Many-body steps: the sparse Jacobian path gives the dense path's steps.

formulation.StepProblem stores J densely below SPARSE_MIN_UNKNOWNS unknowns and as a
scipy.sparse matrix above (see its docstring); the solver factorises either. A pile of six
bodies, two of them quasi-rigid against each other, stepped through its first landings both
ways, must give the same states to the solver's tolerance."""
import dartpy as dart
import numpy as np
import pytest

import implicit_contact as ic
from implicit_contact import formulation as fm

G = 9.81
H = 0.01
STATE_TOL = 1e-8          # [m, m/s] two LU factorisations of the same Newton systems (tol 1e-10)


def _pile():
    world = dart.simulation.World()
    world.setTimeStep(H)
    world.setGravity([0.0, 0.0, -G])
    ground = dart.dynamics.Skeleton("ground")
    _, gb = ground.createWeldJointAndBodyNodePair()
    ic.attach(gb, ic.shapes.HalfSpace([0.0, 0.0, 1.0], 0.0), friction=ic.Friction(mu=0.5))
    world.addSkeleton(ground)
    shapes = [ic.shapes.Superquadric([0.1, 0.08, 0.06], 4.0), ic.shapes.Sphere(0.07),
              ic.shapes.Ellipsoid([0.1, 0.07, 0.06])]
    rng = np.random.default_rng(3)
    nodes = []
    for k in range(6):
        skel = dart.dynamics.Skeleton(f"b{k}")
        _, body = skel.createFreeJointAndBodyNodePair()
        body.setName(f"b{k}")
        body.setMass(0.5)
        body.setMomentOfInertia(2e-3, 2e-3, 2e-3)
        position = [0.2 * (k % 3) - 0.2, 0.2 * (k // 3) - 0.1, 0.13 + 0.01 * k]
        skel.setPositions(np.r_[rng.uniform(-0.3, 0.3, 3), position])
        skel.setVelocities(np.r_[0.0, 0.0, 0.0, -0.6 * np.sign(position[0]), 0.0, -0.6])
        ic.attach(body, shapes[k % 3], friction=ic.Friction(mu=0.5))
        world.addSkeleton(skel)
        nodes.append(body)
    return world, nodes


def _run(monkeypatch, threshold, steps=10):
    monkeypatch.setattr(fm, "SPARSE_MIN_UNKNOWNS", threshold)
    world, nodes = _pile()
    stepper = ic.ImplicitContactStepper(world, on_failure="raise")
    stepper.set_pair_compliance(nodes[0], nodes[1], ic.Compliance(1e4, 10.0, 0.01))
    contacts, unknowns = 0, 0
    for _ in range(steps):
        report = stepper.step()
        contacts = max(contacts, sum(1 for c in report.contacts if c.p_n > 0.0))
        unknowns = max(unknowns, report.unknowns)
    state = np.concatenate([np.r_[world.getSkeleton(i).getPositions(), world.getSkeleton(i).getVelocities()]
                            for i in range(world.getNumSkeletons())])
    return state, contacts, unknowns


def test_pile_steps_the_same_with_dense_and_sparse_jacobians(monkeypatch):
    dense, contacts, unknowns = _run(monkeypatch, 10 ** 9)
    sparse, _, _ = _run(monkeypatch, 0)
    assert contacts >= 4 and unknowns > 100          # the pile landed: a real many-body problem
    np.testing.assert_allclose(sparse, dense, rtol=0.0, atol=STATE_TOL)
