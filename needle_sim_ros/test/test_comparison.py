"""Comparison core against exact geometry: polyline distances, shape errors, stamp pairing, extrinsic calibration."""
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from needle_common.transforms import RigidTransform

from needle_sim_ros.comparison import (CenterlineSamples, ComparisonError, ErrorSummary, ShapePairer,
                                       calibrate_extrinsic, closest_points_on_polyline, compare_centerlines, kabsch)
from needle_sim_ros.comparison import centerline_distance

# Round-off of a few float64 operations on metre-scale coordinates.
EXACT = 1e-12

CAMERA_TO_MODEL = RigidTransform(Rotation.from_euler("xyz", [170.0, -20.0, 35.0], degrees=True).as_matrix(),
                                 [0.12, -0.30, 0.45])


def arc(radius: float, length: float, count: int, plane_normal=(0.0, 0.0, 1.0)):
    """Vertices and arc lengths of a circular arc leaving the origin along +x, bending about ``plane_normal``."""
    s = np.linspace(0.0, length, count)
    theta = s / radius
    local = np.column_stack([radius * np.sin(theta), radius * (1.0 - np.cos(theta)), np.zeros_like(s)])
    tilt = Rotation.align_vectors([plane_normal], [[0.0, 0.0, 1.0]])[0] if plane_normal != (0.0, 0.0, 1.0) else None
    return (local if tilt is None else tilt.apply(local)), s


def test_straight_polyline_distances_and_arc_lengths_including_beyond_the_ends():
    vertices = np.column_stack([np.linspace(0.0, 1.0, 5), np.zeros(5), np.zeros(5)])
    points = np.array([[0.3, 0.2, 0.0], [0.55, 0.0, -0.4], [-0.1, 0.0, 0.3], [1.5, 0.0, 0.0]])
    found = closest_points_on_polyline(points, vertices)
    np.testing.assert_allclose(found.distance, [0.2, 0.4, math.hypot(0.1, 0.3), 0.5], atol=EXACT)
    np.testing.assert_allclose(found.arc_length, [0.3, 0.55, 0.0, 1.0], atol=EXACT)
    np.testing.assert_allclose(found.point, [[0.3, 0, 0], [0.55, 0, 0], [0, 0, 0], [1, 0, 0]], atol=EXACT)


def test_points_on_a_concentric_circle_have_the_closed_form_chord_distance():
    radius, offset, count = 0.5, 0.01, 21
    vertices, s = arc(radius, 1.0, count)
    theta_vertex = s[1:-1] / radius                     # above a vertex: the vertex is closest, distance = offset
    theta_mid = 0.5 * (s[:-1] + s[1:]) / radius           # above a chord midpoint: R + d - R cos(dtheta / 2)
    theta = np.concatenate([theta_vertex, theta_mid])
    outer = radius + offset
    points = np.column_stack([outer * np.sin(theta), radius - outer * np.cos(theta), np.zeros_like(theta)])
    found = closest_points_on_polyline(points, vertices, s)
    half = 0.5 * (s[1] - s[0]) / radius
    expected = np.concatenate([np.full(len(theta_vertex), offset),
                               np.full(len(theta_mid), outer - radius * np.cos(half))])
    np.testing.assert_allclose(found.distance, expected, atol=EXACT)
    # The closest point of a point above a vertex is that vertex; above a chord midpoint, the chord midpoint.
    np.testing.assert_allclose(found.arc_length, radius * theta, atol=EXACT)


def test_blocked_evaluation_matches_dense_brute_force(monkeypatch):
    rng = np.random.default_rng(1)
    vertices = np.cumsum(rng.normal(0.0, 0.01, (30, 3)), axis=0)
    points = vertices.mean(axis=0) + rng.normal(0.0, 0.03, (200, 3))
    monkeypatch.setattr(centerline_distance, "_PAIRS_PER_BLOCK", 29 * 7)  # 7 points per block: many blocks
    found = closest_points_on_polyline(points, vertices)
    t = np.linspace(0.0, 1.0, 401)
    dense = (vertices[:-1, None, :] + t[None, :, None] * np.diff(vertices, axis=0)[:, None, :]).reshape(-1, 3)
    brute = np.min(np.linalg.norm(points[:, None, :] - dense[None], axis=2), axis=1)
    # Dense sampling overestimates by at most half the sample spacing (segments ~1.7 cm / 400).
    spacing = np.max(np.linalg.norm(np.diff(vertices, axis=0), axis=1)) / 400
    assert np.all(found.distance <= brute + EXACT)
    assert np.all(brute - found.distance <= 0.5 * spacing + EXACT)


