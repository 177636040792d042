"""How much the images say about a stretch of needle along the epipolar lines (issue 39): an alternative
centerline displaced only within each point's epipolar plane and across the tangent, and the statistical distance
between the noise-free renders of the two shapes under the renderer's own Gaussian sensor noise.

The displaced curve X'(s) = X(s) + delta(s) n(s): n the unit vector in the epipolar plane of X(s) (the plane through
X(s) and both camera centres) square to the tangent t(s), i.e. along m x t with m the plane's normal; delta(s) a C²
window (a plateau with quintic smootherstep ramps) that is zero outside a chosen stretch. A point moved within its
epipolar plane stays on its epipolar line in both images, so the image of the centerline changes at first order only
by delta * sin(angle between t and the plane); where the stretch lies in the planes, only the tube's apparent width
(radius * f / depth) still changes at first order in delta (``report``: D scales with the radius there).

Two hypotheses, the true and the displaced shape, give per-pixel Gaussians N(I_a, sigma_a²) and N(I_b, sigma_b²) with
sigma² = read_noise² + shot_gain * I (:func:`needle_vision.render.noise_sigma`). Their Mahalanobis distance is
D = sqrt(sum (I_a - I_b)² / sigma_a²) over both images; for two Gaussians of equal covariance the total variation
distance is 2 Phi(D / 2) - 1, and any decision between them errs with probability >= (1 - TV) / 2 on one of them.
The variances differ slightly (shot noise): :func:`decision_error_bound` also gives the bound that holds without
that approximation, from the Bhattacharyya distance (TV <= sqrt(1 - exp(-2 D_B))). Quantisation and clipping are
left out: they are functions of the noisy image, so they can only make the two hypotheses harder to tell apart (data
processing) and the bounds hold for the quantised images too.

The tip is another matter (:func:`tip_alternative`): moved within its epipolar plane it slides along the line by a
different amount in each view, so its end shows where it is. D for one parameter of displacement is a lower bound
only in that family: an estimator that must also find nuisance parameters (the bevel's length and turn) can do worse.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import brentq
from scipy.stats import norm

from needle_vision.calibration.rig import StereoRig
from needle_vision.detection.curves import arc_length
from needle_vision.render import NEEDLE_RADIUS, Imaging, Scene, default_rig, make_scene, noise_sigma, render_signal, \
    world_from_camera
from vision_shapes import EPIPOLAR_SHAPES, ROD_EPIPOLAR_SHAPES, SHAPES, background_models, bright_scene, \
    distance_to_curve

#: The stretch displaced: the longest run of the curve whose tangent is within this angle of its epipolar plane.
MAX_PLANE_ANGLE_DEG = 1.0
#: Each ramp of the displacement's window, as a fraction of the stretch.
RAMP_FRACTION = 0.25
#: The stretch before the tip over which :func:`tip_alternative` moves it [m].
TIP_STRETCH = 10e-3
#: The kinds whose end runs along the epipolar lines (its tangent within 0.3° of its plane).
TIP_ALONG = ("curl_down", "curl_up", "turning_plane", "rod_curl_down", "rod_curl_up")


def camera_centres(rig: StereoRig) -> tuple[np.ndarray, np.ndarray]:
    """World positions of the left and right camera centres."""
    return tuple(world_from_camera(rig, side).translation for side in ("left", "right"))


def unit(vectors: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length."""
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def tangents(points: np.ndarray) -> np.ndarray:
    """Unit tangents ``(n, 3)`` of a densely sampled polyline (central differences)."""
    return unit(np.gradient(points, axis=0))


def epipolar_normals(points: np.ndarray, rig: StereoRig) -> np.ndarray:
    """Unit normals ``(n, 3)`` of each point's epipolar plane (through the point and both camera centres)."""
    left, right = camera_centres(rig)
    return unit(np.cross(points - left, right - left))


def plane_angle(points: np.ndarray, rig: StereoRig) -> np.ndarray:
    """Angle [rad] between the tangent and the epipolar plane at each point: 0 where the curve runs in its
    epipolar plane (its image along the epipolar lines in both views)."""
    return np.arcsin(np.clip(np.abs(np.einsum("ij,ij->i", tangents(points), epipolar_normals(points, rig))), 0, 1))


