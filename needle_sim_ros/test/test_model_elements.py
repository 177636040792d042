"""ANCF cable element: shape functions (eq. 4), mass (eq. 7), elastic forces and their analytic Jacobian
(eqs. 8-13), checked against finite differences, exact integrals and rigid-body invariance."""
import numpy as np
import pytest

from needle_sim_ros.model import (NeedleProperties, axial_strain, build_model, curvature, elastic_energy,
                                  elastic_forces, tangent_stiffness)
from needle_sim_ros.model.banded import ELEMENT_BANDWIDTH, band_to_dense, band_width_columns
from needle_sim_ros.model.damping import reference_stiffness_slots
from needle_sim_ros.model.mesh import search_right, shape_functions
from needle_sim_ros.model.newton import assemble_system, model_tables

NEEDLE = NeedleProperties(length=0.27, radius=0.635e-3, youngs_modulus=193e9, density=8000.0)


def rotation(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def straight(model, axis=(1.0, 0.0, 0.0), origin=(0.0, 0.0, 0.0)):
    t = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    nodes = np.zeros((model.n_nodes, 2, 3))
    nodes[:, 0] = np.asarray(origin) + model.mesh.node_arc_length[:, None] * t
    nodes[:, 1] = t
    return nodes.ravel()


def rigidly_moved(q, R, d):
    nodes = q.reshape(-1, 2, 3)
    return np.stack([nodes[:, 0] @ R.T + d, nodes[:, 1] @ R.T], axis=1).ravel()


def test_shape_functions_interpolate_cubics_and_their_derivatives():
    """eq. 4: Hermite interpolation reproduces any cubic from end values and slopes; S_x, S_xx are derivatives."""
    length = 0.037
    xi = np.linspace(-1, 1, 9)
    x = (xi + 1) * length / 2
    S, S_x, S_xx = shape_functions(xi, length)
    f = lambda x: 2 - 3 * x + 40 * x**2 - 900 * x**3
    df = lambda x: -3 + 80 * x - 2700 * x**2
    ddf = lambda x: 80 - 5400 * x
    ends = np.array([f(0), df(0), f(length), df(length)])
    assert np.allclose(S @ ends, f(x), atol=1e-14)
    assert np.allclose(S_x @ ends, df(x), atol=1e-12)
    assert np.allclose(S_xx @ ends, ddf(x), atol=1e-9)


def test_consistent_mass_matrix():
    """eq. 7: total mass on every translation, symmetric positive definite, equal to a 12-point quadrature."""
    model = build_model(NEEDLE, element_lengths=[0.05, 0.1, 0.12])
    M = model.mass_matrix
    translation = np.tile([1.0, 0, 0, 0, 0, 0], model.n_nodes)
    assert translation @ M @ translation == pytest.approx(NEEDLE.mass, rel=1e-13)
    assert np.allclose(M, M.T) and np.linalg.eigvalsh(M).min() > 0
    xi, w = np.polynomial.legendre.leggauss(12)
    reference = np.zeros_like(model.mass_slots)
    for j, l in enumerate(model.mesh.element_lengths):
        S = shape_functions(xi, l)[0]
        reference[2 * j:2 * j + 4, 2 * j:2 * j + 4] += NEEDLE.mass_per_length * l / 2 * (S.T * w) @ S
    assert np.allclose(model.mass_slots, reference, rtol=1e-13, atol=0)


def finite_difference_stiffness(model, q, h):
    n = q.size
    K = np.zeros((n, n))
    for i in range(n):
        step = np.zeros(n)
        step[i] = h
        K[:, i] = -(elastic_forces(model, q + step) - elastic_forces(model, q - step)) / (2 * h)
    return K


@pytest.mark.parametrize("axial_gauss,bending_gauss", [(5, 3), (2, 3), (4, 5)])
def test_analytic_jacobian_matches_finite_differences(axial_gauss, bending_gauss):
    """K = -dQ_el/dq against central differences, at a large 3D deformation of a non-uniform mesh."""
    model = build_model(NEEDLE, element_lengths=[0.04, 0.06, 0.08, 0.09], axial_gauss=axial_gauss,
                        bending_gauss=bending_gauss)
    rng = np.random.default_rng(7)
    q = straight(model) + 0.02 * rng.normal(size=model.n_dof)
    K = tangent_stiffness(model, q)
    # Central differences with h = 1e-7: truncation ~h^2 |Q'''| and round-off ~1e-16 |Q| / h, both ~1e-8 relative
    # to the largest stiffness entry (EA / l ~ 1e7 N/m), hence 1e-6.
    assert np.abs(K - finite_difference_stiffness(model, q, 1e-7)).max() < 1e-6 * np.abs(K).max()
    assert np.allclose(K, K.T, atol=1e-12 * np.abs(K).max())


def test_analytic_jacobian_at_the_straight_unloaded_state():
    """At the straight state kappa is not differentiable; the Jacobian of the smooth kappa^2 form is, and equals
    both the finite differences and the closed form K_0(t) = kron(K_a, t t^T) + kron(K_b, I - t t^T)."""
    model = build_model(NEEDLE, 5)
    axis = np.array([0.3, -0.5, 0.8])
    q = straight(model, axis, origin=(0.1, 0.2, -0.3))
    assert np.abs(elastic_forces(model, q)).max() < 1e-9  # unloaded: no force (round-off of EA ~ 2e5 N)
    K = tangent_stiffness(model, q)
    # finite differences are exact up to round-off here as the forces are smooth: same bound as above
    assert np.abs(K - finite_difference_stiffness(model, q, 1e-7)).max() < 1e-6 * np.abs(K).max()
    # K_0 from the slot matrices K_a, K_b that the Rayleigh damping beta K_0 is built from
    t = axis / np.linalg.norm(axis)
    axial, bending = reference_stiffness_slots(model.elastic)
    K_0 = np.kron(axial, np.outer(t, t)) + np.kron(bending, np.eye(3) - np.outer(t, t))
    assert np.allclose(K, K_0, rtol=0, atol=1e-9 * np.abs(K).max())


def test_elastic_forces_are_the_energy_gradient_and_objective():
    """eq. 10: Q_el = -dPi/dq (finite differences of eq. 9); Pi and Q_el are invariant (resp. covariant) under
    rigid motions; Q_el has no resultant force or moment."""
    model = build_model(NEEDLE, 4)
    rng = np.random.default_rng(11)
    q = straight(model) + 0.01 * rng.normal(size=model.n_dof)
    Q = elastic_forces(model, q)
    h = 1e-8
    gradient = np.array([(elastic_energy(model, q + h * e) - elastic_energy(model, q - h * e)) / (2 * h)
                         for e in np.eye(model.n_dof)])
    # energy differences of ~1e-8 relative round-off over h: 1e-5 of the largest force
    assert np.abs(Q + gradient).max() < 1e-5 * np.abs(Q).max()
    R, d = rotation([1, 2, 3], 1.2), np.array([0.3, -0.1, 0.2])
    moved = rigidly_moved(q, R, d)
    assert elastic_energy(model, moved) == pytest.approx(elastic_energy(model, q), rel=1e-11)
    assert np.allclose(elastic_forces(model, moved), rigidly_moved(Q, R, np.zeros(3)), atol=1e-9 * np.abs(Q).max())
    nodes, forces = q.reshape(-1, 2, 3), Q.reshape(-1, 2, 3)
    assert np.abs(forces[:, 0].sum(axis=0)).max() < 1e-9 * np.abs(Q).max()
    moment = np.cross(nodes[:, 0], forces[:, 0]).sum(axis=0) + np.cross(nodes[:, 1], forces[:, 1]).sum(axis=0)
    assert np.abs(moment).max() < 1e-9 * np.abs(Q).max()


def test_exact_curvature_and_strain_of_a_circular_arc():
    """Nodes on a circle of radius rho with unit tangents: kappa = 1/rho and eps = 0 up to the cubic interpolation
    error, bending energy EI L / (2 rho^2); the |r_xx| shortcut would be off by the stretch."""
    model = build_model(NEEDLE, 16)
    rho = 0.2
    phi = model.mesh.node_arc_length / rho
    nodes = np.zeros((model.n_nodes, 2, 3))
    nodes[:, 0] = np.column_stack([rho * np.sin(phi), np.zeros_like(phi), rho * (1 - np.cos(phi))])
    nodes[:, 1] = np.column_stack([np.cos(phi), np.zeros_like(phi), np.sin(phi)])
    q = nodes.ravel()
    s = np.linspace(0, NEEDLE.length, 97)
    # cubic Hermite arcs of l = 17 mm on a 200 mm radius: the second derivative of the interpolant errs by
    # ~(l / rho)^2 / 12 = 6e-4 relative, the first (strain) by far less
    assert np.allclose(curvature(model, q, s), 1 / rho, rtol=1e-3)
    assert np.abs(axial_strain(model, q, s)).max() < 2e-6
    bending = 0.5 * NEEDLE.EI * NEEDLE.length / rho**2
    assert elastic_energy(model, q) == pytest.approx(bending, rel=1e-3)
    # the same arc stretched by 1 %: kappa of eq. 8 measures the geometric curvature (1/rho), the shortcut
    # |r_xx| would give 1.01/rho
    stretched = nodes.copy()
    stretched[:, 0] *= 1.01
    stretched[:, 1] *= 1.01
    assert np.allclose(curvature(model, stretched.ravel(), s), 1 / (1.01 * rho), rtol=1e-3)


def test_iteration_matrix_full_and_lower_against_finite_differences():
    """The Newton matrix J = dR/dq of the dynamic residual (elastic, axial strain-rate damping, mass, Rayleigh
    damping) from ``assemble_system`` against central differences of its own residual, with q' and q'' affine in q
    as in a step; the lower-triangle assembly (what the Cholesky reads) equals the full band's lower triangle."""
    model = build_model(NEEDLE, 4, rayleigh_alpha=2.0, rayleigh_beta=1e-3)
    rng = np.random.default_rng(3)
    n, kl = model.n_dof, ELEMENT_BANDWIDTH
    q = straight(model) + 0.01 * rng.normal(size=n)
    qd0, qdd0 = 1e-3 * rng.normal(size=n), 100.0 * rng.normal(size=n)  # slow: the omitted term stays small
    c_M, c_C = 3.0e6, 2.0e3  # dq''/dq, dq'/dq
    tables, axis, active = model_tables(model), np.array([0.6, 0.0, 0.8]), np.ones(n, dtype=bool)
    empty, ext_Q = np.zeros((0, 0)), np.zeros(n)

    def assembled(x: np.ndarray, with_matrix: bool, lower: bool = False) -> tuple[np.ndarray, np.ndarray]:
        residual, band = np.zeros(n), np.zeros((n, band_width_columns(kl)))
        shift = x - q
        assemble_system(x, qd0 + c_C * shift, qdd0 + c_M * shift, tables, axis, ext_Q, empty, 1.0, c_M, c_C, active,
                        residual, band, kl, with_matrix, lower)
        return residual, band

    residual, band = assembled(q, True)
    J = band_to_dense(band, kl)
    h = 1e-7
    differences = np.array([(assembled(q + h * e, False)[0] - assembled(q - h * e, False)[0]) / (2 * h)
                            for e in np.eye(n)]).T
    # the matrix omits the axial damping's q-derivative (damping module docstring): small against c_C beta EA
    assert np.abs(J - differences).max() < 1e-4 * np.abs(J).max()
    lower = assembled(q, True, True)[1]
    assert np.array_equal(assembled(q, False)[0], residual)
    assert np.array_equal(np.tril(band_to_dense(lower, kl)), np.tril(J))


def test_search_right_is_numpys_searchsorted_on_the_right():
    """The compiled bisection of the tissue's per-point loops against NumPy: ties, both ends, NaN."""
    rng = np.random.default_rng(3)
    for size in (0, 1, 2, 7, 500):
        values = np.sort(rng.choice(np.linspace(0.0, 1.0, 11), size))  # repeated values: ties
        for value in (*rng.uniform(-0.2, 1.2, 40), *values[:5], 0.0, 1.0, np.nan):
            assert search_right(values, value) == np.searchsorted(values, value, side="right"), (size, value)
