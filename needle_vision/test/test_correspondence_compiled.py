"""The compiled correspondence (numba, GIL released) against its previous NumPy formulation, kept here as the
reference, on the renders' rectified centerlines: the same matches up to float rounding."""
import numpy as np
import pytest

from needle_vision.calibration.rectification import Rectification
from needle_vision.detection.centerline import GAP_PX, extract_centerline
from needle_vision.detection.curves import arc_length, derivative, interpolate, moving_average
from needle_vision.matching.correspondence import MatchingConfig, _warp, match_centerlines
from needle_vision.matching.reconstruction import _ends_inside


def _coarse_map(s, e_left, t, e_right, config):
    spacing = config.dtw_spacing_px
    s_coarse = np.linspace(0, s[-1], max(int(s[-1] / spacing), 2))
    t_coarse = np.linspace(0, t[-1], max(int(t[-1] / spacing), 2))
    scale = 0.5 * (s[-1] + t[-1])
    index, cost = _warp(np.interp(s_coarse, s, e_left), np.interp(t_coarse, t, e_right),
                        s_coarse / s[-1] * scale, t_coarse / t[-1] * scale, config.continuity_weight)
    return np.interp(s, s_coarse, np.interp(index, np.arange(len(t_coarse)), t_coarse)), cost


def _smooth_runs(points, window):
    points = np.asarray(points, float)
    cuts = np.flatnonzero(np.linalg.norm(np.diff(points, axis=0), axis=1) > GAP_PX) + 1
    return np.vstack([moving_average(run, window) for run in np.split(points, cuts)])


def _in_gaps(t, curve_t):
    inside = np.zeros(len(t), bool)
    for k in np.flatnonzero(np.diff(curve_t) > GAP_PX):
        inside |= (t > curve_t[k]) & (t < curve_t[k + 1])
    return inside


def _common_ends(left, right, e, min_sin, tolerance):
    curves = [left, right]
    for end in (0, 1):
        flipped = [curve[::-1] if end == 0 else curve for curve in curves]
        tangents = [curve[-1] - curve[-6] for curve in flipped]
        tangents = [tangent / max(np.linalg.norm(tangent), 1e-12) for tangent in tangents]
        ends_e = [curve[-1, e] for curve in flipped]
        if min(abs(tangent[e]) for tangent in tangents) < min_sin or abs(ends_e[0] - ends_e[1]) > tolerance:
            continue
        moved = []
        for curve, tangent, end_e in zip(flipped, tangents, ends_e):
            shift = (0.5 * sum(ends_e) - end_e) / tangent[e]
            inside = (curve[:-1] - curve[-1]) @ tangent < shift - 0.25
            inside[:-int(np.ceil(abs(shift))) - 2] = True
            kept, new_end = curve[:-1][inside], curve[-1] + shift * tangent
            if len(kept) < 16:
                curve = np.vstack([kept, new_end])
            else:  # the last points evenly spaced at the curve's step, from the 4th last kept one to the new end
                step = np.linalg.norm(kept[-1] - kept[-11]) / 10
                count = max(round(np.linalg.norm(new_end - kept[-4]) / max(step, 0.5)), 1)
                curve = np.vstack([kept[:-3], kept[-4] + np.outer(np.arange(1, count + 1) / count, new_end - kept[-4])])
            moved.append(curve[::-1] if end == 0 else curve)
        curves = moved
    return curves[0], curves[1]


def numpy_match(left, right, e, config, ends_visible):
    """match_centerlines as it was before compilation (returns left, right, anchored, sin_angle)."""
    left, right = _smooth_runs(left, 5), _smooth_runs(right, 5)
    s = arc_length(left)
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
    t_match = t0.copy()
    step_limit = 2 * config.dtw_spacing_px / min_sin
    for _ in range(4):
        slope = np.interp(t_match, t, slope_right)
        update = np.where(anchored & (np.abs(slope) >= 0.5 * min_sin),
                          (left[:, e] - np.interp(t_match, t, right[:, e])) / np.where(slope == 0, 1, slope), 0)
        t_match = np.clip(t_match + update, np.maximum(t0 - step_limit, 0), np.minimum(t0 + step_limit, t[-1]))
    residual = left[:, e] - np.interp(t_match, t, right[:, e])
    anchored &= np.abs(residual) <= config.max_epipolar_error_px
    anchored &= (t_match > 0) & (t_match < t[-1]) & ~_in_gaps(t_match, t)
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
    t_match = np.where(anchored, t_match, np.interp(s, s[index], t_match[index]))
    for reference, nearby, outside in ((index[0], index[:10], s < s[index[0]]),
                                       (index[-1], index[-10:], s > s[index[-1]])):
        spread = s[nearby] - s[nearby].mean()
        ratio = spread @ t_match[nearby] / (spread @ spread) if np.ptp(s[nearby]) > 0 else t[-1] / s[-1]
        t_match[outside] = t_match[reference] + ratio * (s[outside] - s[reference])
    residual = left[:, e] - np.interp(t_match, t, right[:, e])
    keep = (t_match >= 0) & (t_match <= t[-1]) & (anchored | (np.abs(residual) <= 2 * config.max_epipolar_error_px))
    keep &= ~_in_gaps(t_match, t)
    return left[keep], interpolate(t, right, t_match[keep]), anchored[keep], sin_angle[keep]


@pytest.mark.parametrize("name", ["planar", "3d", "hook", "s_curve", "end_on", "straight"])
def test_compiled_match_equals_the_numpy_formulation(rig, backgrounds, renders, name):
    rectification = Rectification.from_rig(rig)
    centerlines = [extract_centerline(image, background) for image, background in zip(renders(name), backgrounds)]
    left, right = (rectification.rectify(c.points, side) for c, side in zip(centerlines, ("left", "right")))
    ends_visible = all(_ends_inside(c.points, camera.width, camera.height)
                       for c, camera in zip(centerlines, (rig.left, rig.right)))
    for flip in (False, True):  # the right curve in either direction
        oriented = right[::-1] if flip else right
        for visible in {ends_visible, False}:
            config = MatchingConfig()
            match = match_centerlines(left, oriented, rectification.epipolar_axis, config, visible)
            reference = numpy_match(left, oriented, rectification.epipolar_axis, config, visible)
            assert len(match.left) == len(reference[0]) > 100
            for got, expected in zip((match.left, match.right, match.anchored, match.sin_angle), reference):
                np.testing.assert_allclose(got, expected, rtol=1e-11, atol=1e-9)
