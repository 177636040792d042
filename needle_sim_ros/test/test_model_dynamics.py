"""Dynamics of the ANCF needle: natural frequencies (issue test 3), large rigid-body motion (test 4), energy
(test 5), the seed's pitch experiment at slow motion (test 7), eq. 20 in motion, and integrator failure handling."""
import math

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import simpson
from scipy.optimize import brentq
from scipy.spatial.transform import Rotation

from needle_sim_ros.model import (BaseMotion, Fixture, ForceContribution, GeneralizedForce, Gravity, Integrator,
                                  NeedleProperties, PointLoad, StepFailed, axial_strain, build_model, centerline,
                                  curvature, elastic_energy, kinetic_energy, reaction_wrench, solve_static,
                                  tangent_stiffness)

NEEDLE = NeedleProperties(length=0.27, radius=0.635e-3, youngs_modulus=193e9, density=8000.0)
WEIGHTLESS = NeedleProperties(length=0.27, radius=0.635e-3, youngs_modulus=193e9, density=8000.0,
                              gravity=(0.0, 0.0, 0.0))
BASE = BaseMotion((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))


def cantilever_beta_l(n_modes: int) -> list[float]:
    """Euler-Bernoulli clamped-free eigenvalues beta_n L: roots of cos(x) cosh(x) = -1."""
    return [brentq(lambda x: np.cos(x) * np.cosh(x) + 1.0, (k + 0.3) * np.pi, (k + 0.7) * np.pi, xtol=1e-14)
            for k in range(n_modes)]


def linearized_modes(model):
    """Eigenfrequencies [Hz] and modes (full coordinates) of K(q0), M about the straight state."""
    q0 = model.straight_state(BASE).q
    active = model.partition.active_dofs
    K = tangent_stiffness(model, q0)[np.ix_(active, active)]
    omega2, vectors = scipy.linalg.eigh(K, model.mass_matrix[np.ix_(active, active)])
    modes = np.zeros((model.n_dof, active.size))
    modes[active] = vectors
    return np.sqrt(omega2) / (2 * np.pi), modes


def test_bending_frequencies_match_euler_bernoulli():
    """Issue test 3: first two bending frequencies of the linearized model (10 elements) within 1 % of
    f_n = (beta_n L)^2 / (2 pi L^2) sqrt(EI / (rho A)); each appears twice (y and z)."""
    frequencies, modes = linearized_modes(build_model(NEEDLE, 10))
    transverse = [f for f, mode in zip(frequencies, modes.T)
                  if np.abs(mode[0::6]).max() < 1e-6 * np.abs(mode).max()]  # no axial motion of the nodes
    exact = [b**2 / (2 * np.pi * NEEDLE.length**2) * math.sqrt(NEEDLE.EI / NEEDLE.mass_per_length)
             for b in cantilever_beta_l(2)]
    measured = np.array(transverse[:4]).reshape(2, 2)
    print(f"bending frequencies {measured[:, 0]} Hz, Euler-Bernoulli {exact} Hz")
    # 1 % is the requirement; cubic Hermite elements are far better (measured 1e-6 and 3e-5)
    assert np.allclose(measured, np.array(exact)[:, None], rtol=1e-2)
    assert np.allclose(measured[:, 0], measured[:, 1], rtol=1e-9)


def constant_rate_motion(angular_velocity, velocity, origin, orientation):
    """t -> BaseMotion rotating at a constant world angular velocity about A, which moves at constant velocity."""
    def motion(t):
        rotation = Rotation.from_rotvec(angular_velocity * t) * orientation
        return BaseMotion(origin + velocity * t, rotation.as_quat(), velocity, angular_velocity)
    return motion


