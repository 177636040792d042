"""The needle's centerline as one 3D curve fitted to both views at once (issue 39).

A uniform cubic B-spline ``C(u)`` (``u`` ~ arc length, control points every ``knot_spacing``) in the left
rectified camera frame minimises

    sum_i (n_i . (q_i - P_v(C(u_i))))^2 / sigma_i^2  +  sum_ends (t_end . (q_end - P_v(C(u_end))))^2 / sigma_end^2
    +  bending_weight * integral |C''(u)|^2 du

over every detected centerline point ``q_i`` of both rectified views ``v`` (``u_i`` its foot on the projected curve,
``n_i`` the projected curve's normal there, ``sigma_i`` its local image noise), the four image ends and a bending-energy
prior (Gauss-Newton, the feet re-projected each iteration, Huber weights against stray points). Where the needle runs
along the epipolar lines the images say nothing about depth; the curve's continuity carries it across from the stretches
around, and the fit's covariance (the normal matrix's inverse: image noise through the Jacobian, with the prior; the
image noise's correlated part widens the image terms only) says how well: each sample's sigma is the standard deviation
along the worst direction across the needle. The per-point triangulation is the initial guess.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numba
import numpy as np

#: Half-bandwidth of the normal matrix: a cubic B-spline couples control points up to 3 apart, 3 coordinates each.
_BAND = 11
#: Steps between consecutive image points farther apart than this [px] (a hidden stretch) restart the foot search.
_JUMP_PX = 8.0


@dataclass(frozen=True)
class CurveFit:
    """The fitted curve sampled densely from its first to its last control parameter: ``points (n, 3)`` in the left
    rectified frame [m], ``sigma (n,)`` [m] (1-sigma across the needle, worst direction), ``supported (n,)`` (both
    views have image points within ``max_gap`` around the sample) and ``parameters (n,)`` [m] (the samples' curve
    parameter: the arc length along the initial points)."""

    points: np.ndarray
    sigma: np.ndarray
    supported: np.ndarray
    parameters: np.ndarray


@numba.njit(cache=True, nogil=True)
def _basis(u, h, segments, b, d1):  # pragma: no cover - compiled
    """Segment index of ``u``; its 4 basis values ``b`` and first derivatives ``d1`` (d/du) of a uniform cubic
    B-spline, written into the given arrays."""
    s = min(max(int(u / h), 0), segments - 1)
    t = u / h - s
    c = 1.0 - t
    b[0], b[1], b[2], b[3] = c * c * c / 6, (3 * t * t * t - 6 * t * t + 4) / 6, \
        (-3 * t * t * t + 3 * t * t + 3 * t + 1) / 6, t * t * t / 6
    d1[0], d1[1], d1[2], d1[3] = -c * c / (2 * h), (3 * t * t - 4 * t) / (2 * h), (-3 * t * t + 2 * t + 1) / (2 * h), \
        t * t / (2 * h)
    return s


@numba.njit(cache=True, nogil=True)
def _evaluate(control, u, h, segments, b, d1, point, derivative):  # pragma: no cover - compiled
    """The curve's point and derivative at ``u`` into the arrays (its basis into ``b``, ``d1``); its segment index."""
    s = _basis(u, h, segments, b, d1)
    for k in range(3):
        point[k] = b[0] * control[s, k] + b[1] * control[s + 1, k] + b[2] * control[s + 2, k] \
            + b[3] * control[s + 3, k]
        derivative[k] = d1[0] * control[s, k] + d1[1] * control[s + 1, k] + d1[2] * control[s + 2, k] \
            + d1[3] * control[s + 3, k]
    return s


@numba.njit(cache=True, nogil=True)
def _project(projection, point, derivative, pixel, jacobian, tangent):  # pragma: no cover - compiled
    """Pixel (2,) of a rectified-frame point through a 3x4 projection, its Jacobian (2, 3) and the projected
    ``derivative`` (2,), into the arrays."""
    w = projection[2, 0] * point[0] + projection[2, 1] * point[1] + projection[2, 2] * point[2] + projection[2, 3]
    for r in range(2):
        pixel[r] = (projection[r, 0] * point[0] + projection[r, 1] * point[1] + projection[r, 2] * point[2]
                    + projection[r, 3]) / w
        for k in range(3):
            jacobian[r, k] = (projection[r, k] - pixel[r] * projection[2, k]) / w
        tangent[r] = jacobian[r, 0] * derivative[0] + jacobian[r, 1] * derivative[1] + jacobian[r, 2] * derivative[2]


