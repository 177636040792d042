"""Corresponding points of the left and right needle centerlines (seed 000, Sec. III-A: "using principles
from photogrammetry and projective geometry, the corresponding points between the two images are found").

After rectification a 3D point has the same epipolar coordinate ``e`` in both images, so along the needle ``e_left(s) =
e_right(t(s))`` for a monotone map ``t(s)`` between the two curves' arc lengths. Matching each left point to "the right
point on the same epipolar line" fails where the needle runs nearly parallel to the epipolar lines (``e`` barely
changes) or crosses one line several times. So the map comes from the curves as ordered wholes:

1. dynamic time warping of the two ``e``-profiles (coarsely resampled) gives a globally consistent monotone
   ``t(s)`` and also decides whether the right curve runs in the same direction as the left one;
2. where both curves cross the epipolar lines at more than ``min_epipolar_angle`` the match is refined to
   sub-pixel by solving ``e_right(t) = e_left(s)`` (Newton steps): these are the *anchors*;
3. elsewhere (parallel stretches, turning points of ``e``) ``t`` follows from continuity: linear in ``s``
   between the neighbouring anchors, extrapolated with the local ratio ``dt/ds`` beyond the last ones.
"""
from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np

from needle_vision.detection.centerline import GAP_PX
from needle_vision.detection.curves import arc_length, derivative, interpolate, moving_average, run_bounds


class MatchError(ValueError):
    """The two centerlines could not be put in correspondence (message says why)."""


@dataclass(frozen=True)
class MatchingConfig:
    """Settings of the correspondence search (names match the node's ``matching.*`` parameters)."""

    min_epipolar_angle_deg: float = 10.0  # anchors need both curves this far from parallel to epipolar lines
    max_epipolar_error_px: float = 1.0    # anchors whose e-residual exceeds this are dropped (not matched)
    dtw_spacing_px: float = 4.0           # resampling step of the coarse profiles for the warping
    continuity_weight: float = 0.05       # weak preference of the warping for proportional arc lengths


@dataclass(frozen=True)
class Correspondence:
    """Matched points, in left-curve order. ``left``: rectified left points ``(n, 2)``; ``right``: the matched
    rectified right points ``(n, 2)``; ``anchored``: matched along an epipolar line (else by continuity);
    ``sin_angle``: sine of the smaller angle between a curve and the epipolar lines at the match."""

    left: np.ndarray
    right: np.ndarray
    anchored: np.ndarray
    sin_angle: np.ndarray


