"""Rayleigh damping C = alpha M + beta K_0 (seed 000 Sec. II-B, Q_d = -C q'), made objective for large motions.

K_0 is the tangent stiffness of the unstressed straight reference state.  For a straight needle along the unit
axis t, the analytic Jacobian of eqs. 12-13 reduces to
    K_0(t) = kron(K_a, t t^T) + kron(K_b, I - t t^T),   K_a = int EA S_x^T S_x,  K_b = int EI S_xx^T S_xx
(scalar matrices on the q slots, see ``mesh``).  Taken literally with a constant t, the axial part damps every
rotation of the gradients r_x away from t -- under large deflections that is a spurious dissipation scaled by the
huge E A (a needle vibrating with 10 mm tip amplitude lost 99 % of its energy in 10 periods instead of 38 %).
So the two parts are applied objectively:
* axial: the Kelvin-Voigt strain-rate form  Q_d,a = -beta int EA (r_x . r_x') S_x^T r_x  (eps' = r_x . r_x'),
  which equals beta kron(K_a, t t^T) q' at the straight state and vanishes for any rigid rotation (evaluated at
  the axial Gauss points with the elastic forces, ``elastic.add_elastic``);
* bending: beta kron(K_b, I - t t^T) q' with t the current axis of the holder (the reference state turns with the
  holder, so rigid motions of the straight needle are not damped).  For a deformed needle this linear part is not
  exactly free of a net moment (of order beta EI kappa omega: ~4e-7 N m for a 10 mm tip vibration with
  beta = 1e-4) -- negligible next to the elastic moments, but visible in an exact momentum balance.
The alpha term damps absolute velocities (a viscous drag on the whole needle).  For small motions about the
straight state C is exactly alpha M + beta K_0.  In the Newton matrix the small derivative of the axial form with
respect to q (relative size |r_x'| h against its q' derivative) is omitted, which keeps the matrix symmetric.
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