@numba.njit(cache=True, nogil=True)
def _accumulate(normal, rhs, s, b, jacobian, nx, ny, row, weight, residual):  # pragma: no cover - compiled
    """One weighted scalar residual of segment ``s`` along the image direction (``nx``, ``ny``) into the normal
    equations: its row (d residual / d point: the direction through the projection's ``jacobian``, into ``row``)
    spread over the segment's four control points by the basis ``b`` (lower triangle of ``normal``)."""
    for k in range(3):
        row[k] = nx * jacobian[0, k] + ny * jacobian[1, k]
    for a in range(4):
        wa = weight * b[a]
        for c in range(a, 4):
            w = wa * b[c]
            for i in range(3):
                for j in range(3):
                    normal[3 * (s + c) + i, 3 * (s + a) + j] += w * row[j] * row[i]
        for k in range(3):
            rhs[3 * (s + a) + k] += wa * row[k] * residual


@numba.njit(cache=True, nogil=True)
def _cholesky(matrix):  # pragma: no cover - compiled
    """Lower Cholesky factor of a symmetric positive definite band matrix (half-bandwidth _BAND), in place."""
    n = matrix.shape[0]
    for j in range(n):
        value = matrix[j, j]
        for k in range(max(0, j - _BAND), j):
            value -= matrix[j, k] * matrix[j, k]
        if value <= 0.0:
            return False
        matrix[j, j] = np.sqrt(value)
        for i in range(j + 1, min(n, j + _BAND + 1)):
            value = matrix[i, j]
            for k in range(max(0, i - _BAND), j):
                value -= matrix[i, k] * matrix[j, k]
            matrix[i, j] = value / matrix[j, j]
    return True


@numba.njit(cache=True, nogil=True)
def _solve(factor, rhs):  # pragma: no cover - compiled
    n = factor.shape[0]
    y = rhs.copy()
    for i in range(n):
        for k in range(max(0, i - _BAND), i):
            y[i] -= factor[i, k] * y[k]
        y[i] /= factor[i, i]
    for i in range(n - 1, -1, -1):
        for k in range(i + 1, min(n, i + _BAND + 1)):
            y[i] -= factor[k, i] * y[k]
        y[i] /= factor[i, i]
    return y


@numba.njit(cache=True, nogil=True)
def _inverse_band(factor):  # pragma: no cover - compiled
    """The band (half-bandwidth _BAND) of the inverse of L L^T from its Cholesky factor L (Takahashi's recurrence:
    (Z L)[i, j] = delta_ij / L[j, j] for i >= j)."""
    n = factor.shape[0]
    z = np.zeros((n, n))
    for j in range(n - 1, -1, -1):
        top = min(n - 1, j + _BAND)
        for i in range(top, j - 1, -1):
            value = 1.0 / factor[j, j] if i == j else 0.0
            for k in range(j + 1, top + 1):
                value -= (z[i, k] if i >= k else z[k, i]) * factor[k, j]
            z[i, j] = value / factor[j, j]
    return z


@numba.njit(cache=True, nogil=True)
def _bending_matrix(count, h):  # pragma: no cover - compiled
    """R with c^T R c = integral of |C''(u)|^2 du per coordinate (count control points, knot spacing h): the
    bending energy of a rod (over its stiffness / 2) when u is its arc length."""
    r = np.zeros((count, count))
    nodes = (0.5 - 0.5 / np.sqrt(3.0), 0.5 + 0.5 / np.sqrt(3.0))
    for s in range(count - 3):
        for t in nodes:
            d2 = np.array([1 - t, 3 * t - 2, 1 - 3 * t, t])
            for a in range(4):
                for b in range(4):
                    r[s + a, s + b] += 0.5 * d2[a] * d2[b] / (h * h * h)
    return r


