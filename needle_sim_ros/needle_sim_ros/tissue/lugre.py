"""Modified LuGre axial force model of seed 003 (eqs. 1-2) with its RK3 discretisation and sensitivities.

With l the insertion depth, l' its velocity and sgn(l') regularised as tanh(l'/v_s) (``velocity_scale`` v_s,
0 = exact sign); the reading of the printed equations (which lose the time derivatives' dots) is explained in
docs/design_notes.md:

    dz/dt = l' - sigma0 |l'| z / g(l)                                                        (1a)
    f     = l [ sigma0 z + sigma1 exp(-alpha l) (sgn(l') - sigma0 z / g(l)) + sigma2 sgn(l') ]  (1b)
    g(l)  = f1 + f2 exp(-alpha l)                                                            (2)

Units: z [m] (bristle deflection); f1, f2, sigma1, sigma2 [N/m]; sigma0 [N/m^2]; alpha [1/m]. Parameter vectors
theta are ordered as ``PARAMETER_NAMES``; the estimator's augmented state is (z, theta).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

PARAMETER_NAMES = ("f1", "f2", "sigma0", "sigma1", "sigma2", "alpha")
_G_FLOOR = 1e-9   # [N/m] g is kept positive when an estimator wanders to f1 + f2 exp(-alpha l) <= 0


@dataclass(frozen=True)
class LuGreParameters:
    """The six parameters of eqs. 1-2 (units in the module docstring)."""

    f1: float
    f2: float
    sigma0: float
    sigma1: float
    sigma2: float
    alpha: float

    def as_array(self) -> np.ndarray:
        return np.array([getattr(self, name) for name in PARAMETER_NAMES])

    @classmethod
    def from_array(cls, theta) -> "LuGreParameters":
        theta = np.asarray(theta, dtype=float)
        if theta.shape != (6,) or not np.all(np.isfinite(theta)):
            raise ValueError(f"LuGre parameter vector must be 6 finite values {PARAMETER_NAMES}, got {theta!r}")
        return cls(*(float(v) for v in theta))


@njit(cache=True)
def stribeck_value(theta: np.ndarray, depth: float) -> float:
    """g(l) of eq. 2 [N/m] alone, for a scalar depth (per step: no derivatives)."""
    return max(theta[0] + theta[1] * np.exp(-theta[5] * depth), _G_FLOOR)


@njit(cache=True)
def _stage_rate(z, theta, depth, velocity, speed, rate_slope):
    """dz/dt of eq. 1a (reading above) at one RK3 stage; with a (7,) ``rate_slope``, d(dz/dt)/d(z, theta) into it
    (a (0,) array: none)."""
    sigma0 = theta[2]
    g = stribeck_value(theta, depth)
    if rate_slope.size:
        decay = np.exp(-theta[5] * depth)
        ratio = sigma0 * speed * z / (g * g)
        rate_slope[:] = 0.0
        rate_slope[0] = -sigma0 * speed / g
        rate_slope[1] = ratio                                  # dg/df1 = 1
        rate_slope[2] = ratio * decay                          # dg/df2 = exp(-alpha l)
        rate_slope[3] = -speed * z / g
        rate_slope[6] = ratio * (-theta[1] * depth * decay)    # dg/dalpha
    return velocity - sigma0 * speed * z / g


@njit(cache=True)
def bristle_step(z, theta, depth, velocity, dt, velocity_scale, row):
    """Kutta's RK3 for eq. 1a over ``dt`` [s], the depth advancing at the constant ``velocity`` (seed 003 Sec. III),
    split into sub-steps inside RK3's stability region (|dz'/dz| dt <= 1); the simulator's step and the EKF
    (``rk3_step``) both use it. Returns z_next; a (7,) ``row`` receives dz_next/d(z, theta) (a (0,) array: none)."""
    stiffness = abs(theta[2] * velocity / stribeck_value(theta, depth))
    n_sub = int(min(np.ceil(stiffness * dt), 1000.0)) if np.isfinite(stiffness) else 1000
    h = dt / max(n_sub, 1)
    if velocity_scale <= 0.0:
        speed = velocity * np.sign(velocity)
    else:
        speed = velocity * np.tanh(velocity / velocity_scale)
    n = row.size
    d1, d2, d3, step_row = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    for i in range(max(n_sub, 1)):
        start = depth + i * h * velocity if i > 0 else depth
        k1 = _stage_rate(z, theta, start, velocity, speed, d1)
        k2 = _stage_rate(z + 0.5 * h * k1, theta, start + 0.5 * h * velocity, velocity, speed, d2)
        k3 = _stage_rate(z - h * k1 + 2.0 * h * k2, theta, start + h * velocity, velocity, speed, d3)
        z = z + h / 6.0 * (k1 + 4.0 * k2 + k3)
        if n:  # stage sensitivities dk_s = a_s (e_0 + stage combination) + [0, b_s]; d1..d3 hold a_s, b_s
            a1, a2, a3 = d1[0], d2[0], d3[0]
            d1[0] = 0.0
            d2[0] = 0.0
            d3[0] = 0.0
            for j in range(n):
                unit = 1.0 if j == 0 else 0.0
                dk1 = a1 * unit + d1[j]
                dk2 = a2 * (unit + 0.5 * h * dk1) + d2[j]
                dk3 = a3 * (unit - h * dk1 + 2.0 * h * dk2) + d3[j]
                step_row[j] = unit + h / 6.0 * (dk1 + 4.0 * dk2 + dk3)
            if i == 0:
                row[:] = step_row
            else:
                scale = step_row[0]
                row[0] = scale * row[0]
                for j in range(1, n):
                    row[j] = scale * row[j] + step_row[j]
    return z


def rk3_step(z: float, theta: np.ndarray, depth: float, velocity: float, dt: float,
             velocity_scale: float) -> tuple[float, np.ndarray]:
    """(z_next, dz_next/d(z, theta) (7,)) of one RK3 step (``bristle_step``), for the estimator."""
    row = np.empty(7)
    z_next = bristle_step(float(z), np.asarray(theta, dtype=float), float(depth), float(velocity), float(dt),
                          float(velocity_scale), row)
    return z_next, row


def bracket(z, theta, depth, sign):
    """The bracket of eq. 1b [N/m] at a scalar depth for the (regularised) velocity sign ``sign`` (any shape)."""
    sigma0, sigma1, sigma2, alpha = theta[2], theta[3], theta[4], theta[5]
    g = stribeck_value(theta, depth)
    return sigma0 * z + sigma1 * np.exp(-alpha * depth) * (sign - sigma0 * z / g) + sigma2 * sign


bracket_kernel = njit(cache=True)(bracket)  # the simulator's per-step coefficients (``shaft_laws``)


def axial_force(z, theta, depth, velocity, velocity_scale):
    """f of eq. 1b (reading above) [N] and df/d(z, theta) (7,) for a scalar depth (0 for depth <= 0)."""
    f1, f2, sigma0, sigma1, sigma2, alpha = theta
    depth = max(depth, 0.0)                                    # no force out of the tissue
    s = np.tanh(velocity / velocity_scale) if velocity_scale > 0.0 else np.sign(velocity)  # sgn_vs(l')
    decay = np.exp(-alpha * depth)
    g = max(f1 + f2 * decay, _G_FLOOR)                         # eq. 2 and dg/dtheta
    dg = np.array([1.0, decay, 0.0, 0.0, 0.0, -f2 * depth * decay])
    cut = s - sigma0 * z / g                                   # sgn(l') (1 - sigma0 sgn(l') z / g)
    per_length = bracket(z, theta, depth, s)                   # the force per inserted length [N/m]
    d_cut = sigma0 * z / g**2 * dg
    d_cut[2] -= z / g
    d_per_length = sigma1 * decay * d_cut
    d_per_length[2] += z
    d_per_length[3] += decay * cut
    d_per_length[4] += s
    d_per_length[5] -= sigma1 * depth * decay * cut
    d_dz = sigma0 - sigma1 * decay * sigma0 / g
    return depth * per_length, depth * np.concatenate([[d_dz], d_per_length])


@dataclass(frozen=True)
class ModifiedLuGre:
    """Seed 003 model with fixed parameters; ``velocity_scale`` v_s [m/s] regularises sgn(l')."""

    parameters: LuGreParameters
    velocity_scale: float = 0.0

    def __post_init__(self) -> None:
        if not np.isfinite(self.velocity_scale) or self.velocity_scale < 0.0:
            raise ValueError(f"ModifiedLuGre.velocity_scale must be >= 0, got {self.velocity_scale!r}")
        p = self.parameters
        if p.f1 + min(p.f2, 0.0) <= 0.0 or p.sigma0 <= 0.0:
            raise ValueError("ModifiedLuGre: need sigma0 > 0 and g(l) = f1 + f2 exp(-alpha l) > 0 for all l >= 0")

    def step(self, z: float, depth: float, velocity: float, dt: float) -> float:
        """Advance the bristle state z over dt (RK3, ``bristle_step``)."""
        return bristle_step(float(z), self.parameters.as_array(), float(depth), float(velocity), float(dt),
                            self.velocity_scale, np.empty(0))

    def force(self, z, depth, velocity) -> float:
        """Axial force f [N] resisting the motion (positive while inserting)."""
        return float(axial_force(z, self.parameters.as_array(), depth, velocity, self.velocity_scale)[0])
