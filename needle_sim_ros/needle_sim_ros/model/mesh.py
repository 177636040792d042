"""Mesh of ANCF cable elements and the cubic shape functions of seed 000 eq. 4.

Node i carries [r_i (3), r_x,i (3)] of q (6 n_nodes entries); element j has e_j = q[6j : 6j + 12] =
[r_A, r_xA, r_B, r_xB] (eq. 1). "Slots" are the 3-vectors of q (slot 2i: r_i, 2i+1: r_x,i); element j uses slots
2j .. 2j+3, each weighted by one scalar shape function (S = [S1 I3, S2 I3, S3 I3, S4 I3], eq. 4).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit


def shape_functions(xi: np.ndarray, length: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """S_a, dS_a/dx, d2S_a/dx2 (each (..., 4)) at local coordinates xi = 2 x / l - 1 of elements of length l (eq. 4)."""
    xi = np.asarray(xi, dtype=float)
    l = np.broadcast_to(np.asarray(length, dtype=float), xi.shape)
    tables = np.empty((3, xi.size, 4))
    hermite_shapes(np.ascontiguousarray(xi).ravel(), np.ascontiguousarray(l).ravel(), *tables)
    return tuple(table.reshape(*xi.shape, 4) for table in tables)


@njit(cache=True)
def hermite_shapes(xi, length, S, S_x, S_xx):
    """Fill S, S_x, S_xx (k, 4) of eq. 4 at local coordinates xi (k,) of elements of lengths ``length`` (k,)."""
    for k in range(xi.size):
        x, l = xi[k], length[k]
        S[k, 0] = 0.5 - 0.75 * x + 0.25 * x**3
        S[k, 1] = l / 8.0 * (1.0 - x - x**2 + x**3)
        S[k, 2] = 0.5 + 0.75 * x - 0.25 * x**3
        S[k, 3] = l / 8.0 * (-1.0 - x + x**2 + x**3)
        S_x[k, 0] = (-1.5 + 1.5 * x**2) / l
        S_x[k, 1] = 0.25 * (-1.0 - 2.0 * x + 3.0 * x**2)
        S_x[k, 2] = (1.5 - 1.5 * x**2) / l
        S_x[k, 3] = 0.25 * (-1.0 + 2.0 * x + 3.0 * x**2)
        S_xx[k, 0] = 6.0 * x / l**2
        S_xx[k, 1] = (-1.0 + 3.0 * x) / l
        S_xx[k, 2] = -6.0 * x / l**2
        S_xx[k, 3] = (1.0 + 3.0 * x) / l


@dataclass(frozen=True)
class GaussTable:
    """Shape-function values at the Gauss points of every element: arrays (n_elements, n_points, 4); weights
    (n_elements, n_points) already include the Jacobian l/2 (integral over x in [0, l] = sum of weights * f)."""

    S: np.ndarray
    S_x: np.ndarray
    S_xx: np.ndarray
    weights: np.ndarray


def gauss_table(element_lengths: np.ndarray, n_points: int) -> GaussTable:
    """Gauss-Legendre table with n_points per element (seed 000 Sec. II-B: 5 for the axial, 3 for bending)."""
    if not (isinstance(n_points, (int, np.integer)) and 1 <= n_points <= 20):
        raise ValueError(f"number of Gauss points must be an integer in [1, 20], got {n_points!r}")
    xi, w = np.polynomial.legendre.leggauss(int(n_points))
    l = np.asarray(element_lengths, dtype=float)[:, None]
    s, s_x, s_xx = shape_functions(np.broadcast_to(xi, (l.shape[0], xi.size)), l)
    return GaussTable(s, s_x, s_xx, w[None, :] * l / 2.0)


@dataclass(frozen=True)
class Interpolation:
    """Shape-function tables for k material points: element index (k,), S, S_x, S_xx (k, 4), reference arc
    length (k,), the q slots (k, 4) each point reads, and the same tables as dense slot matrices (k, n_slots) for
    fast evaluation: r(s) = sum_a S_a e_a (eq. 3) = P @ q.reshape(-1, 3)."""

    element: np.ndarray
    S: np.ndarray
    S_x: np.ndarray
    S_xx: np.ndarray
    arc_length: np.ndarray
    slots: np.ndarray
    P: np.ndarray
    P_x: np.ndarray
    P_xx: np.ndarray

    def positions(self, q: np.ndarray) -> np.ndarray:
        """r = S e, (k, 3); also velocities (accelerations) when given q' (q'')."""
        return self.P @ np.asarray(q, dtype=float).reshape(-1, 3)

    def gradients(self, q: np.ndarray) -> np.ndarray:
        """r_x = S_x e, (k, 3)."""
        return self.P_x @ np.asarray(q, dtype=float).reshape(-1, 3)

    def second_derivatives(self, q: np.ndarray) -> np.ndarray:
        """r_xx = S_xx e, (k, 3)."""
        return self.P_xx @ np.asarray(q, dtype=float).reshape(-1, 3)


