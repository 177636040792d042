"""Insertion force profile of seed 002 (stiffness, Fourier friction, cutting); identified by
:func:`needle_sim_ros.identification.insertion_profile_fit.fit_insertion_profile`.

Eq. 1:  F_s(x) = a1 x + a2 x^2                                       for x <= d1 (d1: the peak before puncture)
Eq. 2:  F_f(x) = sum_{i=0..M} A_i cos(w_i x) + B_i sin(w_i x)        after puncture (w_0 = 0: the mean friction)
Eq. 3:  F_c(x) = F_a(x) - F_f(x)  for d1 < x < d2, else 0            (cutting = measured total - friction)

x: insertion depth [m]; d2: the depth where the needle has passed through. The seed's unitless a1 = 0.0019,
a2 = 0.0499 (x in mm, F in N, its Fig. 6) are 1.9 N/m and 4.99e4 N/m^2. For simulation the cutting force is eq. 3's
mean over (d1, d2), constant. All forces are magnitudes resisting insertion (positive while inserting).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numba import njit


@njit(cache=True)
def fourier_series(parameters, x):
    """Eq. 2 at one depth x [m] from ``parameters`` = [w_1..w_M, A_0..A_M, B_1..B_M]
    (``InsertionForceProfile.series_parameters``)."""
    m = (parameters.size - 1) // 3
    total = parameters[m]
    for i in range(m):
        phase = x * parameters[i]
        total += parameters[m + 1 + i] * np.cos(phase) + parameters[2 * m + 1 + i] * np.sin(phase)
    return total


@dataclass(frozen=True)
class InsertionForceProfile:
    """Parameters of seed 002 eqs. 1-3.

    a1 [N/m], a2 [N/m^2]: capsule stiffness polynomial.   puncture_depth: d1 [m].
    frequencies: w_i [rad/m] of the friction series, i = 1..M (w_0 = 0 is implicit).
    cos_coefficients: A_0..A_M [N];  sin_coefficients: B_1..B_M [N].
    cutting_force: constant cutting force [N] applied while the tip cuts (mean of eq. 3).
    """

    a1: float
    a2: float
    puncture_depth: float
    frequencies: tuple[float, ...]
    cos_coefficients: tuple[float, ...]
    sin_coefficients: tuple[float, ...]
    cutting_force: float

    def __post_init__(self) -> None:
        if not np.isfinite(self.puncture_depth) or self.puncture_depth <= 0.0:
            raise ValueError(f"InsertionForceProfile.puncture_depth must be > 0, got {self.puncture_depth!r}")
        m = len(self.frequencies)
        if len(self.cos_coefficients) != m + 1 or len(self.sin_coefficients) != m:
            raise ValueError("InsertionForceProfile: need M frequencies, M+1 cos_coefficients (A_0..A_M) and "
                             f"M sin_coefficients, got {m}, {len(self.cos_coefficients)}, "
                             f"{len(self.sin_coefficients)}")
        values = (self.a1, self.a2, self.cutting_force, *self.frequencies, *self.cos_coefficients,
                  *self.sin_coefficients)
        if not np.all(np.isfinite(values)):
            raise ValueError("InsertionForceProfile: all parameters must be finite")

    def stiffness_force(self, x):
        """Eq. 1 [N] (valid before puncture)."""
        x = np.asarray(x, dtype=float)
        return self.a1 * x + self.a2 * x**2

    @cached_property
    def series_parameters(self) -> np.ndarray:
        """[w_1..w_M, A_0..A_M, B_1..B_M] (``fourier_series``)."""
        return np.array([*self.frequencies, *self.cos_coefficients, *self.sin_coefficients], dtype=float)

    def friction_force(self, x):
        """Eq. 2 [N] (``fourier_series`` at each depth)."""
        x = np.asarray(x, dtype=float)
        parameters = self.series_parameters
        return np.reshape([fourier_series(parameters, value) for value in x.ravel()], x.shape)

    def total_force(self, x, exit_depth: float = np.inf):
        """Model of the measured insertion force F_a [N] for a monotonic insertion to depth x: eq. 1 before d1,
        friction + cutting between d1 and d2 = ``exit_depth``, friction alone beyond."""
        x = np.asarray(x, dtype=float)
        cutting = np.where(x < exit_depth, self.cutting_force, 0.0)
        return np.where(x <= self.puncture_depth, self.stiffness_force(x), self.friction_force(x) + cutting)
