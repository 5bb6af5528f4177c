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


SEED_POINT_TOL = 1e-12    # [m] batched against per-pair static closest points (the same kernel)
SEED_KKT_TOL = 1e-10      # eq (15) a1 - a2 = -l1 grad f(a1) of a seed, relative to |a1 - a2|


def test_new_pairs_seeded_in_one_batch_match_the_per_pair_seeds(monkeypatch):
    """ImplicitContactStepper._seed_pairs: the new pairs of two single functions apart at l take
    their static closest points and gradients from closest.closest_points_batch. On the pile's
    first steps every such seed equals _seed_pair's (points, multipliers), and those with body 1
    one function satisfy eq (15), a1 - a2 = -l1 grad f(a1)."""
    from implicit_contact import closest
    from implicit_contact import stepper as stepper_module

    world, _ = _pile()
    stepper = ic.ImplicitContactStepper(world, on_failure="raise")
    batched = []
    real_batch = closest.closest_points_batch

    def spy(shapes1, poses1, shapes2, poses2):
        out = real_batch(shapes1, poses1, shapes2, poses2)
        batched.append(int(out[0].sum()))
        return out

    monkeypatch.setattr(closest, "closest_points_batch", spy)
    real = stepper_module.ImplicitContactStepper._seed_pairs
    checked = []

    def compare(self, problem, specs, new, state):
        seeds = real(self, problem, specs, new, state)
        for k in new:
            a1, a2, l1, l2, s = seeds[k]
            r1, r2, m1, m2, t = self._seed_pair(problem, specs[k], state)
            assert np.allclose(a1, r1, rtol=0, atol=SEED_POINT_TOL) and np.allclose(a2, r2, rtol=0, atol=SEED_POINT_TOL)
            assert np.allclose(l1, m1, rtol=1e-9) and np.allclose(l2, m2, rtol=1e-9) and s == t
            spec = specs[k]
            if len(spec.obj1.functions) == 1 and not spec.obj1.fixed_halfspace and np.linalg.norm(a2 - a1) > 1e-9:
                P1 = problem.bodies[spec.obj1.body].pose(np.zeros(problem.bodies[spec.obj1.body].ndof))
                _, G1 = fm.eval_functions(spec.obj1.functions, P1, a1)
                assert np.linalg.norm(a1 - a2 + l1[0] * G1[0]) <= SEED_KKT_TOL * np.linalg.norm(a2 - a1)
                checked.append(k)
        return seeds

    monkeypatch.setattr(stepper_module.ImplicitContactStepper, "_seed_pairs", compare)
    for _ in range(6):
        stepper.step()
    assert sum(batched) >= 5 and len(checked) >= 5