@numba.njit(cache=True, nogil=True)
def _initial_control(points, abscissa, weights, count, h, bending):  # pragma: no cover - compiled
    """Control points of the spline fitted to ``points (n, 3)`` at ``abscissa`` (weighted, with the prior)."""
    segments = count - 3
    normal = bending * _bending_matrix(count, h)
    rhs = np.zeros((count, 3))
    b, d1 = np.empty(4), np.empty(4)
    for i in range(points.shape[0]):
        s = _basis(abscissa[i], h, segments, b, d1)
        for a in range(4):
            for c in range(4):
                normal[s + a, s + c] += weights[i] * b[a] * b[c]
            for k in range(3):
                rhs[s + a, k] += weights[i] * b[a] * points[i, k]
    scale = 1e-9 * max(np.max(np.abs(np.diag(normal))), 1e-300)
    for i in range(count):
        normal[i, i] += scale
    if not _cholesky(normal):  # the same matrix for each coordinate
        return np.full((count, 3), np.nan)
    return np.column_stack((_solve(normal, rhs[:, 0].copy()), _solve(normal, rhs[:, 1].copy()),
                            _solve(normal, rhs[:, 2].copy())))


@numba.njit(cache=True, nogil=True)
def _feet(control, h, segments, length, projection, observations, feet, first, steps):  # pragma: no cover
    """Feet of every image point on the projected curve, ``steps`` Gauss-Newton steps each from the previous ones
    (``first``: from the nearest of the projected curve sampled every 1 mm, walked from point to point and searched
    afresh after a jump), clamped to [0, length]."""
    n = observations.shape[0]
    b, d1, point, derivative = np.empty(4), np.empty(4), np.empty(3), np.empty(3)
    pixel, jacobian, tangent = np.empty(2), np.empty((2, 3)), np.empty(2)
    if first:
        samples = max(int(length / 1e-3), 8) + 1
        grid = np.empty(samples)
        pixels = np.empty((samples, 2))
        for k in range(samples):
            grid[k] = length * k / (samples - 1)
            _evaluate(control, grid[k], h, segments, b, d1, point, derivative)
            _project(projection, point, derivative, pixel, jacobian, tangent)
            pixels[k] = pixel
        current = -1
        for i in range(n):
            q = observations[i]
            jump = i == 0 or (q[0] - observations[i - 1, 0]) ** 2 + (q[1] - observations[i - 1, 1]) ** 2 > _JUMP_PX ** 2
            if jump:
                best = np.inf
                for k in range(samples):
                    d = (pixels[k, 0] - q[0]) ** 2 + (pixels[k, 1] - q[1]) ** 2
                    if d < best:
                        best, current = d, k
            else:
                d = (pixels[current, 0] - q[0]) ** 2 + (pixels[current, 1] - q[1]) ** 2
                for step in (1, -1):
                    while 0 <= current + step < samples:
                        e = (pixels[current + step, 0] - q[0]) ** 2 + (pixels[current + step, 1] - q[1]) ** 2
                        if e >= d:
                            break
                        d, current = e, current + step
            feet[i] = grid[current]
    for i in range(n):
        u = feet[i]
        for _ in range(steps):
            _evaluate(control, u, h, segments, b, d1, point, derivative)
            _project(projection, point, derivative, pixel, jacobian, tangent)
            norm2 = tangent[0] * tangent[0] + tangent[1] * tangent[1]
            if norm2 <= 0.0:
                break
            u = min(max(u + ((observations[i, 0] - pixel[0]) * tangent[0]
                             + (observations[i, 1] - pixel[1]) * tangent[1]) / norm2, 0.0), length)
        feet[i] = u


