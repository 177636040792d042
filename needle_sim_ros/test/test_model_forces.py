"""External generalized forces (eqs. 14-16): virtual work of point, line and nodal loads, gravity, and the
Jacobians of MaterialPointForce; state-dependent forces in the integrator and the static solver."""
import numpy as np
import pytest
from scipy.integrate import simpson

from needle_sim_ros.model import (BaseMotion, ForceContribution, GeneralizedForce, Gravity, Integrator, LineLoad,
                                  MaterialPointForce, NeedleProperties, NodalLoad, PointForces, PointLoad, build_model,
                                  check_forces, reaction_wrench, solve_static)
from needle_sim_ros.tissue import build_tissue_model

NEEDLE = NeedleProperties(length=0.27, radius=0.635e-3, youngs_modulus=193e9, density=8000.0)
BASE = BaseMotion((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))
TILTED = BaseMotion((0.0, 0.0, 0.0), (0.2, -0.3, 0.1, np.sqrt(1 - 0.14)))


def test_point_and_line_loads_do_the_virtual_work_of_eq_14():
    """Q . dq = F . dr(s) for a point load and int f . dr ds for a line load, for random virtual displacements;
    the line integral is done independently (Simpson on 1201 samples, exact per cubic element)."""
    model = build_model(NEEDLE, element_lengths=[0.05, 0.07, 0.15])
    rng = np.random.default_rng(5)
    force, density = np.array([0.3, -0.2, 0.5]), np.array([-1.0, 0.4, 0.2])
    for frame, base in (("world", BASE), ("base", TILTED)):
        point = PointLoad(0.1234, force, frame=frame).evaluate(model, None, None, 0.0, base).Q
        line = LineLoad(0.05, 0.12, density, frame=frame).evaluate(model, None, None, 0.0, base).Q
        f_world = force if frame == "world" else base.rotation @ force
        d_world = density if frame == "world" else base.rotation @ density
        s = np.linspace(0.05, 0.12, 1401)  # element ends 0.05 and 0.12 are samples 0 and 1400
        for _ in range(3):
            dq = rng.normal(size=model.n_dof)
            assert point @ dq == pytest.approx(f_world @ model.interpolation([0.1234]).positions(dq)[0], rel=1e-12)
            work = simpson(model.interpolation(s).positions(dq) @ d_world, x=s)
            assert line @ dq == pytest.approx(work, rel=1e-9)


def test_gravity_is_the_weight_line_load():
    model = build_model(NEEDLE, 7)
    Q = Gravity().evaluate(model, None, None, 0.0, BASE).Q
    reference = LineLoad(0.0, NEEDLE.length, NEEDLE.mass_per_length * np.asarray(NEEDLE.gravity))
    assert np.allclose(Q, reference.evaluate(model, None, None, 0.0, BASE).Q, rtol=1e-13, atol=0)
    assert np.allclose(Q.reshape(-1, 2, 3)[:, 0].sum(axis=0), NEEDLE.mass * np.asarray(NEEDLE.gravity), rtol=1e-13)


def test_nodal_loads_and_frames():
    model = build_model(NEEDLE, 3)
    Q = NodalLoad(-1, (1.0, 2.0, 3.0), (0.1, 0.2, 0.3), frame="base").evaluate(model, None, None, 0.0, TILTED).Q
    assert np.allclose(Q[-6:-3], TILTED.rotation @ [1.0, 2.0, 3.0])
    assert np.allclose(Q[-3:], TILTED.rotation @ [0.1, 0.2, 0.3]) and not Q[:-6].any()
    with pytest.raises(ValueError, match="node"):
        NodalLoad(4, (1.0, 0.0, 0.0)).evaluate(model, None, None, 0.0, BASE)
    with pytest.raises(ValueError, match="frame"):
        PointLoad(0.1, (1.0, 0.0, 0.0), frame="tool")
    with pytest.raises(ValueError, match="arc lengths"):
        PointLoad(0.3, (1.0, 0.0, 0.0)).evaluate(model, None, None, 0.0, BASE)


def nonlinear_law(r, r_x, v, t, base):
    """A cubic spring to the x axis, a force along the local tangent and viscous drag (a tissue-like law)."""
    k3, c, tension = 50.0, 0.3, 0.7
    offset = r * np.array([0.0, 1.0, 1.0])
    square = np.einsum("ki,ki->k", offset, offset)
    F = -k3 * square[:, None] * offset + tension * r_x - c * v
    P = np.diag([0.0, 1.0, 1.0])
    dF_dr = -k3 * (square[:, None, None] * P + 2 * offset[:, :, None] * offset[:, None, :])
    eye = np.broadcast_to(np.eye(3), dF_dr.shape)
    return PointForces(F, dF_dr, tension * eye, -c * eye)