def test_large_rigid_body_motion_causes_no_artificial_deformation():
    """Issue test 4: a weightless needle turning 90 deg about an oblique axis through A (perpendicular to the
    needle) while A translates 0.2 m, within 0.5 s at constant rates from the matching rigid velocity field.
    The exact motion is rigid: only the centrifugal stretch rho w^2 (L^2 - s^2) / (2E) <= 1.5e-8 appears."""
    axis = np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0)
    omega = (math.pi / 2) / 0.5
    motion = constant_rate_motion(omega * axis, np.array([0.2, 0.2, 0.2]) / math.sqrt(3) / 0.5,
                                  np.array([0.1, -0.2, 0.3]), Rotation.from_euler("x", 0.4))
    model = build_model(WEIGHTLESS, 10)
    integrator = Integrator(model)
    state = model.straight_state(motion(0.0))
    s = np.linspace(0.0, WEIGHTLESS.length, 101)
    worst = np.zeros(3)
    dt = 1e-3
    for k in range(1, 501):
        base = motion(k * dt)
        state = integrator.step(state, dt, base, []).state
        worst = np.maximum(worst, [curvature(model, state.q, s).max(), np.abs(axial_strain(model, state.q, s)).max(),
                                   elastic_energy(model, state.q)])
    # Curvature: the time discretization of the rotating coordinates leaves 2.6e-6 1/m (scales with dt^2); any
    # small-rotation error would bend the needle by O(1) rad over the 90 deg turn. Strain: centrifugal 1.5e-8, the
    # step response of the suddenly spinning needle doubles it. Energy: ~1e-11 J (a 1 mm tip deflection: 2e-5 J).
    assert worst[0] < 1e-4 and worst[1] < 1e-7 and worst[2] < 1e-9, worst
    expected_tip = base.position + WEIGHTLESS.length * base.axis
    assert np.linalg.norm(state.q[-6:-3] - expected_tip) < 1e-7  # measured 4 nm
    assert np.allclose(base.axis, [0.0, math.sqrt(0.5), -math.sqrt(0.5)], atol=1e-12)  # turned by 90 deg
    # eq. 20 in motion: the needle pulls its holder outwards with the centripetal force m w^2 L / 2
    wrench = reaction_wrench(model, state, base, [])
    centrifugal = WEIGHTLESS.mass * omega**2 * WEIGHTLESS.length / 2 * base.axis
    # 1e-3: the force still carries the damped axial oscillation excited at the start (measured 2e-5). The moment
    # at A is EI kappa(0) <= 0.025 N m^2 x 2.6e-6 / m from the time discretization: 1e-4 of F L.
    assert np.allclose(wrench.force_world, centrifugal, rtol=0, atol=1e-3 * np.linalg.norm(centrifugal))
    assert np.abs(wrench.torque_world).max() < 1e-4 * np.linalg.norm(centrifugal) * WEIGHTLESS.length


def first_mode_swing(model, amplitude):
    """Straight state with the velocity field of the first bending mode (z), tip speed amplitude * omega."""
    frequencies, modes = linearized_modes(model)
    for frequency, mode in zip(frequencies, modes.T):
        # y and z bending are degenerate: the solver may return any mix of the pair (machine dependent). About
        # the straight state the planes decouple, so the z part of a mixed eigenvector is itself the z mode.
        mode = mode.copy()
        mode[1::3] = 0.0  # the y components of r and r_x
        if abs(mode[-4]) > 0.1 * np.abs(mode).max():
            break
    state = model.straight_state(BASE)
    omega = 2 * np.pi * frequency
    state.qd = mode * amplitude * omega / mode[-4]
    return state, 1.0 / frequency


def energies_over(model, integrator, state, duration, dt=1e-3):
    energy = [kinetic_energy(model, state.qd) + elastic_energy(model, state.q)]
    for _ in range(int(round(duration / dt))):
        state = integrator.step(state, dt, BASE, []).state
        energy.append(kinetic_energy(model, state.qd) + elastic_energy(model, state.q))
    return np.array(energy)


def test_undamped_free_vibration_conserves_energy():
    """Issue test 5 (conservation): 30 mm tip amplitude (large: the needle swings through 11 % of its length) of
    the first bending mode, rho_inf = 1 (trapezoidal rule), 10 periods at dt = 1 ms."""
    model = build_model(WEIGHTLESS, 10)
    state, period = first_mode_swing(model, 0.03)
    energy = energies_over(model, Integrator(model, rho_inf=1.0), state, 10 * period)
    deviation = np.abs(energy / energy[0] - 1.0).max()
    print(f"energy deviation over 10 periods: {deviation:.2e}")
    assert deviation < 5e-3  # the 0.5 %; measured 5e-4 (nonlinear, Newton tolerance 1e-6)


def test_released_tip_load_keeps_its_energy_with_slight_numerical_damping():
    """Issue test 5 for a rough start: a 20 g tip load released at once excites all modes, including unresolved
    ones (dt = 1 ms), which the undamped trapezoidal rule cannot handle for large deformations (see
    ``integrators``); with rho_inf = 0.95 the energy of the ~12 Hz swing stays within 0.5 % over 10 periods."""
    model = build_model(WEIGHTLESS, 10)
    state = solve_static(model, BASE, [PointLoad(WEIGHTLESS.length, (0.0, 0.0, -0.196))]).state
    energy = energies_over(model, Integrator(model, rho_inf=0.95), state, 0.84)
    deviation = np.abs(energy / energy[0] - 1.0).max()
    print(f"released load, rho_inf = 0.95: energy deviation {deviation:.2e}")
    assert deviation < 5e-3  # measured 1.6e-3 (the high-frequency share is damped out, the swing is kept)


