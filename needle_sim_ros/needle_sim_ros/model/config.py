"""Needle configuration from a ROS 2 parameters file (``/**: ros__parameters: {needle: ..., damping: ...}``): only
the groups ``needle.``, ``damping.``, ``integrator.`` and ``fixtures.`` are read, and an unknown key inside them is
an error (a typo cannot fall back to a default).
"""
from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from needle_common.parameters import flatten_tree, parameter_tree

from .fixtures import Fixture
from .integrators import METHODS
from .properties import NeedleProperties

GROUPS = ("needle", "damping", "integrator", "fixtures")

# seed 000 Sec. III needle; AISI 304 stainless steel (E = 193 GPa, rho = 8000 kg/m^3, AK Steel / ASM datasheet)
DEFAULTS: dict[str, Any] = {
    "needle.length": 0.27,
    "needle.radius": 0.635e-3,
    "needle.inner_radius": 0.0,
    "needle.youngs_modulus": 193e9,
    "needle.density": 8000.0,
    "needle.elements": 10,
    "needle.element_lengths": [0.0],  # [0.0] (or [] / null in a file): needle.elements uniform elements
    "needle.gravity": [0.0, 0.0, -9.81],
    "needle.axial_gauss_points": 2,   # reduced axial integration: locking-free (README "Needle model")
    "needle.bending_gauss_points": 3,
    "damping.rayleigh_alpha": 0.0,
    "damping.rayleigh_beta": 1e-4,
    "integrator.method": "generalized_alpha",
    "integrator.rho_inf": 0.8,
    "integrator.dt": 1e-3,
    "integrator.newton_tolerance": 1e-6,
    "integrator.max_newton_iterations": 10,
    "integrator.max_substep_halvings": 4,
    "fixtures.intervals": None,
    "fixtures.frame": "world",
    "fixtures.needle_position": [0.0, 0.0, 0.0],
    "fixtures.needle_orientation": [0.0, 0.0, 0.0, 1.0],
    # needle_simulator only (read by the node, ignored here): [s_start, s_end] clamped where the needle lies when
    # it starts; [0.0] = none
    "fixtures.clamp_interval": [0.0],
    # needle_simulator only: (re)start at rest in static equilibrium (the scenarios set their own initial states)
    "needle.start_in_equilibrium": True,
}


def needle_parameters(source) -> dict[str, Any]:
    """All needle/damping/integrator/fixtures parameters (flat dotted names), defaults filled in."""
    flat = flatten_tree(parameter_tree(source))
    ours = {k: v for k, v in flat.items() if k.split(".", 1)[0] in GROUPS}
    unknown = sorted(set(ours) - set(DEFAULTS))
    if unknown:
        raise ValueError(f"unknown needle config key(s) {unknown}; known: {sorted(DEFAULTS)}")
    return {**DEFAULTS, **ours}


def _fixtures(p: Mapping[str, Any]) -> tuple[Fixture, ...]:
    intervals = p["fixtures.intervals"]
    if intervals is None:
        return ()
    values = np.asarray(intervals, dtype=float).ravel()
    if values.size % 2:
        raise ValueError(f"fixtures.intervals must hold pairs [s_start, s_end, ...] in m, got {intervals!r}")
    pose = (tuple(p["fixtures.needle_position"]), tuple(p["fixtures.needle_orientation"]))
    return tuple(Fixture(interval=(a, b), frame=p["fixtures.frame"], needle_pose=pose)
                 for a, b in values.reshape(-1, 2))


def element_lengths(p: Mapping[str, Any]) -> list[float] | None:
    """The mesh's element lengths [m] from ``needle.element_lengths``, or None for ``needle.elements`` uniform ones
    (the value [0.0], [] or null)."""
    value = p.get("needle.element_lengths")
    return None if value is None or list(value) in ([], [0.0]) else [float(length) for length in value]


def needle_properties(p: Mapping[str, Any]) -> NeedleProperties:
    """NeedleProperties from the flat ``needle.*`` parameters."""
    return NeedleProperties(length=p["needle.length"], radius=p["needle.radius"],
                            youngs_modulus=p["needle.youngs_modulus"], density=p["needle.density"],
                            gravity=tuple(p["needle.gravity"]), inner_radius=p["needle.inner_radius"])


def load_needle_config(source) -> tuple[NeedleProperties, dict[str, Any], dict[str, Any]]:
    """(NeedleProperties, build_model kwargs incl. n_elements, Integrator kwargs) from a params file or dict.
    The time step is ``needle_parameters(source)["integrator.dt"]``."""
    p = needle_parameters(source)
    if p["integrator.method"] not in METHODS:
        raise ValueError(f"integrator.method must be one of {METHODS}, got {p['integrator.method']!r}")
    props = needle_properties(p)
    build = {"n_elements": int(p["needle.elements"]), "axial_gauss": int(p["needle.axial_gauss_points"]),
             "bending_gauss": int(p["needle.bending_gauss_points"]),
             "rayleigh_alpha": float(p["damping.rayleigh_alpha"]), "rayleigh_beta": float(p["damping.rayleigh_beta"]),
             "fixtures": _fixtures(p)}
    if (lengths := element_lengths(p)) is not None:
        build["element_lengths"] = lengths
    dt = float(p["integrator.dt"])
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"integrator.dt must be > 0 [s], got {p['integrator.dt']!r}")
    integrator = {"method": p["integrator.method"], "rho_inf": float(p["integrator.rho_inf"]),
                  "newton_tol": float(p["integrator.newton_tolerance"]),
                  "max_newton_iterations": int(p["integrator.max_newton_iterations"]),
                  "max_substep_halvings": int(p["integrator.max_substep_halvings"])}
    return props, build, integrator