@numba.njit(cache=True, nogil=True)
def _gauss_newton(control, h, length, observations, views, noise, multiplicity, ends, end_noise, projections,
                  bending, iterations, huber, inflation):  # pragma: no cover - compiled
    """Fit (module docstring) from ``control (K, 3)``. ``observations (m, 2)`` rectified image points of both
    views (``views (m,)``: 0 left, 1 right; each view's points consecutive and in its curve order), ``noise (m,)``
    [px] (each point stands for ``multiplicity`` image points), ``ends (2, 2, 2)``: where each view sees the curve's
    first and last point, ``projections (2, 3, 4)``; ``iterations`` steps. Returns
    the control points, the Cholesky factor of their covariance's inverse (the normal matrix at the result with the
    image terms' variance times ``inflation`` and the residuals' reduced chi-square when above 1, the prior's not),
    the feet and the normalised RMS residual; NaN control points when the normal matrix is singular."""
    count = control.shape[0]
    segments = count - 3
    size = 3 * count
    m = observations.shape[0]
    prior = bending * _bending_matrix(count, h)
    feet = np.zeros(m)
    normal = np.zeros((size, size))
    b, d1, point, derivative = np.empty(4), np.empty(4), np.empty(3), np.empty(3)
    pixel, jacobian, tangent, row = np.empty(2), np.empty((2, 3)), np.empty(2), np.empty(3)
    rms = 0.0
    for iteration in range(iterations + 1):  # the last pass: the covariance, feet and residuals at the result
        for v in range(2):
            index = np.flatnonzero(views == v)
            view_feet = feet[index]
            _feet(control, h, segments, length, projections[v], observations[index], view_feet, iteration == 0,
                  3 if iteration == 0 else 1)
            feet[index] = view_feet
        normal[:] = 0.0
        rhs = np.zeros(size)
        total, used = 0.0, 0
        for i in range(m):
            u = feet[i]
            s = _evaluate(control, u, h, segments, b, d1, point, derivative)
            _project(projections[views[i]], point, derivative, pixel, jacobian, tangent)
            norm = np.sqrt(tangent[0] * tangent[0] + tangent[1] * tangent[1])
            if norm <= 0.0:
                continue
            # Across the projected curve; at a point beyond the curve's end (its foot clamped) in both directions.
            beyond = not 0.0 < u < length
            for direction in range(2 if beyond else 1):
                if beyond:
                    nx, ny = (1.0, 0.0) if direction == 0 else (0.0, 1.0)
                else:
                    nx, ny = -tangent[1] / norm, tangent[0] / norm
                residual = nx * (observations[i, 0] - pixel[0]) + ny * (observations[i, 1] - pixel[1])
                scaled = abs(residual) / noise[i]
                if not beyond:
                    total += scaled * scaled
                    used += 1
                weight = multiplicity * min(1.0, huber / max(scaled, 1e-12)) / (noise[i] * noise[i])
                _accumulate(normal, rhs, s, b, jacobian, nx, ny, row, weight, residual)
        rms = np.sqrt(total / max(used, 1))
        for v in range(2):
            for e in range(2):  # along the projected curve only: across it, the image points say it
                u = 0.0 if e == 0 else length
                s = _evaluate(control, u, h, segments, b, d1, point, derivative)
                _project(projections[v], point, derivative, pixel, jacobian, tangent)
                norm = max(np.sqrt(tangent[0] * tangent[0] + tangent[1] * tangent[1]), 1e-300)
                tx, ty = tangent[0] / norm, tangent[1] / norm
                residual = tx * (ends[v, e, 0] - pixel[0]) + ty * (ends[v, e, 1] - pixel[1])
                _accumulate(normal, rhs, s, b, jacobian, tx, ty, row, 1.0 / (end_noise * end_noise), residual)
        if iteration == iterations:
            # The covariance: the correlated image error and noisier images than their scatter said widen what the
            # images say (their terms' variance), not what the prior says.
            scale = 1.0 / (inflation * max(rms, 1.0) ** 2)
            for i in range(size):
                for j in range(max(0, i - _BAND), i + 1):
                    normal[i, j] *= scale
        for a in range(count):  # the prior: its curvature term and its gradient at the current control points
            for c in range(max(0, a - 3), min(count, a + 4)):
                for k in range(3):
                    rhs[3 * a + k] -= prior[a, c] * control[c, k]
                    if c >= a:
                        normal[3 * c + k, 3 * a + k] += prior[a, c]
        for i in range(size):  # symmetric: the lower triangle was accumulated
            for j in range(i + 1, min(size, i + _BAND + 1)):
                normal[i, j] = normal[j, i]
        if not _cholesky(normal):
            return np.full((count, 3), np.nan), normal, feet, rms
        if iteration == iterations:
            break
        step = _solve(normal, rhs)
        for a in range(count):
            for k in range(3):
                control[a, k] += step[3 * a + k]
    return control, normal, feet, rms


