"""Online identification of the seed 003 LuGre parameters: multiple asynchronous joint EKFs and a single joint EKF.

Seed 003 eqs. 3-4: the bristle state z augmented with the parameters theta (random walk), discretised by RK3
(``lugre.rk3_step``), measured axial force ``f_k = H(z_k, theta_k, l_k) + w_k``. One filter class serves both:
* single joint EKF over (z, f1, f2, sigma0, sigma1, sigma2, alpha);
* multiple asynchronous joint EKFs (seed 003 Sec. III, Table I) over (z, f2, sigma0), (z, f1, sigma1) and
  (z, alpha, sigma2), taking turns (``dwell`` samples each); each keeps its own covariance, so the reported
  covariance is block-diagonal and conditional on the other groups (optimistic) and no parameter is flagged
  identifiable.
Each filter works on parameters divided by their prior scale (Table I's noise values are in unstated units). A
parameter is identifiable when its posterior std is below ``identifiability_tolerance`` times its magnitude;
``fisher_information`` gives a record's Cramer-Rao bound.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from needle_sim_ros.tissue.lugre import PARAMETER_NAMES, LuGreParameters, axial_force, rk3_step

# Feasible region (projection after each update, a standard constrained-EKF device): g(l) > 0 and sigma0 > 0 need
# f1 > 0, f2 >= 0, sigma0 > 0, and alpha >= 0 keeps the puncture term decaying; sigma1, sigma2 >= 0 (dissipative).
_LOWER_BOUND_FRACTION = 1e-3   # positive parameters are kept above this fraction of their prior scale
_Z_SCALE = 1e-3   # [m] normalisation of z in the filters' covariances (bristle deflections are ~ mm)
TABLE_I_GROUPS = (("f2", "sigma0"), ("f1", "sigma1"), ("alpha", "sigma2"))


@dataclass(frozen=True)
class LuGreEstimate:
    """Estimates reported by ``LuGreEstimator.estimate``: parameters; z: bristle state [m]; covariance (6, 6) in SI
    units (PARAMETER_NAMES order), std, correlation (6, 6); identifiable: per-parameter flags (relative std below the
    tolerance; always False for the multiple scheme, whose covariances are conditional); samples fed;
    cross_group_covariance_tracked: False for the multiple-EKF scheme (off-block entries zero)."""

    parameters: LuGreParameters
    z: float
    covariance: np.ndarray
    std: np.ndarray
    correlation: np.ndarray
    identifiable: dict
    samples: int
    cross_group_covariance_tracked: bool

    def summary(self) -> str:
        """One line per parameter: estimate +- std and identifiability."""
        theta = self.parameters.as_array()
        return "\n".join(
            f"{name:7s} {value:12.5g} +- {std:10.3g}  {'identifiable' if self.identifiable[name] else 'weak'}"
            for name, value, std in zip(PARAMETER_NAMES, theta, self.std))


class _JointEKF:
    """Joint EKF over a subset ``indices`` (always containing 0 = z) of the normalised augmented state."""

    def __init__(self, indices: np.ndarray, covariance: np.ndarray, random_walk: np.ndarray):
        self.indices = indices
        self.covariance = covariance
        self.random_walk = random_walk            # normalised variance growth per second, per state in indices

    def update(self, state: np.ndarray, scale: np.ndarray, innovation: float, output_gradient: np.ndarray,
               measurement_variance: float) -> None:
        h = output_gradient[self.indices] * scale[self.indices]
        ph = self.covariance @ h
        gain = ph / (h @ ph + measurement_variance)
        state[self.indices] += scale[self.indices] * gain * innovation
        state[1:] = np.maximum(state[1:], _LOWER_BOUND_FRACTION * scale[1:])
        i_kh = np.eye(h.size) - np.outer(gain, h)
        self.covariance = i_kh @ self.covariance @ i_kh.T + measurement_variance * np.outer(gain, gain)

    def predict(self, transition_row: np.ndarray, scale: np.ndarray, dt: float) -> None:
        sub = np.eye(self.indices.size)
        sub[0] = transition_row[self.indices] * scale[self.indices] / scale[0]
        self.covariance = sub @ self.covariance @ sub.T + np.diag(self.random_walk * dt)


class LuGreEstimator:
    """Online joint-EKF identification of seed 003 eqs. 1-2 from (depth, velocity, axial force) samples.

    initial: prior guess; initial_std: (6,) prior standard deviations [SI]; measurement_std: force noise [N] (seed 003:
    R = 0.01 N^2); groups: None = one joint EKF over all six, ``TABLE_I_GROUPS`` = the seed's three;
    parameter_random_walk: (6,) [unit/sqrt(s)] (0 = constant); z_random_walk [m/sqrt(s)]; z_std0: prior std of z [m]
    (z starts at 0, outside the tissue); velocity_scale: sgn regularisation [m/s] (0 = exact sign);
    identifiability_tolerance: relative posterior std for "identifiable"; dwell: samples per filter turn."""

    def __init__(self, initial: LuGreParameters, initial_std, measurement_std: float, groups=None,
                 parameter_random_walk=None, z_random_walk: float = 0.0, z_std0: float = 1e-6,
                 velocity_scale: float = 0.0, identifiability_tolerance: float = 0.05, dwell: int = 1):
        initial_std = np.asarray(initial_std, dtype=float)
        if initial_std.shape != (6,) or np.any(initial_std <= 0.0) or not np.all(np.isfinite(initial_std)):
            raise ValueError("LuGreEstimator: initial_std must be 6 finite positive values")
        if not measurement_std > 0.0:
            raise ValueError(f"LuGreEstimator: measurement_std must be > 0, got {measurement_std!r}")
        if dwell < 1:
            raise ValueError(f"LuGreEstimator: dwell must be >= 1, got {dwell!r}")
        walk = np.zeros(6) if parameter_random_walk is None else np.asarray(parameter_random_walk, dtype=float)
        self._state = np.concatenate([[0.0], initial.as_array()])
        self._scale = np.concatenate([[_Z_SCALE], initial_std])
        self._measurement_variance = measurement_std**2
        self._velocity_scale = velocity_scale
        self._tolerance = identifiability_tolerance
        self._dwell = dwell
        names = [list(PARAMETER_NAMES)] if groups is None else [list(g) for g in groups]
        flat = [n for g in names for n in g]
        if sorted(flat) != sorted(set(flat)) or not set(flat) <= set(PARAMETER_NAMES):
            raise ValueError(f"LuGreEstimator: groups must be disjoint subsets of {PARAMETER_NAMES}, got {groups!r}")
        walk_normalised = np.concatenate([[(z_random_walk / self._scale[0]) ** 2], (walk / initial_std) ** 2])
        self._filters = []
        for group in names:
            indices = np.array([0] + [1 + PARAMETER_NAMES.index(n) for n in group])
            prior = np.eye(indices.size)
            prior[0, 0] = (z_std0 / _Z_SCALE) ** 2
            self._filters.append(_JointEKF(indices, prior, walk_normalised[indices]))
        self._samples = 0

    def feed(self, depth: float, velocity: float, force: float, dt: float) -> None:
        """Process one sample: measurement update with f_k at (l_k, l'_k), then RK3 prediction over dt [s]."""
        if not (np.isfinite(depth) and np.isfinite(velocity) and np.isfinite(force)) or not dt > 0.0:
            raise ValueError("LuGreEstimator.feed: depth, velocity and force must be finite and dt > 0")
        active = self._filters[(self._samples // self._dwell) % len(self._filters)]
        predicted, gradient = axial_force(self._state[0], self._state[1:], depth, velocity, self._velocity_scale)
        if depth > 0.0:                                 # out of the tissue the force carries no information
            active.update(self._state, self._scale, force - predicted, gradient, self._measurement_variance)
        z_next, row = rk3_step(self._state[0], self._state[1:], depth, velocity, dt, self._velocity_scale)
        self._state[0] = z_next
        for ekf in self._filters:
            ekf.predict(row, self._scale, dt)
        if not (np.all(np.isfinite(self._state)) and all(np.all(np.isfinite(e.covariance)) for e in self._filters)):
            raise FloatingPointError(f"LuGreEstimator diverged at sample {self._samples} (non-finite state or "
                                     "covariance); retune the priors or noise intensities")
        self._samples += 1

    def estimate(self) -> LuGreEstimate:
        """Current estimates with covariance, correlation and identifiability."""
        covariance = np.zeros((7, 7))  # parameters outside every group (known) keep zero variance
        for ekf in self._filters:
            block = ekf.covariance * np.outer(self._scale[ekf.indices], self._scale[ekf.indices])
            covariance[np.ix_(ekf.indices[1:], ekf.indices[1:])] = block[1:, 1:]
        cov = covariance[1:, 1:]
        std = np.sqrt(np.maximum(np.diag(cov), 0.0))
        safe = np.where(std > 0.0, std, 1.0)
        correlation = cov / np.outer(safe, safe)
        np.fill_diagonal(correlation, 1.0)
        theta = self._state[1:]
        joint = len(self._filters) == 1
        identifiable = {name: joint and bool(std[i] <= self._tolerance * abs(theta[i]))
                        for i, name in enumerate(PARAMETER_NAMES)}
        return LuGreEstimate(LuGreParameters.from_array(theta), float(self._state[0]), cov, std, correlation,
                             identifiable, self._samples, joint)


def fisher_information(parameters: LuGreParameters, depth, velocity, dt: float, measurement_std: float,
                       velocity_scale: float = 0.0) -> np.ndarray:
    """Fisher information (6, 6) of theta from one record (z_0 = 0, white force noise of ``measurement_std``):
    sum_k J_k J_k^T / sigma^2 with J_k = df_k/dtheta including the sensitivity of z.  Its inverse is the
    Cramer-Rao bound on the covariance of any unbiased estimator, i.e. what the record can identify at all."""
    theta = parameters.as_array()
    z, dz = 0.0, np.zeros(6)
    information = np.zeros((6, 6))
    for l_k, v_k in zip(np.asarray(depth, dtype=float), np.asarray(velocity, dtype=float)):
        _, gradient = axial_force(z, theta, l_k, v_k, velocity_scale)
        j = gradient[1:] + gradient[0] * dz
        information += np.outer(j, j)
        z, row = rk3_step(z, theta, l_k, v_k, dt, velocity_scale)
        dz = row[1:] + row[0] * dz
    return information / measurement_std**2


def identify_record(depth, velocity, force, dt: float, initial: LuGreParameters, initial_std,
                    measurement_std: float, **estimator_options) -> LuGreEstimate:
    """Run a ``LuGreEstimator`` over a recorded (depth, velocity, force) series sampled every dt [s] and return
    the final estimate; ``estimator_options`` go to ``LuGreEstimator`` (e.g. ``groups=TABLE_I_GROUPS``)."""
    estimator = LuGreEstimator(initial, initial_std, measurement_std, **estimator_options)
    for l_k, v_k, f_k in zip(depth, velocity, force):
        estimator.feed(float(l_k), float(v_k), float(f_k), dt)
    return estimator.estimate()