@njit(cache=True)
def interpolate(slots: np.ndarray, S: np.ndarray, x: np.ndarray) -> np.ndarray:
    """sum_a S[k, a] x_slot(k, a) (eq. 3) at each point k of an interpolation table (``Interpolation``: its
    ``slots`` and one of S, S_x, S_xx) of coordinates x in the model layout: r, r_x or r_xx of q, r' of q', (k, 3)."""
    values = np.zeros((slots.shape[0], 3))
    for k in range(slots.shape[0]):
        for a in range(4):
            first = 3 * slots[k, a]
            for i in range(3):
                values[k, i] += S[k, a] * x[first + i]
    return values


@njit(cache=True, inline="always")
def search_right(sorted_values: np.ndarray, value: float) -> int:
    """``np.searchsorted(sorted_values, value, side="right")`` of one value by bisection (NaN last, as NumPy sorts
    it): the segment of an arc length in per-point loops, where numba 0.59's searchsorted costs ~90 ns a call (8x)."""
    if value != value:
        return sorted_values.size
    low, high = 0, sorted_values.size
    while low < high:
        middle = (low + high) >> 1
        if sorted_values[middle] <= value:
            low = middle + 1
        else:
            high = middle
    return low


def clamped_element_lengths(length: float, n_elements: int, intervals) -> np.ndarray:
    """Element lengths [m] of an n_elements mesh with nodes at every clamp interval's ends: one element per clamped
    interval, the others over the free spans in proportion to their lengths. A span held at both ends (base or clamp)
    gets Chebyshev-Lobatto nodes s = a + (b - a)(1 - cos(pi i / k)) / 2, resolving the boundary layers of width
    sqrt(EI / T) at the holds (README, "Wrench accuracy"); a span ending at the free tip keeps equal elements."""
    pairs = sorted((float(a), float(b)) for a, b in intervals)
    if not all(0.0 <= a <= b <= length for a, b in pairs):  # NaN fails too
        raise ValueError(f"clamp intervals {pairs} must satisfy 0 <= s_start <= s_end <= L = {length:g} m")
    spans: list[tuple[float, float, bool]] = []  # (start, end, clamped), covering [0, length]
    covered = 0.0
    for start, end in pairs:
        start, end = max(start, covered), min(end, length)
        if start > covered:
            spans.append((covered, start, False))
        if end > start:
            spans.append((start, end, True))
        covered = max(covered, end)
    if covered < length:
        spans.append((covered, length, False))
    free = [(a, b) for a, b, clamped in spans if not clamped]
    n_clamped = len(spans) - len(free)
    if n_elements < len(spans):
        raise ValueError(f"{n_elements} elements cannot mesh {n_clamped} clamp interval(s) and {len(free)} free "
                         f"span(s): at least {len(spans)} are needed")
    extra = n_elements - n_clamped - len(free)  # elements beyond one per free span, shared by length
    share = np.array([b - a for a, b in free]) / sum(b - a for a, b in free) * extra
    counts = 1 + np.floor(share).astype(int)
    for index in np.argsort(np.floor(share) - share)[:extra - int(np.floor(share).sum())]:  # largest remainders
        counts[index] += 1
    lengths: list[float] = []
    free_counts = iter(counts.tolist())  # the free spans' element counts, in span order
    for start, end, clamped in spans:
        if clamped:
            lengths.append(end - start)
            continue
        k = next(free_counts)
        unit = np.arange(k + 1) / k
        nodes = (1.0 - np.cos(np.pi * unit)) / 2.0 if end < length else unit
        lengths.extend(np.diff(start + (end - start) * nodes))
    return np.array(lengths)


