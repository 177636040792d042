"""Tissue force contributions on the ANCF needle: Jacobians, passivity, friction work, readout, configuration."""
import numpy as np
import pytest

from needle_sim_ros.model import BaseMotion, Integrator, NeedleProperties, build_model, elastic_energy, kinetic_energy
from needle_sim_ros.model.records import pack_record
from needle_sim_ros.model.step import pack
from needle_sim_ros.tissue.factory import TISSUE_PARAMETERS, build_tissue_model
from needle_sim_ros.tissue.coupling import ANCHOR, COULOMB, SHAPES, STICK_STIFFNESS, STIFFNESS, TANGENT, WEIGHT
from needle_sim_ros.tissue.tissue_model import TissueState
from needle_sim_ros.tissue.track import segment_blocks
from lugre_record import simulate

PROPS = NeedleProperties(0.27, 0.635e-3, 193e9, 8000.0, gravity=(0.0, 0.0, 0.0))   # seed 000 needle
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
ENTRY_X = 0.28


def config(**overrides):
    values = {"tissue.entry_point": [ENTRY_X, 0.0, 0.0], "tissue.bevel_tip.side": [0.0, 1.0, 0.0]}
    values.update({f"tissue.{k.replace('__', '.')}": v for k, v in overrides.items()})
    return values


def inserted_state(model, tissue, depth, velocity=0.0, t=0.0, own=None):
    """Straight needle along x with the tip ``depth`` below the surface, moving at ``velocity``, at time t, and the
    tissue state advanced to it from ``own`` (fresh tissue if None): track started, shaft points anchored."""
    base = BaseMotion(np.array([ENTRY_X + depth - PROPS.length, 0.0, 0.0]), IDENTITY,
                      linear_velocity=np.array([velocity, 0.0, 0.0]))
    state = model.straight_state(base, t)
    own = tissue.advance(model, state, base, tissue.initial_state(model) if own is None else own)
    return state, base, own


def integrate(model, integrator, tissue, state, own, dt, base):
    """One step under the tissue's contributions of the step, then the tissue advanced (as NeedleData's step)."""
    state = integrator.step(state, dt, base, tissue.at(own)).state
    return state, tissue.advance(model, state, base, own)


def finite_difference_check(force, model, q, qd, base, h=1e-7):
    """Compare evaluate()'s Jacobians with central differences of Q over the active coordinates."""
    result = force.evaluate(model, q, qd, 0.0, base)
    n = q.size
    fd_q, fd_qd = np.zeros((n, n)), np.zeros((n, n))
    for i in range(6, n):                                   # node 0 is the clamped base node
        e = np.zeros(n)
        e[i] = h
        fd_q[:, i] = (force.evaluate(model, q + e, qd, 0.0, base).Q
                      - force.evaluate(model, q - e, qd, 0.0, base).Q) / (2 * h)
        fd_qd[:, i] = (force.evaluate(model, q, qd + e, 0.0, base).Q
                       - force.evaluate(model, q, qd - e, 0.0, base).Q) / (2 * h)
    dq = np.zeros((n, n)) if result.dQ_dq is None else result.dQ_dq
    dqd = np.zeros((n, n)) if result.dQ_dqd is None else result.dQ_dqd
    # central differences of smooth pieces: truncation ~h^2 * third derivative, rounding ~1e-16 |Q| / h
    scale_q = max(np.abs(dq).max(), 1e-12)
    scale_qd = max(np.abs(dqd).max(), 1e-12)
    np.testing.assert_allclose(dq[:, 6:], fd_q[:, 6:], atol=1e-6 * scale_q)
    np.testing.assert_allclose(dqd[:, 6:], fd_qd[:, 6:], atol=1e-6 * scale_qd)
    return result


def perturbed(state, rng, amplitude=2e-5):
    q = state.q + amplitude * rng.normal(size=state.q.size)
    qd = state.qd + 1e-3 * rng.normal(size=state.qd.size)
    return q, qd


