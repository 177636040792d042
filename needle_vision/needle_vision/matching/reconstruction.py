"""From two image centerlines to the measured 3D needle centerline (seed 000, Sec. III-A: corresponding points
"are used for constructing an estimate of the three-dimensional needle's state").

Rectify the points, correspond them (:mod:`needle_vision.matching.correspondence`), triangulate them into the raw left
optical frame, reject outliers (depth range, then robust distance to a smoothed curve), order from the base
(the end nearer the configured base point) to the tip, smooth with a local cubic fit along the arc length over
``smoothing_length`` and resample every ``sample_spacing`` of arc length. Each sample carries a 1-sigma
uncertainty propagated from the measured image noise (calibration error is not included).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numba
import numpy as np

from needle_vision.detection.centerline import CANDIDATE_TAPER_FACTOR, ImageCenterline, with_end_reading
from needle_vision.matching.correspondence import MatchError, MatchingConfig, match_centerlines
from needle_vision.matching.curve_fit import fit_curve
from needle_vision.detection.curves import (arc_length, interpolate, local_polynomial_smooth, median, run_bounds,
                                            step_lengths)
from needle_vision.calibration.rectification import Rectification
from needle_common.transforms import RigidTransform

#: Floor of the per-point image noise [px] used for the uncertainty (the centroid's aliasing error).
MIN_IMAGE_NOISE_PX = 0.02
#: 1-sigma error [px] of the needle's end positions along the needle (sub-pixel edge; flat or bevelled end).
END_LOCALIZATION_PX = 0.3
#: Correlated part of the image centerlines' lateral error [px] and the points it spans (not averaged by the fit).
CORRELATED_NOISE_PX = 0.02
CORRELATED_NOISE_POINTS = 20
#: Arc length [m] of the anchored stretch beside a stretch placed by continuity over which the needle's bending in
#: depth is fitted (:func:`_continuity_sigma`).
CURVATURE_SPAN = 20e-3
#: How far beyond a flat end each view puts it, over the half axis of its end disc's projection along the needle
#: (the half ellipse's band-integrated profile falls to half at sqrt(3)/2 of it).
END_CAP_CROSSING = math.sqrt(3.0) / 2
#: Longest half taper [px] of an end one view reads tapered that is placed flat where the other view reads no taper
#: (``_shared_bevels``).
FLAT_TIP_HALF_TAPER_PX = 1.0
#: ``uncertainty`` of a sample in a gap (no triangulated point within ``max_gap``): interpolated, not measured.
UNMEASURED = -1.0


class ImplausibleError(MatchError):
    """A reconstruction that no needle in the configured working volume can produce (message says why)."""


@dataclass(frozen=True)
class ReconstructionConfig:
    """Settings of triangulation and post-processing (names match the node's ``reconstruction.*``)."""

    min_depth: float = 0.05           # [m] triangulated points nearer to the left camera are rejected
    max_depth: float = 5.0            # [m] ... and farther
    outlier_sigma: float = 4.0        # robust standard deviations from the smoothed curve that make an outlier
    outlier_floor: float = 0.5e-3     # [m] distances below this are never outliers
    smoothing_length: float = 8e-3    # [m] arc length of the local cubic fit that smooths the centerline
    sample_spacing: float = 1e-3      # [m] arc-length step of the published samples
    min_points: int = 20              # fewer inliers than this: no measurement
    max_length: float = 0.3           # [m] a longer centerline is implausible for a needle: rejected
    max_image_scatter: float = 0.5    # [px] image centerlines scattering more across the curve are not a needle
    max_gap: float = 1e-3             # [m] longer stretches without a triangulated point are unmeasured
    max_uncertainty: float = 1e-3     # [m] samples with a larger 1-sigma uncertainty are flagged unmeasured
    curve_fit: bool = False           # fit one 3D curve to both views (else: the smoothed triangulated points)
    knot_spacing: float = 5e-3        # [m] control point spacing of the fitted curve
    bending_weight: float = 10.0      # [m] weight of the bending-energy prior (integral of |C''|^2) of the fit
    end_noise_px: float = 0.1         # [px] 1-sigma error of the image ends in the fit
    needle_radius: float = 0.0        # [m] its flat ends' discs lengthen the images (0: not corrected)
    base_point: np.ndarray = field(default_factory=lambda: np.zeros(3))  # [m] near the base, output frame


@dataclass(frozen=True)
class NeedleMeasurement:
    """The measured centerline in the output frame, base to tip: samples ``points (k, 3)`` [m], unit ``tangents``,
    ``arc_length`` [m], 1-sigma ``uncertainty`` [m] (UNMEASURED in gaps, see ``measured``), total ``length`` [m]; and
    the raw image centerlines (for the debug image)."""

    points: np.ndarray
    tangents: np.ndarray
    arc_length: np.ndarray
    uncertainty: np.ndarray
    length: float
    left_centerline: ImageCenterline
    right_centerline: ImageCenterline
    anchored_fraction: float
    measured: np.ndarray

    @property
    def coverage(self) -> float:
        """Fraction of the sampled length that was measured (not in a gap) [-]."""
        return float(np.mean(self.measured))


def _odd_window(length: float, spacing: float, count: int, minimum: int = 5) -> int:
    window = int(round(length / max(spacing, 1e-12))) | 1
    return max(minimum, min(window, count if count % 2 else count - 1))


def _ends_inside(points: np.ndarray, width: int, height: int, margin: float = 5.0) -> bool:
    """Whether both ends of an image centerline lie ``margin`` px inside the image (not cut by its border)."""
    return all(margin <= x <= width - 1 - margin and margin <= y <= height - 1 - margin
               for x, y in points[[0, -1]].tolist())


@numba.njit(cache=True, nogil=True)
def _nearest_of(reference, query, first, last, step):  # pragma: no cover - compiled
    """Index of the nearest to ``query`` of the ``reference`` points ``first:last:step``."""
    best, nearest = np.inf, first
    for k in range(first, last, step):
        distance = (reference[k, 0] - query[0]) ** 2 + (reference[k, 1] - query[1]) ** 2
        if distance < best:
            best, nearest = distance, k
    return nearest


@numba.njit(cache=True, nogil=True)
def _nearest_points(rectified, matched, stride=8):  # pragma: no cover - compiled
    """For each of the ``matched`` points ``(m, 2)``, the index of the nearest point of a centerline (``rectified``:
    its points rectified, ``(n, 2)`` in curve order: the nearest of every ``stride``-th point, then of the points
    within ``stride`` of it), whose own per-point values (local noise, extrapolation error) are the matched point's:
    where the background passes through the needle's level a single slice errs by a pixel and its own noise says so."""
    out = np.empty(matched.shape[0], np.int64)
    n = rectified.shape[0]
    for i in range(matched.shape[0]):
        coarse = _nearest_of(rectified, matched[i], 0, n, stride)
        out[i] = _nearest_of(rectified, matched[i], max(coarse - stride, 0), min(coarse + stride + 1, n), 1)
    return out


def _rectified(centerline: ImageCenterline, rectification: Rectification, side: str) -> tuple[np.ndarray,
                                                                                             np.ndarray]:
    """The centerline's points rectified, and its ``end_taper_px`` (first and last end) in rectified pixels (scaled
    like the last 5 px of the curve at each end)."""
    rectified = rectification.rectify(centerline.points, side)
    tapers = centerline.end_taper_px
    if not np.any(tapers):
        return rectified, tapers
    raw = centerline.points
    scale = (math.dist(rectified[0], rectified[5]) / max(math.dist(raw[0], raw[5]), 1e-12),
             math.dist(rectified[-1], rectified[-6]) / max(math.dist(raw[-1], raw[-6]), 1e-12))
    return rectified, tapers * scale


def _runs(points: np.ndarray, split: float, min_points: int = 0) -> list[slice]:
    """The runs of at least ``min_points`` consecutive points not separated by a step longer than ``split`` (a hidden
    stretch)."""
    bounds = run_bounds(np.ascontiguousarray(points), split).tolist()
    return [slice(a, b) for a, b in zip(bounds[:-1], bounds[1:]) if b - a >= min_points]


@numba.njit(cache=True, nogil=True)
def _smooth_along(points, abscissa, window):  # pragma: no cover - compiled
    """Local cubic fit of ``points (n, 3)`` against ``abscissa (n,)`` over the ``window`` (odd, <= n) points centred
    on each (the first/last full window's fit for the first/last ``window // 2``): the fitted points and each one's
    white-noise gain (the norm of its row of the fit's hat matrix)."""
    n, half = points.shape[0], window // 2
    out = np.empty_like(points)
    gain = np.empty(n)
    moments, powers, sums = np.empty(7), np.empty(7), np.empty((4, 3))
    normal = np.empty((4, 4))
    coefficients = np.empty(4)
    for k in range(n):
        first = min(max(k - half, 0), n - window)
        inverse_scale = 1.0 / max(abscissa[first + window - 1] - abscissa[first], 1e-12)
        moments[:] = 0.0
        sums[:] = 0.0  # sum over the window of t^a times the points
        moments[0] = float(window)
        for j in range(first, first + window):
            t = (abscissa[j] - abscissa[k]) * inverse_scale
            t2 = t * t
            t3 = t2 * t
            powers[1], powers[2], powers[3], powers[4], powers[5], powers[6] = t, t2, t3, t2 * t2, t2 * t3, t3 * t3
            for a in range(1, 7):
                moments[a] += powers[a]
            for c in range(3):
                sums[0, c] += points[j, c]
                for a in range(1, 4):
                    sums[a, c] += powers[a] * points[j, c]
        # The fit's value at t = 0 is c . (the sums of t^a times the points) with c = solve(normal, e0) (Cholesky of
        # the moment matrix); its white-noise gain is sqrt(c0) (the hat matrix row's squared norm: e0' normal^-1 e0).
        for a in range(4):
            for b in range(a + 1):
                value = moments[a + b]
                for m in range(b):
                    value -= normal[a, m] * normal[b, m]
                normal[a, b] = np.sqrt(max(value, 1e-300)) if a == b else value / normal[b, b]
        for a in range(4):  # forward: L y = e0
            value = 1.0 if a == 0 else 0.0
            for m in range(a):
                value -= normal[a, m] * coefficients[m]
            coefficients[a] = value / normal[a, a]
        for a in range(3, -1, -1):  # back: L^T c = y
            value = coefficients[a]
            for m in range(a + 1, 4):
                value -= normal[m, a] * coefficients[m]
            coefficients[a] = value / normal[a, a]
        for c in range(3):
            out[k, c] = coefficients[0] * sums[0, c] + coefficients[1] * sums[1, c] + coefficients[2] * sums[2, c] \
                + coefficients[3] * sums[3, c]
        gain[k] = np.sqrt(max(coefficients[0], 0.0))
    return out, gain


def _smooth_runs(points: np.ndarray, runs: list[slice], length: float, spacing: float) -> tuple[np.ndarray,
                                                                                                 np.ndarray]:
    """Local cubic smoothing over ``length`` of each run separately, and its noise gain at each point. The cubic's
    abscissa is the arc length of the run smoothed by point index (the points' own steps carry their noise): where
    the points thin out (a stretch seen nearly end-on) a cubic in the index bends the curve."""
    parts = []
    for run in runs:
        window = _odd_window(length, spacing, run.stop - run.start)
        rough = local_polynomial_smooth(points[run], window, 3)
        parts.append(_smooth_along(np.ascontiguousarray(points[run]), arc_length(rough), window))
    return np.vstack([p[0] for p in parts]), np.concatenate([p[1] for p in parts])


def _robust_inliers(points: np.ndarray, config: ReconstructionConfig, window: int) -> np.ndarray:
    """Points within max(outlier_sigma robust sigmas, outlier_floor) of a smoothed curve; repeated once more
    when outliers were found (they bend the first smoothed curve)."""
    keep = np.ones(len(points), bool)
    for _ in range(2):
        index = np.flatnonzero(keep)
        w = _odd_window(window, 1, len(index))
        if len(index) <= w:
            break
        distance = np.linalg.norm(points[index] - local_polynomial_smooth(points[index], w, 2), axis=1)
        limit = max(config.outlier_sigma * 1.4826 * median(distance), config.outlier_floor)
        outliers = distance > limit
        if not outliers.any():
            break
        keep[index[outliers]] = False
    return keep


@dataclass(frozen=True)
class Triangulation:
    """The inlier triangulated points of a pair in the output frame, in left-curve order (base and tip not told yet),
    their 1-sigma uncertainty [m] (white: the smoothing averages it) and whether each was anchored; their mean spacing
    [m]; the image centerlines. What :func:`order_and_resample` needs: independent of the previous frames."""

    points: np.ndarray
    sigma: np.ndarray
    slide_sigma: np.ndarray  # [m] 1-sigma error that the smoothing does not average (see _slide)
    anchored: np.ndarray
    spacing: float
    left_centerline: ImageCenterline
    right_centerline: ImageCenterline
    fit: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None  # the fitted curve: points, sigma, supported


def reconstruct_centerline(left: ImageCenterline, right: ImageCenterline, rectification: Rectification,
                           matching: MatchingConfig, config: ReconstructionConfig,
                           output_from_left: RigidTransform, base_hint: np.ndarray | None = None
                           ) -> NeedleMeasurement:
    """Triangulate, clean, order, smooth and resample; raises MatchError when no measurement results.
    The base is the end nearer to ``base_hint`` (output frame; e.g. the previous frame's base) when given, else
    nearer to ``config.base_point``."""
    return order_and_resample(triangulate_centerline(left, right, rectification, matching, config, output_from_left),
                              rectification, config, output_from_left, base_hint)


def triangulate_centerline(left: ImageCenterline, right: ImageCenterline, rectification: Rectification,
                           matching: MatchingConfig, config: ReconstructionConfig,
                           output_from_left: RigidTransform) -> Triangulation:
    """Rectify, correspond, triangulate and reject outliers (the part that does not depend on earlier frames);
    raises MatchError when too few points remain."""
    left, right = _shared_bevels(left, right, rectification, 2 * matching.max_epipolar_error_px)
    if config.needle_radius > 0:
        first = triangulate_centerline(left, right, rectification, matching,
                                       replace(config, needle_radius=0.0, curve_fit=False), RigidTransform())
        left, right = (_without_end_caps(centerline, side, first.points, rectification, config.needle_radius)
                       for centerline, side in ((left, "left"), (right, "right")))
    scatter = max(left.noise_px, right.noise_px)
    if scatter > config.max_image_scatter:
        raise ImplausibleError(f"implausible: image centerline scatters {scatter:.2f} px across the curve "
                               f"(> {config.max_image_scatter:g} px): low detection confidence")
    left_rect, left_tapers = _rectified(left, rectification, "left")
    right_rect, right_tapers = _rectified(right, rectification, "right")
    ends_visible = all(_ends_inside(centerline.points, camera.width, camera.height) for centerline, camera
                       in ((left, rectification.rig.left), (right, rectification.rig.right)))
    match = match_centerlines(left_rect, right_rect, rectification.epipolar_axis, matching, ends_visible,
                              (left_tapers, right_tapers))
    points = rectification.triangulate(match.left, match.right[:, rectification.disparity_axis])
    depth = np.linalg.norm(points, axis=1)
    valid = np.isfinite(depth) & (depth >= config.min_depth) & (depth <= config.max_depth)
    if np.count_nonzero(valid) < config.min_points:
        raise MatchError(f"only {np.count_nonzero(valid)} triangulated points lie within "
                         f"{config.min_depth:g}-{config.max_depth:g} m of the left camera")
    points, anchored, sin_angle = points[valid], match.anchored[valid], match.sin_angle[valid]
    # Hidden stretches (no point over half the smoothing length) split the points into runs, each cleaned and
    # smoothed on its own; runs too short for the cubic fit are dropped.
    split = 0.5 * config.smoothing_length
    steps = step_lengths(points)
    spacing = float(np.mean(steps[steps <= split])) if np.any(steps <= split) else split
    window = _odd_window(config.smoothing_length, spacing, len(points))
    inliers = np.zeros(len(points), bool)
    for run in _runs(points, split, 5):
        inliers[run] = _robust_inliers(points[run], config, window)
    inliers = np.flatnonzero(inliers)
    inliers = np.concatenate([inliers[run] for run in _runs(points[inliers], split, 5)] + [np.zeros(0, int)])
    points, anchored, sin_angle = points[inliers], anchored[inliers], sin_angle[inliers]
    if len(points) < config.min_points:
        raise MatchError(f"only {len(points)} points left after outlier rejection")

    # Per-point noise: lateral from the image noise, depth through the disparity (worse where the needle runs along
    # the epipolar lines).
    kept = np.flatnonzero(valid)[inliers]
    nearest = _nearest_points(left_rect, match.left[kept]), _nearest_points(right_rect, match.right[kept])
    noise_px = np.maximum.reduce([left.local_noise_px[nearest[0]], right.local_noise_px[nearest[1]],
                                  np.full(len(kept), max(left.noise_px, right.noise_px, MIN_IMAGE_NOISE_PX))])
    extrapolation_px = np.hypot(left.extrapolation_px[nearest[0]], right.extrapolation_px[nearest[1]])
    min_sin = np.sin(np.radians(matching.min_epipolar_angle_deg))
    slope = np.where(anchored, np.maximum(sin_angle, min_sin), 0.5 * min_sin)
    per_disparity = rectification.depth_per_disparity(points)
    depth_noise = per_disparity * noise_px * np.sqrt(2 + 1 / slope ** 2)
    lateral_scale = np.linalg.norm(points, axis=1) / rectification.focal_length  # [m/px]
    point_sigma = np.sqrt(depth_noise ** 2 + 2 * (lateral_scale * noise_px) ** 2)
    # Not averaged by the smoothing: the correlated error's slide and the extrapolated ends' shared error.
    unaveraged = _unaveraged(per_disparity, lateral_scale, slope, extrapolation_px)

    fit = None
    if config.curve_fit:
        chained = np.diff(kept) == 1  # consecutive kept matches: no rejected or invalid match between them
        matched = _matched(len(left_rect), nearest[0], chained), _matched(len(right_rect), nearest[1], chained)
        fit = _fitted_curve(points, point_sigma, unaveraged,
                            _unaveraged(per_disparity, lateral_scale, slope, extrapolation_px, 0.0), spacing,
                            (left, right), (left_rect, right_rect), matched, rectification, config)
    return Triangulation(output_from_left.apply(points), point_sigma, unaveraged,
                         anchored, spacing, left, right,
                         None if fit is None else (output_from_left.apply(fit[0]), fit[1], fit[2]))


def _shared_bevels(left: ImageCenterline, right: ImageCenterline, rectification: Rectification,
                   tolerance: float) -> tuple[ImageCenterline, ImageCenterline]:
    """Both views with each taper candidate (``ImageCenterline.taper_candidates``) taken where the other view reads at
    the same end a strong candidate, a taper of at least :data:`FLAT_TIP_HALF_TAPER_PX`, or, for a strong candidate,
    any taper or candidate; the rest flat; and each end tapered by less than :data:`FLAT_TIP_HALF_TAPER_PX` placed
    flat (``flat_ends``) where the other view reads neither a taper nor a strong candidate there (a bevel is one
    feature, seen by both cameras). The same end: the two ends lie within ``tolerance`` [px] of one epipolar line,
    the other view's other end does not."""
    views = (left, right)
    if all(reading is None for view in views for reading in view.taper_candidates + view.flat_ends):
        return left, right
    e = rectification.epipolar_axis
    ends = [rectification.rectify(np.array([view.points[-1 if end else 0] if candidate is None else candidate.points[-1]
                                            for end, candidate in enumerate(view.taper_candidates)]), side)[:, e]
            for view, side in zip(views, ("left", "right"))]
    out = []
    for k, view in enumerate(views):
        other = views[1 - k]
        for end, (candidate, flat) in enumerate(zip(view.taper_candidates, view.flat_ends)):
            if candidate is None and flat is None:
                continue
            apart = np.abs(ends[1 - k] - ends[k][end])
            partner = int(np.argmin(apart))
            if not apart[partner] <= tolerance < apart[1 - partner]:
                continue
            other_taper, other_candidate = other.end_taper_px[partner], other.taper_candidates[partner]
            other_strong = other_candidate is not None and other_candidate.fall_ratio > CANDIDATE_TAPER_FACTOR
            other_reads = other_taper > 0 or other_candidate is not None
            if candidate is not None and (other_strong or other_taper >= FLAT_TIP_HALF_TAPER_PX
                                          or (candidate.fall_ratio > CANDIDATE_TAPER_FACTOR and other_reads)):
                view = with_end_reading(view, end, candidate)
            elif flat is not None and not (other_taper > 0 or other_strong) \
                    and view.end_taper_px[end] < FLAT_TIP_HALF_TAPER_PX:
                view = with_end_reading(view, end, flat)
        out.append(replace(view, taper_candidates=(None, None), flat_ends=(None, None)))
    return out[0], out[1]


def _without_end_caps(centerline: ImageCenterline, side: str, points: np.ndarray, rectification: Rectification,
                      radius: float) -> ImageCenterline:
    """``centerline`` of camera ``side`` shortened at each end by what the end's disc (``radius``, square to the needle)
    adds beyond the flat cut: a half ellipse of half axis a = f radius |cos theta| / Z along the needle (theta between
    the end's tangent and the viewing ray, Z the end's distance; from the first triangulation ``points``, raw left
    frame), whose half-contrast point lies END_CAP_CROSSING a beyond the end (tapered ends: not moved)."""
    rig = rectification.rig
    camera, centre = (rig.left, np.zeros(3)) if side == "left" else (rig.right, rig.left_from_right.translation)
    ends = points[[0, -1]]
    tangents = ends - points[[min(5, len(points) - 1), max(len(points) - 6, 0)]]
    projected = rectification.project_rectified(ends, side)
    image_ends = rectification.rectify(centerline.points[[0, -1]], side)
    if (np.linalg.norm(image_ends - projected, axis=1).sum()
            > np.linalg.norm(image_ends - projected[::-1], axis=1).sum()):  # this view's curve runs the other way
        ends, tangents = ends[::-1], tangents[::-1]
    cuts = []
    for end, tangent, taper in zip(ends, tangents, centerline.end_taper_px):
        if taper > 0:  # a bevel seen side-on, already placed from its fitted taper
            cuts.append(0.0)
            continue
        ray = end - centre
        distance = float(np.linalg.norm(ray))
        cosine = abs(float(tangent @ ray)) / max(float(np.linalg.norm(tangent)) * distance, 1e-12)
        cuts.append(END_CAP_CROSSING * camera.camera_matrix[0, 0] * radius * min(cosine, 1.0) / distance)
    arc = arc_length(centerline.points)
    start, stop = cuts[0], arc[-1] - cuts[1]
    if stop - start < 0.5 * arc[-1]:
        return centerline
    new_arc = np.concatenate([[start], arc[(arc > start) & (arc < stop)], [stop]])
    return replace(centerline, points=interpolate(arc, centerline.points, new_arc),
                   **{name: np.interp(new_arc, arc, getattr(centerline, name))
                      for name in ("contrast", "local_noise_px", "extrapolation_px")})


def _slide(sin_angle: np.ndarray, extrapolation_px: np.ndarray, correlated_px: float) -> np.ndarray:
    """Disparity error [px] of a match that the smoothing along the curve does not average, where the image
    tangent makes an angle theta (``sin_angle``, floored like the anchors) with the epipolar lines; at the points
    extrapolated towards an image's ends, their shared lateral error too (``extrapolation_px``, both views').

    A lateral image error e moves the match by e / sin(theta) along the epipolar line; its correlated part
    c = ``correlated_px`` is not averaged: sqrt(2) c / sin(theta) for both views, the extrapolated stretch's error
    added in quadrature (its lateral part in :func:`_unaveraged`)."""
    return np.sqrt(2.0 * correlated_px ** 2 + extrapolation_px ** 2) / sin_angle


def _unaveraged(per_disparity: np.ndarray, lateral_scale: np.ndarray, slope: np.ndarray,
                extrapolation_px: np.ndarray, correlated_px: float = CORRELATED_NOISE_PX) -> np.ndarray:
    """1-sigma error [m] of each triangulated point that averaging along the curve does not reduce: the slide
    (:func:`_slide`) through the depth per disparity pixel, and the extrapolated ends' shared error laterally
    (``lateral_scale`` [m/px]). The curve fit takes ``correlated_px`` = 0: its covariance carries the correlated
    image error already (``noise_inflation``)."""
    return np.hypot(per_disparity * _slide(slope, extrapolation_px, correlated_px), lateral_scale * extrapolation_px)


def _depth_curvature(curve: np.ndarray, arc: np.ndarray, anchored: np.ndarray, start: float, stop: float,
                     depth_axis: np.ndarray) -> float:
    """|d^2 depth / du^2| [1/m] of the ``anchored`` points of ``curve`` (arc lengths ``arc``) between ``start`` and
    ``stop``: the depth component of the curvature vector of a quadratic fitted to them in arc length (least squares;
    0 with fewer than 10 points)."""
    inside = anchored & (arc >= start) & (arc <= stop)
    if np.count_nonzero(inside) < 10:
        return 0.0
    u = arc[inside] - 0.5 * (start + stop)
    depth = curve[inside] @ depth_axis
    return float(abs(2 * np.polyfit(u, depth, 2)[0]))


def _continuity_sigma(smooth: np.ndarray, anchored: np.ndarray, span: float, depth_axis: np.ndarray) -> np.ndarray:
    """1-sigma error [m] of the points placed by continuity (not ``anchored``: the correspondence interpolates their
    match linearly between the anchors around them, or extrapolates it with the local ratio beyond the last ones).

    The depth (along the unit ``depth_axis``, the rectified optical axis) follows the chord between the bordering
    anchors; a depth profile of second derivative Z'' leaves the chord between points a before and b after it (arc
    lengths) by Z'' a b / 2, and the end tangent by Z'' a^2 / 2 when extrapolated. Z'' is taken as large as the
    anchored needle's beside it (fitted over ``span`` beyond each bordering anchor, the larger): a rod's curvature is
    continuous."""
    n = len(smooth)
    sigma = np.zeros(n)
    gap = ~anchored
    if not gap.any():
        return sigma
    if not anchored.any():
        return np.full(n, np.inf)
    arc = arc_length(smooth)
    index = np.arange(n)
    before = np.maximum.accumulate(np.where(anchored, index, -1))
    after = np.minimum.accumulate(np.where(anchored, index, n)[::-1])[::-1]
    curvature = np.zeros(n)
    for k in np.flatnonzero(anchored[:-1] & gap[1:]):  # anchors that a stretch follows: the curve behind them
        curvature[k] = _depth_curvature(smooth, arc, anchored, arc[k] - span, arc[k], depth_axis)
    for k in np.flatnonzero(gap[:-1] & anchored[1:]) + 1:  # anchors that a stretch precedes: the curve ahead of them
        curvature[k] = max(curvature[k], _depth_curvature(smooth, arc, anchored, arc[k], arc[k] + span, depth_axis))
    k_before, k_after = np.clip(before, 0, n - 1), np.clip(after, 0, n - 1)
    kappa = np.maximum(np.where(before >= 0, curvature[k_before], 0.0), np.where(after < n, curvature[k_after], 0.0))
    a = np.where(before >= 0, arc - arc[k_before], np.inf)
    b = np.where(after < n, arc[k_after] - arc, np.inf)
    sigma[gap] = 0.5 * kappa[gap] * np.where(np.isfinite(a[gap]) & np.isfinite(b[gap]), a[gap] * b[gap],
                                             np.minimum(a[gap], b[gap]) ** 2)
    return sigma


def _matched(count: int, nearest: np.ndarray, chained: np.ndarray) -> np.ndarray:
    """Which of a view's ``count`` image points the kept matches stand for: each kept match's ``nearest`` image point
    and those between two kept matches that were consecutive matches (``chained``: no rejected or invalid match
    between them); not the image points of rejected matches nor those the other view did not match."""
    low, high = np.minimum(nearest[:-1], nearest[1:])[chained], np.maximum(nearest[:-1], nearest[1:])[chained]
    steps = np.zeros(count + 1, int)
    np.add.at(steps, low, 1)
    np.add.at(steps, high + 1, -1)
    matched = np.cumsum(steps[:-1]) > 0
    matched[nearest] = True
    return matched


def _beyond_hidden_stretches(parameters: np.ndarray, arc: np.ndarray, runs: list[slice], per_point: np.ndarray,
                             max_gap: float) -> tuple[np.ndarray, np.ndarray]:
    """The per-point path's sigma (``per_point`` at the triangulated points, arc lengths ``arc``) and whether it
    measures (no step above ``max_gap``) at the fitted curve's ``parameters`` on each run of the points (``runs``) that
    a hidden stretch longer than the run separates from the rest; 0 and True elsewhere.

    Across a hidden stretch the curve's parameter is the chord between the runs, shorter than the hidden needle, and
    its bending prior ties the run to the rest along a curve of the wrong length: a bias its covariance does not know,
    which outweighs the run's own image points where the run is the shorter (the 3D shape behind the soft column band:
    a 22 mm run beyond 182 mm, fitted 1.4-1.6 mm off at sigma 0.3 mm, its triangulated points 0.1-0.8 mm off). There
    the fit says no more than the per-point path."""
    floor, gapless = np.zeros(len(parameters)), np.ones(len(parameters), bool)
    for run in runs:
        run_arc = arc[run]
        hidden = max(run_arc[0] - arc[max(run.start - 1, 0)], arc[min(run.stop, len(arc) - 1)] - run_arc[-1])
        if hidden <= run_arc[-1] - run_arc[0]:
            continue
        inside = (parameters >= run_arc[0]) & (parameters <= run_arc[-1])
        floor[inside] = np.interp(parameters[inside], run_arc, per_point[run])
        after = np.clip(np.searchsorted(run_arc, parameters[inside]), 1, len(run_arc) - 1)
        gapless[inside] = run_arc[after] - run_arc[after - 1] <= max_gap
    return floor, gapless


def _fitted_curve(points: np.ndarray, point_sigma: np.ndarray, unaveraged: np.ndarray, extrapolation_sigma: np.ndarray,
                  spacing: float, centerlines: tuple[ImageCenterline, ImageCenterline],
                  rectified: tuple[np.ndarray, np.ndarray], matched: tuple[np.ndarray, np.ndarray],
                  rectification: Rectification, config: ReconstructionConfig
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The curve fitted to both views (:mod:`needle_vision.matching.curve_fit`) from the triangulated ``points``
    (raw left frame, smoothed first), sampled every half ``sample_spacing``: points (raw left frame), sigma,
    supported; None when the fit fails (then the triangulated points are used).

    Only the image points that the kept matches stand for (``matched``, :func:`_matched`) are fitted and support it:
    the curve spans the triangulated points only, so an image point the other view did not match (one view's needle
    beyond the other's end) has its foot clamped at an end and pulls the curve towards it (the S-curve behind the soft
    column band: 180 right image points beyond the left view's end put 30 mm of the curve 0.4-0.8 mm off at 3-6
    sigma), and where the per-point path rejected a match as an outlier its image points err beyond their noise.

    The fit weighs each image point by its own noise, the extrapolation error included, and its covariance averages
    that over the stretch like white noise; but an extrapolated stretch shares one error (the fitted curve follows
    it), so each sample's sigma adds in quadrature the ``extrapolation_sigma`` [m] of the triangulated points
    (:func:`_unaveraged` of the extrapolation alone) at its curve parameter (their arc length). On a run beyond a
    longer hidden stretch the sigma is at least the per-point path's (``point_sigma`` smoothed, ``unaveraged``
    added) and the samples are measured only where it measures (:func:`_beyond_hidden_stretches`)."""
    split = 0.5 * config.smoothing_length
    runs = _runs(points, split)
    smooth, gain = _smooth_runs(points, runs, config.smoothing_length, spacing)
    rotation = rectification.rotation_left
    noise = tuple(np.maximum.reduce([c.local_noise_px, c.extrapolation_px, np.full(len(c.points), max(
        c.noise_px, MIN_IMAGE_NOISE_PX))])[m] for c, m in zip(centerlines, matched))
    rectified = tuple(view[m] for view, m in zip(rectified, matched))
    # The correlated error, once per CORRELATED_NOISE_POINTS points, inflates the image terms' variance.
    white = float(np.median(np.concatenate(noise)))
    inflation = 1.0 + CORRELATED_NOISE_POINTS * (CORRELATED_NOISE_PX / white) ** 2
    # The ends as the correspondence placed them, seen by each view.
    ends = np.stack([rectification.project_rectified(points[[0, -1]], side) for side in ("left", "right")])
    fit = fit_curve(smooth @ rotation.T, 1.0 / np.maximum(point_sigma * gain, 1e-9) ** 2, ends, rectified, noise,
                    (rectification.projection_left, rectification.projection_right),
                    knot_spacing=config.knot_spacing, bending_weight=config.bending_weight,
                    end_noise_px=config.end_noise_px, max_gap=config.max_gap,
                    sample_spacing=0.5 * config.sample_spacing, noise_inflation=inflation)
    if fit is None:
        return None
    arc = arc_length(smooth)
    floor, gapless = _beyond_hidden_stretches(fit.parameters, arc, runs, np.hypot(point_sigma * gain, unaveraged),
                                              config.max_gap)
    sigma = np.maximum(np.hypot(fit.sigma, np.interp(fit.parameters, arc, extrapolation_sigma)), floor)
    supported = fit.supported & gapless
    return fit.points @ rotation, sigma, supported


@numba.njit(cache=True, nogil=True)
def _resampled(smooth, point_sigma, supported, sample_spacing, max_gap, max_uncertainty, camera,
               focal_length):  # pragma: no cover - compiled
    """The centerline ``smooth (n, 3)`` (smoothed, or the fitted curve's samples) resampled every ``sample_spacing``
    of arc length (no sliver at the tip): arc lengths, points, unit tangents, 1-sigma uncertainty (interpolated from
    ``point_sigma``, the end samples' with the localization of the needle's ends, ~END_LOCALIZATION_PX at the
    distance from the ``camera`` centre; UNMEASURED in gaps) and whether each was measured (no step longer than
    ``max_gap`` around it, both points around it ``supported``, the uncertainty at most ``max_uncertainty``)."""
    arc = arc_length(smooth)
    length = arc[-1]
    steps = np.arange(0.0, length, sample_spacing)
    count = steps.shape[0] + 1
    if steps.shape[0] > 0 and length - steps[-1] < 0.25 * sample_spacing:
        count -= 1
    samples = np.empty(count)
    samples[:count - 1] = steps[:count - 1]
    samples[-1] = length
    resampled = np.empty((count, 3))
    for j in range(3):
        resampled[:, j] = np.interp(samples, arc, smooth[:, j])
    tangents = np.empty((count, 3))
    for k in range(count):
        before, after = max(k - 1, 0), min(k + 1, count - 1)  # central differences, one-sided at the ends
        for j in range(3):
            tangents[k, j] = (resampled[after, j] - resampled[before, j]) / (samples[after] - samples[before])
        tangents[k] /= max(np.sqrt(np.sum(tangents[k] * tangents[k])), 1e-12)
    uncertainty = np.interp(samples, arc, point_sigma)
    for k in (0, count - 1):
        offset = resampled[k] - camera
        distance = np.sqrt(offset[0] * offset[0] + offset[1] * offset[1] + offset[2] * offset[2])
        uncertainty[k] = np.hypot(uncertainty[k], END_LOCALIZATION_PX * (distance / focal_length))
    measured = np.empty(count, np.bool_)
    last = arc.shape[0] - 1
    for k in range(count):
        after = min(max(np.searchsorted(arc, samples[k], side="right"), 1), last)
        measured[k] = (arc[after] - arc[after - 1] <= max_gap and supported[after] and supported[after - 1]
                       and uncertainty[k] <= max_uncertainty)
        if not measured[k]:
            uncertainty[k] = UNMEASURED
    return samples, resampled, tangents, uncertainty, measured


def order_and_resample(triangulation: Triangulation, rectification: Rectification, config: ReconstructionConfig,
                       output_from_left: RigidTransform, base_hint: np.ndarray | None = None) -> NeedleMeasurement:
    """Order ``triangulation`` from the base (the end nearer to ``base_hint``, else to ``config.base_point``) to the
    tip, smooth and resample it; raises ImplausibleError for a needle longer than ``max_length``."""
    points, point_sigma, anchored = triangulation.points, triangulation.sigma, triangulation.anchored
    split, spacing = 0.5 * config.smoothing_length, triangulation.spacing
    base = config.base_point if base_hint is None else base_hint
    reverse = np.linalg.norm(points[-1] - base) < np.linalg.norm(points[0] - base)
    if reverse:
        points, point_sigma, anchored = points[::-1], point_sigma[::-1], anchored[::-1]
    if triangulation.fit is not None:
        smooth, point_sigma, supported = (np.ascontiguousarray(a[::-1] if reverse else a) for a in triangulation.fit)
    else:
        smooth, smoothing_gain = _smooth_runs(points, _runs(points, split), config.smoothing_length, spacing)
        # white noise kept by the cubic fit, and the slide along the epipolar lines that it does not average
        slide = triangulation.slide_sigma[::-1] if reverse else triangulation.slide_sigma
        depth_axis = output_from_left.rotation @ rectification.rotation_left[2]
        point_sigma = np.sqrt((point_sigma * smoothing_gain) ** 2 + slide ** 2
                              + _continuity_sigma(smooth, anchored, CURVATURE_SPAN, depth_axis) ** 2)
        supported = np.ones(len(smooth), np.bool_)
    samples, resampled, tangents, uncertainty, measured = _resampled(
        smooth, point_sigma, supported, config.sample_spacing, config.max_gap, config.max_uncertainty,
        output_from_left.translation, rectification.focal_length)
    length = float(samples[-1])
    if length > config.max_length:
        raise ImplausibleError(f"implausible: measured needle is {length * 1e3:.0f} mm long "
                               f"(> max_length {config.max_length * 1e3:.0f} mm)")
    return NeedleMeasurement(resampled, tangents, samples, uncertainty, length, triangulation.left_centerline,
                             triangulation.right_centerline, float(np.mean(anchored)), measured)
