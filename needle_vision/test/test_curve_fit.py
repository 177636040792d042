"""The curve fit (``needle_vision.matching.curve_fit``) on its own, against an analytic needle: a circular arc seen by
two ideal rectified cameras, its image centerlines sampled densely with known white noise (no renderer, no
detection). Independent truth: the arc itself."""
import numpy as np
import pytest

from needle_vision.matching.curve_fit import fit_curve
from vision_shapes import distance_to_curve

FOCAL, CX, CY, BASELINE = 1400.0, 720.0, 540.0, 0.15
PROJECTIONS = (np.array([[FOCAL, 0, CX, 0], [0, FOCAL, CY, 0], [0, 0, 1, 0]]),
               np.array([[FOCAL, 0, CX, -FOCAL * BASELINE], [0, FOCAL, CY, 0], [0, 0, 1, 0]]))
NOISE_PX = 0.05


def _arc(count: int) -> np.ndarray:
    """A 250 mm arc of radius 0.4 m bent in depth, 0.5 m in front of the left camera, crossing the epipolar lines
    (rows) at 50-90 deg."""
    angle = np.linspace(-0.3125, 0.3125, count)
    return np.column_stack([0.02 + 0.1 * np.sin(angle), 0.4 * np.sin(angle), 0.5 + 0.4 * (1 - np.cos(angle))])


def _project(projection: np.ndarray, points: np.ndarray) -> np.ndarray:
    homogeneous = np.column_stack([points, np.ones(len(points))]) @ projection.T
    return homogeneous[:, :2] / homogeneous[:, 2:]


def _fit(rng: np.random.Generator, hidden: slice = slice(0, 0)):
    dense = _arc(4001)
    views, noise = [], []
    for projection in PROJECTIONS:
        pixels = _project(projection, dense)
        steps = np.linalg.norm(np.diff(pixels, axis=0), axis=1)
        arc = np.concatenate([[0.0], np.cumsum(steps)])
        at = np.arange(0.0, arc[-1], 1.0)  # one image point per pixel along the needle, as the slices are
        view = np.column_stack([np.interp(at, arc, pixels[:, k]) for k in range(2)])
        view = np.delete(view + rng.normal(0.0, NOISE_PX, view.shape), hidden, axis=0) if projection is PROJECTIONS[0] \
            else view + rng.normal(0.0, NOISE_PX, view.shape)
        views.append(view)
        noise.append(np.full(len(view), NOISE_PX))
    initial = _arc(600) + rng.normal(0.0, 0.1e-3, (600, 3))  # a triangulation's scatter around the truth
    ends = np.stack([_project(projection, dense[[0, -1]]) for projection in PROJECTIONS])
    fit = fit_curve(initial, np.full(600, 1 / 0.1e-3 ** 2), ends, tuple(views), tuple(noise), PROJECTIONS,
                    knot_spacing=5e-3, bending_weight=10.0, end_noise_px=0.1, max_gap=1e-3, sample_spacing=0.5e-3,
                    noise_inflation=1.0)
    assert fit is not None
    truth = _arc(1001)  # polyline within 0.1 um of the arc
    return fit, distance_to_curve(fit.points, truth)[0], truth


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_fit_matches_the_arc_and_its_sigma_holds(seed):
    """Points within 0.1 mm of the arc (RMS <= 0.03 mm), both ends within 0.1 mm, every sample supported, and
    the sigma from the fit's covariance calibrated: >= 98 % of the samples within 3 sigma, none beyond 5."""
    fit, distance, truth = _fit(np.random.default_rng(seed))
    assert np.sqrt(np.mean(distance ** 2)) <= 0.03e-3 and distance.max() <= 0.1e-3
    assert np.linalg.norm(fit.points[0] - truth[0]) <= 0.1e-3 and np.linalg.norm(fit.points[-1] - truth[-1]) <= 0.1e-3
    ratio = distance / fit.sigma
    assert np.mean(ratio <= 3) >= 0.98 and ratio.max() <= 5
    assert np.all(fit.supported)


def test_a_stretch_hidden_in_one_view_is_unsupported():
    """60 image points (~60 px, ~20 mm of needle) removed from the left view: the samples over that stretch, and
    only near it, are flagged unsupported."""
    fit, _, truth = _fit(np.random.default_rng(4), slice(300, 360))
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(fit.points, axis=0), axis=1))])
    unsupported = arc[~fit.supported]
    assert 15e-3 <= np.ptp(unsupported) <= 25e-3
    assert np.count_nonzero(~fit.supported) >= 30
