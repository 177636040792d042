"""Base kinematics (flange offset, prescribed coordinates q_c), fixtures and the partition (eqs. 18-19), and the
geometric outputs (centerline, tip pose)."""
import dataclasses
import math
import pickle

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from needle_sim_ros.model import (BaseMotion, Fixture, Gravity, NeedleProperties, PointLoad, build_model, centerline,
                                  solve_static, tip_pose)
from needle_sim_ros.messages.geometry import tube_triangles
from needle_sim_ros.model.partition import hermite_quintic

NEEDLE = NeedleProperties(length=0.27, radius=0.635e-3, youngs_modulus=193e9, density=8000.0)
AXIS = np.array([0.36, -0.48, 0.8])
OFFSET = (np.array([0.02, -0.01, 0.15]), Rotation.from_euler("zyx", [0.3, -0.2, 0.5]))


def flange_pose(t):
    """Flange moving along a parabola and turning about a fixed axis by phi(t) = 0.4 t + 0.9 t^2."""
    position = np.array([0.1, 0.2, 0.3]) + np.array([0.5, -0.2, 0.1]) * t + np.array([0.3, 0.4, -0.6]) * t**2
    return position, Rotation.from_rotvec(AXIS * (0.4 * t + 0.9 * t**2)) * Rotation.from_euler("x", 0.7)


def flange_motion(t):
    position, rotation = flange_pose(t)
    rate, acceleration = 0.4 + 1.8 * t, 1.8
    return BaseMotion.from_flange(position, rotation.as_quat(), OFFSET[0], OFFSET[1].as_quat(),
                                  np.array([0.5, -0.2, 0.1]) + 2 * np.array([0.3, 0.4, -0.6]) * t, AXIS * rate,
                                  2 * np.array([0.3, 0.4, -0.6]), AXIS * acceleration)


def test_flange_offset_kinematics_match_finite_differences():
    """The clamp point A = flange + R_f offset: velocity and acceleration by central differences of its path."""
    t, h = 0.37, 1e-4
    motion = flange_motion(t)
    def clamp(t):
        position, rotation = flange_pose(t)
        return position + rotation.apply(OFFSET[0])
    # central differences: O(h^2) truncation on a smooth path, ~1e-8 here
    assert np.allclose(motion.position, clamp(t), atol=1e-14)
    assert np.allclose(motion.linear_velocity, (clamp(t + h) - clamp(t - h)) / (2 * h), atol=1e-7)
    assert np.allclose(motion.linear_acceleration, (clamp(t + h) - 2 * clamp(t) + clamp(t - h)) / h**2, atol=1e-5)
    expected = (flange_pose(t)[1] * OFFSET[1]).as_matrix()
    assert np.allclose(motion.rotation, expected, atol=1e-14)


def test_straight_state_prescribes_the_base_coordinates_and_rigid_rates():
    """q_c = [r_A, r_xA = unit axis]; every node moves rigidly: compare with differences of the node paths."""
    model = build_model(NEEDLE, element_lengths=[0.1, 0.07, 0.1])
    t, h = 0.21, 1e-4
    state = model.straight_state(flange_motion(t), t)
    path = lambda t: model.straight_state(flange_motion(t), t).q
    assert np.allclose(state.q[:3], flange_motion(t).position) and np.allclose(state.q[3:6], flange_motion(t).axis)
    assert np.allclose(np.linalg.norm(state.q.reshape(-1, 2, 3)[:, 1], axis=1), 1.0)
    assert np.allclose(state.qd, (path(t + h) - path(t - h)) / (2 * h), atol=1e-7)
    assert np.allclose(state.qdd, (path(t + h) - 2 * path(t) + path(t - h)) / h**2, atol=1e-5)


def test_base_motion_rejects_bad_input():
    with pytest.raises(ValueError, match="orientation"):
        BaseMotion((0, 0, 0), (0, 0, 0, 2))
    with pytest.raises(ValueError, match="position"):
        BaseMotion((0, 0), (0, 0, 0, 1))
    with pytest.raises(ValueError, match="angular_velocity"):
        BaseMotion((0, 0, 0), (0, 0, 0, 1), angular_velocity=(0, math.nan, 0))


def test_a_motion_from_packed_fields_reads_them_as_one_built_from_them():
    """A motion from_packed (one per compiled step, its fields views made when read) has the fields, replace and
    pickle of the motion its constructor builds from the same values (an independent path: validation, copy)."""
    packed = BaseMotion((0.1, -0.2, 0.3), (0.5, -0.5, 0.5, 0.5), linear_velocity=(1.0, 2.0, 3.0),
                        angular_velocity=(-1.0, 0.5, 0.25), linear_acceleration=(4.0, 5.0, 6.0),
                        angular_acceleration=(0.0, -7.0, 8.0))
    lazy = BaseMotion.from_packed(packed.packed.copy(), packed.rotation)
    for name in ("position", "orientation", "linear_velocity", "angular_velocity", "linear_acceleration",
                 "angular_acceleration"):
        for motion in (lazy, pickle.loads(pickle.dumps(lazy)), dataclasses.replace(lazy)):
            assert np.array_equal(getattr(motion, name), getattr(packed, name)), name
    assert repr(lazy) == repr(packed)
    with pytest.raises(AttributeError):
        lazy.velocity  # noqa: B018 (no such field)


