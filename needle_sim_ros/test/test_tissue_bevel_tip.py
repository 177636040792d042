"""Bevel-tip forces P, Q of seed 001 eqs. 4-5 and the bevel frame."""
import numpy as np
import pytest

from needle_sim_ros.tissue.bevel_tip import BevelTip

LAMBDA = np.deg2rad(30.0)                                               # seed 001: 30 degree bevel
SEED_TIP = BevelTip.for_diameter(9.42e3, LAMBDA, 0.2, 1.27e-3)          # K_T, beta/lambda = 0.2, 18 gauge


def test_forces_follow_eqs_4_5():
    beta = 0.2 * LAMBDA
    b, a = 1.27e-3 / np.sin(LAMBDA), 1.27e-3 / np.tan(LAMBDA)
    # (tan l - tan b) / (1 + tan l tan b) = tan(l - b): an independent form of the same expressions.
    assert SEED_TIP.axial_force == pytest.approx(9.42e3 * b**2 / 2 * np.sin(LAMBDA) * np.tan(LAMBDA - beta))
    assert SEED_TIP.transverse_force == pytest.approx(
        9.42e3 * b**2 / 2 * np.cos(LAMBDA) * np.tan(LAMBDA - beta) - 9.42e3 * a**2 / 2 * np.tan(beta))
    assert SEED_TIP.transverse_force > 0                              # pushes toward the bevel side
    # Without the acting-point offset and the a edge the resultant is normal to the bevel face: P/Q = tan(lambda).
    face = BevelTip(9.42e3, LAMBDA, 0.0, 0.0, 2e-3)
    assert face.axial_force / face.transverse_force == pytest.approx(np.tan(LAMBDA))


def test_tip_force_in_bevel_frame_and_axial_rotation_reverses_it():
    tangent = np.array([1.0, 0.02, -0.01]) * 1.001
    side = np.array([0.0, 0.0, 1.0])
    force, _ = SEED_TIP.tip_force(tangent, side)
    t = tangent / np.linalg.norm(tangent)
    assert force @ t == pytest.approx(-SEED_TIP.axial_force)
    lateral = force - (force @ t) * t
    assert np.linalg.norm(lateral) == pytest.approx(SEED_TIP.transverse_force)
    assert lateral[2] > 0                                             # toward the configured bevel side
    flipped, _ = SEED_TIP.tip_force(tangent, -side)                    # base rolled by 180 degrees
    np.testing.assert_allclose(flipped - (flipped @ t) * t, -lateral, atol=1e-15)


def test_tip_force_jacobian_matches_finite_differences():
    rng = np.random.default_rng(2)
    for _ in range(5):
        rx = np.array([1.0, 0, 0]) + 0.2 * rng.normal(size=3)
        side = rng.normal(size=3)
        _, jac = SEED_TIP.tip_force(rx, side)
        h = 1e-7
        fd = np.column_stack([(SEED_TIP.tip_force(rx + h * e, side)[0] - SEED_TIP.tip_force(rx - h * e, side)[0])
                              / (2 * h) for e in np.eye(3)])
        np.testing.assert_allclose(jac, fd, rtol=1e-6, atol=1e-9 * SEED_TIP.transverse_force)


def test_bad_input():
    with pytest.raises(ValueError, match="acting_angle"):
        BevelTip(1e4, LAMBDA, LAMBDA, 1e-3, 1e-3)
    with pytest.raises(ValueError, match="parallel"):
        SEED_TIP.tip_force(np.array([1.0, 0, 0]), np.array([2.0, 0, 0]))
