"""Tissue geometry: a block of planar layers in the world frame, and the depth and inserted interval of a needle.

The entry surface is the plane through ``entry_point`` with unit normal ``entry_normal`` into the tissue; layers
follow along the normal with given thicknesses (the last may be infinite), laterally unbounded. A point's depth is
``n . (r - p0)``; the needle's insertion depth is its tip's.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from needle_sim_ros.model.mesh import search_right

# Per-layer parameter names (all SI), in config and in TissueLayer; in this order the rows of the kernels' table.
LAYER_PARAMETERS = {
    "thickness": "layer thickness along the entry normal [m] (.inf for the last layer)",
    "lateral_stiffness": "Winkler foundation stiffness: lateral force per unit length per unit offset [N/m^2]",
    "lateral_damping": "lateral damping per unit length [N s/m^2]",
    "friction_coulomb": "Karnopp Coulomb friction per unit inserted length C_n [N/m] (seed 001 eq. 2: 6)",
    "friction_viscous": "Karnopp viscous friction per unit length b_n [N s/m^2] (seed 001 eq. 2: 120)",
    "tip_stiffness": "bevel-tip tissue property K_T [N/m^2] (seed 001 eqs. 4-5: 9.42e3)",
}
ROW = {name: row for row, name in enumerate(LAYER_PARAMETERS)}
LATERAL_ROWS = np.array([ROW["lateral_stiffness"], ROW["lateral_damping"]])
FRICTION_ROWS = np.array([ROW["friction_coulomb"], ROW["friction_viscous"]])
TIP_STIFFNESS_ROW = ROW["tip_stiffness"]


@dataclass(frozen=True)
class TissueLayer:
    """One layer; parameters as in ``LAYER_PARAMETERS``."""

    thickness: float
    lateral_stiffness: float
    lateral_damping: float
    friction_coulomb: float
    friction_viscous: float
    tip_stiffness: float

    def __post_init__(self) -> None:
        for name in LAYER_PARAMETERS:
            value = getattr(self, name)
            if np.isnan(value) or value < 0.0 or (name != "thickness" and not np.isfinite(value)):
                raise ValueError(f"tissue layer parameter {name} must be >= 0 (and finite), got {value!r}")
        if self.thickness <= 0.0:
            raise ValueError(f"tissue layer thickness must be > 0, got {self.thickness!r}")


@dataclass(frozen=True, eq=False)
class TissueBlock:
    """Planar layered tissue block: entry_point (3,) [m], entry_normal (3,) (normalised here), layers."""

    entry_point: np.ndarray
    entry_normal: np.ndarray
    layers: tuple[TissueLayer, ...]

    def __post_init__(self) -> None:
        point = np.asarray(self.entry_point, dtype=float)
        normal = np.asarray(self.entry_normal, dtype=float)
        if point.shape != (3,) or not np.all(np.isfinite(point)):
            raise ValueError(f"tissue entry_point must be 3 finite values, got {self.entry_point!r}")
        norm = np.linalg.norm(normal) if normal.shape == (3,) else 0.0
        if not np.isfinite(norm) or norm < 1e-12:
            raise ValueError(f"tissue entry_normal must be a non-zero 3-vector, got {self.entry_normal!r}")
        if not self.layers:
            raise ValueError("tissue needs at least one layer")
        object.__setattr__(self, "entry_point", point)
        object.__setattr__(self, "entry_normal", normal / norm)
        object.__setattr__(self, "_bottoms", np.cumsum([layer.thickness for layer in self.layers]))
        table = np.array([[getattr(layer, name) for layer in self.layers] + [0.0] for name in LAYER_PARAMETERS])
        object.__setattr__(self, "kernel_tables", (self._bottoms, table))

    @property
    def thickness(self) -> float:
        """Total thickness [m] (inf if the last layer is unbounded)."""
        return float(self._bottoms[-1])

    def depth(self, points) -> np.ndarray:
        """Depth below the entry surface [m] of points (..., 3); negative outside, above the surface."""
        return (np.asarray(points, dtype=float) - self.entry_point) @ self.entry_normal

    def inside(self, depth) -> np.ndarray:
        depth = np.asarray(depth, dtype=float)
        return (depth > 0.0) & (depth < self.thickness)

    def layer_index(self, depth) -> np.ndarray:
        """Index of the layer containing each depth; ``len(layers)`` outside the block."""
        flat = np.ascontiguousarray(depth, dtype=float).reshape(-1)
        return _layer_index(self._bottoms, flat).reshape(np.shape(depth))


def inserted_interval(block: TissueBlock, points: np.ndarray, arc_length: np.ndarray) -> tuple[float, float]:
    """Reference arc-length interval (s_entry, s_tip) of the needle below the entry surface, from centerline samples
    ``points`` (n, 3) base to tip and their ``arc_length`` (n,): s_entry is the last crossing before the tip (linear
    between samples); (s_tip, s_tip) if the tip is not below the surface."""
    depth = block.depth(points)
    s_tip = float(arc_length[-1])
    if depth[-1] <= 0.0:
        return s_tip, s_tip
    outside = np.flatnonzero(depth <= 0.0)
    if outside.size == 0:
        return float(arc_length[0]), s_tip
    i = outside[-1]
    fraction = depth[i] / (depth[i] - depth[i + 1])          # depth[i] <= 0 < depth[i+1]
    return float(arc_length[i] + fraction * (arc_length[i + 1] - arc_length[i])), s_tip


@njit(cache=True)
def layer_rows(bottoms, table, depth, rows):
    """Rows ``rows`` of the layer ``table`` (``TissueBlock.kernel_tables``) at each depth (n,): (len(rows), n),
    0 outside the block."""
    index = _layer_index(bottoms, depth)
    values = np.empty((rows.size, depth.size))
    for r in range(rows.size):
        for k in range(depth.size):
            values[r, k] = table[rows[r], index[k]]
    return values


@njit(cache=True)
def layer_row(bottoms, table, depth, row):
    """Row ``row`` of the layer table at one depth (0 outside the block)."""
    index = search_right(bottoms, depth) if depth > 0.0 else bottoms.size
    return table[row, index]


@njit(cache=True)
def _layer_index(bottoms, depth):
    index = np.searchsorted(bottoms, depth, side="right")
    for k in range(depth.size):
        if not depth[k] > 0.0:
            index[k] = bottoms.size
    return index