@numba.njit(cache=True, nogil=True)
def _warp(e_left, e_right, prior_left, prior_right, prior_weight):  # pragma: no cover - compiled
    """Monotone alignment minimising sum((e_l - e_r)² + (w (p_l - p_r))²); returns (matched right index for
    each left index (mean over the path), mean cost per path step)."""
    n, m = e_left.shape[0], e_right.shape[0]
    total = np.full((n + 1, m + 1), np.inf)
    total[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            d = e_left[i - 1] - e_right[j - 1]
            p = prior_weight * (prior_left[i - 1] - prior_right[j - 1])
            total[i, j] = d * d + p * p + min(total[i - 1, j - 1], total[i - 1, j], total[i, j - 1])
    sums = np.zeros(n)
    counts = np.zeros(n)
    i, j, steps = n, m, 0
    while i > 0 and j > 0:
        sums[i - 1] += j - 1
        counts[i - 1] += 1
        steps += 1
        diagonal, up, left = total[i - 1, j - 1], total[i - 1, j], total[i, j - 1]
        if diagonal <= up and diagonal <= left:
            i, j = i - 1, j - 1
        elif up <= left:
            i -= 1
        else:
            j -= 1
    return sums / counts, total[n, m] / steps


@numba.njit(cache=True, nogil=True)
def _coarse_map(s, e_left, t, e_right, spacing, continuity_weight):  # pragma: no cover - compiled
    """Dense initial ``t(s)`` from warping profiles resampled every ``spacing`` px; and its mean cost."""
    s_coarse = np.linspace(0.0, s[-1], max(int(s[-1] / spacing), 2))
    t_coarse = np.linspace(0.0, t[-1], max(int(t[-1] / spacing), 2))
    scale = 0.5 * (s[-1] + t[-1])
    index, cost = _warp(np.interp(s_coarse, s, e_left), np.interp(t_coarse, t, e_right),
                        s_coarse / s[-1] * scale, t_coarse / t[-1] * scale, continuity_weight)
    return np.interp(s, s_coarse, np.interp(index, np.arange(t_coarse.shape[0]) * 1.0, t_coarse)), cost


@numba.njit(cache=True, nogil=True)
def _smooth_runs(points, window):  # pragma: no cover - compiled
    """Moving average of each run of points between gaps (steps > GAP_PX): never across a hidden stretch."""
    out = np.empty_like(points)
    bounds = run_bounds(points, GAP_PX)
    for k in range(bounds.shape[0] - 1):
        out[bounds[k]:bounds[k + 1]] = moving_average(points[bounds[k]:bounds[k + 1]], window)
    return out


@numba.njit(cache=True, nogil=True)
def _in_gaps(t, curve_t):  # pragma: no cover - compiled
    """Whether each arc length ``t`` falls inside a gap (a step > GAP_PX) of the curve with arc lengths
    ``curve_t``: no point of that curve was seen there."""
    inside = np.zeros(t.shape[0], np.bool_)
    for k in range(curve_t.shape[0] - 1):
        if curve_t[k + 1] - curve_t[k] > GAP_PX:
            for i in range(t.shape[0]):
                inside[i] |= curve_t[k] < t[i] < curve_t[k + 1]
    return inside


@numba.njit(cache=True, nogil=True)
def _match_arcs(s, e_left, t, e_right, t0, min_sin, step_limit, max_error, ends_visible):  # pragma: no cover
    """Steps 2 and 3 of the module docstring on the arc lengths ``s``, ``t`` and epipolar profiles of two
    oriented curves, from the warping's ``t0(s)``. Returns (t_match, anchored, sin_angle, keep); anchored
    has fewer than 2 entries set when there is no anchor pair (then nothing else is meaningful)."""
    n = s.shape[0]
    slope_right = derivative(e_right, t)
    sin_angle = np.minimum(np.abs(derivative(e_left, s)), np.abs(np.interp(t0, t, slope_right)))
    anchored = sin_angle >= min_sin
    # Sub-pixel: Newton steps on e_right(t) = e_left(s) at the anchors, staying near the warping's guess.
    t_match = t0.copy()
    low, high = np.maximum(t0 - step_limit, 0.0), np.minimum(t0 + step_limit, t[-1])
    for _ in range(4):
        slope = np.interp(t_match, t, slope_right)
        at = np.interp(t_match, t, e_right)
        for k in range(n):
            update = (e_left[k] - at[k]) / slope[k] if anchored[k] and abs(slope[k]) >= 0.5 * min_sin else 0.0
            t_match[k] = min(max(t_match[k] + update, low[k]), high[k])
    residual = e_left - np.interp(t_match, t, e_right)
    gaps = _in_gaps(t_match, t)
    anchored &= (np.abs(residual) <= max_error) & (t_match > 0) & (t_match < t[-1]) & ~gaps
    # Keep the anchors in order: drop those behind the running maximum (noise at near-parallel stretches).
    highest = -np.inf
    for k in range(n):
        if anchored[k]:
            highest = max(highest, t_match[k])
            anchored[k] = t_match[k] >= highest - 0.5
    if ends_visible:
        for end, other_end, other_e in ((0, 0.0, e_right[0]), (n - 1, t[-1], e_right[-1])):
            if abs(e_left[end] - other_e) <= 2 * max_error:
                anchored[end], t_match[end] = True, other_end
    index = np.flatnonzero(anchored)
    if index.size < 2:
        return t_match, anchored, sin_angle, anchored
    # Continuity between anchors, local-ratio extrapolation beyond them.
    between = np.interp(s, s[index], t_match[index])
    for k in range(n):
        if not anchored[k]:
            t_match[k] = between[k]
    for reference, nearby, before in ((index[0], index[:10], True), (index[-1], index[-10:], False)):
        spread = s[nearby] - np.mean(s[nearby])
        ratio = np.dot(spread, t_match[nearby]) / np.dot(spread, spread) if np.ptp(s[nearby]) > 0 else t[-1] / s[-1]
        for k in range(n):
            if (s[k] < s[reference]) if before else (s[k] > s[reference]):
                t_match[k] = t_match[reference] + ratio * (s[k] - s[reference])
    # Points placed by continuity must still (nearly) satisfy the epipolar constraint, and none is matched
    # into a gap of the right curve: a stretch missing in one image (occlusion) is not bridged.
    residual = e_left - np.interp(t_match, t, e_right)
    keep = (t_match >= 0) & (t_match <= t[-1]) & (anchored | (np.abs(residual) <= 2 * max_error))
    keep &= ~_in_gaps(t_match, t)
    return t_match, anchored, sin_angle, keep


@numba.njit(cache=True, nogil=True)
def _end_last(curve, end):  # pragma: no cover - compiled
    """``curve`` with its ``end`` (0: first point, 1: last) last, contiguous."""
    return np.ascontiguousarray(curve[::-1]) if end == 0 else curve


@numba.njit(cache=True, nogil=True)
def _end_tangent(curve):  # pragma: no cover - compiled
    """Unit direction out of the last point of ``curve`` (from the point 5 before it)."""
    tangent = curve[-1] - curve[-6]
    return tangent / max(np.sqrt(tangent[0] * tangent[0] + tangent[1] * tangent[1]), 1e-12)


@numba.njit(cache=True, nogil=True)
def _moved_end(curve, tangent, shift):  # pragma: no cover - compiled
    """``curve`` with its last point moved ``shift`` px along ``tangent`` (outward +), the points beyond the new
    end dropped, and the last few points before it evenly spaced at the curve's step (the 3D smoothing fits by
    point index: an uneven last step moves the end)."""
    n = curve.shape[0]
    inside = np.ones(n - 1, np.bool_)  # only the last points can lie beyond the new end
    for i in range(max(n - 1 - int(np.ceil(abs(shift))) - 2, 0), n - 1):
        inside[i] = ((curve[i, 0] - curve[-1, 0]) * tangent[0]
                     + (curve[i, 1] - curve[-1, 1]) * tangent[1]) < shift - 0.25
    kept = curve[:-1][inside]
    end = curve[-1] + shift * tangent
    if kept.shape[0] < 16:
        return np.vstack((kept, end.reshape(1, 2)))
    step = np.sqrt(np.sum((kept[-1] - kept[-11]) ** 2)) / 10
    anchor = kept[-4]
    gap = np.sqrt(np.sum((end - anchor) ** 2))
    count = max(int(round(gap / max(step, 0.5))), 1)
    out = np.empty((kept.shape[0] - 3 + count, 2))
    out[:kept.shape[0] - 3] = kept[:-3]
    for j in range(1, count + 1):
        out[kept.shape[0] - 4 + j] = anchor + (end - anchor) * j / count
    return out


@numba.njit(cache=True, nogil=True)
def _common_ends(left, right, e, min_sin, tolerance):  # pragma: no cover - compiled
    """Both curves (same direction) with each pair of corresponding ends moved to their mean epipolar
    coordinate: a needle end is one 3D point, on one epipolar line in both images. Each end moves along its
    curve's end tangent (trimmed or extended by at most ``tolerance / min_sin`` px); ends whose tangents run
    within asin(min_sin) of the epipolar lines, or that are more than ``tolerance`` px apart, stay."""
    for end in range(2):
        curves = (_end_last(left, end), _end_last(right, end))  # this end last
        tangents = (_end_tangent(curves[0]), _end_tangent(curves[1]))
        ends_e = (curves[0][-1, e], curves[1][-1, e])
        if min(abs(tangents[0][e]), abs(tangents[1][e])) < min_sin or abs(ends_e[0] - ends_e[1]) > tolerance:
            continue
        moved = []
        for k in range(2):
            curve, tangent = curves[k], tangents[k]
            shift = (0.5 * (ends_e[0] + ends_e[1]) - ends_e[k]) / tangent[e]  # [px] along the tangent, outward +
            moved.append(_end_last(_moved_end(curve, tangent, shift), end))
        left, right = moved[0], moved[1]
    return left, right


@numba.njit(cache=True, nogil=True)
def _shared_tapers(left, right, tapers_left, tapers_right, e, min_sin):  # pragma: no cover - compiled
    """Both curves (same direction) with each pair of ends that run within asin(min_sin) of the epipolar lines put the
    same taper beyond their half-contrast points. There the end's depth is the two ends' disparity alone, so each view's
    noise in its taper (a bevel's length; ``tapers_*``: first and last end [px]) went into it whole; a bevel is one
    length on the needle: both views get their mean (the right one's scaled by the ratio of the curves' lengths)."""
    ratio = -1.0
    for end in range(2):
        curves = (_end_last(left, end), _end_last(right, end))
        tangents = (_end_tangent(curves[0]), _end_tangent(curves[1]))
        if max(abs(tangents[0][e]), abs(tangents[1][e])) >= min_sin:
            continue
        if ratio < 0:
            ratio = arc_length(right)[-1] / max(arc_length(left)[-1], 1e-12)
        common = 0.5 * (tapers_left[end] + tapers_right[end] / ratio)
        left = _end_last(_moved_end(curves[0], tangents[0], common - tapers_left[end]), end)
        right = _end_last(_moved_end(curves[1], tangents[1], ratio * common - tapers_right[end]), end)
    return left, right


def match_centerlines(left: np.ndarray, right: np.ndarray, epipolar_axis: int,
                      config: MatchingConfig = MatchingConfig(), ends_visible: bool = False,
                      tapers: tuple[np.ndarray, np.ndarray] | None = None) -> Correspondence:
    """Correspond two ordered rectified centerlines ``(n, 2)``, ``(m, 2)`` (either direction for the right).

    ``ends_visible``: both curves end at the needle's real ends (not cut by an image border). Then each pair of ends
    within ``2 max_epipolar_error_px`` of one epipolar line are corresponding points: moved onto their mean epipolar
    line where they cross the lines (:func:`_common_ends`), taken as they are where the end stretch runs along the lines
    (no anchor there); there the two views' ``tapers`` (how far [px] each curve's first and last end lies beyond its
    half-contrast point, see ``ImageCenterline.end_taper_px``) are shared (:func:`_shared_tapers`)."""
    if len(left) < 5 or len(right) < 5:
        raise MatchError("a centerline has fewer than 5 points")
    left = _smooth_runs(np.ascontiguousarray(left, dtype=float), 5)
    right = _smooth_runs(np.ascontiguousarray(right, dtype=float), 5)
    e = epipolar_axis
    s = arc_length(left)
    # Direction of the right curve: from the ends' epipolar coordinates when they tell clearly, else by warping
    # both ways and keeping the better alignment.
    same = abs(left[0, e] - right[0, e]) + abs(left[-1, e] - right[-1, e])
    swapped = abs(left[0, e] - right[-1, e]) + abs(left[-1, e] - right[0, e])
    if abs(same - swapped) > 0.2 * np.ptp(left[:, e]) + 10 * config.max_epipolar_error_px:
        directions = [right if same < swapped else right[::-1]]
    else:
        directions = [right, right[::-1]]
    spacing, weight = config.dtw_spacing_px, config.continuity_weight
    e_left = np.ascontiguousarray(left[:, e])
    candidates = []
    for oriented in directions:
        reversed_ = oriented is not right
        oriented = np.ascontiguousarray(oriented)
        t = arc_length(oriented)
        t0, cost = _coarse_map(s, e_left, t, np.ascontiguousarray(oriented[:, e]), spacing, weight)
        candidates.append((cost, oriented, t, t0, reversed_))
    _, right, t, t0, reversed_ = min(candidates, key=lambda candidate: candidate[0])
    min_sin = np.sin(np.radians(config.min_epipolar_angle_deg))
    if ends_visible:
        if tapers is not None and (np.any(tapers[0]) or np.any(tapers[1])):
            left, right = _shared_tapers(left, right, np.ascontiguousarray(tapers[0], dtype=float),
                                         np.ascontiguousarray(tapers[1][::-1] if reversed_ else tapers[1], dtype=float),
                                         e, min_sin)
        left, right = _common_ends(left, right, e, min_sin, 2 * config.max_epipolar_error_px)
        s, t = arc_length(left), arc_length(right)
        e_left = np.ascontiguousarray(left[:, e])
        t0, _ = _coarse_map(s, e_left, t, np.ascontiguousarray(right[:, e]), spacing, weight)
    t_match, anchored, sin_angle, keep = _match_arcs(
        s, e_left, t, np.ascontiguousarray(right[:, e]), t0, min_sin, 2 * config.dtw_spacing_px / min_sin,
        config.max_epipolar_error_px, ends_visible)
    if np.count_nonzero(anchored) < 2:
        raise MatchError("no stretch of the needle crosses the epipolar lines in both images "
                         f"(by >= {config.min_epipolar_angle_deg:g} deg): depth is unobservable")
    matched_right = interpolate(t, right, t_match[keep])
    return Correspondence(left[keep], matched_right, anchored[keep], sin_angle[keep])
