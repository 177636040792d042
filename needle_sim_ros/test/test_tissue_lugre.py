"""Modified LuGre model of seed 003 (eqs. 1-2, reading in needle_sim_ros.tissue.lugre)."""
import numpy as np
import pytest

from needle_sim_ros.tissue.lugre import LuGreParameters, ModifiedLuGre, axial_force, rk3_step
from lugre_record import simulate

TRUE = LuGreParameters(f1=8.0, f2=500.0, sigma0=2.5e5, sigma1=50.0, sigma2=12.0, alpha=125.0)


def insertion_retraction(depth=0.05, speed=0.01, dt=0.005, hold=0.5):
    n = int(round(depth / speed / dt))
    v = np.concatenate([np.full(n, speed), np.zeros(int(hold / dt)), np.full(n, -speed)])
    l = np.concatenate([[0.0], np.cumsum(v[:-1] * dt)])
    return l, v


def test_force_rises_drops_at_puncture_plateaus_and_turns_negative_on_retraction():
    l, v = insertion_retraction()
    f, _ = simulate(ModifiedLuGre(TRUE), l, v, 0.005)
    inserting = v > 0
    fi, li = f[inserting], l[inserting]
    k_peak = np.argmax(fi)
    assert 0.004 < li[k_peak] < 0.015                                  # puncture near 1/alpha = 8 mm
    assert np.all(np.diff(fi[:k_peak]) > 0)                            # rise
    assert fi[k_peak] > 1.5 * fi[li > 0.03].max()                      # drop after the puncture
    plateau = fi[li > 0.03]
    assert np.ptp(plateau) < 0.15 * plateau.mean()                     # plateau (slowly varying)
    retracting = v < 0
    assert np.all(f[retracting][l[retracting] > 0.002] < 0)            # negative on retraction
    # f is proportional to depth: |f| <= l (f1 + f2 + sigma1 + sigma2), so it vanishes at the surface
    assert abs(f[-1]) <= l[-1] * (8.0 + 500.0 + 50.0 + 12.0)
    assert f[0] == 0.0


def test_steady_state_is_the_analytic_one():
    # alpha = 0 makes g constant: at constant speed z -> g / sigma0 and f -> l (g + sigma2) exactly.
    p = LuGreParameters(f1=8.0, f2=2.0, sigma0=2.5e5, sigma1=50.0, sigma2=12.0, alpha=0.0)
    l, v = insertion_retraction(hold=0.0)
    f, z = simulate(ModifiedLuGre(p), l, v, 0.005)
    k = np.flatnonzero(v > 0)[-1]
    assert z[k] == pytest.approx(10.0 / 2.5e5, rel=1e-9)
    assert f[k] == pytest.approx(l[k] * (10.0 + 12.0), rel=1e-9)


def test_rk3_is_third_order():
    theta = TRUE.as_array()
    def integrate(n):
        z, dt = 0.0, 0.004 / n
        for k in range(n):
            z, _ = rk3_step(z, theta, 0.002 + 0.01 * k * dt, 0.01, dt, 0.0)
        return z
    reference = integrate(4096)
    errors = [abs(integrate(n) - reference) for n in (1, 2, 4)]
    # halving the step divides a third-order error by 2^3 = 8 (accept 6..10 for higher-order remainders)
    assert 6 < errors[0] / errors[1] < 10 and 6 < errors[1] / errors[2] < 10


def test_sensitivities_match_finite_differences():
    x = np.concatenate([[1.3e-3], TRUE.as_array()])
    for depth, velocity, vs in ((0.006, 0.01, 0.0), (0.03, -0.008, 0.0), (0.02, 2e-4, 1e-3)):
        _, row = rk3_step(x[0], x[1:], depth, velocity, 0.005, vs)
        _, grad = axial_force(x[0], x[1:], depth, velocity, vs)
        for i in range(7):
            h = 1e-6 * max(abs(x[i]), 1e-3)
            xp, xm = x.copy(), x.copy()
            xp[i] += h
            xm[i] -= h
            fd_row = (rk3_step(xp[0], xp[1:], depth, velocity, 0.005, vs)[0]
                      - rk3_step(xm[0], xm[1:], depth, velocity, 0.005, vs)[0]) / (2 * h)
            fd_grad = (axial_force(xp[0], xp[1:], depth, velocity, vs)[0]
                       - axial_force(xm[0], xm[1:], depth, velocity, vs)[0]) / (2 * h)
            assert row[i] == pytest.approx(fd_row, rel=1e-5, abs=1e-12)
            assert grad[i] == pytest.approx(fd_grad, rel=1e-5, abs=1e-12)


def test_invalid_parameters_rejected():
    with pytest.raises(ValueError, match="sigma0"):
        ModifiedLuGre(LuGreParameters(8, 500, -1.0, 50, 12, 125))
    with pytest.raises(ValueError, match="6 finite"):
        LuGreParameters.from_array([1, 2, 3])
