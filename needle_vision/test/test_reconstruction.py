"""3D centerline accuracy on renders of known needles (issue #6: RMS < 0.1 mm over >= 95 % of the length)."""
import numpy as np
import pytest

from vision_shapes import SHAPES, distance_to_curve
from needle_vision.detection.centerline import extract_centerline
from needle_vision.matching.correspondence import MatchingConfig
from needle_vision.matching.reconstruction import UNMEASURED, ReconstructionConfig, _continuity_sigma, \
    _matched, _nearest_points, _smooth_along, reconstruct_centerline
from needle_vision.calibration.rectification import Rectification
from needle_vision.render import world_from_camera
from needle_common.transforms import RigidTransform


@pytest.fixture(scope="module")
def measure(rig, backgrounds, renders):
    rectification = Rectification.from_rig(rig)
    cache = {}

    def get(name, output_from_left=None, base_point=np.zeros(3)):
        key = (name, output_from_left is None)
        if key not in cache:
            centerlines = [extract_centerline(image, background)
                           for image, background in zip(renders(name), backgrounds)]
            cache[key] = reconstruct_centerline(*centerlines, rectification, MatchingConfig(),
                                                ReconstructionConfig(base_point=base_point),
                                                output_from_left or rig.world_from_left)
        return cache[key]
    return get


def _length(curve: np.ndarray) -> float:
    return float(np.linalg.norm(np.diff(curve, axis=0), axis=1).sum())


@pytest.mark.parametrize("name", ["straight", "planar", "3d"])
def test_centerline_accuracy_and_coverage(measure, name):
    measurement = measure(name)
    truth = SHAPES[name]
    distance, arc = distance_to_curve(measurement.points, truth)
    # Issue requirement (0.1 mm; the paper's measurements scattered by 0.75 mm). Measured: 0.03-0.04 mm.
    assert np.sqrt(np.mean(distance ** 2)) < 1e-4
    assert distance.max() < 0.5e-3  # no outliers (the tip sample is the worst, ~0.25 mm)
    coverage = (arc[-1] - arc[0]) / _length(truth)
    assert coverage >= 0.95
    # Ordered from the base (origin of the world frame, the default base point) to the tip.
    assert np.linalg.norm(measurement.points[0] - truth[0]) < 2e-3
    assert np.linalg.norm(measurement.points[-1] - truth[-1]) < 2e-3
    assert np.all(np.diff(arc) > 0)


@pytest.mark.parametrize("name", ["straight", "planar", "3d"])
def test_samples_are_consistent(measure, name):
    measurement = measure(name)
    spacing = ReconstructionConfig().sample_spacing
    np.testing.assert_allclose(np.diff(measurement.arc_length)[:-1], spacing, rtol=1e-9)
    assert measurement.arc_length[-1] == pytest.approx(measurement.length)
    np.testing.assert_allclose(np.linalg.norm(measurement.tangents, axis=1), 1.0, rtol=1e-12)
    # Tangents agree with the chord between neighbouring samples (1 mm apart): to the curvature's order.
    chords = np.diff(measurement.points, axis=0)
    chords /= np.linalg.norm(chords, axis=1, keepdims=True)
    assert np.min(np.einsum("ij,ij->i", chords, measurement.tangents[1:])) > 0.999
    # Arc length of the smoothed centerline, not inflated by noise: the measured extent of a 0.27 m needle.
    assert measurement.length == pytest.approx(_length(SHAPES[name]), abs=2e-3)
    assert np.all(np.isfinite(measurement.uncertainty)) and np.all(measurement.uncertainty > 0)


@pytest.mark.parametrize("name", ["straight", "planar", "3d"])
def test_reported_uncertainty_matches_the_actual_error(measure, name):
    """The 1-sigma uncertainty (image noise only) is within a factor 2.5 of the actual RMS error."""
    measurement = measure(name)
    rms = np.sqrt(np.mean(distance_to_curve(measurement.points, SHAPES[name])[0] ** 2))
    assert 0.4 < np.median(measurement.uncertainty) / rms < 2.5


def test_points_reported_in_the_raw_left_optical_frame(measure, rig):
    """With no output transform the points are in the raw (not the rectified) left optical frame."""
    measurement = measure("planar", output_from_left=RigidTransform(),
                          base_point=world_from_camera(rig, "left").inverse().apply(np.zeros(3)))
    truth = world_from_camera(rig, "left").inverse().apply(SHAPES["planar"])
    distance, _ = distance_to_curve(measurement.points, truth)
    assert np.sqrt(np.mean(distance ** 2)) < 1e-4
    assert np.linalg.norm(measurement.points[0] - truth[0]) < 2e-3


def test_stretch_parallel_to_epipolar_lines_comes_from_continuity(measure):
    """The hook's 54 mm tail hangs along the baseline: its depth cannot be triangulated point-wise. It is
    placed by curve order and continuity (between the bend and the tip) and still lands close to the truth."""
    measurement = measure("hook")
    distance, arc = distance_to_curve(measurement.points, SHAPES["hook"])
    assert measurement.anchored_fraction < 0.85  # the tail was not matched along epipolar lines
    # Continuity is weaker than triangulation: the error grows along the tail (0.2 mm at the tip measured).
    assert np.sqrt(np.mean(distance ** 2)) < 2e-4
    assert distance.max() < 0.6e-3
    assert (arc[-1] - arc[0]) / _length(SHAPES["hook"]) >= 0.95
    # The uncertainty says so: larger on the tail than on the triangulated stretch, or flagged unmeasured (above
    # max_uncertainty: its bending in depth is not seen, reconstruction._continuity_sigma); the stretch is measured.
    tail = measurement.uncertainty[arc > 0.23]
    body = measurement.uncertainty[arc < 0.12]
    assert np.all((tail == UNMEASURED) | (tail > 3 * np.median(body))) and np.all(body > 0)