@pytest.fixture(scope="module")
def model():
    return build_model(PROPS, n_elements=10)


def test_contact_keeps_the_segment_blocks_of_its_track(model):
    """The contact record's segment blocks (made again only when the track grows) are its track's at every step:
    the track started, grown by a few vertices, and not grown."""
    tissue = build_tissue_model(config(), model)
    own, sizes = None, []
    for depth in (0.03, 0.0305, 0.0305):
        _, _, own = inserted_state(model, tissue, depth, own=own)
        contact = own.records[0]
        sizes.append(contact.arc.size)
        centres, radii = segment_blocks(contact.vertices, contact.arc)
        np.testing.assert_array_equal(contact.centres, centres)
        np.testing.assert_array_equal(contact.radii, radii)
    assert sizes[0] > 16 and sizes[1] > sizes[0] and sizes[2] == sizes[1]


def test_shaft_support_jacobians_match_finite_differences_in_stick_and_slip(model):
    tissue = build_tissue_model(config(bevel_tip__enable=False), model)
    state, base, own = inserted_state(model, tissue, 0.03)
    contact, shaft = own.records
    assert shaft.active.sum() >= 10
    points = shaft.points.copy()
    lateral, axial = points[:shaft.lateral_count], points[shaft.lateral_count:]
    assert axial[:, WEIGHT].sum() == pytest.approx(0.03)            # weights add up to the inserted length
    # the lateral springs hold the cut part: all of it but the last track spacing at most
    assert 0.03 - tissue.contact.spacing <= lateral[:, WEIGHT].sum() <= 0.03 + 1e-9
    # push every other anchor beyond the stick band (0.3 mm): those points slip, the others stick
    axial[::2, ANCHOR:ANCHOR + 3] -= 1e-3 * axial[::2, TANGENT:TANGENT + 3]
    moved = shaft._replace(points=points)
    shaft, = tissue.at(TissueState(tissue, pack([pack_record(contact), pack_record(moved)])))
    q, qd = perturbed(state, np.random.default_rng(4))
    result = finite_difference_check(shaft, model, q, qd, base)
    assert np.abs(result.Q).max() > 0


@pytest.mark.parametrize("bevel", [False, True])
def test_bevel_and_tip_resistance_jacobians_match_finite_differences(model, bevel):
    # the tip forces alone (no shaft support): the seed 002 tip resistance, with or without the bevel tip
    tissue = build_tissue_model(config(insertion_profile__enable=True, insertion_profile__puncture_depth=0.005,
                                      insertion_profile__cutting_speed_scale=1e-2, bevel_tip__enable=bevel,
                                      shaft__lateral_support=False, shaft__axial_model="none"), model)
    # before puncture: capsule stiffness along the entry normal
    state, base, own = inserted_state(model, tissue, 0.003)
    assert not own.records[0].punctured
    q, qd = perturbed(state, np.random.default_rng(5))
    assert np.abs(finite_difference_check(tissue.at(own)[0], model, q, qd, base).Q).max() > 0
    # after puncture, cutting at 6 mm/s (inside the 10 mm/s ramp of F_c): tip force depends on r_x and v
    state, base, own = inserted_state(model, tissue, 0.02, velocity=0.006, t=1.0, own=own)
    assert own.records[0].punctured and own.records[0].at_front
    punctured, cutting = own.records[-1]
    assert punctured and cutting and (not bevel or own.records[2][0] > 0)   # the bevel's scale
    q, qd = perturbed(state, np.random.default_rng(6))
    assert np.abs(finite_difference_check(tissue.at(own)[0], model, q, qd, base).Q).max() > 0


