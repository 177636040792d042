"""The fast quaternion helpers agree with scipy's Rotation (an independent implementation)."""
import numpy as np
from scipy.spatial.transform import Rotation

from needle_sim_ros import quaternion

RNG = np.random.default_rng(3)
A = Rotation.random(50, random_state=4)
B = Rotation.random(50, random_state=5)


def test_product_conjugate_and_matrix_match_scipy():
    product = quaternion.multiply(A.as_quat(), B.as_quat())
    assert np.all(np.abs(np.sum(product * (A * B).as_quat(), axis=1)) > 1 - 1e-12)  # same rotation, up to sign
    np.testing.assert_allclose(quaternion.multiply(A.as_quat(), quaternion.conjugate(A.as_quat()))[:, 3], 1.0)
    for q, matrix in zip(A.as_quat(), A.as_matrix()):
        np.testing.assert_allclose(quaternion.to_matrix(q), matrix, atol=1e-12)


def test_rotation_vectors_match_scipy_including_tiny_and_half_turn_angles():
    quats = np.vstack([A.as_quat(), Rotation.from_rotvec([[1e-10, 0, 0], [0, 0, np.pi - 1e-9]]).as_quat()])
    np.testing.assert_allclose(quaternion.to_rotation_vector(quats), Rotation.from_quat(quats).as_rotvec(), atol=1e-9)
    vectors = np.vstack([RNG.normal(size=(20, 3)), [[0.0, 0.0, 0.0], [1e-12, 0.0, 0.0]]])
    q = quaternion.from_rotation_vector(vectors)
    assert np.all(np.abs(np.sum(q * Rotation.from_rotvec(vectors).as_quat(), axis=1)) > 1 - 1e-12)
