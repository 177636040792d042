"""Tissue block geometry and the track cut by the tip."""
import numpy as np
import pytest

from needle_sim_ros.tissue.geometry import LATERAL_ROWS, TissueBlock, TissueLayer, inserted_interval, layer_rows
from needle_sim_ros.tissue.track import cut_polyline, locate_on_polyline, project_on_polyline


def started(entry: np.ndarray, direction: np.ndarray) -> tuple:
    """A track (vertices, arc lengths, end tangent) of the entry point alone, heading along ``direction``."""
    return entry.reshape(1, 3).astype(float), np.zeros(1), direction / np.linalg.norm(direction)


def ahead(track: tuple, point: np.ndarray) -> float:
    """Track coordinate of a point near the end, measured along the end tangent (beyond the length: uncut)."""
    vertices, arc, end_tangent = track
    return arc[-1] + (point - vertices[-1]) @ end_tangent


def locate(track: tuple, coordinate: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points and unit tangents of the track at coordinates (compiled kernel)."""
    return locate_on_polyline(*track, coordinate)


def project(track: tuple, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Closest track coordinates and distances of points (compiled kernel)."""
    return project_on_polyline(*track, np.ascontiguousarray(points))


def layer(thickness, stiffness=1.0):
    return TissueLayer(thickness, stiffness, 0.0, 6.0, 120.0, 9.42e3)


BLOCK = TissueBlock(np.array([0.1, 0.0, 0.0]), np.array([2.0, 0.0, 0.0]), (layer(0.01, 1.0), layer(np.inf, 2.0)))


def test_depth_layers_and_values():
    points = np.array([[0.09, 0, 0], [0.105, 1, 0], [0.2, 0, 3]])
    np.testing.assert_allclose(BLOCK.depth(points), [-0.01, 0.005, 0.1])
    np.testing.assert_array_equal(BLOCK.layer_index(BLOCK.depth(points)), [2, 0, 1])
    np.testing.assert_allclose(layer_rows(*BLOCK.kernel_tables, BLOCK.depth(points), LATERAL_ROWS)[0], [0.0, 1.0, 2.0])
    finite = TissueBlock(np.zeros(3), np.array([0, 0, -1.0]), (layer(0.05),))
    assert not finite.inside(0.06) and finite.inside(0.01)          # a finite block can be passed through


def test_inserted_interval_of_a_tilted_straight_needle():
    s = np.linspace(0.0, 0.2, 41)
    direction = np.array([np.cos(0.3), np.sin(0.3), 0.0])
    points = np.array([0.0, 0.0, 0.0]) + s[:, None] * direction
    s_entry, s_tip = inserted_interval(BLOCK, points, s)
    assert s_entry == pytest.approx(0.1 / np.cos(0.3))              # crossing of the plane x = 0.1
    assert s_tip == 0.2
    outside = inserted_interval(BLOCK, points * 0.1, s)
    assert outside == (0.2, 0.2)


def test_track_cuts_locates_and_projects():
    spacing = 0.001
    track = started(np.array([0.1, 0, 0]), np.array([2.0, 0, 0]))
    points, tangents = locate(track, np.array([0.003]))                 # straight continuation before any cut
    np.testing.assert_allclose(points[0], [0.103, 0, 0])
    tips = [track[0][0]]
    for x in np.arange(0.1007, 0.12, 0.0007):                       # tip advancing 0.7 mm a step on a parabola
        tips.append(np.array([x, 0.5 * (x - 0.1) ** 2 / 0.05, 0]))
        track = cut_polyline(*track, tips[-2], tips[-1], spacing)
    tip, (vertices, arc, end_tangent) = tips[-1], track
    # path memory: every vertex after the entry point lies on the tip's path (the chords between its positions),
    # exactly one spacing ahead of the previous vertex along its end tangent
    for vertex in vertices[1:]:
        chords = [np.linalg.norm(np.cross(vertex - a, b - a)) / np.linalg.norm(b - a)
                  + max(np.dot(vertex - b, b - a), np.dot(vertex - a, a - b), 0.0) for a, b in zip(tips, tips[1:])]
        assert min(chords) < 1e-12
    segments = np.linalg.norm(np.diff(vertices, axis=0), axis=1)
    assert np.all((segments >= spacing * (1 - 1e-9)) & (segments < spacing * 1.01))
    assert 0.0 <= ahead(track, tip) - arc[-1] < spacing           # the tip is at the front
    # the polyline through the tip's positions stays on the parabola to within its chord sag kappa s^2 / 8
    assert project(track, tip[None])[1][0] < 1e-5
    short = cut_polyline(*track, tip, vertices[-1] + 0.5 * spacing * end_tangent, spacing)
    assert short[0] is vertices                                     # half a spacing ahead: nothing cut
    points, tangents = locate(track, np.array([0.0, 0.01, arc[-1] + 0.002]))
    np.testing.assert_allclose(points[0], [0.1, 0, 0])
    np.testing.assert_allclose(points[2], vertices[-1] + 0.002 * end_tangent)
    np.testing.assert_allclose(np.linalg.norm(tangents, axis=1), 1.0)
    normal = np.cross(tangents, [0, 0, 1.0])                        # offsets perpendicular to the track
    coordinate, distance = project(track, points + 1e-4 * normal)
    np.testing.assert_allclose(coordinate, [0.0, 0.01, arc[-1] + 0.002], atol=1e-7)
    np.testing.assert_allclose(distance, 1e-4, rtol=1e-3)


def test_bad_geometry_rejected():
    with pytest.raises(ValueError, match="entry_normal"):
        TissueBlock(np.zeros(3), np.zeros(3), (layer(1.0),))
    with pytest.raises(ValueError, match="lateral_stiffness"):
        TissueLayer(1.0, -1.0, 0.0, 0.0, 0.0, 0.0)


def test_track_keeps_up_with_a_tip_jittering_sideways():
    """A tip advancing 20 um a step along x with +-30 um of lateral jitter (a vibrating needle) cuts a vertex every
    spacing of advance and stays at the front: the end tangent is a chord over the last millimetre, not the last
    0.1 mm segment, which the jitter tilted by up to ~30 deg (the front then receded from the tip and the track
    stopped growing: 62 vertices instead of 80 over 8 mm in an insertion)."""
    rng = np.random.default_rng(3)
    spacing, track, previous = 1e-4, started(np.zeros(3), np.array([1.0, 0, 0])), np.zeros(3)
    for k in range(1, 401):
        tip = np.array([2e-5 * k, *rng.uniform(-3e-5, 3e-5, 2)])
        track, previous = cut_polyline(*track, previous, tip, spacing), tip
        assert -spacing <= ahead(track, tip) - track[1][-1] < spacing
    assert 7.85e-3 < track[1][-1] < 9e-3  # the polyline through the jitter is a little longer than the advance
    assert abs(len(track[0]) - 1 - 80) <= 2
