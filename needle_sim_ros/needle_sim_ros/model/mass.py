"""Constant consistent mass matrix of seed 000 eq. 7, M_j = rho A int S^T S dx, assembled over shared nodes (eq. 16)."""
from __future__ import annotations

import numpy as np

from .mesh import Mesh, gauss_table, slot_matrix

# S_a S_b is a polynomial of degree 6 in x: 4 Gauss points integrate it exactly.
MASS_GAUSS_POINTS = 4


def mass_slot_matrix(mesh: Mesh, mass_per_length: float) -> np.ndarray:
    """Scalar (2 n_nodes)^2 factor of the mass matrix: M = kron(result, I3) (S = [S_a I3], eq. 4)."""
    table = gauss_table(mesh.element_lengths, MASS_GAUSS_POINTS)
    return slot_matrix(table.S, table.S, mass_per_length * table.weights)
