"""Issue 39: the depth of a stretch along the epipolar lines is (almost) not in the images. Two centerlines that differ
by 0.2 mm RMS over that stretch, displaced within the epipolar planes and across the tangent, give noise-free renders
whose difference is below the sensor noise: Mahalanobis distance D < 1 over both images, so any estimator errs between
them with probability > 0.25, and is then >= 0.1 mm RMS off over the stretch on one of them; a larger one (0.36-0.77 mm,
its half 0.1 mm RMS over the whole needle) puts one of them >= 0.1 mm RMS off over the whole needle with probability >
0.15. The same bump on a stretch across the lines, or across the epipolar planes, is seen at D > 30; the tip of a needle
that ends along the lines, moved 0.2 mm, at D > 5. Independent truth: the renderer's forward model (``render_signal``)
and its Gaussian noise model; no reconstruction code is used."""
import numpy as np
import pytest

from epipolar_observability import TIP_ALONG, TIP_STRETCH, decision_error_bound, depth_direction, displaced, \
    epipolar_alternative, epipolar_normals, epipolar_stretch, image_distance, in_plane_direction, plane_angle, \
    tangents, tip_alternative
from vision_shapes import EPIPOLAR_SHAPES, ROD_EPIPOLAR_SHAPES, SHAPES, bright_scene
from needle_vision.calibration.rectification import Rectification
from needle_vision.detection.curves import arc_length
from needle_vision.render import NEEDLE_RADIUS, project_points, render_signal

RMS = 0.2e-3  # twice issue 39's 0.1 mm target
SHAPES_ALONG = {**EPIPOLAR_SHAPES, **ROD_EPIPOLAR_SHAPES}


@pytest.fixture(scope="module")
def scenes(scene):
    """The default dark needle, and a bright one (albedo 0.9) on the background at 0.3x its albedo."""
    return {"dark": scene, "bright": bright_scene(scene)}


def _distance(rig, scene, first: np.ndarray, second: np.ndarray):
    return image_distance(*(render_signal(rig, points, NEEDLE_RADIUS, scene=scene) for points in (first, second)))


@pytest.mark.parametrize("polarity", ["dark", "bright"])
@pytest.mark.parametrize("name", list(SHAPES_ALONG))
def test_depth_along_the_epipolar_lines_is_not_in_the_images(rig, scenes, name, polarity):
    truth = SHAPES_ALONG[name]
    alternative = epipolar_alternative(truth, rig, RMS)
    start, stop = epipolar_stretch(truth, rig, 1.0)
    assert alternative.rms >= RMS - 1e-9 and alternative.max <= 1.3 * RMS
    assert abs(alternative.length_change) < 1e-4  # second order: 1-83 µm
    np.testing.assert_array_equal(alternative.points[[0, -1]], truth[[0, -1]])  # base and tip in place
    assert np.degrees(plane_angle(truth, rig)[(arc_length(truth) >= start) & (arc_length(truth) <= stop)]).max() <= 1
    distance = image_distance(render_signal(rig, truth, NEEDLE_RADIUS, scene=scenes[polarity]),
                              render_signal(rig, alternative.points, NEEDLE_RADIUS, scene=scenes[polarity]))
    assert distance.mahalanobis < 1.0  # measured 0.41-0.92
    assert min(decision_error_bound(distance)) > 0.25
    # The same bump across the epipolar planes (off the lines in both images) is seen: the renders can fail the above.
    across = displaced(truth, epipolar_normals(truth, rig), start, stop, RMS)
    assert _distance(rig, scenes[polarity], truth, across.points).mahalanobis > 100  # measured 102-610