@pytest.mark.parametrize("name", ["straight", "planar", "3d", "hook"])
def test_tip_localized_within_a_fifth_of_a_millimetre(measure, name):
    """Sub-pixel needle ends from the contrast profile along the end's direction, on one epipolar line in both
    views (issue 16: before, 0.32-0.70 mm off; then 0.06-0.40 mm, the planar tip cut diagonally across the
    slices). Measured: tips 0.02-0.12 mm, bases 0.13-0.15 mm."""
    measurement = measure(name)
    assert np.linalg.norm(measurement.points[-1] - SHAPES[name][-1]) <= 0.2e-3
    assert np.linalg.norm(measurement.points[0] - SHAPES[name][0]) <= 0.2e-3


def test_local_cubic_along_an_uneven_abscissa():
    """The 3D smoothing's local cubic runs along the arc length, not the point index: points spaced 0.4 mm, then 2 mm
    (a stretch seen nearly end-on), then 0.4 mm. A cubic in that abscissa is reproduced exactly (the cubic in the
    index put points 1.5 mm along and 0.06 mm off the curve), and each point's noise gain is the norm of its row of
    the least-squares hat matrix (closed form: numpy's pseudo-inverse of the window's Vandermonde matrix)."""
    abscissa = np.concatenate([np.arange(30) * 0.4e-3, 12e-3 + np.arange(10) * 2e-3, 32e-3 + np.arange(30) * 0.4e-3])
    s = abscissa - abscissa.mean()
    points = np.column_stack([s, 2 * s ** 2 - 30 * s ** 3, 0.5 * s ** 3])
    window = 21
    smooth, gain = _smooth_along(points, abscissa, window)
    assert np.abs(smooth - points).max() < 1e-12
    for k in (0, 5, 29, 35, 69):
        first = min(max(k - window // 2, 0), len(points) - window)
        vandermonde = np.vander(abscissa[first:first + window] - abscissa[k], 4, increasing=True)
        assert gain[k] == pytest.approx(np.linalg.norm(np.linalg.pinv(vandermonde)[0]), rel=1e-9)


@pytest.mark.parametrize("spike", [0, 3, 4, 37, 99])
def test_a_single_points_noise_reaches_the_matched_point_beside_it(spike):
    """Each centerline point's noise may be its own (a slice's centroid noise where the contrast fades): the noise at
    a matched point is that of the centerline point it lies on, wherever that point is among every 8th."""
    points = np.column_stack([np.arange(100.0), np.zeros(100)])
    noise = np.full(100, 0.1)
    noise[spike] = 0.7
    matched = points[[spike, 50]] + [0.3, 0.2]
    assert noise[_nearest_points(points, matched)] == pytest.approx([0.7, 0.1])


@pytest.mark.parametrize("tilt_deg", [0.0, 60.0])
def test_continuity_sigma_is_the_sagitta_of_the_unseen_bend(tilt_deg):
    """A stretch placed by continuity follows the chord between the anchors around it in depth; a circular arc of
    radius R bent in a plane through the depth axis z leaves its chord by the sagitta, R - sqrt(R^2 - (h/2)^2) at
    the middle of a gap of arc length h, and the sigma is that to the curvature's order (the curvature taken on the
    anchored side); tilted by an angle about the arc's chord, the depth part of it (times the cosine). Beyond the
    last anchor (extrapolated from the end tangent) it grows like the arc's offset from its tangent,
    R (1 - cos(a / R)). A bend across the depth axis is seen in the images: no sigma."""
    radius, spacing, tilt = 1.0, 0.25e-3, np.radians(tilt_deg)
    angle = np.arange(0.0, 0.12, spacing) / radius
    bend = radius * (1 - np.cos(angle))
    arc = np.column_stack([radius * np.sin(angle), bend * np.sin(tilt), bend * np.cos(tilt)])
    depth = np.array([0.0, 0.0, 1.0])
    anchored = np.ones(len(arc), bool)
    gap = slice(200, 360)  # 40 mm placed by continuity between 50 mm and 70 mm of anchors
    anchored[gap] = False
    sigma = _continuity_sigma(arc, anchored, 20e-3, depth)
    half = 0.5 * (gap.stop - gap.start + 1) * spacing
    middle = (gap.start + gap.stop - 1) // 2
    assert sigma[middle] == pytest.approx(np.cos(tilt) * (radius - np.sqrt(radius ** 2 - half ** 2)), rel=0.03)
    assert np.all(sigma[anchored] == 0) and np.all(sigma[gap] > 0)
    assert np.all(_continuity_sigma(arc[:, [0, 2, 1]] * [1, 1, 0], anchored, 20e-3, depth) < 1e-12)
    anchored[gap] = True
    anchored[400:] = False  # the last 20 mm extrapolated
    sigma = _continuity_sigma(arc, anchored, 20e-3, depth)
    beyond = (len(arc) - 400) * spacing
    assert sigma[-1] == pytest.approx(np.cos(tilt) * radius * (1 - np.cos(beyond / radius)), rel=0.03)


def test_the_fit_takes_the_image_points_of_kept_matches_only():
    """The curve fit's image points (``_matched``): those of the kept matches and between two consecutive kept
    matches (either direction along the view); not those beyond the matched range (the other view did not see them)
    nor between kept matches that a rejected match separates."""
    nearest = np.array([2, 4, 7, 6, 9])  # the image points of five kept matches; a rejected one between the 2nd and 3rd
    chained = np.array([True, False, True, True])
    assert np.flatnonzero(_matched(12, nearest, chained)).tolist() == [2, 3, 4, 6, 7, 8, 9]