def test_measured_shape_offset_by_a_known_distance_in_the_camera_frame():
    vertices, s = arc(0.4, 0.2, 41)
    normal = np.array([0.0, 0.0, 1.0])                   # the arc lies in z = 0: offsetting along z keeps distances
    offset = 0.002
    measured_model_frame = vertices[::4] + offset * normal
    measured = CenterlineSamples(CAMERA_TO_MODEL.inverse().apply(measured_model_frame))
    result = compare_centerlines(CenterlineSamples(vertices, s), measured, CAMERA_TO_MODEL)
    assert result.matched_samples == len(measured_model_frame)
    np.testing.assert_allclose(result.errors, offset, atol=1e-12)
    assert result.rmse == pytest.approx(offset, abs=1e-12)
    assert result.max_error == pytest.approx(offset, abs=1e-12)
    assert result.tip_error == pytest.approx(offset, abs=1e-12)
    np.testing.assert_allclose(result.arc_length, s[::4], atol=1e-12)


def test_short_measurement_tip_error_and_outlier_gate():
    vertices, s = arc(0.4, 0.2, 41)
    measured = np.vstack([vertices[:31], [[0.05, 0.2, 0.0]]])   # ends 5 cm early, plus one stray sample
    result = compare_centerlines(CenterlineSamples(vertices, s), CenterlineSamples(measured), max_match_distance=0.01)
    assert result.matched_samples == 31 and not result.matched[-1]
    assert result.rmse == pytest.approx(0.0, abs=1e-12)
    # Ordered: the tip is the last sample, the stray one, whatever the gate says.
    assert result.tip_error == pytest.approx(np.linalg.norm(vertices[-1] - measured[-1]), abs=1e-12)
    unordered = compare_centerlines(CenterlineSamples(vertices, s), CenterlineSamples(measured[::-1], ordered=False),
                                    max_match_distance=0.01)
    # Unordered: the matched sample farthest along the model, here vertex 30; the chord from it to the tip.
    assert unordered.tip_error == pytest.approx(np.linalg.norm(vertices[-1] - vertices[30]), abs=1e-12)


@pytest.mark.parametrize("points, arc_length, message", [
    (np.array([[0.0, 0.0, np.nan]]), None, "finite"),
    (np.array([[np.inf, -np.inf, 0.0], [0.0, 0.0, 0.0]]), None, "finite"),
    (np.zeros((2, 3)), [0.0, np.inf], "finite"),
    (np.zeros((0, 3)), None, "non-empty"),
    (np.zeros((3, 2)), None, "non-empty"),
    (np.zeros((3, 3)), [0.0, 0.1], "arc_length has 2 values"),
    (np.zeros((3, 3)), [0.0, 0.2, 0.1], "non-decreasing"),
])
def test_bad_centerlines_are_rejected_with_a_reason(points, arc_length, message):
    with pytest.raises(ComparisonError, match=message):
        CenterlineSamples(points, arc_length)


def test_finite_centerlines_whose_sums_overflow_are_accepted():
    """The finiteness check tries the sum first: a sum that overflows must not reject finite samples."""
    points = np.array([[1e308, 1e308, 0.0], [1e308, 1e308, 1.0]])
    assert CenterlineSamples(points, [1e308, 1.7e308]).points is not None


def test_nothing_matched_is_an_error_not_nan():
    vertices, _ = arc(0.4, 0.2, 11)
    with pytest.raises(ComparisonError, match="no measured sample"):
        compare_centerlines(CenterlineSamples(vertices), CenterlineSamples(vertices + [0.0, 0.0, 1.0]),
                            max_match_distance=0.01)


def test_summary_statistics():
    summary = ErrorSummary()
    assert summary.as_dict()["rmse_mean_m"] is None
    vertices, _ = arc(0.4, 0.2, 11)
    for offset in (0.001, 0.003):
        summary.add(compare_centerlines(CenterlineSamples(vertices), CenterlineSamples(vertices + [0.0, 0.0, offset])))
    report = summary.as_dict()
    assert report["compared"] == 2
    assert report["rmse_mean_m"] == pytest.approx(0.002, abs=1e-12)
    assert report["rmse_max_m"] == pytest.approx(0.003, abs=1e-12)