@pytest.mark.parametrize("polarity", ["dark", "bright"])
@pytest.mark.parametrize("name", ["curl_down", "curl_up", "s_epipolar", "turning_plane", "rod_s"])
def test_whole_needle_target_is_missed_on_one_of_two_shapes(rig, scenes, name, polarity):
    """The bump whose half is 0.1 mm RMS over the whole needle: a method that takes one shape for the other is then
    >= 0.1 mm RMS off over all of it, and every method does so with probability > 0.15 on one of the two."""
    truth = SHAPES_ALONG[name]
    start, stop = epipolar_stretch(truth, rig, 1.0)
    rms = 2 * 0.1e-3 * np.sqrt(arc_length(truth)[-1] / (stop - start))  # 0.36-0.77 mm over the stretch
    alternative = epipolar_alternative(truth, rig, rms)
    distance = _distance(rig, scenes[polarity], truth, alternative.points)
    assert min(decision_error_bound(distance)) > 0.15  # measured 0.151-0.287 (exact), D 0.89-1.63


@pytest.mark.parametrize("polarity", ["dark", "bright"])
@pytest.mark.parametrize("name, start, stop", [("straight", 0.10, 0.17), ("planar", 0.10, 0.17), ("3d", 0.10, 0.17),
                                               ("curl_down", 0.0, 0.15)])
def test_depth_across_the_epipolar_lines_is_in_the_images(rig, scenes, name, start, stop, polarity):
    """The control: the same size of bump in depth (the viewing ray from the rig's midpoint, square to the tangent)
    on a stretch that crosses the epipolar lines."""
    truth = {**SHAPES, **EPIPOLAR_SHAPES}[name]
    assert np.degrees(plane_angle(truth, rig)[(arc_length(truth) >= start) & (arc_length(truth) <= stop)]).min() > 15
    bump = displaced(truth, depth_direction(truth, rig), start, stop, RMS)
    distance = _distance(rig, scenes[polarity], truth, bump.points)
    assert distance.mahalanobis > 30  # measured 59-111
    assert max(decision_error_bound(distance)) < 1e-9


@pytest.mark.parametrize("polarity", ["dark", "bright"])
@pytest.mark.parametrize("name", TIP_ALONG)
def test_the_tip_along_the_lines_is_in_the_images(rig, scenes, name, polarity):
    """Unlike the stretch before it, the tip of a needle that ends along the lines is seen: moved 0.2 mm in depth
    (within its epipolar plane, over the last 10 mm), with a 2 mm bevel, it changes the images by D > 5, so a tip
    error of 0.2 mm (issue 39's target) is not forced by the images; it is the ends' localization (its shift along
    the line differs between the views)."""
    truth = SHAPES_ALONG[name]
    assert np.degrees(plane_angle(truth, rig)[-5:]).max() < 0.3
    moved = tip_alternative(truth, rig, RMS)
    assert np.linalg.norm(moved[-1] - truth[-1]) == pytest.approx(RMS)
    before = arc_length(truth) < arc_length(truth)[-1] - TIP_STRETCH
    np.testing.assert_array_equal(moved[before], truth[before])
    distance = image_distance(*(render_signal(rig, points, NEEDLE_RADIUS, scene=scenes[polarity], bevel_length=2e-3)
                                for points in (truth, moved)))
    assert distance.mahalanobis > 5  # measured 6.4-13.5
    assert max(decision_error_bound(distance)) < 0.01


@pytest.mark.parametrize("name", list(SHAPES_ALONG))
def test_in_plane_direction_keeps_each_point_on_its_epipolar_lines(rig, name):
    """Independent of the plane geometry above: a point moved 1 mm along the direction keeps its rectified
    epipolar coordinate (OpenCV's rectification of the rig) in both images; moved along the planes' normal, not."""
    truth = SHAPES_ALONG[name]
    rectification = Rectification.from_rig(rig)
    axis = rectification.epipolar_axis

    def epipolar_shift(direction: np.ndarray) -> np.ndarray:
        return np.array([rectification.rectify(project_points(rig, truth + 1e-3 * direction, side), side)[:, axis]
                         - rectification.rectify(project_points(rig, truth, side), side)[:, axis]
                         for side in ("left", "right")])

    assert np.abs(epipolar_shift(in_plane_direction(truth, rig))).max() < 0.01  # px
    assert np.abs(epipolar_shift(epipolar_normals(truth, rig))).min() > 1.0
    np.testing.assert_allclose(np.einsum("ij,ij->i", in_plane_direction(truth, rig), tangents(truth)), 0, atol=1e-12)
