"""Insertion force profile of seed 002 (stiffness, Fourier friction, cutting) and its identification.

Eq. 1:  F_s(x) = a1 x + a2 x^2                                       for x <= d1 (d1: the peak before puncture)
Eq. 2:  F_f(x) = sum_{i=0..M} A_i cos(w_i x) + B_i sin(w_i x)        after puncture (w_0 = 0: the mean friction)
Eq. 3:  F_c(x) = F_a(x) - F_f(x)  for d1 < x < d2, else 0            (cutting = measured total - friction)

x is the needle displacement (insertion depth) [m], d1 the puncture depth, d2 the depth at which the needle has
passed through the tissue.  The seed prints a1 = 0.0019 and a2 = 0.0499 without units; with x in mm and F in N
(the scale of its Fig. 6) that is a1 = 1.9 N/m and a2 = 4.99e4 N/m^2.  Eq. 3 only defines the cutting force from a
recorded total; for simulation the profile keeps its mean over (d1, d2) as a constant cutting force.

Signs: all forces here are magnitudes resisting insertion (positive while inserting).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares


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

    def stiffness_slope(self, x):
        """dF_s/dx [N/m]."""
        return self.a1 + 2.0 * self.a2 * np.asarray(x, dtype=float)

    def friction_force(self, x):
        """Eq. 2 [N]."""
        x = np.asarray(x, dtype=float)
        w = np.asarray(self.frequencies, dtype=float)
        phase = np.multiply.outer(x, w)
        return (self.cos_coefficients[0] + np.cos(phase) @ np.asarray(self.cos_coefficients[1:])
                + np.sin(phase) @ np.asarray(self.sin_coefficients))

    def friction_slope(self, x):
        """dF_f/dx [N/m]."""
        x = np.asarray(x, dtype=float)
        w = np.asarray(self.frequencies, dtype=float)
        phase = np.multiply.outer(x, w)
        return (-np.sin(phase) @ (w * np.asarray(self.cos_coefficients[1:]))
                + np.cos(phase) @ (w * np.asarray(self.sin_coefficients)))

    def total_force(self, x, exit_depth: float = np.inf):
        """Model of the measured insertion force F_a [N] for a monotonic insertion to depth x: eq. 1 before d1,
        friction + cutting between d1 and d2 = ``exit_depth``, friction alone beyond."""
        x = np.asarray(x, dtype=float)
        cutting = np.where(x < exit_depth, self.cutting_force, 0.0)
        return np.where(x <= self.puncture_depth, self.stiffness_force(x), self.friction_force(x) + cutting)


@dataclass(frozen=True)
class ProfileFit:
    """Result of ``fit_insertion_profile``: the identified profile, the eq. 3 cutting force series on the
    samples with d1 < x < d2 (``cutting_depth``, ``cutting_series``) and the RMS residual [N] of the full model."""

    profile: InsertionForceProfile
    cutting_depth: np.ndarray
    cutting_series: np.ndarray
    rms_residual: float


def detect_puncture(depth: np.ndarray, force: np.ndarray, drop_window: float) -> int:
    """Index of the puncture: the sample after which the force falls most within ``drop_window`` [m] of depth
    (the peak followed by the sharp decrease of seed 002 Fig. 5)."""
    ahead = np.searchsorted(depth, depth + drop_window, side="right")
    drops = np.zeros(depth.size)
    for i in np.flatnonzero(ahead > np.arange(depth.size) + 1):     # offline tool: n ~ 1e3..1e4 samples
        drops[i] = force[i] - force[i + 1:ahead[i]].min()
    return int(np.argmax(drops))


def fit_insertion_profile(depth, force, n_frequencies: int = 2, exit_depth: float | None = None,
                          drop_window: float = 1e-3) -> ProfileFit:
    """Identify a1, a2, d1, the Fourier friction terms and the cutting force from a force-vs-depth record.

    depth [m] (monotonically increasing insertion), force [N] (measured total F_a).
    n_frequencies: M, the number of dominant frequencies kept (seed 002 keeps two).
    exit_depth: d2 if the record goes through the tissue; the friction is then fitted on x > d2 (phase III, as in
    the seed) and the cutting force on d1 < x < d2.  Without it the friction and the (constant) cutting force are
    fitted together on x > d1: they are then only separable through the series' shape, so the split is
    reported with the mean friction A_0 absorbing any constant part (cutting_force = 0).
    Steps: puncture = largest force drop; eq. 1 by linear least squares on x < d1 (no intercept); dominant
    frequencies from the FFT of the uniformly resampled, mean-removed friction; then all of eq. 2 (A_i, B_i,
    w_i) refined by nonlinear least squares; eq. 3 as the residual total - friction.
    """
    x = np.asarray(depth, dtype=float)
    f = np.asarray(force, dtype=float)
    if x.ndim != 1 or x.shape != f.shape or x.size < 8:
        raise ValueError("fit_insertion_profile: depth and force must be 1-D arrays of equal length >= 8")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(f))):
        raise ValueError("fit_insertion_profile: depth and force must be finite")
    if np.any(np.diff(x) <= 0.0):
        raise ValueError("fit_insertion_profile: depth must increase strictly (one insertion)")
    if n_frequencies < 0:
        raise ValueError(f"fit_insertion_profile: n_frequencies must be >= 0, got {n_frequencies}")

    i_puncture = detect_puncture(x, f, drop_window)
    d1 = float(x[i_puncture])
    pre = x <= d1
    design = np.column_stack([x[pre], x[pre] ** 2])
    (a1, a2), *_ = np.linalg.lstsq(design, f[pre], rcond=None)

    separate_cutting = exit_depth is not None and exit_depth < x[-1]
    friction_mask = x > (exit_depth if separate_cutting else d1)
    xf, ff = x[friction_mask], f[friction_mask]
    if xf.size < 2 * n_frequencies + 2:
        raise ValueError("fit_insertion_profile: too few samples in the friction phase for "
                         f"{n_frequencies} frequencies")

    grid = np.linspace(xf[0], xf[-1], xf.size)
    resampled = np.interp(grid, xf, ff)
    spectrum = np.abs(np.fft.rfft(resampled - resampled.mean()))
    wavenumbers = 2.0 * np.pi * np.fft.rfftfreq(grid.size, grid[1] - grid[0])
    spectrum[0] = 0.0
    peaks = [k for k in range(1, spectrum.size - 1)
             if spectrum[k] >= spectrum[k - 1] and spectrum[k] >= spectrum[k + 1]]
    peaks = sorted(peaks, key=lambda k: -spectrum[k])[:n_frequencies]
    w0 = np.array(sorted(wavenumbers[k] for k in peaks))
    m = w0.size

    def linear_coefficients(w):
        basis = np.column_stack([np.ones_like(xf), np.cos(np.outer(xf, w)), np.sin(np.outer(xf, w))])
        coefficients, *_ = np.linalg.lstsq(basis, ff, rcond=None)
        return basis, coefficients

    def residual(w):                                   # variable projection: A, B solved for each w
        basis, coefficients = linear_coefficients(w)
        return basis @ coefficients - ff

    if m:
        w = least_squares(residual, w0, x_scale=np.maximum(w0, 1.0)).x
    else:
        w = w0
    _, coefficients = linear_coefficients(w)
    cos_coefficients = tuple(float(c) for c in coefficients[: m + 1])
    sin_coefficients = tuple(float(c) for c in coefficients[m + 1:])

    friction_only = InsertionForceProfile(float(a1), float(a2), d1, tuple(float(v) for v in w),
                                          cos_coefficients, sin_coefficients, 0.0)
    cut_mask = (x > d1) & (x < (exit_depth if separate_cutting else np.inf))
    cutting_series = f[cut_mask] - friction_only.friction_force(x[cut_mask])
    cutting_force = float(cutting_series.mean()) if separate_cutting and cutting_series.size else 0.0
    profile = InsertionForceProfile(float(a1), float(a2), d1, friction_only.frequencies, cos_coefficients,
                                    sin_coefficients, cutting_force)
    model = profile.total_force(x, exit_depth if separate_cutting else np.inf)
    return ProfileFit(profile, x[cut_mask], cutting_series, float(np.sqrt(np.mean((model - f) ** 2))))