class TestStampPairer:
    MS = 1_000_000

    def test_measurement_pairs_with_the_nearest_model_once_a_later_model_arrived(self):
        pairer = ShapePairer(tolerance_ns=3 * self.MS)
        assert pairer.add_model(10 * self.MS, "m10") == []
        assert pairer.add_measurement(14 * self.MS, "a") == []       # undecided: a nearer model may follow
        pairs = pairer.add_model(20 * self.MS, "m20")
        assert pairs == []                                             # nearest is m10, 4 ms away: over tolerance
        assert pairer.unpaired == 1
        pairs = pairer.add_measurement(18 * self.MS, "b")              # decidable at once: m20 is 2 ms away
        assert [(p.model, p.measurement, p.model_stamp_ns) for p in pairs] == [("m20", "b", 20 * self.MS)]

    def test_late_measurement_finds_its_model_in_the_buffer(self):
        pairer = ShapePairer(tolerance_ns=self.MS, model_buffer=5)
        for k in range(10):
            pairer.add_model(k * 10 * self.MS, k)
        assert [p.model for p in pairer.add_measurement(70 * self.MS + 400_000, "x")] == [7]
        assert pairer.add_measurement(30 * self.MS, "too old") == []  # fell out of the 5-shape buffer
        assert pairer.unpaired == 1

    def test_time_going_backwards_restarts_pairing(self):
        pairer = ShapePairer(tolerance_ns=self.MS)
        pairer.add_model(100 * self.MS, "late")
        pairer.add_measurement(200 * self.MS, "waiting")
        pairer.add_model(0, "restart")
        assert pairer.restarts == 1 and pairer.unpaired == 1
        assert [p.model for p in pairer.add_measurement(0, "new")] == ["restart"]

    def test_pending_measurements_are_bounded(self):
        pairer = ShapePairer(tolerance_ns=self.MS, pending_limit=3)
        for k in range(5):
            pairer.add_measurement(k * self.MS, k)
        assert pairer.unpaired == 2                                    # 0 and 1 dropped
        # 3 ms and 4 ms are within 1 ms of the model; 2 ms is not.
        assert [p.measurement for p in pairer.add_model(4 * self.MS, "m")] == [3, 4]
        assert pairer.unpaired == 3


def calibration_frames(ordered=True):
    """Three static frames of a bent needle in different planes; measured samples lie on the model polylines
    between vertices (so the exact extrinsic leaves zero residual)."""
    frames = []
    for radius, normal in ((0.3, (0.0, 0.0, 1.0)), (0.5, (0.0, 1.0, 0.0)), (0.8, (1.0, 1.0, 1.0))):
        vertices, s = arc(radius, 0.2, 21, tuple(np.asarray(normal) / np.linalg.norm(normal)))
        sample_s = np.linspace(0.003, 0.197, 17)
        on_polyline = np.column_stack([np.interp(sample_s, s, vertices[:, i]) for i in range(3)])
        measured = CenterlineSamples(CAMERA_TO_MODEL.inverse().apply(on_polyline), sample_s if ordered else None,
                                     ordered)
        frames.append((CenterlineSamples(vertices, s), measured))
    return frames


def transform_error(a: RigidTransform, b: RigidTransform) -> tuple[float, float]:
    relative = Rotation.from_matrix(a.rotation.T @ b.rotation)
    return float(np.linalg.norm(a.translation - b.translation)), float(relative.magnitude())


def test_kabsch_recovers_a_known_motion_exactly():
    rng = np.random.default_rng(2)
    source = rng.normal(size=(10, 3))
    estimate = kabsch(source, CAMERA_TO_MODEL.apply(source))
    translation, rotation = transform_error(estimate, CAMERA_TO_MODEL)
    assert translation < 1e-12 and rotation < 1e-12


def test_calibration_from_arc_length_start_recovers_the_extrinsic():
    result = calibrate_extrinsic(calibration_frames())
    translation, rotation = transform_error(result.model_from_camera, CAMERA_TO_MODEL)
    assert result.converged
    # Noise-free samples exactly on the polylines: exact up to round-off.
    assert translation < 1e-9 and rotation < 1e-9 and result.rmse < 1e-9


def test_calibration_from_a_perturbed_guess_with_unordered_samples():
    nudge = RigidTransform(Rotation.from_rotvec(np.radians([3.0, -2.0, 4.0])).as_matrix(), [0.004, -0.003, 0.002])
    result = calibrate_extrinsic(calibration_frames(ordered=False), initial=nudge.compose(CAMERA_TO_MODEL),
                                 max_iterations=500)
    translation, rotation = transform_error(result.model_from_camera, CAMERA_TO_MODEL)
    # ICP converges linearly; 1 um / 10 urad is far below any stereo measurement noise.
    assert translation < 1e-6 and rotation < 1e-5 and result.rmse < 1e-6