def test_passive_tissue_never_adds_energy(model):
    # Needle 40 mm deep with its base fixed, released with random velocities: the mechanical energy
    # (kinetic + needle elastic + tissue springs) may only decrease under lateral support + Karnopp friction.
    tissue = build_tissue_model(config(bevel_tip__enable=False), model)
    state, base, own = inserted_state(model, tissue, 0.04)
    rng = np.random.default_rng(7)
    state.qd[6:] = 0.02 * rng.normal(size=state.qd.size - 6)
    integrator = Integrator(model, method="generalized_alpha", rho_inf=1.0)   # no numerical dissipation
    def energy_of(state):
        return kinetic_energy(model, state.qd) + elastic_energy(model, state.q) + shaft_energy(own, state.q)

    energy = [energy_of(state)]
    for _ in range(200):
        state = integrator.step(state, 1e-4, base, tissue.at(own)).state
        energy.append(energy_of(state))
        own = tissue.advance(model, state, base, own)
    energy = np.array(energy)
    # The trapezoidal rule conserves the energy of linear systems exactly; the nonlinear cable and the stick/slip
    # switches inside a step leave single-step errors below 1e-3 of the total (measured 5e-4), so the test
    # bounds the single steps by that and requires that the energy never exceeds its initial value: an active
    # law (a negative damper, a slip that releases more than it stored) makes it grow over the 200 steps.
    assert np.all(np.diff(energy) <= 1e-3 * energy[0])
    assert np.all(energy[1:] <= energy[0])
    assert energy[-1] < 0.6 * energy[0]                                       # and it does dissipate


def shaft_energy(own, q) -> float:
    """Energy [J] stored in the lateral springs and the sticking axial anchors (stick band |u| <= C/k_a) of the
    shaft's frozen points, from their record."""
    shaft = own.records[1]
    p, tangents = shaft.points, shaft.points[:, TANGENT:TANGENT + 3]
    r = np.einsum("ka,kai->ki", p[:, SHAPES:SHAPES + 4], q.reshape(-1, 3)[shaft.slots])
    offset = r - p[:, ANCHOR:ANCHOR + 3]
    u = np.einsum("ki,ki->k", offset, tangents)
    lateral = 0.5 * p[:, STIFFNESS] * np.sum((offset - u[:, None] * tangents) ** 2, axis=1)
    stick_stiffness = p[:, STICK_STIFFNESS]
    band = p[:, COULOMB] / stick_stiffness                                 # coulomb / k_a
    return float(p[:, WEIGHT] @ (lateral + 0.5 * stick_stiffness * np.clip(u, -band, band) ** 2))


def test_friction_work_equals_force_times_distance_in_the_coupled_model(model):
    # Straight insertion without bevel and lateral support: the tissue's axial force is eq. 2, (C_n + b_n v) d,
    # and its work over the insertion is int (C_n + b_n v) x dx = (C_n + b_n v) D^2 / 2.
    tissue = build_tissue_model(config(bevel_tip__enable=False, shaft__lateral_support=False), model)
    own = tissue.initial_state(model)
    speed, dt = 0.006, 2e-3
    velocity = np.array([speed, 0.0, 0.0])
    start = ENTRY_X - PROPS.length - 1e-3
    base = BaseMotion(np.array([start, 0, 0]), IDENTITY, linear_velocity=velocity)
    state = model.straight_state(base, 0.0)
    integrator = Integrator(model)
    work, depth_history, force_history = 0.0, [], []
    for k in range(1, int(0.031 / speed / dt) + 1):
        base = BaseMotion(np.array([start + speed * k * dt, 0, 0]), IDENTITY, linear_velocity=velocity)
        state, own = integrate(model, integrator, tissue, state, own, dt, base)
        readout = tissue.readout(model, own, state, base)
        work += readout.axial_force * speed * dt
        depth_history.append(readout.insertion_depth)
        force_history.append(readout.axial_force)
    depth = depth_history[-1]
    per_length = 6.0 + 120.0 * speed
    # stick band 0.3 mm and the 2 mm point spacing (one point enters at a time): 2 % at 30 mm
    assert force_history[-1] == pytest.approx(per_length * depth, rel=0.02)
    assert work == pytest.approx(per_length * depth**2 / 2, rel=0.03)