def in_plane_direction(points: np.ndarray, rig: StereoRig) -> np.ndarray:
    """Unit vectors in each point's epipolar plane, square to the tangent (m x t), turned away from the cameras.
    Ill-defined where the tangent is square to the plane (the needle across the epipolar lines): use it on
    stretches near the planes only."""
    direction = unit(np.cross(epipolar_normals(points, rig), tangents(points)))
    depth = points - 0.5 * np.add(*camera_centres(rig))
    return direction * np.sign(np.einsum("ij,ij->i", direction, depth))[:, None]


def depth_direction(points: np.ndarray, rig: StereoRig) -> np.ndarray:
    """Unit vectors along the viewing ray from the rig's midpoint, made square to the tangent: the direction a
    stereo rig sees least, for a stretch across the epipolar lines (where it lies in the epipolar plane)."""
    depth = unit(points - 0.5 * np.add(*camera_centres(rig)))
    along = tangents(points)
    return unit(depth - np.einsum("ij,ij->i", depth, along)[:, None] * along)


def window(arc: np.ndarray, start: float, stop: float, ramp: float) -> np.ndarray:
    """A C² plateau: 0 outside [start, stop], 1 inside it but for quintic smootherstep ramps of length ``ramp``
    at both ends (their first and second derivatives vanish at both ends of the ramp)."""
    def smootherstep(x: np.ndarray) -> np.ndarray:
        x = np.clip(x, 0.0, 1.0)
        return x ** 3 * (10 - 15 * x + 6 * x ** 2)
    return smootherstep((arc - start) / ramp) * smootherstep((stop - arc) / ramp)


def epipolar_stretch(points: np.ndarray, rig: StereoRig, max_angle_deg: float) -> tuple[float, float]:
    """Arc lengths [m] of the longest run of points whose tangent is within ``max_angle_deg`` of its epipolar
    plane."""
    near = plane_angle(points, rig) <= np.radians(max_angle_deg)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], near.astype(int), [0]])))
    starts, stops = edges[::2], edges[1::2] - 1
    longest = np.argmax(stops - starts)
    arc = arc_length(points)
    return arc[starts[longest]], arc[stops[longest]]


@dataclass(frozen=True)
class Displacement:
    """An alternative centerline and how far it is from the true one over the displaced stretch."""

    points: np.ndarray  # (n, 3) [m]
    max: float  # largest displacement [m]
    rms: float  # RMS displacement over the stretch [start, stop] [m]
    length_change: float  # arc length of the displaced minus the true curve [m]


def displaced(points: np.ndarray, direction: np.ndarray, start: float, stop: float, rms: float) -> Displacement:
    """``points`` moved along the unit ``direction`` ``(n, 3)`` by a :func:`window` over [start, stop] (ramps
    ``RAMP_FRACTION`` of it) scaled to ``rms`` [m] RMS over [start, stop]."""
    arc = arc_length(points)
    inside = (arc >= start) & (arc <= stop)
    shape = window(arc, start, stop, RAMP_FRACTION * (stop - start))
    offset = rms / np.sqrt(np.mean(shape[inside] ** 2)) * shape
    moved = points + offset[:, None] * direction
    return Displacement(moved, float(offset.max()), float(np.sqrt(np.mean(offset[inside] ** 2))),
                        float(arc_length(moved)[-1] - arc[-1]))


@dataclass(frozen=True)
class Distance:
    """Statistical distance between the sensor readings of two noise-free image pairs."""

    mahalanobis: float  # D, with the first pair's per-pixel sigma
    bhattacharyya: float  # D_B, exact for the two heteroscedastic Gaussians
    changed_pixels: int  # pixels whose signal differs by more than 1e-3 sigma


def image_distance(first: tuple[np.ndarray, np.ndarray], second: tuple[np.ndarray, np.ndarray],
                   imaging: Imaging = Imaging()) -> Distance:
    """D and D_B over both images of two noise-free pairs (:func:`needle_vision.render.render_signal`)."""
    squared, bhattacharyya, changed = 0.0, 0.0, 0
    for a, b in zip(first, second):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        var_a, var_b = noise_sigma(a, imaging) ** 2, noise_sigma(b, imaging) ** 2
        difference = a - b
        squared += np.sum(difference ** 2 / var_a)
        bhattacharyya += np.sum(0.25 * difference ** 2 / (var_a + var_b)
                                + 0.5 * np.log((var_a + var_b) / (2 * np.sqrt(var_a * var_b))))
        changed += int(np.count_nonzero(np.abs(difference) > 1e-3 * np.sqrt(var_a)))
    return Distance(float(np.sqrt(squared)), float(bhattacharyya), changed)