def test_material_point_force_jacobians_match_finite_differences():
    model = build_model(NEEDLE, 4)
    force = MaterialPointForce(np.linspace(0.01, NEEDLE.length, 9), np.full(9, 0.03), nonlinear_law)
    rng = np.random.default_rng(2)
    q = model.straight_state(BASE).q + 0.02 * rng.normal(size=model.n_dof)
    qd = rng.normal(size=model.n_dof)
    value = force.evaluate(model, q, qd, 0.0, BASE)
    h = 1e-6
    for jacobian, moved in ((value.dQ_dq, lambda d: (q + d, qd)), (value.dQ_dqd, lambda d: (q, qd + d))):
        numeric = np.column_stack([(force.evaluate(model, *moved(h * e), 0.0, BASE).Q
                                    - force.evaluate(model, *moved(-h * e), 0.0, BASE).Q) / (2 * h)
                                   for e in np.eye(model.n_dof)])
        # cubic law: central differences err by h^2 |F'''| ~ 1e-10, far below 1e-7 of the largest entry
        assert np.abs(jacobian - numeric).max() < 1e-7 * np.abs(jacobian).max()
    with pytest.raises(ValueError, match="law must return"):
        MaterialPointForce([0.1, 0.2], [1.0, 1.0],
                           lambda r, rx, v, t, b: PointForces(np.zeros((3, 3)))).evaluate(model, q, qd, 0.0, BASE)


def winkler(stiffness):
    """Elastic foundation pulling every point back to the world x axis (force per length)."""
    def law(r, r_x, v, t, base):
        k = r.shape[0]
        P = np.diag([0.0, 1.0, 1.0])
        return PointForces(-stiffness * r @ P, np.broadcast_to(-stiffness * P, (k, 3, 3)).copy())
    return law


def test_state_dependent_forces_in_statics_and_dynamics():
    """A Winkler foundation (MaterialPointForce, 30 points) under gravity: the integrator (compiled Newton with the
    force Jacobians in the matrix) settles to the static solution, which balances the base wrench."""
    model = build_model(NEEDLE, 6, rayleigh_beta=5e-3)
    s = np.linspace(0.0, NEEDLE.length, 31)
    weights = np.full(31, NEEDLE.length / 30)
    weights[[0, -1]] /= 2
    foundation = MaterialPointForce(s, weights, winkler(200.0))
    forces = [Gravity(), foundation]
    static = solve_static(model, BASE, forces).state
    integrator = Integrator(model)
    state = model.straight_state(BASE)
    for _ in range(800):
        state = integrator.step(state, 2e-3, BASE, forces).state
    # the transient decays by ~250x per 0.4 s (beta = 5e-3, numerical damping): after 1.6 s below 1e-12 m;
    # 1e-10 m leaves margin and is still 1e-6 of the sag
    assert np.abs(state.q - static.q).max() < 1e-10
    wrench = reaction_wrench(model, static, BASE, forces)
    foundation_force = foundation.evaluate(model, static.q, static.qd, 0.0, BASE).Q.reshape(-1, 2, 3)[:, 0].sum(0)
    total = NEEDLE.mass * np.asarray(NEEDLE.gravity) + foundation_force
    assert np.allclose(wrench.force_world, total, atol=1e-9)


class TipTether(ForceContribution):
    """A spring between the tip and node 1 (couples coordinates 11 elements apart): widens the Newton band."""

    state_dependent, time_invariant, stateful = True, False, False

    def __init__(self, stiffness):
        self.stiffness = stiffness

    def evaluate(self, model, q, qd, t, base):
        n = model.n_dof
        tip, near = slice(n - 6, n - 3), slice(6, 9)
        Q = np.zeros(n)
        Q[tip] = -self.stiffness * (q[tip] - q[near] - np.array([NEEDLE.length - model.mesh.node_arc_length[1], 0, 0]))
        Q[near] = -Q[tip]
        K = np.zeros((n, n))
        for a, sign_a in ((tip, 1.0), (near, -1.0)):
            for b, sign_b in ((tip, 1.0), (near, -1.0)):
                K[a, b] = -sign_a * sign_b * self.stiffness * np.eye(3)
        return GeneralizedForce(Q, K)


def test_wide_jacobians_are_handled():
    model = build_model(NEEDLE, 4, rayleigh_beta=5e-3)
    forces = [Gravity(), TipTether(50.0)]
    static = solve_static(model, BASE, forces).state
    plain = solve_static(model, BASE, [Gravity()]).state
    assert static.q[-4] > plain.q[-4]  # the tether lifts the tip
    integrator = Integrator(model)
    state = model.straight_state(BASE)
    for _ in range(300):
        state = integrator.step(state, 2e-3, BASE, forces).state
    assert np.abs(state.q - static.q).max() < 1e-7  # settled (as above)


class Undeclared:
    def evaluate(self, model, q, qd, t, base):
        return GeneralizedForce(np.zeros(model.n_dof))


class ForgetsItsState(Undeclared, ForceContribution):
    state_dependent, time_invariant, stateful = True, False, True

    def advance(self, model, state, base):
        pass


class AdvancesUnseen(ForgetsItsState):
    stateful = False


class ConstantButMoving(Undeclared, ForceContribution):
    state_dependent, time_invariant, stateful = True, True, False


class LocalWithoutBand(Undeclared, ForceContribution):
    state_dependent, time_invariant, stateful, element_local = True, False, False, True