def test_damped_free_vibration_decays_monotonically():
    """Issue test 5 (decay): Rayleigh damping dissipates at the linear rate exp(-beta w^2 t), step by step;
    numerical damping (rho_inf = 0.5) lowers the energy from each period to the next."""
    model = build_model(WEIGHTLESS, 10, rayleigh_beta=1e-4)
    state, period = first_mode_swing(model, 0.03)
    energy = energies_over(model, Integrator(model, rho_inf=1.0), state, 10 * period)
    # dE/dt = -q'^T C q' <= 0; the discrete (trapezoidal) balance keeps it: no step may gain energy beyond round-off
    assert np.all(np.diff(energy) <= 1e-12 * energy[0])
    omega = 2 * np.pi / period
    # mode-1 energy decays as exp(-beta w^2 t); 2 % covers the period rounding and the nonlinear amplitude
    assert energy[-1] / energy[0] == pytest.approx(math.exp(-1e-4 * omega**2 * 10 * period), rel=2e-2)

    undamped = build_model(WEIGHTLESS, 10)
    state, period = first_mode_swing(undamped, 0.03)
    energy = energies_over(undamped, Integrator(undamped, rho_inf=0.5), state, 10 * period)
    steps = int(round(period / 1e-3))
    peaks = np.array([energy[k * steps:(k + 1) * steps].max() for k in range(10)])
    # numerical damping is not a passive force, so single steps may exchange energy; per period it decays
    assert np.all(np.diff(peaks) < 0) and peaks[-1] < peaks[0]


def pitch_motion(t, amplitude=math.radians(5.0), frequency=0.2):
    omega = 2 * math.pi * frequency
    angle = amplitude * math.sin(omega * t)
    return BaseMotion((0.0, 0.0, 0.0), (0.0, math.sin(angle / 2), 0.0, math.cos(angle / 2)), 0.0,
                      (0.0, amplitude * omega * math.cos(omega * t), 0.0), 0.0,
                      (0.0, -amplitude * omega**2 * math.sin(omega * t), 0.0))


def test_slow_pitch_experiment_is_quasi_static():
    """Issue test 7: seed 000's dynamic experiment (distal 40 % clamped, base pitch of 10 deg range at 0.2 Hz):
    at slow motion the shape at each instant equals the static equilibrium for the same base angle."""
    model = build_model(NEEDLE, 10, rayleigh_beta=1e-4,
                        fixtures=[Fixture(interval=(0.6 * NEEDLE.length, NEEDLE.length))])
    integrator = Integrator(model)
    forces = [Gravity()]
    state = solve_static(model, pitch_motion(0.0), forces).state
    dt, instants = 2e-3, {625: None, 1250: None, 1875: None, 2500: None}
    for k in range(1, 2501):
        state = integrator.step(state, dt, pitch_motion(k * dt), forces).state
        if k in instants:
            instants[k] = state
    largest = 0.0
    for k, dynamic in instants.items():
        static = solve_static(model, pitch_motion(k * dt), forces).state
        difference = np.abs(centerline(model, dynamic.q, 101).points - centerline(model, static.q, 101).points).max()
        largest = max(largest, np.abs(centerline(model, static.q, 101).points[:, 2]).max())
        # Inertia of the 0.2 Hz motion against the 210 Hz first mode of the free span: (0.2 / 210)^2 ~ 1e-6 of the
        # ~1 mm deflection; start-up vibration is damped out (beta = 1e-4, numerical damping). 1 um is 1000x that.
        assert difference < 1e-6, (k, difference)
    assert largest > 1e-3  # the comparison is not trivial: the free span deflects by more than 1 mm


