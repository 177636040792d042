"""The compiled quaternion helpers agree with scipy's Rotation (an independent implementation)."""
import numpy as np
from scipy.spatial.transform import Rotation

from needle_sim_ros import quaternion

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
