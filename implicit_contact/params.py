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
