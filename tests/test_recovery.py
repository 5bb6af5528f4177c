"""recovery.friction_rows on a pair whose friction rows would go off and on forever.

The case (example-robot-data's icub_reduced at t = 0.886 s, h / 16): the hand touches the ground
with p_n > 0 while it has no friction rows, and carries no impulse once it has them (the other
contacts' friction holds the body). friction_rows took its rows off at every converged solve with
them and gave them back at every converged solve without them, ten solves in a row, until a solve
stalled and the step failed. A converged solve with the rows and p_n = 0 solves the frictional
problem (its friction rows hold; only sigma is undetermined), so the pair keeps its rows there.

The problem and the stepper are stand-ins with what friction_rows reads: the flags of
rows/checks.solution_checks for a solution, a layout of one pair, and no slip.
"""
from types import SimpleNamespace

import numpy as np

from implicit_contact import ncp, recovery
from implicit_contact.params import Friction
from implicit_contact.rows import checks as rk


class _Problem:
    """One pair; checks() gives the flags set by the test, as solution_checks would."""

    def __init__(self, specs, flags):
        self.specs = specs
        self.flags = flags
        self.layout = SimpleNamespace(pairs=[SimpleNamespace(p_n=0)])
        self._pairs_at = [(None, np.zeros(3), np.array([0.0, 0.0, 1.0]))]

    def checks(self, z, tol, solver_tol, touch):
        return np.array(self.flags, np.int64)

    def _evaluated_at(self, z):
        pass

    def unpack_pair(self, z, k):
        return SimpleNamespace(tangents=np.eye(3)[:2])

    def relative_velocity(self, z, k):
        return np.zeros(3)          # no slip: a new row starts sticking


class _Stepper:
    def _impulse_speed(self, h):
        return 1.0

    def _share_patches(self, specs, solved, fresh):
        pass


def _converged(x):
    return SimpleNamespace(success=True, status=ncp.Status.CONVERGED, x=np.asarray(x, float))


def test_a_pair_whose_rows_came_back_keeps_them_at_a_converged_solve_without_impulse():
    spec = SimpleNamespace(key=("ground", "hand"), with_friction=True, friction=Friction(mu=0.5))
    att = recovery.Attempt([spec], [("ground", "hand")], 1e-6, 1e-10, 1e-3, {}, [])
    stepper = _Stepper()

    # converged with rows and p_n = 0: the rows go (sigma undetermined), as before
    assert recovery.friction_rows(stepper, att, _Problem([spec], [rk.OFF]), _converged([0.0])) is recovery.RETRY
    assert spec.with_friction is False
    # converged without rows, touching: the rows come back
    assert recovery.friction_rows(stepper, att, _Problem([spec], [rk.ON]), _converged([2e-3])) is recovery.RETRY
    assert spec.with_friction is True
    # converged with rows and p_n = 0 again: that is the answer (before: off again, and so on until
    # the step's solves ran out)
    assert recovery.friction_rows(stepper, att, _Problem([spec], [rk.OFF]), _converged([1e-11])) is None
    assert spec.with_friction is True


def test_a_pair_without_impulse_loses_rows_it_was_built_with():
    """The rule the cycle breaker leaves alone: rows the step started with go when p_n = 0."""
    spec = SimpleNamespace(key=("ground", "box"), with_friction=True, friction=Friction(mu=0.5))
    other = SimpleNamespace(key=("ground", "hand"), with_friction=False, friction=Friction(mu=0.5))
    att = recovery.Attempt([spec, other], [("ground", "box"), ("ground", "hand")], 1e-6, 1e-10, 1e-3, {}, [])
    problem = _Problem([spec, other], [rk.OFF, rk.ON])
    problem.layout.pairs.append(SimpleNamespace(p_n=1))
    problem._pairs_at.append(problem._pairs_at[0])
    assert recovery.friction_rows(_Stepper(), att, problem, _converged([0.0, 2e-3])) is recovery.RETRY
    assert spec.with_friction is False and other.with_friction is True