def test_calibration_rejects_a_straight_needle_in_one_pose():
    vertices = np.column_stack([np.linspace(0.0, 0.2, 11), np.zeros(11), np.zeros(11)])
    with pytest.raises(ComparisonError, match="collinear"):
        calibrate_extrinsic([(CenterlineSamples(vertices), CenterlineSamples(vertices))])


def test_parameter_file_lists_every_compare_node_parameter_with_a_valid_default():
    import yaml
    from needle_common.package_files import share_file
    from needle_sim_ros.parameters.compare import COMPARE_PARAMETERS as PARAMETERS
    config = share_file("needle_sim_ros", "config/needle_compare.yaml")  # as installed
    values = yaml.safe_load(config.read_text())["/**"]["ros__parameters"]
    assert set(values) == {spec.name for spec in PARAMETERS}
    for spec in PARAMETERS:
        assert spec.validate(values[spec.name]) == spec.default, spec.name


@pytest.mark.parametrize("big_endian", [False, True])
def test_point_cloud_points_are_read_by_field_offsets_and_non_finite_points_dropped(big_endian):
    from sensor_msgs.msg import PointCloud2, PointField
    from needle_sim_ros.nodes.compare_node import cloud_points
    points = np.array([[0.1, 0.2, 0.3], [np.nan, 0.0, 0.0], [-1.5, 2.25, 4.0]], dtype=np.float32)
    order = ">" if big_endian else "<"
    # Layout z, intensity, x, y (16 bytes per point) and 4 bytes of row padding: offsets must be honoured.
    record = np.zeros(3, dtype=np.dtype({"names": ["z", "i", "x", "y"], "formats": [order + "f4"] * 4,
                                         "offsets": [0, 4, 8, 12], "itemsize": 16}))
    record["x"], record["y"], record["z"] = points.T
    fields = [PointField(name=n, offset=o, datatype=PointField.FLOAT32, count=1)
              for n, o in (("z", 0), ("intensity", 4), ("x", 8), ("y", 12))]
    cloud = PointCloud2(height=1, width=3, fields=fields, is_bigendian=big_endian, point_step=16, row_step=52,
                        data=record.tobytes() + b"\0" * 4)
    np.testing.assert_array_equal(cloud_points(cloud), points[[0, 2]].astype(float))
    cloud.fields = fields[:2]
    with pytest.raises(ValueError, match="float32 fields x, y, z"):
        cloud_points(cloud)


def test_comparison_session_rejects_pairs_and_compares_as_the_node_and_the_offline_stage():
    from needle_sim_ros.comparison import ComparisonSession
    from needle_sim_ros.parameters.compare import COMPARE_PARAMETERS
    values = {spec.name: spec.default for spec in COMPARE_PARAMETERS}
    values.update({"model_frame": "world", "measured_frame": "camera", "tolerance": 0.002,
                   "extrinsic.translation": [0.0, 0.0, 0.5]})
    rejected = []
    session = ComparisonSession(values, lambda what, reason: rejected.append((what, reason)))
    s = np.linspace(0.0, 0.1, 11)
    model = np.column_stack([s, np.zeros(11), np.zeros(11)])
    offset = 1e-3  # measured 1 mm off the model along y, in a camera frame 0.5 m below the model frame
    measured = model + [0.0, offset, -0.5]
    assert session.add_model(1_000_000_000, "map", "wrong frame", model, s) == []
    assert session.add_model(1_000_000_000, "world", "one sample", model[:1], s[:1]) == []
    assert session.add_model(1_000_000_000, "world", "model", model, s) == []
    assert session.add_measurement(1_001_000_000, "camera", "points", measured[::-1]) == []  # waits for a model
    [compared] = session.add_model(1_010_000_000, "world", "later model", model, s)
    assert (compared.model_tag, compared.measured_tag) == ("model", "points")
    assert compared.result.rmse == pytest.approx(offset, rel=1e-9)
    [compared] = session.add_measurement(1_009_000_000, "camera", "shape", measured, s)
    assert compared.model_tag == "later model" and compared.result.tip_error == pytest.approx(offset, rel=1e-9)
    assert session.add_measurement(1_005_000_000, "camera", "too far from both", measured, s) == []
    summary = session.finish()
    assert (summary["compared"], summary["unpaired_measurements"]) == (2, 1)
    assert summary["rejected_inputs"] == {"model shape": 2}
    assert rejected == [("model shape", "frame_id 'map' is not 'world'"), ("model shape", "needs at least two samples")]