@pytest.mark.parametrize("force, message", [
    (Undeclared(), "Undeclared must declare state_dependent"),
    (ForgetsItsState(), "ForgetsItsState declares stateful = True but has no initial_state, at"),
    (AdvancesUnseen(), "AdvancesUnseen has advance.. but declares stateful = False"),
    (ConstantButMoving(), "ConstantButMoving declares time_invariant = True, which excludes state_dependent"),
    (LocalWithoutBand(), "LocalWithoutBand declares element_local = True but has no assemble_banded")])
def test_contributions_breaking_the_force_protocol_are_refused_by_name(force, message):
    model = build_model(NEEDLE, 2)
    with pytest.raises(TypeError, match=message):
        Integrator(model).step(model.straight_state(BASE), 1e-3, BASE, [Gravity(), force])
    with pytest.raises(TypeError, match=message):
        solve_static(model, BASE, [force])


def test_every_contribution_declares_its_capabilities():
    """(state_dependent, time_invariant, stateful, element_local) of the product's contributions, tissue from its
    factory."""
    model = build_model(NEEDLE, 4)
    loads = {"gravity": Gravity(), "point": PointLoad(0.1, (0, 0, 1)), "point base": PointLoad(0.1, (0, 0, 1), "base"),
             "line": LineLoad(0.0, 0.1, (0, 0, 1)), "nodal": NodalLoad(-1, (0, 0, 1)),
             "nodal base": NodalLoad(-1, (0, 0, 1), frame="base"),
             "material points": MaterialPointForce([0.1], [1.0], winkler(1.0))}
    tissue = build_tissue_model({"tissue.insertion_profile.enable": True}, model)
    declared = {name: (f.state_dependent, f.time_invariant, f.stateful, f.element_local) for name, f in loads.items()}
    assert declared == {"gravity": (False, True, False, False), "point": (False, True, False, False),
                        "point base": (False, False, False, False), "line": (False, True, False, False),
                        "nodal": (False, True, False, False), "nodal base": (False, False, False, False),
                        "material points": (True, False, False, True)}
    def capabilities(forces):
        return [(type(f).__name__, f.state_dependent, f.time_invariant, f.stateful, f.element_local)
                for f in check_forces(forces)]
    assert capabilities([tissue]) == [("TissueModel", True, False, True, False)]
    # the tissue's parts (contact, shaft, bevel tip, tip resistance) act as one composition over a step
    assert capabilities(tissue.at(tissue.initial_state(model))) == [("ComposedForces", True, False, False, True)]
    assert tissue.at_tip == (False, False, True, True)
    with pytest.raises(TypeError, match="TissueModel is stateful: integrate its contributions at"):
        Integrator(model).step(model.straight_state(BASE), 1e-3, BASE, [Gravity(), tissue])
    assert check_forces(loads.values()) == tuple(loads.values())


def test_element_local_blocks_and_the_base_wrench():
    """assemble_banded adds c_q dQ/dq + c_qd dQ/dq' in band layout: equal to the dense Jacobians (themselves checked
    against finite differences above) for any factors; the base wrench skips an element-local force only where it
    has no point in the first element, so it equals the wrench from the full Q of every force either way."""
    from needle_sim_ros.model.banded import ELEMENT_BANDWIDTH, band_to_dense, band_width_columns
    from needle_sim_ros.model.elastic import ELEMENT_WORK
    from needle_sim_ros.model.reaction import base_constraint_kernel, base_rows

    model = build_model(NEEDLE, 5)
    rng = np.random.default_rng(4)
    q = model.straight_state(BASE).q + 0.02 * rng.normal(size=model.n_dof)
    qd = rng.normal(size=model.n_dof)
    for start in (0.01, 0.15):  # in the first element (0.054 m long) or beyond it
        force = MaterialPointForce(np.linspace(start, NEEDLE.length, 7), np.full(7, 0.03), nonlinear_law)
        dense = force.evaluate(model, q, qd, 0.0, BASE)
        band = np.zeros((model.n_dof, band_width_columns(ELEMENT_BANDWIDTH)))
        Q = force.assemble_banded(model, q, qd, 0.0, BASE, band, ELEMENT_BANDWIDTH, -2.0, 0.5)
        np.testing.assert_array_equal(Q, dense.Q)
        np.testing.assert_allclose(band_to_dense(band, ELEMENT_BANDWIDTH), -2.0 * dense.dQ_dq + 0.5 * dense.dQ_dqd,
                                   rtol=0, atol=1e-12 * np.abs(dense.dQ_dq).max())
        assert force.touches_element(model, 0) == (start < model.mesh.node_arc_length[1])
        state = model.straight_state(BASE)
        state.q, state.qd = q, qd
        full = np.empty(12)
        base_constraint_kernel(q[:12].copy(), qd[:12].copy(), np.zeros(12), *base_rows(model), BASE.rotation,
                               dense.Q[:6].copy(), np.empty(ELEMENT_WORK), full)
        wrench = reaction_wrench(model, state, BASE, [force])
        np.testing.assert_array_equal(wrench.force_world, -full[6:9])
