"""A user's force law in one module: quadratic (Morison) drag on the needle's shaft, as in a viscous gel.

Force per unit length f = -c |v| v on the centreline's velocity v, lumped to the nodes with their length shares
w_i (half an element at each end, two halves in between): F_i = -c w_i |v_i| v_i. Not in the product; written once
as a compiled kernel, it runs on the general path (sub-stepping, statics) and in the simulator's compiled run of
steps, with no change to the engine (``docs/extending.md``).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from needle_sim_ros.model.contribution import CompiledContribution
from needle_common.parameters import ParamSpec

PARAMETERS = (
    ParamSpec("shaft_drag.coefficient", 0.0, "Quadratic drag coefficient c of the shaft [N s^2/m^3]: force per "
              "length -c |v| v on the centreline's velocity v.", low=0.0),
)


@njit(cache=True)
def drag_assemble(state, q, qd, rotation, Q, band, kl, c_q, c_qd):
    """Q += the nodal drag forces; band += c_qd dQ/dq' (dQ/dq is zero). state: [c, w_0, ..., w_N]."""
    with_matrix = band.shape[0] > 0
    for node in range(state.size - 1):
        row = 6 * node  # node coordinates [r, r_x]: the position's three rows
        v = (qd[row], qd[row + 1], qd[row + 2])
        speed = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])
        k = state[0] * state[node + 1]
        for a in range(3):
            Q[row + a] -= k * speed * v[a]
            if with_matrix and speed > 0.0:  # dF/dv = -k (|v| I + v v^T / |v|)
                for b in range(3):
                    band[row + a, b - a + kl] -= c_qd * k * ((speed if a == b else 0.0) + v[a] * v[b] / speed)
    return True


@njit(cache=True)
def on_base_node(state):
    """The base node's share acts on the base element's rows (the holder feels it directly)."""
    return True


class ShaftDrag(CompiledContribution):
    """The drag law on a needle model (its parameters in ``PARAMETERS``)."""

    assemble = drag_assemble
    touches_base = on_base_node

    def __init__(self, model, coefficient: float) -> None:
        shares = np.zeros(model.n_nodes)
        lengths = model.mesh.element_lengths
        shares[:-1] += 0.5 * lengths
        shares[1:] += 0.5 * lengths
        super().__init__(np.concatenate([[float(coefficient)], shares]))


def shaft_drag_from_parameters(p: dict, model) -> ShaftDrag:
    """The law from validated parameter values (flat dotted names)."""
    return ShaftDrag(model, p["shaft_drag.coefficient"])