@numba.njit(cache=True, nogil=True)
def _sample(control, h, length, factor, spacing):  # pragma: no cover - compiled
    """Points and 1-sigma across the needle (worst direction of the covariance whose inverse's Cholesky factor is
    ``factor``) every ~``spacing`` of the parameter, from 0 to ``length``."""
    count = control.shape[0]
    segments = count - 3
    covariance = _inverse_band(factor)
    n = max(int(np.ceil(length / spacing)), 1) + 1
    points = np.empty((n, 3))
    sigma = np.empty(n)
    parameters = np.empty(n)
    b, d1, t = np.empty(4), np.empty(4), np.empty(3)
    block, e1, e2 = np.empty((3, 3)), np.empty(3), np.empty(3)
    for p in range(n):
        u = length * p / (n - 1)
        parameters[p] = u
        s = _evaluate(control, u, h, segments, b, d1, points[p], t)
        t /= max(np.sqrt(np.sum(t * t)), 1e-300)
        block[:] = 0.0
        for a in range(4):
            for c in range(4):
                weight = b[a] * b[c]
                for k in range(3):
                    for j in range(3):
                        row, col = 3 * (s + a) + k, 3 * (s + c) + j
                        block[k, j] += weight * (covariance[row, col] if row >= col else covariance[col, row])
        # Two unit vectors across the tangent (e1: the axis least along it, less its tangential part; e2 = t x e1);
        # the largest eigenvalue of the 2x2 covariance across the needle.
        axis = 0 if abs(t[0]) < 0.9 else 1
        for k in range(3):
            e1[k] = (1.0 if k == axis else 0.0) - t[axis] * t[k]
        e1 /= np.sqrt(np.sum(e1 * e1))
        e2[0], e2[1], e2[2] = t[1] * e1[2] - t[2] * e1[1], t[2] * e1[0] - t[0] * e1[2], t[0] * e1[1] - t[1] * e1[0]
        a11 = a22 = a12 = 0.0
        for k in range(3):
            for j in range(3):
                a11 += e1[k] * block[k, j] * e1[j]
                a22 += e2[k] * block[k, j] * e2[j]
                a12 += e1[k] * block[k, j] * e2[j]
        largest = 0.5 * (a11 + a22) + np.sqrt(0.25 * (a11 - a22) ** 2 + a12 * a12)
        sigma[p] = np.sqrt(max(largest, 0.0))
    return points, sigma, parameters


@numba.njit(cache=True, nogil=True)
def _support(length, left, right, feet, stride, parameters, max_gap):  # pragma: no cover - compiled
    """Whether both views have image points (``left``, ``right``: every one; their feet interpolated from the
    ``feet`` of their means of ``stride``) around each of the ``parameters`` with no gap above ``max_gap``."""
    supported = np.ones(parameters.shape[0], np.bool_)
    offset = 0
    for v in range(2):
        view = left if v == 0 else right
        merged = view.shape[0] // stride
        everything = np.interp(np.arange(view.shape[0]) * 1.0, stride * np.arange(merged) + 0.5 * (stride - 1),
                               feet[offset:offset + merged])
        offset += merged
        edges = np.empty(view.shape[0] + 2)
        edges[0], edges[-1] = 0.0, length
        edges[1:-1] = np.sort(everything)
        for p in range(parameters.shape[0]):
            k = min(max(np.searchsorted(edges, parameters[p]), 1), edges.shape[0] - 1)
            if edges[k] - edges[k - 1] > max_gap:
                supported[p] = False
    return supported


