"""Harder render cases of issue 16 against their ground truth: an S bent out of the image plane, a stretch seen
nearly end-on, a strong brightness ramp behind the needle, a stretch hidden in one camera only. Each reports RMS
over the measured samples, coverage (measured samples over the true length), the tip error, and no invented
points (measured samples within max(3 sigma, 0.1 mm) of the truth, the others flagged unmeasured)."""
from dataclasses import replace

import numpy as np
import pytest

from vision_shapes import SHAPES, background_models, bright_scene, check_not_invented, distance_to_curve, faded
from needle_vision.detection.background import ContrastThreshold
from needle_vision.detection.centerline import extract_centerline
from needle_vision.detection.curves import arc_length
from needle_vision.matching.correspondence import MatchingConfig
from needle_vision.matching.reconstruction import END_LOCALIZATION_PX, NeedleMeasurement, ReconstructionConfig, \
    reconstruct_centerline
from needle_vision.calibration.rectification import Rectification
from needle_vision.render import NEEDLE_RADIUS, Imaging, Scene, make_scene, project_points, render_stereo_pair


def _measure(rig, backgrounds, images, config: ReconstructionConfig = ReconstructionConfig()) -> NeedleMeasurement:
    centerlines = [extract_centerline(image, background) for image, background in zip(images, backgrounds)]
    return reconstruct_centerline(*centerlines, Rectification.from_rig(rig), MatchingConfig(), config,
                                  rig.world_from_left)


#: The hook's 54 mm tail runs along the epipolar lines: where its depth bending (not seen) may move it by more than
#: max_uncertainty it is flagged (measured coverage 0.74-1.00 over the seeds).
HOOK_COVERAGE = 0.7


def _length(curve: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(curve, axis=0), axis=1).sum())


