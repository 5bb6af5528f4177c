"""Random step problems for tests and benchmarks (the stepper does not use this module).

A StepProblem needs Newton-Euler blocks for its moving bodies and, to probe its rows, a point z at
which every row is defined: positive multipliers and normal impulses, a positive slip multiplier
where friction rows exist, a small deflection where a quasi-rigid layer exists.
"""
from __future__ import annotations

import numpy as np

from . import formulation as fm


def random_blocks(bodies, rng) -> list:
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
