"""Joint-EKF identification of the seed 003 LuGre parameters (single joint EKF vs Table I multiple EKFs)."""
import numpy as np
import pytest

from needle_sim_ros.identification.lugre_ekf import (TABLE_I_GROUPS, LuGreEstimator, fisher_information,
                                                     identify_record)
from needle_sim_ros.tissue.lugre import PARAMETER_NAMES, LuGreParameters, ModifiedLuGre
from lugre_record import simulate

TRUE = LuGreParameters(f1=8.0, f2=500.0, sigma0=2.5e5, sigma1=50.0, sigma2=12.0, alpha=125.0)
DT = 0.005                      # seed 003 samples the force at 200 Hz
NOISE = 0.02                    # [N] white force noise std (the seed's R = 0.01 N^2 is 0.1 N std)
IDENTIFIABLE = ("f1", "f2", "sigma0", "sigma2", "alpha")


def lspb_record():
    """Seed 003 Fig. 2 style: LSPB insertion to 50 mm at 10 mm/s, 0.5 s hold, the same retraction."""
    acc, vmax, depth = 0.05, 0.01, 0.05
    ta = vmax / acc
    duration = depth / vmax + ta
    t = np.arange(0.0, duration, DT)
    stroke = np.clip(np.minimum(acc * t, np.minimum(vmax, acc * (duration - t))), 0.0, None)
    v = np.concatenate([stroke, np.zeros(int(0.5 / DT)), -stroke])
    l = np.concatenate([[0.0], np.cumsum(v[:-1] * DT)])
    return l, v


@pytest.fixture(scope="module")
def record():
    l, v = lspb_record()
    f, _ = simulate(ModifiedLuGre(TRUE), l, v, DT)
    return l, v, f + np.random.default_rng(1).normal(0.0, NOISE, f.size)


def test_cramer_rao_bound_says_which_parameters_one_insertion_identifies():
    l, v = lspb_record()
    bound = np.linalg.inv(fisher_information(TRUE, l, v, DT, NOISE))
    std = np.sqrt(np.diag(bound))
    relative = dict(zip(PARAMETER_NAMES, std / np.abs(TRUE.as_array())))
    correlation = bound / np.outer(std, std)
    i = {n: k for k, n in enumerate(PARAMETER_NAMES)}
    assert all(relative[n] < 0.02 for n in IDENTIFIABLE)               # well determined by one record
    assert relative["sigma1"] > 0.05                                   # sigma1 is weak (seed and issue agree)
    assert correlation[i["f2"], i["alpha"]] > 0.8                      # strongly correlated pairs
    assert correlation[i["f1"], i["sigma2"]] < -0.7


def test_single_joint_ekf_recovers_identifiable_parameters_with_honest_uncertainty(record):
    l, v, f = record
    initial = LuGreParameters.from_array(TRUE.as_array() * np.array([1.2, 0.8, 1.2, 0.8, 1.2, 0.8]))
    estimate = identify_record(l, v, f, DT, initial, 0.5 * np.abs(initial.as_array()), NOISE)
    error = estimate.parameters.as_array() - TRUE.as_array()
    relative = np.abs(error) / TRUE.as_array()
    for k, name in enumerate(PARAMETER_NAMES):
        if name in IDENTIFIABLE:
            assert relative[k] < 0.03, name                            # "within a few percent" from 20 % off
            assert estimate.identifiable[name], name
        # EKF covariances are linearised: allow 4 reported sigmas for the true error
        assert abs(error[k]) < 4 * estimate.std[k], name
    assert not estimate.identifiable["sigma1"]                         # reported as weak, not claimed
    assert estimate.cross_group_covariance_tracked
    assert np.all(np.isfinite(estimate.covariance))


def test_multiple_asynchronous_ekfs_run_on_the_same_data(record):
    l, v, f = record
    initial = LuGreParameters.from_array(TRUE.as_array() * np.array([1.3, 0.7, 1.3, 0.7, 1.3, 0.7]))
    estimate = identify_record(l, v, f, DT, initial, 0.5 * np.abs(initial.as_array()), NOISE,
                               groups=TABLE_I_GROUPS)
    assert not estimate.cross_group_covariance_tracked
    assert not any(estimate.identifiable.values())                   # conditional covariances claim nothing
    i = {n: k for k, n in enumerate(PARAMETER_NAMES)}
    assert estimate.correlation[i["f2"], i["f1"]] == 0.0                # different groups: not tracked
    # the best-determined parameters come out within 10 %; the scheme's other estimates are reported, not asserted
    for name in ("f2", "alpha"):
        assert estimate.parameters.as_array()[i[name]] == pytest.approx(getattr(TRUE, name), rel=0.1)


def test_estimator_rejects_bad_input():
    estimator = LuGreEstimator(TRUE, np.ones(6), NOISE)
    with pytest.raises(ValueError, match="finite"):
        estimator.feed(0.01, 0.01, float("nan"), DT)
    with pytest.raises(ValueError, match="groups"):
        LuGreEstimator(TRUE, np.ones(6), NOISE, groups=(("f1", "f1"),))
