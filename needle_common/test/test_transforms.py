"""The quaternion helpers and rigid transforms agree with scipy's Rotation (an independent implementation)."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from needle_common import transforms as quaternion
from needle_common.transforms import (RigidTransform, matrix_quaternion, quaternion_matrix, quaternions_from_x_axes,
                                      rotate, unit_quaternion)

RNG = np.random.default_rng(3)
A = Rotation.random(50, random_state=4)
B = Rotation.random(50, random_state=5)


def test_product_and_conjugate_match_scipy():
    for a, b, ab in zip(A.as_quat(), B.as_quat(), (A * B).as_quat()):
        assert abs(np.array(quaternion.multiply(a, b)) @ ab) > 1 - 1e-12  # same rotation, up to sign
        np.testing.assert_allclose(quaternion.multiply(a, quaternion.conjugate(a)), [0, 0, 0, 1], atol=1e-12)


def test_rotation_vectors_match_scipy_including_tiny_and_half_turn_angles():
    quats = np.vstack([A.as_quat(), Rotation.from_rotvec([[1e-10, 0, 0], [0, 0, np.pi - 1e-9]]).as_quat()])
    for q, expected in zip(quats, Rotation.from_quat(quats).as_rotvec()):
        np.testing.assert_allclose(quaternion.to_rotation_vector(q), expected, atol=1e-9)
        np.testing.assert_allclose(quaternion.to_rotation_vector(-q), expected, atol=1e-9)
    vectors = np.vstack([RNG.normal(size=(20, 3)), [[0.0, 0.0, 0.0], [1e-12, 0.0, 0.0]]])
    for vector, expected in zip(vectors, Rotation.from_rotvec(vectors).as_quat()):
        assert abs(np.array(quaternion.from_rotation_vector(vector)) @ expected) > 1 - 1e-12


def test_matrices_and_back_match_scipy():
    for q, matrix in zip(A.as_quat(), A.as_matrix()):
        np.testing.assert_allclose(quaternion_matrix(q), matrix, atol=1e-12)
        back = matrix_quaternion(matrix)
        assert back[3] >= 0.0 and abs(back @ q) > 1 - 1e-12  # the same rotation, w >= 0
        np.testing.assert_allclose(rotate(q, [0.3, -1.0, 2.0]), Rotation.from_quat(q).apply([0.3, -1.0, 2.0]),
                                   atol=1e-12)


def test_least_rotations_onto_directions():
    directions = np.vstack([RNG.normal(size=(30, 3)), [[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 2.0]]])
    quaternions = quaternions_from_x_axes(directions)
    units = directions / np.linalg.norm(directions, axis=1, keepdims=True)
    np.testing.assert_allclose(Rotation.from_quat(quaternions).apply([1.0, 0.0, 0.0]), units, atol=1e-12)
    angles = Rotation.from_quat(quaternions).magnitude()
    np.testing.assert_allclose(angles, np.arccos(np.clip(units[:, 0], -1, 1)), atol=1e-7)  # the least rotation
    np.testing.assert_array_equal(quaternions_from_x_axes(directions[3]), quaternions[3])  # one direction alike


def test_rigid_transform_from_and_to_position_and_quaternion():
    pose = [0.1, -0.2, 0.3, *A.as_quat()[0] * 2.0]  # quaternion normalized on the way in
    transform = RigidTransform.from_xyz_quaternion(pose)
    np.testing.assert_allclose(transform.rotation, A.as_matrix()[0], atol=1e-12)
    np.testing.assert_allclose(transform.apply([[1.0, 2.0, 3.0]]), A[0].apply([[1.0, 2.0, 3.0]]) + pose[:3],
                               atol=1e-12)
    back = transform.as_xyz_quaternion()
    assert back[:3] == pose[:3] and abs(np.array(back[3:]) @ A.as_quat()[0]) > 1 - 1e-12
    np.testing.assert_allclose(transform.compose(transform.inverse()).rotation, np.eye(3), atol=1e-12)
    with pytest.raises(ValueError, match="non-zero"):
        RigidTransform.from_xyz_quaternion([0.0] * 7)


def test_unit_quaternions_are_checked_and_renormalized():
    np.testing.assert_allclose(unit_quaternion([0.0, 0.0, 0.0, 1.0 + 5e-7]), [0.0, 0.0, 0.0, 1.0], atol=1e-15)
    for value, message in (([0.0, 0.0, 0.0, 2.0], "unit quaternion"), ([0.0, 0.0, np.nan, 1.0], "4 finite"),
                           ([0.0, 1.0], "4 finite")):
        with pytest.raises(ValueError, match=message):
            unit_quaternion(value)
