"""Rayleigh damping C = alpha M + beta K_0 (seed 000 Sec. II-B, Q_d = -C q'), made objective for large motions.

K_0, the tangent stiffness of the straight reference state along the unit axis t, is
    K_0(t) = kron(K_a, t t^T) + kron(K_b, I - t t^T),   K_a = int EA S_x^T S_x,  K_b = int EI S_xx^T S_xx
(scalar matrices on the q slots, see ``mesh``). Its two parts are applied objectively (why: docs/design_notes.md):
* axial: the Kelvin-Voigt strain-rate form  Q_d,a = -beta int EA (r_x . r_x') S_x^T r_x  (eps' = r_x . r_x'),
  equal to beta kron(K_a, t t^T) q' at the straight state, zero for rigid rotations (evaluated at the axial Gauss
  points with the elastic forces, ``elastic.add_elastic``);
* bending: beta kron(K_b, I - t t^T) q' with t the holder's current axis.
The alpha term damps absolute velocities. For small motions about the straight state C is exactly
alpha M + beta K_0. The Newton matrix omits the axial form's small derivative with respect to q (it stays symmetric).
"""
from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .elastic import ElasticTables
from .mesh import slot_matrix


class DampingTables(NamedTuple):
    """Linear part kron(isotropic, I3) + kron(transverse, t t^T) with isotropic = alpha M_s + beta K_b,
    transverse = -beta K_b; axial strain-rate part with weights beta * EA * w at the axial Gauss points."""

    isotropic: np.ndarray
    transverse: np.ndarray
    strain_rate_weights: np.ndarray


def reference_stiffness_slots(elastic: ElasticTables) -> tuple[np.ndarray, np.ndarray]:
    """Scalar slot matrices K_a = int EA S_x^T S_x, K_b = int EI S_xx^T S_xx."""
    axial = slot_matrix(elastic.axial_S_x, elastic.axial_S_x, elastic.axial_weights)
    bending = slot_matrix(elastic.bending_S_xx, elastic.bending_S_xx, elastic.bending_weights)
    return axial, bending


def damping_tables(mass_slots: np.ndarray, elastic: ElasticTables, alpha: float, beta: float) -> DampingTables:
    for name, value in (("rayleigh_alpha", alpha), ("rayleigh_beta", beta)):
        if not (np.isfinite(value) and value >= 0.0):
            raise ValueError(f"{name} must be finite and >= 0, got {value!r}")
    _, bending = reference_stiffness_slots(elastic)
    return DampingTables(alpha * mass_slots + beta * bending, -beta * bending, beta * elastic.axial_weights)
