"""Independent reference for bevel-tip needle insertion (no needle_sim_ros code): a quasi-static Euler-Bernoulli
beam on a Winkler foundation with path memory, Hermite cubic elements, scipy.sparse assembly and solve.

Geometry (geometrically linear, small lateral deflection w(s) in one or two lateral directions): the needle of
length L is clamped at its base s = 0 (w = w' = 0) and lies along the entry axis; the tip is at s = L.  At insertion
depth d the tissue occupies the last d of the needle, s in [L - d, L]; the needle point at s is at depth
p = s - (L - d) below the surface.  Path memory (Glozman & Shoham's virtual springs; seed 001 Sec. II, forces only
from "previously cut" tissue): the tissue point at depth p rests at y_rest(p), the lateral tip position when the tip
was at depth p.  A needle point in cut tissue feels the Winkler load -k (w(s) - y_rest(p)) per unit length
[k in N/m^2]; the cut front (depths the tip has not cut before) carries no spring.  The bevel force Q (seed 001
eq. 5) acts laterally at the tip; the axial bevel force P (eq. 4) optionally enters as a compressive axial force
along the whole needle (geometric stiffness) applied at the tip either as a dead load or as a follower along the
tip tangent (lateral component -P w'(L)).

Quasi-static incremental insertion (``insert``): at each depth d_n the beam is solved with springs over the depths
cut up to d_{n-1}; the new tip deflection then becomes y_rest(d_n) (y_rest is piecewise linear between steps).
"""
from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from typing import Callable

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

_GAUSS_X, _GAUSS_W = np.polynomial.legendre.leggauss(4)


def hermite_shapes(xi: np.ndarray, h: float) -> np.ndarray:
    """Hermite cubic shape functions (..., 4) for the element dofs (w_a, w'_a, w_b, w'_b) at xi in [0, 1]."""
    return np.stack([1.0 - 3.0 * xi**2 + 2.0 * xi**3, h * (xi - 2.0 * xi**2 + xi**3),
                     3.0 * xi**2 - 2.0 * xi**3, h * (xi**3 - xi**2)], axis=-1)


def bending_matrix(bending_stiffness: float, h: float) -> np.ndarray:
    """Euler-Bernoulli element stiffness EI/h^3 [[12, 6h, -12, 6h], ...] (4, 4)."""
    return bending_stiffness / h**3 * np.array([[12.0, 6.0 * h, -12.0, 6.0 * h],
                                                [6.0 * h, 4.0 * h**2, -6.0 * h, 2.0 * h**2],
                                                [-12.0, -6.0 * h, 12.0, -6.0 * h],
                                                [6.0 * h, 2.0 * h**2, -6.0 * h, 4.0 * h**2]])


def geometric_matrix(axial_force: float, h: float) -> np.ndarray:
    """Consistent geometric stiffness N/(30h) [[36, 3h, -36, 3h], ...] for a tensile axial force N (4, 4)."""
    return axial_force / (30.0 * h) * np.array([[36.0, 3.0 * h, -36.0, 3.0 * h],
                                                [3.0 * h, 4.0 * h**2, -3.0 * h, -h**2],
                                                [-36.0, -3.0 * h, 36.0, -3.0 * h],
                                                [3.0 * h, -h**2, -3.0 * h, 4.0 * h**2]])


