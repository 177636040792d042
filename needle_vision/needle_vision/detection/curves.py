"""Small operations on ordered polylines ``(n, d)``: arc length, resampling, moving average."""
from __future__ import annotations

from functools import lru_cache

import numba
import numpy as np
from scipy.ndimage import correlate1d


@numba.njit(cache=True, nogil=True)
def step_lengths(points):  # pragma: no cover - compiled
    """Distances between consecutive points of ``(n, d)`` points: ``(n - 1,)``."""
    n, d = points.shape
    out = np.empty(max(n - 1, 0))
    for k in range(1, n):
        step = 0.0
        for j in range(d):
            step += (points[k, j] - points[k - 1, j]) * (points[k, j] - points[k - 1, j])
        out[k - 1] = np.sqrt(step)
    return out


@numba.njit(cache=True, nogil=True)
def arc_length(points):  # pragma: no cover - compiled
    """Cumulative chord length from the first point of ``(n, d)`` points: ``(n,)``."""
    out = np.zeros(points.shape[0])
    out[1:] = np.cumsum(step_lengths(points))
    return out


@numba.njit(cache=True, nogil=True)
def run_bounds(points, split):  # pragma: no cover - compiled
    """0, the index after each step longer than ``split`` between consecutive ``points``, and their count."""
    steps = step_lengths(points)
    bounds = np.empty(steps.shape[0] + 2, np.int64)
    bounds[0] = 0
    count = 1
    for k in range(steps.shape[0]):
        if steps[k] > split:
            bounds[count] = k + 1
            count += 1
    bounds[count] = points.shape[0]
    return bounds[:count + 1]


@numba.njit(cache=True, nogil=True)
def median(values):  # pragma: no cover - compiled
    """np.median of ``(n,)`` values, compiled (releases the GIL, none of NumPy's per-call overhead)."""
    return np.median(values)


@numba.njit(cache=True, nogil=True)
def derivative(values, parameter):  # pragma: no cover - compiled
    """d values / d parameter of samples ``(n,)`` at increasing ``parameter (n,)`` (central differences, one-sided
    at the ends)."""
    n = values.shape[0]
    out = np.empty(n)
    for k in range(1, n - 1):
        out[k] = (values[k + 1] - values[k - 1]) / (parameter[k + 1] - parameter[k - 1])
    out[0] = (values[1] - values[0]) / (parameter[1] - parameter[0])
    out[n - 1] = (values[n - 1] - values[n - 2]) / (parameter[n - 1] - parameter[n - 2])
    return out


def interpolate(arc: np.ndarray, values: np.ndarray, at: np.ndarray) -> np.ndarray:
    """Piecewise-linear ``values (n, d)`` given at increasing ``arc (n,)``, evaluated at ``at (m,)``
    (clamped to the end values outside)."""
    return np.column_stack([np.interp(at, arc, values[:, k]) for k in range(values.shape[1])])


def resample(points: np.ndarray, count: int) -> np.ndarray:
    """``count`` points equally spaced in arc length along the polyline (ends kept)."""
    arc = arc_length(points)
    return interpolate(arc, points, np.linspace(0.0, arc[-1], count))


@numba.njit(cache=True, nogil=True)
def moving_average(values, window):  # pragma: no cover - compiled
    """Centred moving average along axis 0 of ``(n, d)`` values; the window shrinks symmetrically at the
    ends so that the end points stay put."""
    n, d = values.shape
    out = np.empty_like(values)
    half = window // 2
    for k in range(n):
        h = min(half, k, n - 1 - k)
        for j in range(d):
            total = 0.0
            for i in range(k - h, k + h + 1):
                total += values[i, j]
            out[k, j] = total / (2 * h + 1)
    return out


@lru_cache(maxsize=32)
def _polynomial_projector(window: int, order: int) -> np.ndarray:
    """Hat matrix of a least-squares polynomial fit of ``order`` to ``window`` equally spaced samples."""
    vandermonde = np.vander(np.arange(window) - window // 2, order + 1, increasing=True)
    return vandermonde @ np.linalg.pinv(vandermonde)


def local_polynomial_smooth(values: np.ndarray, window: int, order: int = 3) -> np.ndarray:
    """Savitzky-Golay smoothing of ``(n, d)`` samples along axis 0: each sample is replaced by the value at it
    of the polynomial fitted over the ``window`` (odd) samples centred on it; the first and last
    ``window // 2`` samples take the fit of the first/last full window (polynomial extrapolation, no
    shrinking towards the ends). Requires ``n >= window``."""
    values = np.asarray(values, dtype=float)
    if window % 2 == 0 or window > len(values) or window <= order:
        raise ValueError(f"window {window} must be odd, > order {order} and <= the {len(values)} samples")
    projector = _polynomial_projector(window, order)
    half = window // 2
    out = correlate1d(values, projector[half], axis=0, mode="nearest")
    out[:half] = projector[:half] @ values[:window]
    out[-half:] = projector[-half:] @ values[-window:]
    return out