def test_readout_of_a_straight_inserted_needle(model):
    tissue = build_tissue_model(config(), model)
    state, base, own = inserted_state(model, tissue, 0.025)
    readout = tissue.readout(model, own, state, base)
    assert readout.insertion_depth == pytest.approx(0.025)
    assert readout.inserted_length == pytest.approx(0.025, abs=1e-9)
    bevel = tissue.bevel[0]
    k_t = 9.42e3
    # at the front of a fresh cut: bevel P against the insertion and Q toward +y (the configured bevel side)
    np.testing.assert_allclose(readout.tip_force, k_t * np.array([-bevel.axial_force, bevel.transverse_force, 0]),
                               rtol=1e-9, atol=1e-12)


def test_configuration_errors_name_the_parameter(model):
    with pytest.raises(ValueError, match="tissue.shaft.axial_model"):
        build_tissue_model(config(shaft__axial_model="coulomb"), model)
    with pytest.raises(ValueError, match="unknown parameter 'tissue.layers.stiffness' \\(did you mean"):
        build_tissue_model({"tissue.layers.stiffness": [1.0]}, model)
    with pytest.raises(ValueError, match="tissue.layers.friction_coulomb"):
        build_tissue_model(config(layers__friction_coulomb=[6.0, 6.0]), model)
    with pytest.raises(ValueError, match="'tissue.entry_point' = .*: expected 3 values"):
        build_tissue_model(config(entry_point=[0.28, 0.0]), model)
    assert all(isinstance(spec.description, str) and spec.description for spec in TISSUE_PARAMETERS)


def test_params_file_builds_and_its_keys_are_all_known(model):
    from needle_common.package_files import share_file
    path = share_file("needle_sim_ros", "config/tissue.yaml")  # as installed
    tissue = build_tissue_model(path, model)
    assert tissue.shaft.lateral and tissue.bevel is not None


def test_lugre_axial_law_reproduces_the_seed_003_curve_in_the_coupled_model(model):
    # Insert 30 mm at 10 mm/s and retract 10 mm with the seed 003 law on the shaft: the tissue's axial force on
    # the needle follows the standalone model driven by the same depth history (rise, puncture drop near
    # 1/alpha = 8 mm, friction growth), and turns negative on retraction.
    from needle_sim_ros.tissue.lugre import LuGreParameters, ModifiedLuGre

    tissue = build_tissue_model(config(bevel_tip__enable=False, shaft__axial_model="lugre"), model)
    own = tissue.initial_state(model)
    speed, dt = 0.01, 2e-3
    start = ENTRY_X - PROPS.length - 1e-3
    integrator = Integrator(model)
    position = start
    state = model.straight_state(BaseMotion(np.array([start, 0, 0]), IDENTITY,
                                            linear_velocity=np.array([speed, 0, 0])), 0.0)
    depths, velocities, coupled = [], [], []
    profile = [speed] * int(0.031 / speed / dt) + [-speed] * int(0.01 / speed / dt)
    for k, v in enumerate(profile, start=1):
        position += v * dt
        base = BaseMotion(np.array([position, 0, 0]), IDENTITY, linear_velocity=np.array([v, 0, 0]))
        state, own = integrate(model, integrator, tissue, state, own, dt, base)
        readout = tissue.readout(model, own, state, base)
        depths.append(readout.insertion_depth)
        velocities.append(v)
        coupled.append(readout.axial_force)
    coupled = np.array(coupled)
    seed = ModifiedLuGre(LuGreParameters(8.0, 500.0, 2.5e5, 50.0, 12.0, 125.0), 1e-4)
    standalone, _ = simulate(seed, np.array(depths), np.array(velocities), dt)
    inserting = np.array(velocities) > 0
    # the coupled state z lags the readout by one step and sums over shaft points: 3 % of the peak force
    np.testing.assert_allclose(coupled[inserting], standalone[inserting], atol=0.03 * standalone.max())
    peak = np.argmax(coupled)
    assert 0.004 < depths[peak] < 0.012 and coupled[peak] > 1.3 * coupled[inserting][-1]
    assert np.all(coupled[~inserting][5:] < 0)                        # retraction: the force turns negative