@numba.njit(cache=True, nogil=True)
def _fit(initial, initial_weights, ends, left, right, left_noise, right_noise, projections, knot_spacing, bending,
         end_noise, max_gap, sample_spacing, inflation, iterations, huber, stride):  # pragma: no cover - compiled
    """:func:`fit_curve` in one compiled call: success, points, sigma, supported, parameters."""
    steps = initial[1:] - initial[:-1]
    abscissa = np.concatenate((np.zeros(1), np.cumsum(np.sqrt((steps * steps).sum(axis=1)))))
    length = abscissa[-1]
    empty = np.empty((0, 3)), np.empty(0), np.empty(0, np.bool_), np.empty(0)
    if initial.shape[0] < 8 or not length > 4 * knot_spacing or min(left.shape[0], right.shape[0]) < 8:
        return False, *empty
    segments = max(int(np.ceil(length / knot_spacing)), 1)
    h = length / segments
    control = _initial_control(initial, abscissa, initial_weights, segments + 3, h, bending)
    if not np.all(np.isfinite(control)):
        return False, *empty
    # Means of ``stride`` consecutive points (keeping the cancellation of the centroids' alternating aliasing), each
    # weighted as ``stride`` points.
    counts = (left.shape[0] // stride, right.shape[0] // stride)
    observations = np.zeros((counts[0] + counts[1], 2))
    noise = np.zeros(counts[0] + counts[1])
    views = (np.arange(counts[0] + counts[1]) >= counts[0]).astype(np.int64)
    for i in range(counts[0] + counts[1]):
        view, variance = (left, left_noise) if i < counts[0] else (right, right_noise)
        first = stride * (i if i < counts[0] else i - counts[0])
        for j in range(first, first + stride):
            observations[i, 0] += view[j, 0] / stride
            observations[i, 1] += view[j, 1] / stride
            noise[i] += variance[j] ** 2 / stride
    control, factor, feet, rms = _gauss_newton(control, h, length, observations, views, np.sqrt(noise), float(stride),
                                               ends, end_noise, projections, bending, iterations, huber, inflation)
    if not np.all(np.isfinite(control)):
        return False, *empty
    points, sigma, parameters = _sample(control, h, length, factor, sample_spacing)
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(sigma))):
        return False, *empty
    # Support from every image point (a hidden stretch is no shorter than its gap between single points).
    return True, points, sigma, _support(length, left, right, feet, stride, parameters, max_gap), parameters


def fit_curve(initial: np.ndarray, initial_weights: np.ndarray, ends: np.ndarray,
              views: tuple[np.ndarray, np.ndarray], noise: tuple[np.ndarray, np.ndarray],
              projections: tuple[np.ndarray, np.ndarray], *,
              knot_spacing: float, bending_weight: float, end_noise_px: float, max_gap: float,
              sample_spacing: float, noise_inflation: float, iterations: int = 2, huber: float = 3.0,
              stride: int = 2) -> CurveFit | None:
    """Fit the curve (module docstring) to the rectified image centerlines ``views`` (left, right; ``(n, 2)`` each,
    ordered along the needle, either direction) with per-point ``noise`` [px], from the ordered triangulated points
    ``initial (k, 3)`` [m] in the left rectified frame (weights: their inverse variance) whose first and last points
    the two views see at ``ends (2, 2, 2)`` (view, end, pixel); ``projections``: the rectified 3x4 projections; the
    means of ``stride`` consecutive image points are fitted; ``noise_inflation``: the image terms' variance factor in
    the covariance (:func:`_gauss_newton`). None when the fit fails (singular or non-finite)."""
    array = partial(np.ascontiguousarray, dtype=float)
    success, points, sigma, supported, parameters = _fit(
        array(initial), array(initial_weights), array(ends), *map(array, views), *map(array, noise),
        array(np.stack(projections)), knot_spacing, bending_weight, end_noise_px, max_gap, sample_spacing,
        noise_inflation, iterations, huber, stride)
    return CurveFit(points, sigma, supported, parameters) if success else None