def decision_error_bound(distance: Distance) -> tuple[float, float]:
    """Lower bounds on the error of any decision between the two hypotheses (the larger of its two error
    probabilities is at least their mean, (1 - TV) / 2): from D with equal covariances, TV = 2 Phi(D/2) - 1; and
    without that approximation, TV <= sqrt(1 - exp(-2 D_B))."""
    shift = (1 - (2 * norm.cdf(distance.mahalanobis / 2) - 1)) / 2
    exact = (1 - np.sqrt(1 - np.exp(-2 * distance.bhattacharyya))) / 2
    return float(shift), float(exact)


def epipolar_alternative(points: np.ndarray, rig: StereoRig, rms: float,
                         max_angle_deg: float = MAX_PLANE_ANGLE_DEG) -> Displacement:
    """The alternative centerline: displaced within the epipolar planes, across the tangent, over the longest
    stretch whose tangent is within ``max_angle_deg`` of its plane, by ``rms`` [m] RMS over that stretch."""
    start, stop = epipolar_stretch(points, rig, max_angle_deg)
    return displaced(points, in_plane_direction(points, rig), start, stop, rms)


def tip_alternative(points: np.ndarray, rig: StereoRig, delta: float, length: float = TIP_STRETCH) -> np.ndarray:
    """The centerline with its tip moved ``delta`` [m] within its epipolar plane, across the tangent (in depth where
    the end runs along the lines), by a smootherstep ramp over the last ``length`` [m]: 0 and flat before it, 1 at
    the tip."""
    arc = arc_length(points)
    return points + (delta * window(arc, arc[-1] - length, arc[-1] + length, length))[:, None] * \
        in_plane_direction(points, rig)


