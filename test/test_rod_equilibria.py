"""The rod equilibria that needle_vision's epipolar tests render (needle_vision/test/data/rod_*.npy) are what
needle_sim_ros's static solve gives today (suite-level: it composes both packages)."""
import numpy as np
import pytest

import rod_equilibria


def test_rod_equilibria_are_the_simulators_static_solve():
    """The stored shapes are what needle_sim_ros's static solve gives today (regenerated and compared: a change of
    the model or the needle's defaults shows here); each is 0.27 m long and ends or runs along the baseline (z)."""
    fresh = rod_equilibria.equilibria()
    stored = {name: np.load(rod_equilibria.DATA / f"{name}.npy") for name in fresh}
    assert sorted(fresh) == sorted(path.stem for path in rod_equilibria.DATA.glob("rod_*.npy"))
    for name, points in fresh.items():
        np.testing.assert_allclose(points, stored[name], rtol=0, atol=1e-9)
        tangent = np.gradient(points, axis=0)
        along = np.abs(tangent[:, 2]) / np.linalg.norm(tangent, axis=1)
        assert np.linalg.norm(np.diff(points, axis=0), axis=1).sum() == pytest.approx(0.27, abs=1e-5)
        assert np.count_nonzero(along > np.cos(np.radians(10))) * 0.25e-3 >= 30e-3
