"""Corresponding points of the left and right needle centerlines (seed 000, Sec. III-A: "using principles
from photogrammetry and projective geometry, the corresponding points between the two images are found").

After rectification a 3D point has the same epipolar coordinate ``e`` in both images, so along the needle
``e_left(s) = e_right(t(s))`` for a monotone map ``t(s)`` between the two curves' arc lengths. Matching each
left point to "the right point on the same epipolar line" fails where the needle runs nearly parallel to the
epipolar lines (``e`` barely changes) or crosses one line several times. So the map comes from the curves as
ordered wholes:

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
from needle_vision.detection.curves import arc_length, derivative, interpolate, moving_average


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


def _coarse_map(s: np.ndarray, e_left: np.ndarray, t: np.ndarray, e_right: np.ndarray,
                config: MatchingConfig) -> tuple[np.ndarray, float]:
    """Dense initial ``t(s)`` from warping profiles resampled every ``dtw_spacing_px``; and its mean cost."""
    spacing = config.dtw_spacing_px
    s_coarse = np.linspace(0, s[-1], max(int(s[-1] / spacing), 2))
    t_coarse = np.linspace(0, t[-1], max(int(t[-1] / spacing), 2))
    scale = 0.5 * (s[-1] + t[-1])
    index, cost = _warp(np.interp(s_coarse, s, e_left), np.interp(t_coarse, t, e_right),
                        s_coarse / s[-1] * scale, t_coarse / t[-1] * scale, config.continuity_weight)
    return np.interp(s, s_coarse, np.interp(index, np.arange(len(t_coarse)), t_coarse)), cost


def _smooth_runs(points: np.ndarray, window: int) -> np.ndarray:
    """Moving average of each run of points between gaps (steps > GAP_PX): never across a hidden stretch."""
    points = np.asarray(points, float)
    cuts = np.flatnonzero(np.linalg.norm(np.diff(points, axis=0), axis=1) > GAP_PX) + 1
    return np.vstack([moving_average(run, window) for run in np.split(points, cuts)])


def _in_gaps(t: np.ndarray, curve_t: np.ndarray) -> np.ndarray:
    """Whether each arc length ``t`` falls inside a gap (a step > GAP_PX) of the curve with arc lengths
    ``curve_t``: no point of that curve was seen there."""
    steps = np.flatnonzero(np.diff(curve_t) > GAP_PX)
    inside = np.zeros(len(t), bool)
    for k in steps:
        inside |= (t > curve_t[k]) & (t < curve_t[k + 1])
    return inside


def _common_ends(left: np.ndarray, right: np.ndarray, e: int, min_sin: float, tolerance: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Both curves (same direction) with each pair of corresponding ends moved to their mean epipolar
    coordinate: a needle end is one 3D point, on one epipolar line in both images. Each end moves along its
    curve's end tangent (trimmed or extended by at most ``tolerance / min_sin`` px); ends whose tangents run
    within asin(min_sin) of the epipolar lines, or that are more than ``tolerance`` px apart, stay."""
    curves = [left, right]
    for end in (0, 1):
        flipped = [curve[::-1] if end == 0 else curve for curve in curves]  # this end last
        tangents = [curve[-1] - curve[-6] for curve in flipped]
        tangents = [tangent / max(np.linalg.norm(tangent), 1e-12) for tangent in tangents]
        ends_e = [curve[-1, e] for curve in flipped]
        if min(abs(tangent[e]) for tangent in tangents) < min_sin or abs(ends_e[0] - ends_e[1]) > tolerance:
            continue
        moved = []
        for curve, tangent, end_e in zip(flipped, tangents, ends_e):
            shift = (0.5 * sum(ends_e) - end_e) / tangent[e]  # [px] along the tangent, outward positive
            inside = (curve[:-1] - curve[-1]) @ tangent < shift - 0.25
            inside[:-int(np.ceil(abs(shift))) - 2] = True  # only the last points can lie beyond the new end
            curve = np.vstack([curve[:-1][inside], curve[-1] + shift * tangent])
            moved.append(curve[::-1] if end == 0 else curve)
        curves = moved
    return curves[0], curves[1]