def report() -> None:
    """The numbers of docs/stereo_history.md's section on this: per kind along the lines and polarity, the
    displaced stretch, D at 0.2 mm RMS and the RMS at D = 1; the same bump across the epipolar planes; D with the
    needle's radius doubled (where the information is); the control across the lines."""
    rig = default_rig()
    dark = make_scene(rig, np.random.default_rng(0))
    scenes = {"dark": dark, "bright": bright_scene(dark)}

    def distance(truth: np.ndarray, other: np.ndarray, scene: Scene, radius: float = NEEDLE_RADIUS) -> Distance:
        return image_distance(*(render_signal(rig, points, radius, scene=scene) for points in (truth, other)))

    print("| case | polarity | stretch [mm] | max angle to the plane [°] | max / RMS displacement [mm] | length change "
          "[µm] | D | D_B | error ≥ (shift / exact) | RMS at D = 1 [mm] | D across the planes | D, radius ×2 | "
          "whole needle: stretch RMS [mm], D, error ≥ (shift / exact) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, truth in {**EPIPOLAR_SHAPES, **ROD_EPIPOLAR_SHAPES}.items():
        start, stop = epipolar_stretch(truth, rig, MAX_PLANE_ANGLE_DEG)
        arc = arc_length(truth)
        angle = np.degrees(plane_angle(truth, rig)[(arc >= start) & (arc <= stop)]).max()
        for polarity, scene in scenes.items():
            alternative = epipolar_alternative(truth, rig, 0.2e-3)
            seen = distance(truth, alternative.points, scene)
            at_one = brentq(lambda rms: distance(truth, epipolar_alternative(truth, rig, rms).points, scene)
                            .mahalanobis - 1, 1e-5, 3e-3, xtol=1e-6)
            across = distance(truth, displaced(truth, epipolar_normals(truth, rig), start, stop, 0.2e-3).points, scene)
            wide = distance(truth, alternative.points, scene, 2 * NEEDLE_RADIUS)
            bounds = decision_error_bound(seen)
            # The bump whose half puts 0.1 mm RMS over the whole needle: an estimator that picks the wrong shape is
            # then >= 0.1 mm RMS off over the whole needle, whatever it does elsewhere.
            whole = 2 * 0.1e-3 * np.sqrt(arc[-1] / (stop - start))
            whole_seen = distance(truth, epipolar_alternative(truth, rig, whole).points, scene)
            whole_bounds = decision_error_bound(whole_seen)
            print(f"| {name} | {polarity} | {1e3 * start:.0f}–{1e3 * stop:.0f} | {angle:.2f} | "
                  f"{1e3 * alternative.max:.3f} / {1e3 * alternative.rms:.3f} | "
                  f"{1e6 * alternative.length_change:.1f} | {seen.mahalanobis:.2f} | "
                  f"{seen.bhattacharyya:.3f} | {bounds[0]:.3f} / {bounds[1]:.3f} | {1e3 * at_one:.2f} | "
                  f"{across.mahalanobis:.0f} | {wide.mahalanobis:.2f} | {1e3 * whole:.2f}, "
                  f"{whole_seen.mahalanobis:.2f}, {whole_bounds[0]:.3f} / {whole_bounds[1]:.3f} |", flush=True)
    print("\nWider stretches, 0.2 mm RMS: per largest angle to the plane, the stretches' lengths and D over the kinds "
          "and polarities.\n")
    for angle in (2.0, 3.0, 5.0):
        lengths, seen = [], []
        for truth in {**EPIPOLAR_SHAPES, **ROD_EPIPOLAR_SHAPES}.values():
            start, stop = epipolar_stretch(truth, rig, angle)
            lengths.append(stop - start)
            seen += [distance(truth, epipolar_alternative(truth, rig, 0.2e-3, angle).points, scene).mahalanobis
                     for scene in scenes.values()]
        print(f"- within {angle:.0f}°: {1e3 * min(lengths):.0f}–{1e3 * max(lengths):.0f} mm, D {min(seen):.2f}–"
              f"{max(seen):.2f}", flush=True)
    print("\nWhere it is: the bump on the part exactly in the planes (< 0.05°), dark; along the tangent: the null "
          "check (the needle slid along itself).\n")
    print("| case | part [mm] | direction | RMS [mm] | D | pixels changed > 1e-3 σ | max abs ΔI [DN] |")
    print("|---|---|---|---|---|---|---|")
    for name in ("curl_down", "turning_plane"):
        truth = EPIPOLAR_SHAPES[name]
        exact = arc_length(truth)[plane_angle(truth, rig) < np.radians(0.05)]
        signal = render_signal(rig, truth, NEEDLE_RADIUS, scene=dark)
        for direction, vectors in (("in the plane", in_plane_direction(truth, rig)), ("tangent", tangents(truth))):
            for rms in (0.2e-3, 0.4e-3):
                moved = render_signal(rig, displaced(truth, vectors, exact[0], exact[-1], rms).points, NEEDLE_RADIUS,
                                      scene=dark)
                seen = image_distance(signal, moved)
                change = max(np.abs(np.asarray(a, float) - b).max() for a, b in zip(signal, moved))
                print(f"| {name} | {1e3 * exact[0]:.0f}–{1e3 * exact[-1]:.0f} | {direction} | {1e3 * rms:.1f} | "
                      f"{seen.mahalanobis:.3f} | {seen.changed_pixels} | {change:.3f} |", flush=True)
    print("\nThe tip of the kinds whose end runs along the lines, moved 0.2 mm in depth within its epipolar plane over "
          "the last 10 mm (tip_alternative), per bevel length.\n")
    print("| case | bevel [mm] | polarity | D | tip moved at D = 1 [mm] |")
    print("|---|---|---|---|---|")
    for name in TIP_ALONG:
        truth = {**EPIPOLAR_SHAPES, **ROD_EPIPOLAR_SHAPES}[name]
        for bevel in (0.0, 1e-3, 2e-3):
            for polarity, scene in scenes.items():
                signal = render_signal(rig, truth, NEEDLE_RADIUS, scene=scene, bevel_length=bevel)

                def tip_seen(delta: float) -> Distance:
                    return image_distance(signal, render_signal(rig, tip_alternative(truth, rig, delta),
                                                                 NEEDLE_RADIUS, scene=scene, bevel_length=bevel))
                at_one = brentq(lambda delta: tip_seen(delta).mahalanobis - 1, 1e-6, 5e-3, xtol=1e-7)
                print(f"| {name} | {1e3 * bevel:.0f} | {polarity} | {tip_seen(0.2e-3).mahalanobis:.1f} | "
                      f"{1e3 * at_one:.3f} |", flush=True)
    print("\nControl: the same bump (0.2 mm RMS) in depth, square to the tangent, on a stretch across the lines.\n")
    print("| case | stretch [mm] | angle to the plane [°] | polarity | D | RMS at D = 1 [µm] |")
    print("|---|---|---|---|---|---|")
    for name, start, stop in (("straight", 0.10, 0.17), ("planar", 0.10, 0.17), ("3d", 0.10, 0.17),
                              ("curl_down", 0.0, 0.15)):
        truth = {**SHAPES, **EPIPOLAR_SHAPES}[name]
        arc = arc_length(truth)
        angle = np.degrees(plane_angle(truth, rig)[(arc >= start) & (arc <= stop)])
        for polarity, scene in scenes.items():
            seen = distance(truth, displaced(truth, depth_direction(truth, rig), start, stop, 0.2e-3).points, scene)
            print(f"| {name} | {1e3 * start:.0f}–{1e3 * stop:.0f} | {angle.min():.0f}–{angle.max():.0f} | {polarity} | "
                  f"{seen.mahalanobis:.1f} | {1e6 * 0.2e-3 / seen.mahalanobis:.1f} |", flush=True)


def reconstruction_report(seeds: tuple[int, ...] = (7, 1007)) -> None:
    """The project's reconstruction (per point, and the curve fit at the default ``max_uncertainty``) on the true
    and the displaced shape (0.2 mm RMS), rendered with the same noise draw: over the displaced stretch, how far
    apart the two outputs are and each output's distance to each truth (RMS over its samples there, measured or
    not)."""
    from needle_vision.calibration.rectification import Rectification
    from needle_vision.detection.background import ContrastThreshold
    from needle_vision.detection.centerline import extract_centerline
    from needle_vision.matching.correspondence import MatchingConfig
    from needle_vision.matching.reconstruction import ReconstructionConfig, reconstruct_centerline
    from needle_vision.render import render_stereo_pair

    rig = default_rig()
    rectification = Rectification.from_rig(rig)
    dark = make_scene(rig, np.random.default_rng(0))
    polarities = {}
    for name, scene, polarity in (("dark", dark, 1), ("bright", bright_scene(dark), -1)):
        polarities[name] = (scene, background_models(rig, scene, ContrastThreshold(polarity=polarity)))
    methods = {"per point": ReconstructionConfig(), "fit": ReconstructionConfig(curve_fit=True)}
    print("| case | polarity | seed | method | outputs apart [mm] | true: to true / to displaced [mm] | "
          "displaced: to true / to displaced [mm] | measured (true / displaced) |")
    print("|---|---|---|---|---|---|---|---|")
    for name, truth in {**EPIPOLAR_SHAPES, **ROD_EPIPOLAR_SHAPES}.items():
        alternative = epipolar_alternative(truth, rig, 0.2e-3).points
        start, stop = epipolar_stretch(truth, rig, MAX_PLANE_ANGLE_DEG)
        for polarity, (scene, backgrounds) in polarities.items():
            for seed in seeds:
                centerlines = [[extract_centerline(image, background) for image, background in
                                zip(render_stereo_pair(rig, shape, NEEDLE_RADIUS, np.random.default_rng(seed),
                                                       scene=scene), backgrounds)] for shape in (truth, alternative)]
                for method, config in methods.items():
                    out = [reconstruct_centerline(*pair, rectification, MatchingConfig(), config, rig.world_from_left)
                           for pair in centerlines]
                    cells, measured = [], []
                    for measurement in out:
                        _, arc = distance_to_curve(measurement.points, truth)
                        inside = (arc >= start) & (arc <= stop)
                        points = measurement.points[inside]
                        cells.append([np.sqrt(np.mean(distance_to_curve(points, shape)[0] ** 2)) * 1e3
                                      for shape in (truth, alternative)])
                        measured.append(f"{np.count_nonzero(measurement.measured[inside])}/{np.count_nonzero(inside)}")
                    _, arc = distance_to_curve(out[0].points, truth)
                    apart = distance_to_curve(out[0].points[(arc >= start) & (arc <= stop)], out[1].points)[0]
                    print(f"| {name} | {polarity} | {seed} | {method} | {1e3 * np.sqrt(np.mean(apart ** 2)):.3f} | "
                          f"{cells[0][0]:.3f} / {cells[0][1]:.3f} | {cells[1][0]:.3f} / {cells[1][1]:.3f} | "
                          f"{measured[0]} / {measured[1]} |", flush=True)


if __name__ == "__main__":
    import sys

    reconstruction_report() if "--reconstruct" in sys.argv else report()