def test_fixtures_partition_and_validation():
    equal = [0.027] * 10
    model = build_model(NEEDLE, 10, element_lengths=equal,
                        fixtures=[Fixture(interval=(0.162, 0.27)), Fixture(nodes=(2,), frame="base")])
    clamped_nodes = sorted(set(model.partition.constrained_dofs // 6))
    assert clamped_nodes == [0, 2, 6, 7, 8, 9, 10]
    assert model.partition.active_dofs.size == model.n_dof - 6 * 7
    with pytest.raises(ValueError, match="not a mesh node"):
        build_model(NEEDLE, 10, element_lengths=equal, fixtures=[Fixture(interval=(0.15, 0.27))])
    with pytest.raises(ValueError, match="clamped twice"):
        build_model(NEEDLE, 4, fixtures=[Fixture(nodes=(0,))])
    with pytest.raises(ValueError, match="node index"):
        build_model(NEEDLE, 4, fixtures=[Fixture(nodes=(5,))])
    with pytest.raises(ValueError, match="frame"):
        Fixture(nodes=(1,), frame="tool")


def test_the_default_mesh_of_a_clamped_needle_has_nodes_at_the_clamps_and_clusters_them_at_the_holds():
    """Without element lengths, a clamp interval gets one element and the free spans the others: Chebyshev-Lobatto
    nodes between two holds, equal elements towards the free tip; any interval works, not only uniform nodes."""
    length = NEEDLE.length
    model = build_model(NEEDLE, 10, fixtures=[Fixture(interval=(0.162, length))])
    nodes = model.mesh.node_arc_length
    assert nodes.size == 11 and nodes[9] == pytest.approx(0.162) and nodes[10] == length
    assert np.allclose(nodes[:10], 0.081 * (1 - np.cos(np.pi * np.arange(10) / 9)))
    middle = build_model(NEEDLE, 10, fixtures=[Fixture(interval=(0.1, 0.2))]).mesh.node_arc_length
    assert np.allclose(middle, [0, 0.1 * 0.0955, 0.1 * 0.3455, 0.1 * 0.6545, 0.1 * 0.9045, 0.1, 0.2, 0.2175,
                                0.235, 0.2525, 0.27], atol=1e-5)
    assert np.allclose(build_model(NEEDLE, 10, fixtures=[Fixture(nodes=(-1,))]).mesh.element_lengths, 0.027)
    with pytest.raises(ValueError, match="at least 3"):
        build_model(NEEDLE, 2, fixtures=[Fixture(interval=(0.1, 0.2))])
    with pytest.raises(ValueError, match="0 <= s_start <= s_end"):
        build_model(NEEDLE, 10, fixtures=[Fixture(interval=(0.1, math.nan))])


def test_fixture_on_a_moving_frame_carries_its_nodes():
    """A tip clamp on a frame that translates: the static equilibrium has the tip where the frame put it."""
    shift = np.array([0.0, 0.0, -0.02])
    frame = lambda t: BaseMotion(shift * t, (0.0, 0.0, 0.0, 1.0), shift)
    model = build_model(NEEDLE, 6, fixtures=[Fixture(nodes=(-1,), frame=frame)])
    state = solve_static(model, BaseMotion((0, 0, 0), (0, 0, 0, 1)), [Gravity()], t=1.0).state
    assert np.allclose(state.q[-6:], [NEEDLE.length, 0.0, -0.02, 1.0, 0.0, 0.0], atol=1e-15)
    assert np.allclose(model.straight_state(BaseMotion((0, 0, 0), (0, 0, 0, 1)), 1.0).qd[-6:-3], shift)


def test_quintic_interpolation_of_prescribed_coordinates():
    """Sub-steps interpolate q_c from values, rates and accelerations at both ends: exact for quintics."""
    c = np.array([0.3, -1.0, 2.0, 0.5, -0.7, 1.1])
    y = lambda t: np.polyval(c, t)
    dy, ddy = np.polyder(c), np.polyder(c, 2)
    state = lambda t: np.array([[y(t)], [np.polyval(dy, t)], [np.polyval(ddy, t)]])
    t0, h = 0.4, 0.3
    for theta in (0.25, 0.5, 0.8):
        assert np.allclose(hermite_quintic(state(t0), state(t0 + h), h, theta), state(t0 + theta * h), atol=1e-12)


def test_centerline_and_tip_pose_of_a_planar_bend():
    """Cantilever with a tip load in the x-z plane: tangents are unit, arc length ~ L (inextensible to 1e-5),
    the tip frame is the base frame turned about y by the tip angle."""
    model = build_model(NEEDLE, 10)
    base = BaseMotion((0, 0, 0), (0, 0, 0, 1))
    state = solve_static(model, base, [Gravity(), PointLoad(NEEDLE.length, (0, 0, -0.3))]).state
    line = centerline(model, state.q, 201)
    assert np.allclose(np.linalg.norm(line.tangents, axis=1), 1.0)
    assert line.arc_length[-1] == pytest.approx(NEEDLE.length, rel=1e-5)  # axial strain < 1e-5 under 0.3 N
    assert np.allclose(line.points[-1], state.q[-6:-3])
    position, orientation = tip_pose(model, state.q)
    tangent = state.q[-3:] / np.linalg.norm(state.q[-3:])
    angle = math.atan2(-tangent[2], tangent[0])
    assert np.allclose(Rotation.from_quat(orientation).as_matrix(),
                       Rotation.from_euler("y", angle).as_matrix(), atol=1e-9)
    rolled = Rotation.from_euler("x", 0.3)
    _, with_base = tip_pose(model, state.q, base_orientation=rolled.as_quat())
    assert np.allclose(Rotation.from_quat(with_base).as_matrix(),
                       (Rotation.from_euler("y", angle) * rolled).as_matrix(), atol=1e-9)
    with pytest.raises(ValueError, match="n_samples"):
        centerline(model, state.q, 1)


HELIX_RADIUS, HELIX_PITCH = 0.03, 0.02  # a, b of r(s) = (b s / c, a cos(s / c), a sin(s / c)), c^2 = a^2 + b^2


def helix_frame(s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Point, unit tangent, Frenet normal and binormal of the helix at arc length s."""
    a, b = HELIX_RADIUS, HELIX_PITCH
    c = math.hypot(a, b)
    angle = s / c
    point = np.array([b * s / c, a * math.cos(angle), a * math.sin(angle)])
    tangent = np.array([b, -a * math.sin(angle), a * math.cos(angle)]) / c
    normal = np.array([0.0, -math.cos(angle), -math.sin(angle)])
    return point, tangent, normal, np.cross(tangent, normal)


def twist_free_normal(s: float) -> np.ndarray:
    """The Frenet normal at s = 0 carried along the helix without twist: the Frenet normal turned by -tau s about
    the tangent (torsion tau = b / c^2)."""
    _, _, normal, binormal = helix_frame(s)
    angle = -HELIX_PITCH / (HELIX_RADIUS**2 + HELIX_PITCH**2) * s
    return math.cos(angle) * normal + math.sin(angle) * binormal


def test_centerline_and_tip_frame_of_a_helix_against_its_closed_form():
    """Nodes on a helix (:func:`helix_frame`): the centerline follows it, its arc length is s, and the tip frame's
    y axis is the base's normal carried without twist (:func:`twist_free_normal`)."""
    n_elements = 40  # the cubic interpolation is off the helix by < 1e-7 m
    model = build_model(NEEDLE, n_elements)
    nodes = np.linspace(0.0, NEEDLE.length, n_elements + 1)
    q = np.concatenate([np.concatenate(helix_frame(s)[:2]) for s in nodes])
    line = centerline(model, q, 101)
    helix = np.array([helix_frame(s)[0] for s in line.reference_arc_length])
    assert np.abs(line.points - helix).max() < 5e-7  # 0.9e-7
    assert np.abs(line.arc_length - line.reference_arc_length).max() < 1e-6  # 3e-7
    _, t0, n0, b0 = helix_frame(0.0)
    base = Rotation.from_matrix(np.column_stack([t0, n0, b0]))
    _, orientation = tip_pose(model, q, base_orientation=base.as_quat())
    t_tip, y_tip = helix_frame(NEEDLE.length)[1], twist_free_normal(NEEDLE.length)  # turned by 4.2 rad
    expected = np.column_stack([t_tip, y_tip, np.cross(t_tip, y_tip)])
    assert np.abs(Rotation.from_quat(orientation).as_matrix() - expected).max() < 5e-4  # 1.2e-4 (81 samples)


def test_tube_rings_a_helix_without_twist():
    """The RViz tube around 201 helix samples: every vertex lies on a ring of the tube's radius perpendicular to
    the tangent, and each ring's first vertex follows the twist-free normal (here the first ring's normal
    e_z x t(0) is e_y, minus the Frenet normal at the helix's start)."""
    radius, sides = 1e-3, 8
    s = np.linspace(0.0, NEEDLE.length, 201)
    frames = [helix_frame(value) for value in s]
    points, tangents = np.array([f[0] for f in frames]), np.array([f[1] for f in frames])
    vertices = tube_triangles(points, tangents, radius, sides).reshape(len(s) - 1, sides, 6, 3)
    rings = vertices[:, :, 0]  # corner a of each quad: ring i, vertex j
    offsets = rings - points[:-1, None, :]
    assert np.allclose(np.linalg.norm(offsets, axis=2), radius, rtol=1e-12, atol=0)
    assert np.abs(np.einsum("kjd,kd->kj", offsets, tangents[:-1])).max() < 1e-15
    expected = -np.array([twist_free_normal(value) for value in s[:-1]])
    assert np.abs(offsets[:, 0] / radius - expected).max() < 1e-3  # 3e-4
