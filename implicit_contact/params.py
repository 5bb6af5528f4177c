"""Contact parameters shared by the formulation, the DART adapter and users.

Friction follows the elliptic dry friction law of [GI] eqs (4)-(5): the friction impulses
(p_t, p_o) and the torsional moment impulse p_r about the normal lie in the ellipsoid

    (p_t / e_t)^2 + (p_o / e_o)^2 + (p_r / e_r)^2 <= (mu p_n)^2

and maximise the dissipated power. e_t and e_o are dimensionless; e_r is a length [m] (a moment
divided by a force): the radius of the contact patch that resists spinning. e_r = 0 means no
torsional friction, and then no torsion rows are built.
"""
from __future__ import annotations

from dataclasses import dataclass
import math

import numpy as np


@dataclass(frozen=True)
class Friction:
    """Elliptic dry friction at a contact ([GI] eq 5).

    mu:  Coulomb coefficient, >= 0 (nominal 0..1.5). mu = 0 builds no friction rows.
    e_t, e_o: dimensionless semi-axes of the friction ellipse, > 0 (isotropic: 1, 1).
    e_r: torsion semi-axis [m], >= 0 (nominal 0..patch radius). 0 builds no torsion rows.
    """

    mu: float = 0.0
    e_t: float = 1.0
    e_o: float = 1.0
    e_r: float = 0.0

    def __post_init__(self):
        for name in ("mu", "e_t", "e_o", "e_r"):
            value = getattr(self, name)
            if not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ValueError(f"Friction.{name} must be a finite number, got {value!r}")
        if self.mu < 0:
            raise ValueError(f"Friction.mu must be >= 0, got {self.mu}")
        if self.e_t <= 0 or self.e_o <= 0:
            raise ValueError(f"Friction.e_t and e_o must be > 0, got {self.e_t}, {self.e_o}")
        if self.e_r < 0:
            raise ValueError(f"Friction.e_r must be >= 0 (0 disables torsion), got {self.e_r}")

    @property
    def active(self) -> bool:
        return self.mu > 0.0

    @property
    def torsion(self) -> bool:
        return self.mu > 0.0 and self.e_r > 0.0

    @staticmethod
    def combine(a: "Friction", b: "Friction") -> "Friction":
        """The pair's friction: the smaller mu of the two bodies wins, with its ellipse."""
        return a if a.mu <= b.mu else b

    def to_dict(self) -> dict:
        return {"mu": self.mu, "e_t": self.e_t, "e_o": self.e_o, "e_r": self.e_r}


SCHEMES = ("paper", "midpoint")


@dataclass(frozen=True)
class Compliance:
    """A quasi-rigid contact layer ([GI] Sec. 5): a lumped linear spring-damper over a rigid core.

    k: stiffness [N/m], scalar (normal) or a 3x3 matrix in the contact frame (n, t, o); only its
       normal-normal entry K_nn acts in this implementation (see below).
    c: damping [N s/m], scalar or 3x3 like k (C_nn acts).
    delta_max: largest normal deflection [m] before the rigid core takes the load (eq 36), > 0;
       math.inf for a layer without a core.
    scheme: "paper" evaluates the spring at the end of the step as printed in eq (49),
       p_ns = h k delta^{l+1} + c (delta^{l+1} - delta^l), with q^{l+1} = q^l + h v^{l+1}
       (backward Euler: it dissipates ~ h/2 (g^2 t_flight + k^2 A^2 tau) per bounce);
       "midpoint" uses p_ns = h k (delta^l + delta^{l+1})/2 + c (delta^{l+1} - delta^l) and the
       trapezoidal position update q^{l+1} = q^l + h (v^l + v^{l+1})/2 for the bodies of the pair,
       which conserves the energy of an undamped bounce but turns a hit on the rigid core into a
       rebound instead of a plastic stop.

    Tangential compliance (K_tt, K_oo, ...): the paper gives no kinematics for the tangential
    deflections, so nonzero off-normal entries are refused rather than silently ignored.
    """

    k: object = 0.0
    c: object = 0.0
    delta_max: float = math.inf
    scheme: str = "paper"

    def __post_init__(self):
        for name in ("k", "c"):
            value = np.asarray(getattr(self, name), float)
            if value.shape not in ((), (3, 3)):
                raise ValueError(f"Compliance.{name} must be a scalar or a 3x3 matrix, got shape {value.shape}")
            if not np.all(np.isfinite(value)):
                raise ValueError(f"Compliance.{name} must be finite, got {getattr(self, name)!r}")
            if value.shape == (3, 3):
                off = value.copy()
                off[0, 0] = 0.0
                if np.any(off != 0.0):
                    raise ValueError(f"Compliance.{name}: only the normal entry [0, 0] is supported; "
                                     "tangential compliance has no deflection kinematics in [GI].")
        if not self.k_n > 0:
            raise ValueError(f"Compliance.k must be positive (a stiffness in N/m), got {self.k!r}")
        if self.c_n < 0:
            raise ValueError(f"Compliance.c must be >= 0 (a damping in N s/m), got {self.c!r}")
        if not (isinstance(self.delta_max, (int, float)) and self.delta_max > 0) or math.isnan(self.delta_max):
            raise ValueError(f"Compliance.delta_max must be a positive length or math.inf, got {self.delta_max!r}")
        if self.scheme not in SCHEMES:
            raise ValueError(f"Compliance.scheme must be one of {SCHEMES}, got {self.scheme!r}")

    @property
    def k_n(self) -> float:
        k = np.asarray(self.k, float)
        return float(k) if k.shape == () else float(k[0, 0])

    @property
    def c_n(self) -> float:
        c = np.asarray(self.c, float)
        return float(c) if c.shape == () else float(c[0, 0])

    @staticmethod
    def series(a: "Compliance | None", b: "Compliance | None") -> "Compliance | None":
        """Two layers pressed together: springs and dampers in series, the smaller core depth
        bound by the sum of both layers' delta_max."""
        if a is None or b is None:
            return a if b is None else b
        if a.scheme != b.scheme:
            raise ValueError("two compliant bodies in contact must use the same scheme")
        k = a.k_n * b.k_n / (a.k_n + b.k_n)
        c = a.c_n * b.c_n / (a.c_n + b.c_n) if a.c_n + b.c_n > 0 else 0.0
        return Compliance(k, c, a.delta_max + b.delta_max, a.scheme)

    def to_dict(self) -> dict:
        return {"k": np.asarray(self.k, float).tolist(), "c": np.asarray(self.c, float).tolist(),
                "delta_max": self.delta_max if math.isfinite(self.delta_max) else "inf",
                "scheme": self.scheme}

    @staticmethod
    def from_dict(d: dict) -> "Compliance":
        dm = d.get("delta_max", "inf")
        return Compliance(d["k"], d.get("c", 0.0), math.inf if dm == "inf" else float(dm), d.get("scheme", "paper"))