def _check(measurement: NeedleMeasurement, name: str, min_coverage: float, tip_error: float = 0.2e-3,
           max_rms: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    """RMS < ``max_rms`` over the measured samples, coverage, tip within ``tip_error``, nothing invented."""
    truth = SHAPES[name]
    distance, arc = check_not_invented(measurement, truth)
    measured = measurement.measured
    assert np.sqrt(np.mean(distance[measured] ** 2)) < max_rms
    coverage = np.count_nonzero(measured) * ReconstructionConfig().sample_spacing / _length(truth)
    assert coverage >= min_coverage
    assert np.linalg.norm(measurement.points[-1] - truth[-1]) <= tip_error
    return distance, arc


def test_s_curve_bent_out_of_the_image_plane(rig, backgrounds, renders):
    """Depth +-45 mm along an S (measured: 0.029 mm RMS, tip 0.13 mm, coverage 100 %)."""
    _check(_measure(rig, backgrounds, renders("s_curve")), "s_curve", 0.99)


def test_stretch_seen_nearly_end_on(rig, backgrounds, renders):
    """A 40 mm stretch 18 deg off the viewing rays, ~3x foreshortened: one image pixel spans > 1 mm of needle
    there, so parts of it are flagged unmeasured (max_gap) but never elsewhere (measured: 0.031 mm RMS, tip
    0.02 mm, coverage 91 %). The 3D smoothing's cubic runs along the arc length: in the point index, it bent the
    curve where the points thin out (0.034 mm RMS; over 20 seeds up to 0.037, now 0.034)."""
    measurement = _measure(rig, backgrounds, renders("end_on"))
    _, arc = _check(measurement, "end_on", 0.85, max_rms=0.032e-3)
    length = _length(SHAPES["end_on"])
    end_on = (arc > 0.42 * length) & (arc < 0.63 * length)
    assert np.all(measurement.measured[~end_on])


@pytest.fixture(scope="module")
def edge_scene(rig):
    """The default scene with the background's albedo halved left of the image centre over ~15 px: the
    needle passes in front of that ramp in both cameras."""
    scene = make_scene(rig, np.random.default_rng(0), edge_contrast=0.5)
    return scene, background_models(rig, scene)


@pytest.mark.parametrize("name", ["3d", "planar"])
def test_needle_in_front_of_a_brightness_ramp(rig, edge_scene, name):
    """Half the needle in front of a background at half the brightness, the ramp crossing it (measured:
    0.053-0.060 mm RMS, tip 0.02-0.04 mm, coverage 100 %; the darker half is noisier and says so in its uncertainty).
    The base lies on the darker side: within 0.15 mm (issue 16 left it at 0.22-0.26 mm; measured 0.08-0.09 mm, over
    seeds 7, 1007-5007 0.01-0.10 mm)."""
    scene, backgrounds = edge_scene
    images = render_stereo_pair(rig, SHAPES[name], NEEDLE_RADIUS, np.random.default_rng(7), scene=scene)
    measurement = _measure(rig, backgrounds, images)
    _check(measurement, name, 0.99)
    assert np.linalg.norm(measurement.points[0] - SHAPES[name][0]) <= 0.15e-3


def _band(scene: Scene, level: float, width: float, edge: float, across_rows: bool = False) -> Scene:
    """``scene`` with its background's albedo scaled towards ``level`` (absolute, at the band's centre) inside a
    vertical band (horizontal: ``across_rows``) ``width`` px wide across the image centre, with soft (tanh) edges of
    ``edge`` px."""
    albedo = []
    for a in scene.background_albedo:
        axis = 0 if across_rows else 1
        x = (np.arange(a.shape[axis], dtype=np.float32) - a.shape[axis] / 2).reshape((-1, 1) if across_rows else -1)
        inside = 0.5 * (np.tanh((width / 2 - np.abs(x)) / edge) + 1)
        albedo.append(((1 - inside) * a + inside * level * a / a.mean()).astype(np.float32))
    return Scene(scene.illumination, tuple(albedo), scene.needle_albedo)


def _assert_sigma_promise(measurement: NeedleMeasurement, truth: np.ndarray) -> np.ndarray:
    """The uncertainty's promise: >= 98 % of the measured samples within 3 sigma of the ``truth``, none beyond 5
    sigma; returns the samples' arc lengths along the truth."""
    distance, arc = distance_to_curve(measurement.points, truth)
    measured = measurement.measured
    z = distance[measured] / measurement.uncertainty[measured]
    assert np.mean(z <= 3) >= 0.98
    assert np.max(z) <= 5
    return arc


@pytest.mark.parametrize("name, seed", [("3d", 7), ("s_curve", 9)])
def test_dark_needle_across_a_soft_dark_band(rig, scene, name, seed):
    """Issue 39: the dark needle (albedo 0.12) in front of a 200 px band fading over 60 px to a background of albedo
    0.08: its contrast fades to nothing and reverses, and the centroids there are pulled 4-7 px. Their uncertainty
    says so (image noise over the slice's contrast): >= 98 % of the measured samples within 3 sigma, none beyond 5
    sigma (before: the 3D shape 95.5 %, one sample 5.45 mm off at 5.9 sigma; the S 97.2 %; now 100 %, at most 1.4
    and 2.7 sigma)."""
    band = _band(scene, 0.08, 200.0, 60.0)
    backgrounds = background_models(rig, band, ContrastThreshold())
    images = render_stereo_pair(rig, SHAPES[name], NEEDLE_RADIUS, np.random.default_rng(seed), scene=band)
    measurement = _measure(rig, backgrounds, images)
    _assert_sigma_promise(measurement, SHAPES[name])


@pytest.mark.parametrize("level, width, edge, across_rows, seed", [(1.2, 60.0, 6.0, False, 9),
                                                                    (1.1, 200.0, 60.0, True, 7),
                                                                    (1.1, 200.0, 60.0, False, 8)])
def test_bright_needle_across_a_brighter_band(rig, scene, level, width, edge, across_rows, seed):
    """Issue 39: the bright needle (albedo 0.9) bent in a plane, in front of a band brighter than itself: 60 px at 1.2
    with 6 px edges across the columns, or 200 px fading over 60 px to 1.1 across the rows. Where the band passes
    through the needle's level single slices err by a pixel and say so (noise 0.3-1.0 px; every 8th point, which the
    3D points read, 0.04-0.07 px), and the needle fades into the band as into a long taper: its end is extrapolated 60
    px beyond the last slice, 0.6 px off, an error the whole stretch shares (its uncertainty: how far a cubic and a
    quadratic extrapolation disagree, 0.5 px). >= 98 % of the measured samples within 3 sigma, none beyond 5 sigma
    (before: 98.6 % at 12.3 sigma, 92.9 % at 7.1 sigma; now 100 %, at most 2.7 and 1.2 sigma). Inside the band the
    needle shows reversed (darker than its background): the detection follows it through the band and measures the
    needle beyond it, within 2 mm of both true ends (before: the piece beyond the soft bands lost, the measured
    samples ending 157 mm short of the tip across the rows, starting 178 mm from the base across the columns)."""
    band = _band(bright_scene(scene), level, width, edge, across_rows)
    backgrounds = background_models(rig, band, ContrastThreshold(polarity=-1))
    images = render_stereo_pair(rig, SHAPES["planar"], NEEDLE_RADIUS, np.random.default_rng(seed), scene=band)
    measurement = _measure(rig, backgrounds, images)
    arc = _assert_sigma_promise(measurement, SHAPES["planar"])
    measured = measurement.measured
    assert arc[measured].min() <= 2e-3 and arc[measured].max() >= _length(SHAPES["planar"]) - 2e-3


@pytest.mark.parametrize("name, seed", [("s_curve", 9), ("3d", 7)])
def test_fitted_curve_behind_a_brighter_column_band(rig, scene, name, seed):
    """Issue 39: the curved shapes behind the soft band of 1.1 across the columns, with the curve fit: one view's
    needle runs on beyond the other's end (the S-curve's right view by 180 points) and pieces lie beyond long hidden
    stretches (the 3D shape's 22 mm beyond 182 mm). The fit takes only the image points of kept matches, and on a run
    beyond a longer hidden stretch says no more than the per-point path: >= 98 % of the measured samples within 3
    sigma, none beyond 5 sigma (before: the S-curve 53.6 % at 5.8 sigma, the 3D shape 85.2 % at 21.3 sigma; now 100
    %, at most 2.3 and 1.1 sigma)."""
    band = _band(bright_scene(scene), 1.1, 200.0, 60.0)
    backgrounds = background_models(rig, band, ContrastThreshold(polarity=-1))
    images = render_stereo_pair(rig, SHAPES[name], NEEDLE_RADIUS, np.random.default_rng(seed), scene=band)
    measurement = _measure(rig, backgrounds, images, ReconstructionConfig(curve_fit=True))
    _assert_sigma_promise(measurement, SHAPES[name])


@pytest.mark.parametrize("curve_fit", [False, True])
def test_an_extrapolated_end_shares_one_error(rig, backgrounds, renders, curve_fit):
    """Issue 39: the points extrapolated beyond an image's last slice share one error (where the needle fades into a
    background at its own level its end was extrapolated 48-60 px, 0.4-0.6 px off; docs/stereo_history.md), of the
    size ``extrapolation_px`` says. The left view's last 60 px bent aside by up to 0.6 px (growing with the square of
    the distance), ``extrapolation_px`` as large: >= 98 % of the measured samples within 3 sigma, none beyond 5 sigma,
    per point and with the curve fit (before, the fit took the error as each image point's own and averaged it: 94.9 %
    within 3 sigma, 4.2 sigma; now 100 %, 1.3 sigma)."""
    left, right = (extract_centerline(image, background) for image, background in zip(renders("planar"), backgrounds))
    arc = arc_length(left.points)
    offset = 0.6 * np.clip((arc - arc[-1] + 60.0) / 60.0, 0.0, 1.0) ** 2
    tangent = np.gradient(left.points, axis=0)
    normal = np.column_stack([-tangent[:, 1], tangent[:, 0]]) / np.linalg.norm(tangent, axis=1, keepdims=True)
    left = replace(left, points=left.points + offset[:, None] * normal,
                   extrapolation_px=np.maximum(left.extrapolation_px, offset))
    measurement = reconstruct_centerline(left, right, Rectification.from_rig(rig), MatchingConfig(),
                                         ReconstructionConfig(curve_fit=curve_fit), rig.world_from_left)
    _assert_sigma_promise(measurement, SHAPES["planar"])


@pytest.mark.parametrize("curve_fit", [False, True])
def test_end_samples_carry_the_ends_localization(rig, backgrounds, renders, curve_fit):
    """The needle's ends are located along it to END_LOCALIZATION_PX (a flat or bevelled end's sub-pixel edge), an
    error that neither the smoothing of the triangulated points nor the fit's covariance (its ends at 0.1 px, as the
    correspondence placed them) carries: both end samples' sigma is at least that at their distance from the left
    camera, per point and with the curve fit (before, the fit's: END_LOCALIZATION_PX not added)."""
    measurement = _measure(rig, backgrounds, renders("3d"), ReconstructionConfig(curve_fit=curve_fit))
    ends = measurement.points[[0, -1]]
    floor = END_LOCALIZATION_PX * np.linalg.norm(ends - rig.world_from_left.translation, axis=1) \
        / Rectification.from_rig(rig).focal_length
    assert np.all(measurement.measured[[0, -1]])
    assert np.all(measurement.uncertainty[[0, -1]] >= floor)


@pytest.mark.parametrize("name, start, stop", [("3d", 0.3, 0.4), ("planar", 0.6, 0.7)])
def test_stretch_hidden_in_one_camera(rig, backgrounds, renders, background_frames, name, start, stop):
    """10 % of the needle (plus ~4 mm each side: the occluder's margin) hidden in the left camera only: the left
    image's two parts are linked, the stretch the left camera does not see is flagged unmeasured, the rest
    measured (before: the left image's larger part only, coverage 58 %, the planar tip lost; measured: 84-85 %)."""
    truth = SHAPES[name]
    images = faded(rig, renders(name), background_frames[0], truth, start, stop, 0.0, ("left",))
    measurement = _measure(rig, backgrounds, images)
    _, arc = _check(measurement, name, 0.8)
    length = _length(truth)
    assert not np.any(measurement.measured & (arc > start * length + 1e-3) & (arc < stop * length - 1e-3))


@pytest.mark.parametrize("name", ["straight", "planar", "3d", "hook"])
@pytest.mark.parametrize("bevel", [1e-3, 2e-3])
@pytest.mark.parametrize("seed", [7, 2007, 3007, 4007])
def test_bevelled_tip(rig, backgrounds, scene, name, bevel, seed):
    """A bevel seen side-on tapers the needle's end (2 mm: ~5.5 px, 1 mm: ~2.7 px): the half-contrast point lies
    half the taper short; the taper is fitted to the end's profile of covered fraction (a linear taper blurred like
    the side edges) and the end put half of it beyond its middle. The hook's tail runs along the epipolar lines: its
    tip's depth is the two views' end disparity alone (1.2 mm per px), so they share one taper. Tip within 0.2 mm at
    four sensor-noise seeds (before: 1 mm bevel 0.09-0.37 mm, hook 0.33; 2 mm: hook 0.85 mm, then 0.25 mm at 4007
    while the profile was the background-relative contrast, whose texture put the left view's taper middle 0.1 px
    short). Measured over 20 seeds k = 0..19 (the bevel rendered as the blurred wedge): 1 mm 0.01-0.27 mm, 2 mm
    0.01-0.23 mm, the hook's 2 mm 0.02-0.18 mm; with the end extrapolated from band-only centroids 0.01-0.14,
    0.01-0.18 and 0.01-0.18 mm (the renderer's short taper before: 0.03-0.24, 0.01-0.22, 0.01-0.19).
    3007 failed the no-invented-points check (a 2 mm straight sample 2-3 mm before the tip 0.16 mm off against
    3 sigma = 0.15 mm: its end extrapolated from slices within the bevel's taper, see
    test_bevelled_end_lies_on_the_needle_axis). 1007 failed the straight needle's tip: see
    test_tip_at_noise_seeds_that_failed. The hook's tail, placed by continuity, is flagged unmeasured where its
    unseen bending in depth may exceed 1 mm (reconstruction._continuity_sigma): coverage >= 0.7."""
    images = render_stereo_pair(rig, SHAPES[name], NEEDLE_RADIUS, np.random.default_rng(seed), scene=scene,
                                bevel_length=bevel)
    _check(_measure(rig, backgrounds, images), name, HOOK_COVERAGE if name == "hook" else 0.99, 0.2e-3,
           max_rms=2e-4 if name == "hook" else 1e-4)


@pytest.mark.parametrize("name, bevel, seed", [
    ("end_on", 2e-3, 5007), ("end_on", 2e-3, 11007), ("end_on", 2e-3, 14007), ("end_on", 2e-3, 16007),
    ("planar", 2e-3, 10007), ("s_curve", 1e-3, 15007),
    ("s_curve", 0.0, 5007), ("3d", 0.0, 1007), ("end_on", 0.0, 7007),
    ("hook", 1e-3, 7007), ("hook", 2e-3, 16007), ("hook", 2e-3, 17007),
    ("straight", 0.0, 1007), ("straight", 1e-3, 1007), ("straight", 2e-3, 1007)])
def test_tip_at_noise_seeds_that_failed(rig, backgrounds, scene, name, bevel, seed):
    """Noise seeds whose tip issue 16 left open: a bevel's taper missed (its profile's top scatters 5-6 %: 2 mm,
    end-on 0.84-1.04 mm, planar 0.40 mm; or its spread ratio read 1.13 under the slices' margin noise: S, 1 mm,
    0.37 mm) and flat ends that noise made look tapered (S 0.27, 3D 0.19, end-on 0.11 mm: put ~1 px beyond). The
    profile now sums the needle's band only and a taper must stand out of the profile's scatter: measured
    0.03-0.10 mm. The hook's bevels (tip depth from the end disparity alone) at 0.20, 0.25 and 0.28 mm: the
    background's texture had shifted each view's taper differently (measured 0.17, 0.15, 0.19 mm). The straight
    needle at 1007, whatever its end (0.24, 0.27, 0.23 mm and samples 1-3 mm before the tip invented): the end's
    lateral position, extrapolated from the 80 slices before it, carried their noise (the slices' margins beyond the
    needle's band included: 0.08 px a slice in front of the darker background there) 0.11 and 0.09 px aside in
    opposite directions in the two views, 0.2 px of disparity; fitted to centroids over the band only: <= 0.11 mm.
    Flat ends report no taper, bevels one at the tip in both views; nothing invented."""
    images = render_stereo_pair(rig, SHAPES[name], NEEDLE_RADIUS, np.random.default_rng(seed), scene=scene,
                                bevel_length=bevel)
    centerlines = [extract_centerline(image, background) for image, background in zip(images, backgrounds)]
    measurement = reconstruct_centerline(*centerlines, Rectification.from_rig(rig), MatchingConfig(),
                                         ReconstructionConfig(), rig.world_from_left)
    _check(measurement, name, 0.85 if name == "end_on" else HOOK_COVERAGE if name == "hook" else 0.99, 0.2e-3)
    tip_pixels = [project_points(rig, SHAPES[name][-1:], side)[0] for side in ("left", "right")]
    for centerline, tip in zip(centerlines, tip_pixels):
        at_tip = int(np.argmin(np.linalg.norm(centerline.points[[0, -1]] - tip, axis=1)))
        assert (centerline.end_taper_px[at_tip] > 0) == (bevel > 0)
        assert centerline.end_taper_px[1 - at_tip] == 0  # the base is cut flat


def test_taper_middle_on_a_textured_background(rig, backgrounds, scene):
    """Noise-free render of the hook's 2 mm bevel: in each view the fitted taper's middle (the end less its half
    taper) lies at the projection of the bevel's 3D middle, along the end direction. The background's albedo
    texture (+-10 % over ~4 px) used to weight the contrast along the taper: the left view's middle 0.10 px short,
    the right one's 0.03 px (a disparity error of 0.07 px, 0.09 mm in the tip's depth); now within 0.01 px."""
    truth, bevel = SHAPES["hook"], 2e-3
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(truth, axis=0), axis=1))])
    middle = np.array([np.interp(arc[-1] - bevel / 2, arc, truth[:, i]) for i in range(3)])
    images = render_stereo_pair(rig, truth, NEEDLE_RADIUS, np.random.default_rng(7), scene=scene,
                                bevel_length=bevel, imaging=Imaging(read_noise=0.0, shot_gain=0.0))
    for image, background, side in zip(images, backgrounds, ("left", "right")):
        centerline = extract_centerline(image, background)
        end_pixel, middle_pixel = project_points(rig, np.vstack([truth[-1], middle]), side)
        at_tip = int(np.argmin(np.linalg.norm(centerline.points[[0, -1]] - end_pixel, axis=1)))
        direction = (end_pixel - middle_pixel) / np.linalg.norm(end_pixel - middle_pixel)
        fitted_middle = centerline.points[-at_tip] - centerline.end_taper_px[at_tip] * direction
        assert abs((fitted_middle - middle_pixel) @ direction) < 0.03