def test_base_wrench_in_motion_balances_the_momentum_rate():
    """eq. 20 while vibrating: force on the holder = weight - d(momentum)/dt, moment likewise, with the momentum
    rate integrated independently from the accelerations along the needle.  Undamped: the bending part of the
    Rayleigh damping acts along the holder axis, so for a deformed needle it is not exactly free of a net moment
    (~4e-7 N m here with beta = 1e-4), which would blur this balance."""
    model = build_model(NEEDLE, 8)
    integrator = Integrator(model)
    release = [Gravity(), PointLoad(NEEDLE.length, (0.0, 0.05, -0.2))]
    state = solve_static(model, BASE, release).state
    forces = [Gravity()]
    for _ in range(37):
        state = integrator.step(state, 1e-3, BASE, forces).state
    wrench = reaction_wrench(model, state, BASE, forces)
    line = centerline(model, state.q, 2001)
    s = line.reference_arc_length
    acceleration = model.interpolation(s).positions(state.qdd)  # r'' along the needle (eq. 3 is linear in q)
    rate = NEEDLE.mass_per_length * np.array([simpson(a, x=s) for a in acceleration.T])
    arm = line.points - state.q[:3]
    moment_rate = NEEDLE.mass_per_length * np.array([simpson(c, x=s) for c in np.cross(arm, acceleration).T])
    weight = NEEDLE.mass * np.asarray(NEEDLE.gravity)
    weight_moment = NEEDLE.mass_per_length * np.array(
        [simpson(c, x=s) for c in np.cross(arm, np.asarray(NEEDLE.gravity)).T])
    scale = np.linalg.norm(rate) + np.linalg.norm(weight)
    # Newton tolerance 1e-8 L on the step and exact Simpson quadrature (250 panels per cubic element): 1e-6
    assert np.allclose(wrench.force_world, weight - rate, atol=1e-6 * scale)
    assert np.allclose(wrench.torque_world, weight_moment - moment_rate, atol=1e-6 * scale * NEEDLE.length)


@pytest.mark.parametrize("method,rho_inf", [("hht", 0.7), ("backward_euler", 1.0), ("generalized_alpha", 0.0)])
def test_dissipative_schemes_settle_to_the_static_equilibrium(method, rho_inf):
    """Every scheme converges to the static solution; backward Euler and rho_inf = 0 damp strongly."""
    model = build_model(NEEDLE, 6, rayleigh_beta=5e-3)
    forces = [Gravity(), PointLoad(NEEDLE.length, (0.0, 0.0, -0.2))]
    integrator = Integrator(model, method=method, rho_inf=rho_inf)
    state = model.straight_state(BASE)
    for _ in range(600):
        state = integrator.step(state, 2e-3, BASE, forces).state
    static = solve_static(model, BASE, forces).state
    # 1.2 s with beta = 5e-3 (first mode damped 19 %: amplitude down by exp(-17)) plus numerical damping: 0.1 mm
    assert np.abs(state.q[-6:-3] - static.q[-6:-3]).max() < 1e-4


class PoisonedForce(ForceContribution):
    """A force that becomes NaN after t_bad (a broken tissue model)."""

    state_dependent, time_invariant, stateful = True, False, False

    def __init__(self, t_bad):
        self.t_bad = t_bad

    def evaluate(self, model, q, qd, t, base):
        return GeneralizedForce(np.full(model.n_dof, np.nan if t > self.t_bad else 0.0))


def test_failed_steps_are_reported_never_returned():
    """A NaN force makes the step fail with StepFailed (after sub-stepping); the input state is untouched."""
    model = build_model(NEEDLE, 4)
    integrator = Integrator(model, max_substep_halvings=2)
    state = integrator.step(model.straight_state(BASE), 1e-3, BASE, [Gravity(), PoisonedForce(1.5e-3)]).state
    before = state.q.copy()
    with pytest.raises(StepFailed, match="failed with up to 4 sub-steps"):
        integrator.step(state, 1e-3, BASE, [Gravity(), PoisonedForce(1.5e-3)])
    assert np.array_equal(state.q, before)


def test_sub_stepping_recovers_a_hard_step():
    """A 20 g tip load applied at once with a 50 ms step and only 6 Newton iterations (needs 10): the integrator
    halves the step until Newton converges and reports the sub-steps."""
    model = build_model(NEEDLE, 6)
    integrator = Integrator(model, max_newton_iterations=6, max_substep_halvings=6)
    state = model.straight_state(BASE)
    result = integrator.step(state, 5e-2, BASE, [Gravity(), PointLoad(NEEDLE.length, (0.0, 0.0, -0.196))])
    assert result.converged and result.substeps > 1 and np.all(np.isfinite(result.state.q))


def test_invalid_integrator_settings_are_rejected():
    model = build_model(NEEDLE, 2)
    with pytest.raises(ValueError, match="method"):
        Integrator(model, method="rk4")
    with pytest.raises(ValueError, match="rho_inf"):
        Integrator(model, method="hht", rho_inf=0.3)
    with pytest.raises(ValueError, match="dt"):
        Integrator(model).step(model.straight_state(BASE), 0.0, BASE)
