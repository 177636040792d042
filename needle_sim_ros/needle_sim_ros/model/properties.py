"""Material and cross-section of the needle: a homogeneous circular section, solid as in seed 000 (Sec. II-B,
Sec. III) or a tube (a hollow needle, e.g. 18 G brachytherapy: outer radius 0.635 mm, inner radius 0.419 mm)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class NeedleProperties:
    """Homogeneous needle with a circular (solid or annular) cross-section: length [m] from the clamp point A to the
    tip; radius [m] (outer); youngs_modulus E [Pa]; density rho [kg/m^3]; gravity [m/s^2], world frame (z up);
    inner_radius [m] of the bore (0: solid, seed 000)."""

    length: float
    radius: float
    youngs_modulus: float
    density: float
    gravity: tuple[float, float, float] = (0.0, 0.0, -9.81)
    inner_radius: float = 0.0

    def __post_init__(self) -> None:
        for name in ("length", "radius", "youngs_modulus", "density"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value) and value > 0):
                raise ValueError(f"NeedleProperties.{name} must be a finite number > 0, got {value!r}")
            object.__setattr__(self, name, float(value))
        gravity = np.asarray(self.gravity, dtype=float)
        if gravity.shape != (3,) or not np.all(np.isfinite(gravity)):
            raise ValueError(f"NeedleProperties.gravity must be 3 finite numbers [m/s^2], got {self.gravity!r}")
        object.__setattr__(self, "gravity", tuple(float(g) for g in gravity))
        inner = self.inner_radius
        if not (isinstance(inner, (int, float, np.floating, np.integer)) and 0.0 <= inner < self.radius):
            raise ValueError(f"NeedleProperties.inner_radius must be >= 0 and < radius ({self.radius!r} m), "
                             f"got {inner!r}")
        object.__setattr__(self, "inner_radius", float(inner))

    @property
    def area(self) -> float:
        """Cross-section area A = pi (r^2 - r_i^2) [m^2]."""
        return math.pi * (self.radius**2 - self.inner_radius**2)

    @property
    def second_moment(self) -> float:
        """Second moment of area I = I_y = I_z = pi (r^4 - r_i^4) / 4 [m^4] (seed 000 assumes I_y = I_z)."""
        return math.pi * (self.radius**4 - self.inner_radius**4) / 4.0

    @property
    def mass_per_length(self) -> float:
        """rho A [kg/m]."""
        return self.density * self.area

    @property
    def mass(self) -> float:
        """Total needle mass rho A L [kg]."""
        return self.mass_per_length * self.length

    @property
    def EA(self) -> float:
        """Axial stiffness E A [N]."""
        return self.youngs_modulus * self.area

    @property
    def EI(self) -> float:
        """Bending stiffness E I [N m^2]."""
        return self.youngs_modulus * self.second_moment