@pytest.mark.parametrize("name", ["straight", "planar", "3d", "end_on"])
def test_bevelled_end_lies_on_the_needle_axis(rig, backgrounds, scene, name):
    """Noise-free renders with a 2 mm bevel: the end point lies on the needle's axis, within 0.1 px across the
    projected true end direction in both views. A bevel seen side-on narrows the band from one side, so the slice
    centroids within the taper move across by up to half the needle's width; the end's lateral position is
    extrapolated from the slices before the taper (measured 0.01-0.09 px; before, from the slices within
    half_width + 1 of the end only: 3D 0.10 and 0.13 px)."""
    truth = SHAPES[name]
    images = render_stereo_pair(rig, truth, NEEDLE_RADIUS, np.random.default_rng(7), scene=scene, bevel_length=2e-3,
                                imaging=Imaging(read_noise=0.0, shot_gain=0.0))
    for image, background, side in zip(images, backgrounds, ("left", "right")):
        points = extract_centerline(image, background).points
        end_pixel, before = project_points(rig, truth[[-1, -9]], side)  # 2 mm before the tip
        direction = (end_pixel - before) / np.linalg.norm(end_pixel - before)
        end = min(points[[0, -1]], key=lambda p: np.linalg.norm(p - end_pixel))
        assert abs(direction[0] * (end - end_pixel)[1] - direction[1] * (end - end_pixel)[0]) < 0.1