def match_centerlines(left: np.ndarray, right: np.ndarray, epipolar_axis: int,
                      config: MatchingConfig = MatchingConfig(), ends_visible: bool = False) -> Correspondence:
    """Correspond two ordered rectified centerlines ``(n, 2)``, ``(m, 2)`` (either direction for the right).

    ``ends_visible``: both curves end at the needle's real ends (not cut by an image border). Then each pair
    of ends within ``2 max_epipolar_error_px`` of one epipolar line are corresponding points: moved onto their
    mean epipolar line where they cross the lines (:func:`_common_ends`), taken as they are where the end
    stretch runs along the lines (no anchor there)."""
    if len(left) < 5 or len(right) < 5:
        raise MatchError("a centerline has fewer than 5 points")
    left, right = _smooth_runs(left, 5), _smooth_runs(right, 5)
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
    candidates = []
    for oriented in directions:
        t = arc_length(oriented)
        t0, cost = _coarse_map(s, left[:, e], t, oriented[:, e], config)
        candidates.append((cost, oriented, t, t0))
    _, right, t, t0 = min(candidates, key=lambda candidate: candidate[0])
    min_sin = np.sin(np.radians(config.min_epipolar_angle_deg))
    if ends_visible:
        left, right = _common_ends(left, right, e, min_sin, 2 * config.max_epipolar_error_px)
        s, t = arc_length(left), arc_length(right)
        t0, _ = _coarse_map(s, left[:, e], t, right[:, e], config)

    slope_left = derivative(left[:, e], s)
    slope_right = derivative(right[:, e], t)
    sin_angle = np.minimum(np.abs(slope_left), np.abs(np.interp(t0, t, slope_right)))
    anchored = sin_angle >= min_sin
    # Sub-pixel: Newton steps on e_right(t) = e_left(s) at the anchors, staying near the warping's guess.
    t_match = t0.copy()
    step_limit = 2 * config.dtw_spacing_px / min_sin
    for _ in range(4):
        slope = np.interp(t_match, t, slope_right)
        update = np.where(anchored & (np.abs(slope) >= 0.5 * min_sin),
                          (left[:, e] - np.interp(t_match, t, right[:, e])) / np.where(slope == 0, 1, slope), 0)
        t_match = np.clip(t_match + update, np.maximum(t0 - step_limit, 0), np.minimum(t0 + step_limit, t[-1]))
    residual = left[:, e] - np.interp(t_match, t, right[:, e])
    anchored &= np.abs(residual) <= config.max_epipolar_error_px
    anchored &= (t_match > 0) & (t_match < t[-1]) & ~_in_gaps(t_match, t)  # clamped at an end or in a gap: no match
    # Keep the anchors in order: drop those behind the running maximum (noise at near-parallel stretches).
    index = np.flatnonzero(anchored)
    if index.size:
        ordered = t_match[index] >= np.maximum.accumulate(t_match[index]) - 0.5
        anchored[index[~ordered]] = False
        index = index[ordered]
    if ends_visible:
        for end, other_end in ((0, 0.0), (len(s) - 1, t[-1])):
            if abs(left[end, e] - (right[0, e] if end == 0 else right[-1, e])) <= 2 * config.max_epipolar_error_px:
                anchored[end], t_match[end] = True, other_end
        index = np.flatnonzero(anchored)
    if index.size < 2:
        raise MatchError("no stretch of the needle crosses the epipolar lines in both images "
                         f"(by >= {config.min_epipolar_angle_deg:g} deg): depth is unobservable")
    # Continuity between anchors, local-ratio extrapolation beyond them.
    t_match = np.where(anchored, t_match, np.interp(s, s[index], t_match[index]))
    for reference, nearby, outside in ((index[0], index[:10], s < s[index[0]]),
                                       (index[-1], index[-10:], s > s[index[-1]])):
        spread = s[nearby] - s[nearby].mean()
        ratio = spread @ t_match[nearby] / (spread @ spread) if np.ptp(s[nearby]) > 0 else t[-1] / s[-1]
        t_match[outside] = t_match[reference] + ratio * (s[outside] - s[reference])
    # Points placed by continuity must still (nearly) satisfy the epipolar constraint, and none is matched
    # into a gap of the right curve: a stretch missing in one image (occlusion) is not bridged.
    residual = left[:, e] - np.interp(t_match, t, right[:, e])
    keep = (t_match >= 0) & (t_match <= t[-1]) & (anchored | (np.abs(residual) <= 2 * config.max_epipolar_error_px))
    keep &= ~_in_gaps(t_match, t)
    matched_right = interpolate(t, right, t_match[keep])
    return Correspondence(left[keep], matched_right, anchored[keep], sin_angle[keep])
