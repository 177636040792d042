"""The compiled step sequence (the simulator's fast path) against the general one-step integrator over a seeded,
randomized set of configurations: element count and lengths, a world clamp of the distal nodes, gravity, tip and
point loads, base motions from rest in static equilibrium. Both solve each step's equations (modified Newton with the
iteration matrix kept across steps vs full Newton); they must agree to the Newton tolerance."""
import numpy as np
import pytest

from needle_sim_ros.model import (BaseMotion, Fixture, Gravity, Integrator, NeedleProperties, PointLoad,
                                  build_model, solve_static)

NEEDLE = NeedleProperties(length=0.27, radius=0.635e-3, youngs_modulus=193e9, density=8000.0)
STEPS, DT, TOLERANCE = 25, 1e-3, 1e-11


def _motion(rng: np.random.Generator):
    """A smooth base motion from rest: translation and a rotation about a random axis, both a (1 - cos)."""
    amplitude, omega = rng.uniform(0.0, 0.003, 3), rng.uniform(2.0, 20.0)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    angle_amplitude = rng.uniform(0.0, 0.15)

    def at(t: float) -> BaseMotion:
        c, s = np.cos(omega * t), np.sin(omega * t)
        angle = angle_amplitude * (1 - c)
        return BaseMotion(amplitude * (1 - c), np.r_[np.sin(angle / 2) * axis, np.cos(angle / 2)],
                          amplitude * omega * s, angle_amplitude * omega * s * axis,
                          amplitude * omega ** 2 * c, angle_amplitude * omega ** 2 * c * axis)
    return at


def _configuration(seed: int):
    rng = np.random.default_rng(seed)
    n_elements = int(rng.integers(2, 16))
    weights = rng.uniform(0.5, 2.0, n_elements)
    lengths = NEEDLE.length * weights / weights.sum() if rng.random() < 0.5 else None
    fixtures = ()
    if rng.random() < 0.3:  # the distal node clamped in the world where the straight needle lies
        fixtures = (Fixture(nodes=(-1,), frame="world"),)
    forces = [Gravity()] if rng.random() < 0.8 else []
    for _ in range(int(rng.integers(0, 3))):  # tip and point loads of up to 0.3 N in random directions
        s = NEEDLE.length if rng.random() < 0.5 else float(rng.uniform(0.05, 1.0) * NEEDLE.length)
        forces.append(PointLoad(s, rng.normal(scale=0.1, size=3)))
    model = build_model(NEEDLE, n_elements, element_lengths=lengths, rayleigh_beta=float(rng.uniform(0, 2e-4)),
                        fixtures=fixtures)
    return model, forces, _motion(rng)


@pytest.mark.parametrize("seed", range(12))
def test_compiled_sequence_agrees_with_the_general_step(seed):
    model, forces, motion = _configuration(seed)
    general = Integrator(model, newton_tol=TOLERANCE)
    compiled = Integrator(model, newton_tol=TOLERANCE)
    assert compiled.supports_sequence(forces)
    bases = [motion(k * DT) for k in range(STEPS + 2)]
    rest = solve_static(model, bases[0], forces).state  # at rest in equilibrium under the loads
    first = general.step(rest, DT, bases[1], forces)  # consistent accelerations
    start = first.state
    packed = np.array([np.r_[b.position, b.orientation, b.linear_velocity, b.angular_velocity,
                             b.linear_acceleration, b.angular_acceleration] for b in bases[2:]])
    result = compiled.step_sequence(start, DT, packed, np.array([b.rotation for b in bases[2:]]), forces)
    assert result.done == STEPS
    state = start
    for i in range(STEPS):
        step = general.step(state, DT, bases[i + 2], forces)
        assert step.substeps == 1  # sub-steps would integrate other equations than the compiled step's
        state = step.state
        np.testing.assert_allclose(result.states[i, 0], state.q, rtol=0, atol=1e-9 * NEEDLE.length)
        np.testing.assert_allclose(result.states[i, 1], state.qd, rtol=0,
                                   atol=1e-9 * max(1.0, np.abs(state.qd).max()) / DT)