def test_bevelled_end_along_the_needle(rig, backgrounds, scene):
    """Noise-free renders of the six shapes with a 1 mm bevel (~2.7 px, the taper nearest the blur): the end
    lies at the projected tip along the end direction, mean over shapes and views within 0.06 px, each within
    0.13 px (measured: mean -0.04, -0.11...+0.03 px). Before, the renderer's taper fell short (its band narrowed
    across only, times a blurred end cut): -0.24 (-0.33...-0.18) px; on the wedge with the taper's blur less 1/6
    px² (which had made up for it): +0.09 (+0.03...+0.15) px."""
    offsets = []
    for name, truth in SHAPES.items():
        images = render_stereo_pair(rig, truth, NEEDLE_RADIUS, np.random.default_rng(7), scene=scene,
                                    bevel_length=1e-3, imaging=Imaging(read_noise=0.0, shot_gain=0.0))
        for image, background, side in zip(images, backgrounds, ("left", "right")):
            points = extract_centerline(image, background).points
            end_pixel, before = project_points(rig, truth[[-1, -5]], side)  # 1 mm before the tip
            direction = (end_pixel - before) / np.linalg.norm(end_pixel - before)
            end = min(points[[0, -1]], key=lambda p: np.linalg.norm(p - end_pixel))
            offsets.append((end - end_pixel) @ direction)
    assert abs(np.mean(offsets)) < 0.06
    assert np.max(np.abs(offsets)) < 0.13
