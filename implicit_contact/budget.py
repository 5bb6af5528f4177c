"""A step's work budget: how many Newton iterations and how much wall time one call of
ImplicitContactStepper.step may spend over all its solves, recoveries, re-solves and halvings
(StepperOptions.max_step_iterations, max_step_seconds).

The budget is checked before each solve and charged after it; a solve under way is not cut, but
its iteration limit is lowered to what is left, so a step spends at most max_step_iterations
Newton iterations plus one polishing iteration, and overruns max_step_seconds by at most one
solve. When it is spent, the step fails at once (no further recovery or halving) and the stepper
restores the world. The case: real robot models landing on the ground (comparisons.real_models)
took single failing steps of up to 68 s, and 30 superquadrics in a box under order 2 a step of
over 4 min, before failing or getting through.
"""
from __future__ import annotations

from dataclasses import replace
import math
import time


class BudgetExhausted(Exception):
    """Raised before a solve when the step's budget is spent (its message says which)."""


class Budget:
    """iterations: Newton iterations allowed (None: no limit); seconds: wall time (None: none)."""

    def __init__(self, iterations=None, seconds=None):
        self.limit = math.inf if iterations is None else int(iterations)
        self.seconds = seconds
        self.start = time.perf_counter()
        self.deadline = math.inf if seconds is None else self.start + seconds
        self.spent = 0          # Newton iterations charged so far
        self.solves = 0
        self._capped = None     # (options, left, the options capped to left)

    def admit(self, options):
        """Before a solve: raise BudgetExhausted if no iteration or no time is left, else return
        options (ncp.SolverOptions) with max_iterations lowered to the iterations left (None for
        a solve that takes none: a static closest-point solve)."""
        if self.spent >= self.limit:
            raise BudgetExhausted(f"the step spent its budget of {self.limit} Newton iterations "
                                  f"(StepperOptions.max_step_iterations) in {self.solves} solves")
        if time.perf_counter() > self.deadline:
            raise BudgetExhausted(f"the step spent its budget of {self.seconds:g} s "
                                  f"(StepperOptions.max_step_seconds) in {self.solves} solves, "
                                  f"{self.spent} Newton iterations")
        if options is None:
            return None
        left = self.limit - self.spent
        if left >= options.max_iterations:
            return options
        left = int(left)
        if self._capped is None or self._capped[0] is not options or self._capped[1] != left:
            self._capped = (options, left, replace(options, max_iterations=left))
        return self._capped[2]

    def spend(self, iterations):
        self.spent += int(iterations)
        self.solves += 1

    def elapsed(self) -> float:
        return time.perf_counter() - self.start
