"""Identification of the seed 002 insertion force profile (eqs. 1-3) from one recorded insertion: puncture depth,
stiffness by linear least squares, Fourier friction by nonlinear least squares, cutting as the residual."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

from needle_sim_ros.tissue.insertion_profile import InsertionForceProfile


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

    depth [m] (increasing), force [N] (measured total F_a); n_frequencies: M dominant frequencies kept (seed 002: 2).
    exit_depth: d2 if the record goes through the tissue: friction fitted on x > d2 (phase III), cutting force on
    d1 < x < d2; without it both on x > d1, A_0 absorbing any constant part (cutting_force = 0).
    Steps: puncture = largest force drop; eq. 1 by linear least squares on x < d1 (no intercept); frequencies from the
    FFT of the resampled, mean-removed friction; eq. 2 (A_i, B_i, w_i) refined by nonlinear least squares; eq. 3 as
    the residual total - friction."""
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

    w = least_squares(residual, w0, x_scale=np.maximum(w0, 1.0)).x if m else w0
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