@dataclass(frozen=True)
class Mesh:
    """Element lengths l_j (n_elements,) and reference arc length of each node (n_elements + 1,)."""

    element_lengths: np.ndarray
    node_arc_length: np.ndarray

    @classmethod
    def build(cls, length: float, n_elements: int = 10, element_lengths=None) -> Mesh:
        """Uniform mesh of n_elements, or the given element lengths (they must sum to the needle length)."""
        if element_lengths is None:
            if not (isinstance(n_elements, (int, np.integer)) and n_elements >= 1):
                raise ValueError(f"n_elements must be an integer >= 1, got {n_elements!r}")
            lengths = np.full(int(n_elements), length / n_elements)
        else:
            lengths = np.asarray(element_lengths, dtype=float).ravel()
            if lengths.size == 0 or not np.all(np.isfinite(lengths)) or np.any(lengths <= 0):
                raise ValueError("element_lengths must be a non-empty list of finite lengths > 0 [m]")
            if abs(lengths.sum() - length) > 1e-9 * length:
                raise ValueError(f"element_lengths sum to {float(lengths.sum()):g} m, "
                                 f"not the needle length {length:g} m")
            lengths = lengths * (length / lengths.sum())
        nodes = np.concatenate([[0.0], np.cumsum(lengths)])
        nodes[-1] = length
        return cls(lengths, nodes)

    @property
    def n_elements(self) -> int:
        return self.element_lengths.size

    @property
    def length(self) -> float:
        return float(self.node_arc_length[-1])

    def interpolation(self, arc_lengths) -> Interpolation:
        """Tables for points at reference arc lengths s in [0, L] (a point on a node belongs to the element
        after it, the tip to the last element)."""
        s = np.atleast_1d(np.asarray(arc_lengths, dtype=float)).ravel()
        tol = 1e-9 * self.length
        if not np.all(np.isfinite(s)) or np.any(s < -tol) or np.any(s > self.length + tol):
            raise ValueError(f"arc lengths must lie in [0, {self.length}] m, got range "
                             f"[{np.min(s) if s.size else 0}, {np.max(s) if s.size else 0}]")
        s = np.clip(s, 0.0, self.length)
        element = np.clip(np.searchsorted(self.node_arc_length, s, side="right") - 1, 0, self.n_elements - 1)
        l = self.element_lengths[element]
        xi = np.clip(2.0 * (s - self.node_arc_length[element]) / l - 1.0, -1.0, 1.0)
        shape, shape_x, shape_xx = shape_functions(xi, l)
        slots = 2 * element[:, None] + np.arange(4)[None, :]
        dense = np.zeros((3, s.size, 2 * self.n_elements + 2))
        rows = np.arange(s.size)[:, None]
        for table, values in zip(dense, (shape, shape_x, shape_xx)):
            table[rows, slots] = values
        return Interpolation(element, shape, shape_x, shape_xx, s, slots, *dense)


def slot_matrix(left: np.ndarray, right: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Assemble sum_j int f_a g_b dx over all elements into a (2 n_nodes, 2 n_nodes) scalar matrix on slots (the
    coordinate matrix is kron(result, I3)); left, right: (n_elements, n_points, 4) shape-function tables; weights
    (n_elements, n_points) include l/2 and any coefficient."""
    n_elements = left.shape[0]
    blocks = np.einsum("jg,jga,jgb->jab", weights, left, right)
    matrix = np.zeros((2 * n_elements + 2, 2 * n_elements + 2))
    for j in range(n_elements):
        matrix[2 * j:2 * j + 4, 2 * j:2 * j + 4] += blocks[j]
    return matrix
