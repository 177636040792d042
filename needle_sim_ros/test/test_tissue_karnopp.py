"""Karnopp shaft friction (seed 001 eq. 2) as an elasto-plastic traction law."""
import numpy as np
import pytest

from typing import NamedTuple

from needle_sim_ros.tissue.karnopp import axial_traction


class KarnoppFriction(NamedTuple):
    """Seed 001 eq. 2 with its stick band, per unit length: the product's ``axial_traction`` on arrays of points,
    and the anchors' plastic return (the test's rigid shaft)."""

    coulomb: float          # C_n [N/m]
    viscous: float          # b_n [N s/m^2]
    stick_stiffness: float  # k_a [N/m^2]

    @property
    def stick_band(self) -> float:
        return self.coulomb / self.stick_stiffness

    def traction(self, elastic_displacement, velocity):
        u, v = np.broadcast_arrays(np.asarray(elastic_displacement, float), np.asarray(velocity, float))
        out = np.array([axial_traction(a, b, self.stick_stiffness, self.coulomb, self.viscous, 0.0, 0.0, 0.0)
                        for a, b in zip(u.ravel(), v.ravel())]).T.reshape((3,) + u.shape)
        return out[0], out[1], out[2]

    def slipped_displacement(self, elastic_displacement):
        return np.clip(elastic_displacement, -self.stick_band, self.stick_band)


SEED = KarnoppFriction(coulomb=6.0, viscous=120.0, stick_stiffness=2.0e4)   # seed 001 C_n, b_n; k_a chosen


def slide_rod(friction, velocity_history, depth, dt):
    """Rigid inserted shaft of length ``depth`` moved with a prescribed velocity history; anchors slip after
    each step (the advance hook of the coupled model).  Returns (friction work on the rod, final elastic energy)."""
    u, work = 0.0, 0.0
    for v in velocity_history:
        u += v * dt                                                    # shaft moves, anchor frozen in the step
        t, _, _ = friction.traction(u, v)
        work += t * depth * v * dt
        u = float(friction.slipped_displacement(u))
    return work, 0.5 * friction.stick_stiffness * u**2 * depth


def test_steady_sliding_reproduces_eq2_and_mirrors_on_retraction():
    for v in (0.006, 0.02):
        u_slid = 10 * SEED.stick_band                                  # far outside the band: sliding
        t, dt_du, dt_dv = SEED.traction(u_slid, v)
        assert t == pytest.approx(-(6.0 + 120.0 * v))                  # eq. 2 per unit length
        assert dt_du == 0.0 and dt_dv == -120.0
        assert SEED.traction(-u_slid, -v)[0] == pytest.approx(6.0 + 120.0 * v)  # mirrored on retraction


def test_friction_work_equals_force_times_distance():
    depth, v, dt, distance = 0.05, 0.006, 1e-3, 0.03
    steps = int(round(distance / (v * dt)))
    work, stored = slide_rod(SEED, np.full(steps, v), depth, dt)
    expected = -(6.0 + 120.0 * v) * depth * distance
    # Force x distance: full Coulomb + viscous force over the distance, except that over the first stick band
    # the Coulomb part ramps up elastically from 0 (half of C_n on average).  The step discretisation changes the
    # work by about one step (6 um) of Coulomb force out of 30 mm: rel 1e-3 is ample.
    ramp_deficit = 0.5 * SEED.coulomb * SEED.stick_band * depth
    assert work == pytest.approx(expected + ramp_deficit, rel=1e-3)
    assert stored == pytest.approx(0.5 * SEED.coulomb * SEED.stick_band * depth)


def test_stick_band_holds_load_below_coulomb_limit_without_creep():
    # A load per length below C_n is held by a finite, constant elastic displacement: u = load / k_a.
    load = 0.8 * SEED.coulomb
    u = load / SEED.stick_stiffness
    t, dt_du, _ = SEED.traction(u, 0.0)
    assert t == pytest.approx(-load) and dt_du == -SEED.stick_stiffness
    assert SEED.slipped_displacement(u) == u                            # anchors do not move: stick
    assert SEED.slipped_displacement(2 * SEED.stick_band) == pytest.approx(SEED.stick_band)


def test_friction_is_passive_for_any_motion():
    rng = np.random.default_rng(0)
    velocities = rng.normal(0.0, 0.01, 5000)
    work, stored = slide_rod(SEED, velocities, 0.05, 1e-3)
    assert work + stored <= 1e-12          # energy taken from the shaft >= energy it could give back


def test_traction_jacobians_match_finite_differences():
    rng = np.random.default_rng(1)
    u = rng.uniform(-2, 2, 50) * SEED.stick_band
    v = rng.normal(0, 0.01, 50)
    _, dt_du, dt_dv = SEED.traction(u, v)
    h_u, h_v = 1e-9, 1e-9
    fd_u = (SEED.traction(u + h_u, v)[0] - SEED.traction(u - h_u, v)[0]) / (2 * h_u)
    fd_v = (SEED.traction(u, v + h_v)[0] - SEED.traction(u, v - h_v)[0]) / (2 * h_v)
    away = np.abs(np.abs(u) - SEED.stick_band) > 1e-6                   # kink at the band edge
    np.testing.assert_allclose(dt_du[away], fd_u[away], rtol=1e-6, atol=1e-6)
    np.testing.assert_allclose(dt_dv, fd_v, rtol=1e-6)

