"""Correspondence of rectified centerlines on synthetic curves with known disparity (epipolar axis 1: rows)."""
import numpy as np
import pytest

from needle_vision.matching.correspondence import MatchError, match_centerlines

U = np.linspace(0.0, 1.0, 20001)


def curves(e, x, disparity):
    """Left and right rectified polylines sampled every pixel of their own arc length, and the true matched
    right x for a left point as a function of its position (via the common parameter u)."""
    left_dense = np.column_stack([x(U), e(U)])
    right_dense = np.column_stack([x(U) - disparity(U), e(U)])

    def sample(dense):
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(dense, axis=0), axis=1))])
        u = np.interp(np.arange(0.0, arc[-1], 1.0), arc, U)
        return np.column_stack([x(u), e(u)]) if dense is left_dense else np.column_stack([x(u) - disparity(u), e(u)]), u
    (left, u_left), (right, _) = sample(left_dense), sample(right_dense)
    return left, right, x(u_left) - disparity(u_left)


def matched_error(match, left, truth_right_x):
    """Matched right x minus the truth, for each matched left point (looked up by its position)."""
    index = np.argmin(np.linalg.norm(match.left[:, None, :] - left[None, :, :], axis=2), axis=1)
    return match.right[:, 0] - truth_right_x[index]


def test_curve_crossing_epipolar_lines_matches_to_sub_pixel_in_either_direction():
    left, right, truth = curves(lambda u: 100 + 700 * u, lambda u: 600 + 80 * np.sin(3 * u),
                                lambda u: 40 + 25 * u ** 2)
    for oriented in (right, right[::-1]):
        match = match_centerlines(left, oriented, 1)
        # The 5-point moving average bends a curve by < 0.01 px here; exact epipolar lines otherwise.
        assert np.abs(matched_error(match, left, truth)).max() < 0.02
        assert match.anchored.mean() > 0.99  # all but a point at each end (a match clamped to an end is none)
        assert len(match.left) > 0.97 * len(left)


def test_stretch_parallel_to_epipolar_lines_is_matched_by_continuity():
    """e is constant on u in [0.4, 0.6] (the needle runs along a row); there the disparity varies linearly
    (a straight 3D stretch), so continuity between the anchors at both ends recovers it."""
    e = lambda u: 100 + 500 * np.clip(u, 0, 0.4) + 500 * np.clip(u - 0.6, 0, None)
    x = lambda u: 600 + 300 * np.clip(u - 0.4, 0, 0.2) + 20 * u
    left, right, truth = curves(e, x, lambda u: 40 + 30 * u)
    match = match_centerlines(left, right, 1)
    stretch = (np.abs(match.left[:, 1] - 300) < 1e-6) & (match.left[:, 0] > 612) & (match.left[:, 0] < 668)
    assert stretch.sum() > 40 and not match.anchored[stretch].any()
    # Per-row matching would pair arbitrary points of the stretch (errors up to its 60 px length). Continuity
    # interpolates a nearly linear map: < 1 px at the sharp corners (smoothed differently in the two curves),
    # exact elsewhere.
    error = np.abs(matched_error(match, left, truth))
    assert error.max() < 1.0
    assert np.median(error[stretch]) < 0.1


def test_curve_crossing_an_epipolar_line_twice_is_matched_in_order():
    """An S-bend: each row in e in [300, 400] is crossed three times; the order along the curve decides."""
    e = lambda u: 100 + 600 * u - 120 * np.sin(2 * np.pi * u)
    left, right, truth = curves(e, lambda u: 500 + 200 * u, lambda u: 50 - 30 * u)
    match = match_centerlines(left, right, 1)
    error = matched_error(match, left, truth)
    # Near the turning points of e the match relies on continuity over a few pixels: allow 0.3 px there.
    assert np.abs(error).max() < 0.3
    assert np.median(np.abs(error)) < 0.02


def test_end_stretch_along_epipolar_lines_uses_the_visible_tip():
    """The last 150 px run along a row: with the tips visible they pin the end of the match; without, the match
    is extrapolated from the last anchors and degrades along the stretch."""
    e = lambda u: 100 + 600 * np.clip(u, 0, 0.8) / 0.8
    x = lambda u: 600 + 10 * u + 750 * np.clip(u - 0.8, 0, None)
    disparity = lambda u: 40 + 60 * np.clip(u - 0.8, 0, None)  # the tail recedes: disparity grows by 12 px
    left, right, truth = curves(e, x, disparity)
    with_tips = np.abs(matched_error(match_centerlines(left, right, 1, ends_visible=True), left, truth))
    without = np.abs(matched_error(match_centerlines(left, right, 1, ends_visible=False), left, truth))
    # With the tips: exact at both ends of the tail, < 1 px where the sharp corner meets the anchors.
    assert with_tips.max() < 1.0
    assert without.max() > 3 * with_tips.max()


def test_needle_parallel_to_epipolar_lines_everywhere_is_unobservable():
    left, right, _ = curves(lambda u: 300 + 0 * u, lambda u: 200 + 600 * u, lambda u: 40 + 0 * u)
    with pytest.raises(MatchError, match="unobservable"):
        match_centerlines(left, right, 1)


def test_too_short_curves_are_refused():
    with pytest.raises(MatchError, match="fewer than 5"):
        match_centerlines(np.zeros((3, 2)), np.zeros((10, 2)), 1)
