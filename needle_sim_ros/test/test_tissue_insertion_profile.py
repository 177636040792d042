"""Seed 002 insertion force profile (eqs. 1-3) and its fitting tool."""
import numpy as np
import pytest

from needle_sim_ros.identification import fit_insertion_profile
from needle_sim_ros.tissue.insertion_profile import InsertionForceProfile

# Seed 002 stiffness constants read with x in mm, F in N: a1 = 0.0019 N/mm, a2 = 0.0499 N/mm^2.
TRUE = InsertionForceProfile(a1=1.9, a2=4.99e4, puncture_depth=0.012,
                             frequencies=(2 * np.pi / 0.02, 2 * np.pi / 0.007),
                             cos_coefficients=(2.0, 0.25, 0.10), sin_coefficients=(0.15, -0.08), cutting_force=1.2)


def test_profile_has_the_seed_shape():
    x = np.linspace(0.0, 0.1, 2001)
    f = TRUE.total_force(x, exit_depth=0.06)
    before = x <= TRUE.puncture_depth
    assert np.all(np.diff(f[before]) > 0)                                # stiffness force rises
    peak = f[before][-1]
    assert x[before][-1] == pytest.approx(0.012)
    assert peak == pytest.approx(1.9 * 0.012 + 4.99e4 * 0.012**2)
    after = f[~before][0]
    assert after < peak                                                  # drops at puncture
    x_mid = np.linspace(0.02, 0.05, 7)
    np.testing.assert_allclose(TRUE.total_force(x_mid, 0.06) - TRUE.friction_force(x_mid), 1.2)  # eq. 3
    assert TRUE.total_force(0.08, 0.06) == pytest.approx(TRUE.friction_force(0.08))          # phase III


def test_fit_recovers_parameters_from_noisy_record():
    rng = np.random.default_rng(3)
    x = np.linspace(0.0005, 0.1, 4000)                                  # 25 um sampling, 100 mm record
    noise = 0.01                                                        # [N] std, ~0.5 % of the friction level
    f = TRUE.total_force(x, exit_depth=0.06) + rng.normal(0.0, noise, x.size)
    fit = fit_insertion_profile(x, f, n_frequencies=2, exit_depth=0.06)
    p = fit.profile
    # puncture found within one sample; polynomial and Fourier terms within a few percent / noise-level errors
    assert p.puncture_depth == pytest.approx(0.012, abs=2.5e-5)
    assert p.a2 == pytest.approx(4.99e4, rel=0.05)
    assert p.a1 + 2 * p.a2 * 0.006 == pytest.approx(1.9 + 2 * 4.99e4 * 0.006, rel=0.02)   # slope mid-phase
    np.testing.assert_allclose(p.frequencies, TRUE.frequencies, rtol=0.01)
    np.testing.assert_allclose(p.cos_coefficients, TRUE.cos_coefficients, atol=5 * noise)
    np.testing.assert_allclose(p.sin_coefficients, TRUE.sin_coefficients, atol=5 * noise)
    assert p.cutting_force == pytest.approx(1.2, abs=5 * noise)
    assert fit.rms_residual == pytest.approx(noise, rel=0.1)            # the model explains all but the noise
    np.testing.assert_allclose(fit.cutting_series.mean(), 1.2, atol=5 * noise)


def test_bad_records_are_rejected():
    with pytest.raises(ValueError, match="increase"):
        fit_insertion_profile(np.array([0.0, 1, 0.5, 2, 3, 4, 5, 6, 7]), np.ones(9))
    with pytest.raises(ValueError, match="puncture_depth"):
        InsertionForceProfile(1, 1, 0.0, (), (0.0,), (), 0.0)