@dataclass(frozen=True)
class WinklerNeedle:
    """Clamped needle beam on a path-memory Winkler foundation.

    length: L [m].  bending_stiffness: EI [N m^2].  foundation_modulus: k [N/m^2].  n_elements: Hermite elements.
    axial_compression: P [N] compressing the whole needle (0 ignores it).  follower: P follows the tip tangent
    (adds the lateral tip force -P w'(L)) instead of staying along the entry axis.
    """

    length: float
    bending_stiffness: float
    foundation_modulus: float
    n_elements: int = 400
    axial_compression: float = 0.0
    follower: bool = False

    def __post_init__(self) -> None:
        for name in ("length", "bending_stiffness"):
            if not getattr(self, name) > 0.0:
                raise ValueError(f"WinklerNeedle.{name} must be > 0, got {getattr(self, name)!r}")
        if not self.foundation_modulus >= 0.0:
            raise ValueError(f"WinklerNeedle.foundation_modulus must be >= 0, got {self.foundation_modulus!r}")
        if self.n_elements < 1:
            raise ValueError(f"WinklerNeedle.n_elements must be >= 1, got {self.n_elements!r}")

    @property
    def arc_length(self) -> np.ndarray:
        """Node arc lengths s [m] (n_elements + 1,)."""
        return np.linspace(0.0, self.length, self.n_elements + 1)

    def solve(self, depth: float, cut_depth: float, rest_depth: np.ndarray, rest_position: np.ndarray,
              tip_force: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Static deflection w and slope w' at the nodes, each (n_nodes, n_dir).

        depth: inserted length d [m] (0 <= d <= L).  cut_depth: springs act on depths p in [0, min(cut_depth, d)].
        rest_depth (m,), rest_position (m, n_dir): y_rest(p) knots, linear in between (constant beyond the ends).
        tip_force: lateral tip force per direction (n_dir,) [N].
        """
        n, h = self.n_elements, self.length / self.n_elements
        tip_force = np.atleast_1d(np.asarray(tip_force, dtype=float))
        rest_position = np.asarray(rest_position, dtype=float).reshape(len(rest_depth), tip_force.size)
        element_matrix = bending_matrix(self.bending_stiffness, h) - geometric_matrix(self.axial_compression, h)
        matrices = np.broadcast_to(element_matrix, (n, 4, 4)).copy()
        loads = np.zeros((n, 4, tip_force.size))

        surface = self.length - depth
        start = np.maximum(self.arc_length[:-1], surface)
        stop = np.minimum(self.arc_length[1:], surface + min(cut_depth, depth))
        touching = np.flatnonzero(stop > start)
        if touching.size and self.foundation_modulus > 0.0:
            half = 0.5 * (stop[touching] - start[touching])[:, None]
            s = 0.5 * (start[touching] + stop[touching])[:, None] + half * _GAUSS_X
            weight = self.foundation_modulus * half * _GAUSS_W
            shapes = hermite_shapes((s - self.arc_length[touching, None]) / h, h)
            matrices[touching] += np.einsum("eg,egi,egj->eij", weight, shapes, shapes)
            rest = np.stack([np.interp(s - surface, rest_depth, rest_position[:, j])
                             for j in range(tip_force.size)], axis=-1)
            loads[touching] += np.einsum("eg,egi,egd->eid", weight, shapes, rest)

        dofs = 2 * np.arange(n)[:, None] + np.arange(4)
        rows = np.broadcast_to(dofs[:, :, None], (n, 4, 4)).ravel()
        cols = np.broadcast_to(dofs[:, None, :], (n, 4, 4)).ravel()
        n_dofs = 2 * (n + 1)
        values = matrices.ravel()
        if self.follower:  # lateral part of the follower tip force -P w'(L), moved to the left-hand side
            rows, cols = np.append(rows, n_dofs - 2), np.append(cols, n_dofs - 1)
            values = np.append(values, self.axial_compression)
        stiffness = sp.coo_matrix((values, (rows, cols)), shape=(n_dofs, n_dofs))
        rhs = np.zeros((n_dofs, tip_force.size))
        np.add.at(rhs, dofs.ravel(), loads.reshape(-1, tip_force.size))
        rhs[-2] += tip_force
        free = slice(2, n_dofs)  # clamped base: w(0) = w'(0) = 0
        solution = np.zeros_like(rhs)
        solution[free] = spsolve(stiffness.tocsc()[free, free], rhs[free]).reshape(-1, tip_force.size)
        return solution[0::2], solution[1::2]


@dataclass(frozen=True)
class Insertion:
    """Result of ``insert``: depth (n,) [m], tip lateral deflection (n, n_dir) [m], nodal shapes (n, nodes, n_dir)
    [m] at the node arc lengths ``arc_length`` (nodes,) [m]."""

    depth: np.ndarray
    tip_deflection: np.ndarray
    shape: np.ndarray
    arc_length: np.ndarray

    @property
    def tip_distance(self) -> np.ndarray:
        """The tip's distance from the entry axis (n,) [m]."""
        return np.linalg.norm(self.tip_deflection, axis=1)


def insertion_depths(final_depth: float, step: float, fine_step: float | None = None,
                     fine_until: float = 0.0) -> np.ndarray:
    """Depths 0 .. ``final_depth`` [m]: steps of ``fine_step`` up to ``fine_until``, then of about ``step``."""
    if not 0.0 < final_depth:
        raise ValueError(f"final_depth must be > 0, got {final_depth!r}")
    coarse = np.linspace(0.0, final_depth, int(np.ceil(final_depth / step - 1e-9)) + 1)
    if fine_step is None or fine_until <= 0.0:
        return coarse
    fine = np.arange(0.0, min(fine_until, final_depth), fine_step)
    return np.concatenate([fine, coarse[coarse >= min(fine_until, final_depth)]])


def insert(needle: WinklerNeedle, depths: np.ndarray, bevel_force: Callable[[float], np.ndarray]) -> Insertion:
    """Quasi-static insertion through ``depths`` [m] (0 first, increasing, <= L).

    bevel_force(depth) -> lateral tip force per direction (n_dir,) [N] at that depth.  Each step springs act on the
    depths cut before it (path memory), then the tip position is recorded as the rest position of the new depth.
    """
    depths = np.asarray(depths, dtype=float)
    if depths[0] != 0.0 or np.any(np.diff(depths) <= 0.0) or depths[-1] > needle.length:
        raise ValueError("depths must start at 0, increase strictly and stay <= the needle length")
    tips, shapes = [], []
    for i, depth in enumerate(depths):
        rest = np.array(tips) if tips else np.zeros((1, np.size(bevel_force(depth))))
        w, _ = needle.solve(depth, depths[i - 1] if i else 0.0, depths[:i] if i else np.zeros(1), rest,
                            bevel_force(depth))
        tips.append(w[-1])
        shapes.append(w)
    return Insertion(depths, np.array(tips), np.array(shapes), needle.arc_length)


# --- the issue 13 validation case -------------------------------------------------------------------------------

@dataclass(frozen=True)
class ValidationCase:
    """Issue 13's insertion case: 18 G brachytherapy tube in seed 001's PVC phantom (SI units, angles in rad)."""

    length: float
    outer_diameter: float
    inner_diameter: float
    youngs_modulus: float
    tissue_youngs_modulus: float
    tissue_poisson_ratio: float
    tip_stiffness: float
    bevel_angle: float
    acting_fraction: float
    insertion_speed: float
    final_depth: float

    @property
    def second_moment(self) -> float:
        """I = pi (D^4 - D_i^4) / 64 [m^4]."""
        return np.pi * (self.outer_diameter**4 - self.inner_diameter**4) / 64.0

    @property
    def bending_stiffness(self) -> float:
        """EI [N m^2]."""
        return self.youngs_modulus * self.second_moment

    @property
    def winkler_modulus(self) -> float:
        """Vesic's modulus of subgrade reaction times the width B = D (per unit length, N/m^2):
        k = 0.65 (E_s B^4 / (E I))^(1/12) E_s / (1 - nu_s^2)  (A. B. Vesic, "Bending of beams resting on isotropic
        elastic solid", J. Eng. Mech. Div. ASCE 87(EM2), 35-53, 1961; its limits of validity are discussed in his
        "Beams on elastic subgrade and the Winkler's hypothesis", Proc. 5th ICSMFE, Paris, 1961)."""
        es, nu = self.tissue_youngs_modulus, self.tissue_poisson_ratio
        ratio = es * self.outer_diameter**4 / self.bending_stiffness
        return 0.65 * ratio ** (1.0 / 12.0) * es / (1.0 - nu**2)

    @property
    def edge_a(self) -> float:
        """Bevel edge a = D / tan(lambda) [m]: the bevel's length along the needle axis (seed 001 Fig. 2 reading)."""
        return self.outer_diameter / np.tan(self.bevel_angle)

    @property
    def edge_b(self) -> float:
        """Bevel edge b = D / sin(lambda) [m]: the length of the inclined bevel face (seed 001 Fig. 2 reading)."""
        return self.outer_diameter / np.sin(self.bevel_angle)

    def _tan_difference(self) -> float:
        lam, beta = self.bevel_angle, self.acting_fraction * self.bevel_angle
        return (np.tan(lam) - np.tan(beta)) / (1.0 + np.tan(lam) * np.tan(beta))

    @property
    def axial_bevel_force(self) -> float:
        """P of seed 001 eq. 4 [N]: K_T b^2/2 sin(lambda) (tan lambda - tan beta)/(1 + tan lambda tan beta)."""
        return 0.5 * self.tip_stiffness * self.edge_b**2 * np.sin(self.bevel_angle) * self._tan_difference()

    @property
    def transverse_bevel_force(self) -> float:
        """Q of seed 001 eq. 5 [N]: K_T b^2/2 cos(lambda) (...) - K_T a^2/2 tan(beta), beta = (beta/lambda) lambda."""
        beta = self.acting_fraction * self.bevel_angle
        return (0.5 * self.tip_stiffness * self.edge_b**2 * np.cos(self.bevel_angle) * self._tan_difference()
                - 0.5 * self.tip_stiffness * self.edge_a**2 * np.tan(beta))

    def needle(self, n_elements: int = 400, with_axial_force: bool = False) -> WinklerNeedle:
        """The reference beam; ``with_axial_force`` adds P (eq. 4) as a follower compression."""
        return WinklerNeedle(self.length, self.bending_stiffness, self.winkler_modulus, n_elements,
                             self.axial_bevel_force if with_axial_force else 0.0, with_axial_force)


def validation_case() -> ValidationCase:
    """Issue 13: 18 G tube (OD 1.27 mm, ID 0.838 mm), 0.26 m, E 200 GPa, no gravity; seed 001's phantom
    (E_s 76 kPa, nu 0.34, Sec. V-B) and bevel (K_T 9.42e3 N/m^2, beta/lambda 0.2, lambda 30 deg); 6 mm/s to 90 mm."""
    return ValidationCase(length=0.26, outer_diameter=1.27e-3, inner_diameter=0.838e-3, youngs_modulus=200e9,
                          tissue_youngs_modulus=76e3, tissue_poisson_ratio=0.34, tip_stiffness=9.42e3,
                          bevel_angle=np.deg2rad(30.0), acting_fraction=0.2, insertion_speed=6e-3,
                          final_depth=0.09)


def rolled_bevel_force(transverse_force: float, roll_depth: float = np.inf, roll: float = np.pi,
                       bevel_length: float = 0.0) -> Callable[[float], np.ndarray]:
    """Bevel force in two lateral directions: Q along the first until ``roll_depth`` [m], then turned by the base
    roll ``roll`` [rad] (pi flips Q's sign from that depth on, pi/2 turns the bending plane).

    bevel_length > 0: while the bevel enters (depth < a) only the embedded fraction f = depth/a of its edges a and
    b carries the triangular load of eqs. 4-5, so Q scales with f^2; 0 applies the full Q from depth 0 on.
    """
    def force(depth: float) -> np.ndarray:
        angle = roll if depth >= roll_depth else 0.0
        engaged = min(depth / bevel_length, 1.0) ** 2 if bevel_length > 0.0 else 1.0
        return engaged * transverse_force * np.array([np.cos(angle), np.sin(angle)])
    return force


def reference_insertion(case: ValidationCase, roll_depth: float = np.inf, roll: float = np.pi,
                        bevel_engagement: bool = True, with_axial_force: bool = False,
                        n_elements: int = 400, step: float = 2.5e-4) -> Insertion:
    """The case's reference insertion to ``case.final_depth``; base roll ``roll`` [rad] at ``roll_depth`` [m].

    bevel_engagement: Q grows as (depth/a)^2 while the bevel enters (``rolled_bevel_force``), else full Q at the
    surface (the needle then enters bent as a free cantilever, Q L^3/(3 EI)).  Steps of ``step`` [m], ten times
    finer over the first 3 a, where the tip deflection is set.
    """
    bevel_length = case.edge_a if bevel_engagement else 0.0
    depths = insertion_depths(case.final_depth, step, 0.1 * step, 3.0 * case.edge_a)
    return insert(case.needle(n_elements, with_axial_force), depths,
                  rolled_bevel_force(case.transverse_bevel_force, roll_depth, roll, bevel_length))


def plot_tip_deflection(path: str, depth: np.ndarray, deflection: np.ndarray, label: str = "Winkler reference",
                        overlays: tuple[tuple[np.ndarray, np.ndarray, str], ...] = ()) -> None:
    """Seed 001 Fig. 4-style plot, tip deflection [mm] against insertion depth [mm], to ``path`` (PNG, written to
    a temporary name and renamed).  overlays: further (depth [m], deflection [m], label) curves, e.g. the ANCF."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6.0, 4.0))
    axes.plot(1e3 * np.asarray(depth), 1e3 * np.asarray(deflection), "k-", label=label)
    for markers, (other_depth, other_deflection, other_label) in zip("o^sv", overlays):
        axes.plot(1e3 * np.asarray(other_depth), 1e3 * np.asarray(other_deflection), markers + "--", markevery=0.1,
                  label=other_label)
    axes.set_xlabel("insertion depth [mm]")
    axes.set_ylabel("tip deflection [mm]")
    axes.grid(True, alpha=0.3)
    axes.legend()
    figure.tight_layout()
    directory = os.path.dirname(os.path.abspath(path))
    handle, temporary = tempfile.mkstemp(suffix=".png", dir=directory)
    os.close(handle)
    try:
        figure.savefig(temporary, dpi=120)
        os.replace(temporary, path)
    except BaseException:
        os.unlink(temporary)
        raise
    finally:
        plt.close(figure)


def reference_table(case: ValidationCase, depths: tuple[float, ...] = (0.03, 0.06, 0.09)) -> str:
    """Text table of the case's parameters and reference tip deflections at ``depths`` [m]."""
    half = 0.5 * case.final_depth
    runs = {"Q engaged": reference_insertion(case),
            "+P follower": reference_insertion(case, with_axial_force=True),
            "roll 180 at half": reference_insertion(case, roll_depth=half),
            "full Q at surface": reference_insertion(case, bevel_engagement=False),
            "full Q, roll 180": reference_insertion(case, roll_depth=half, bevel_engagement=False)}
    lines = [f"EI = {case.bending_stiffness:.6g} N m^2, k (Vesic) = {case.winkler_modulus:.6g} N/m^2, "
             f"lambda_w = {(case.winkler_modulus / (4 * case.bending_stiffness)) ** 0.25:.4g} 1/m",
             f"a = {case.edge_a * 1e3:.4f} mm, b = {case.edge_b * 1e3:.4f} mm, beta = "
             f"{np.rad2deg(case.acting_fraction * case.bevel_angle):.3g} deg, "
             f"P (eq. 4) = {case.axial_bevel_force * 1e3:.4f} mN, "
             f"Q (eq. 5) = {case.transverse_bevel_force * 1e3:.4f} mN",
             "tip lateral deflection [mm] (signed, along the initial bevel side)",
             f"{'depth [mm]':>10} | " + " | ".join(f"{name:>17}" for name in runs)]
    for depth in depths:
        values = [run.tip_deflection[np.argmin(np.abs(run.depth - depth)), 0] for run in runs.values()]
        lines.append(f"{depth * 1e3:10.1f} | " + " | ".join(f"{1e3 * v:17.4f}" for v in values))
    return "\n".join(lines)


if __name__ == "__main__":
    import sys

    CASE = validation_case()
    print(reference_table(CASE))
    if len(sys.argv) > 1:  # optional PNG path for the Fig. 4-style plot of the engaged-bevel reference
        RUN = reference_insertion(CASE)
        plot_tip_deflection(sys.argv[1], RUN.depth, RUN.tip_distance)
