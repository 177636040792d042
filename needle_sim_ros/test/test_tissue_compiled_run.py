"""The tissue's compiled run of steps (its ``model.step`` composition) against the general step (``data.step`` with
``TissueModel.advance``): the same needle states, wrenches and tissue states (bit for bit with requirements.lock,
to the last bits with noble's numpy/numba, see RATE_TOLERANCE) for every axial law,
through the capsule puncture and the bevel's engagement; and the track projection's pruned search against a
brute-force projection."""
import sys

import numpy as np
import pytest

from needle_sim_ros.model.contribution import ContributionRun
from needle_sim_ros.model.step import Kernels
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import model_builder_from_parameters, simulation_from_parameters
from needle_sim_ros.tissue.contact import CONTACT_KERNELS
from needle_sim_ros.tissue.factory import build_tissue_model
from needle_sim_ros.tissue.shaft_force import SHAFT_KERNELS
from needle_sim_ros.tissue.tip_forces import BEVEL_KERNELS, RESISTANCE_KERNELS
from needle_sim_ros.tissue.tissue_model import TissueModel, TissueState
from needle_sim_ros.tissue.track import project_on_polyline

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
LAWS = {
    "karnopp": {},
    "none": {"tissue.shaft.axial_model": "none"},
    "insertion_profile": {"tissue.shaft.axial_model": "insertion_profile", "tissue.insertion_profile.enable": True},
    "lugre": {"tissue.shaft.axial_model": "lugre", "tissue.insertion_profile.enable": True},
}


def pose(t: float) -> tuple[list, list]:
    """Inserting at 10 mm/s from t = 0.1 s while swaying 1 mm sideways and rolling the bevel by 20 deg."""
    roll = np.deg2rad(20.0) * np.sin(2.0 * np.pi * t)
    return ([0.01 * max(t - 0.1, 0.0), 1e-3 * np.sin(2.0 * np.pi * t), 0.0],
            [np.sin(0.5 * roll), 0.0, 0.0, np.cos(0.5 * roll)])


def insert(compiled: bool, overrides: dict, monkeypatch, seconds: float = 1.2):
    """The simulator with tissue (entry 6 mm before the needle's tip: 5 mm inserted at the end), driven by poses at
    1 kHz; the general step only unless ``compiled``. Returns the simulation, its records and the number of
    general tissue advances."""
    sim = simulation_from_parameters({**PARAMETERS, "tissue.enable": True, "tissue.entry_point": [0.272, 0.0, 0.0],
                                      **overrides})
    sim.compiled_sequence = compiled
    calls = []
    advance = TissueModel.advance
    monkeypatch.setattr(TissueModel, "advance", lambda *args: calls.append(1) or advance(*args))
    records = []
    for k in range(int(round(seconds * 1e3))):
        sim.offer_pose(k * 1e-3, *pose(k * 1e-3))
        records += sim.advance(k * 1e-3, deterministic=True)
    return sim, records, len(calls)


# The two paths run the same compiled functions in the same order; with numpy 2.5 / numba 0.68 (requirements.lock) and
# kernels compiled alike they agree bit for bit. They differ in the last bits from some step on where the rounding
# differs: with noble's numpy 1.26 / numba 0.59 on the seed 002 tip cases (wrenches <= 1.4e-10 relative, q 2e-15,
# rates 5e-10, accelerations 7.5e-9), and on either lock when some kernels were loaded from numba's cache and others
# compiled in the process (a cached kernel differs from a fresh compile of the same source in the last bits: 5.5e-17 m
# of insertion depth from step 800; Karnopp's wrench then 1.22e-9 relative at the end). The stiff axial modes amplify
# one rounding. Bounds: 1e-8 relative for positions and wrenches, 1e-6 for rates and accelerations (a 1e-4 relative
# change of the stick stiffness, bevel angle or acting fraction on one path moves the wrench by 2.9e-5, 4.5e-3 and
# 7.6e-6); every discrete part of the tissue state (puncture, cut front, track vertices, active points) the same.
RATE_TOLERANCE, VALUE_TOLERANCE = 1e-6, 1e-8


def relative_difference(a, b) -> float:
    """max |a - b| over max |a|, |b| of the finite entries (0 for zeros); inf if a non-finite entry differs (equal
    infinities, e.g. a contact's "none yet" sentinel, and NaNs at the same places count as equal)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    finite = np.isfinite(a) & np.isfinite(b)
    if not np.array_equal(a[~finite], b[~finite], equal_nan=True):
        return np.inf
    a, b = a[finite], b[finite]
    scale = max(np.abs(a).max(initial=0.0), np.abs(b).max(initial=0.0))
    return float(np.abs(a - b).max(initial=0.0) / scale) if scale > 0.0 else 0.0


@pytest.mark.parametrize("law", LAWS)
def test_the_compiled_run_is_the_general_step(law, monkeypatch):
    general, general_records, general_advances = insert(False, LAWS[law], monkeypatch)
    compiled, compiled_records, compiled_advances = insert(True, LAWS[law], monkeypatch)
    contact = general.data.force_states[0].records[0]
    assert contact.punctured and contact.arc[-1] > 4e-3 and contact.at_front  # it cut its way in
    assert general_advances == len(general_records) > 1000 and compiled_advances <= 2  # the paths taken
    for a, b in zip(general_records, compiled_records, strict=True):
        assert a.t == b.t
        assert relative_difference(a.wrench.force_base, b.wrench.force_base) <= VALUE_TOLERANCE
        assert relative_difference(a.wrench.torque_base, b.wrench.torque_base) <= VALUE_TOLERANCE
    assert relative_difference(general.state.q, compiled.state.q) <= VALUE_TOLERANCE
    for name in ("qd", "qdd", "aux"):
        assert relative_difference(getattr(general.state, name), getattr(compiled.state, name)) <= RATE_TOLERANCE
    assert_same(general.data.force_states, compiled.data.force_states, RATE_TOLERANCE)
    assert relative_difference(general.tissue_readout().tip_force,
                               compiled.tissue_readout().tip_force) <= VALUE_TOLERANCE


def test_a_hook_on_every_step_keeps_the_tissue_steps_compiled(monkeypatch):
    """With a hook reading every step's state (the node in simulated time) and poses at 100 Hz (10 steps per
    advance), the tissue's compiled run takes one step at a time, every step (before: every other step took the
    general path), and the hook sees each step once, in order."""
    sim = simulation_from_parameters({**PARAMETERS, "tissue.enable": True, "tissue.entry_point": [0.272, 0.0, 0.0]})
    calls, seen = [], []
    advance = TissueModel.advance
    monkeypatch.setattr(TissueModel, "advance", lambda *args: calls.append(1) or advance(*args))
    sim.after_step = lambda record: seen.append((record.t, sim.state.t))
    records = []
    for k in range(0, 600, 10):
        sim.offer_pose(k * 1e-3, *pose(k * 1e-3))
        records += sim.advance(k * 1e-3, deterministic=True)
    assert len(records) == 590 and sim.data.force_states[0].records[0].punctured
    assert len(calls) <= 2  # the first step (no consistent accelerations yet) and nothing else
    assert seen == [(record.t, record.t) for record in records]


def test_the_run_composes_the_tissue_parts_directly():
    """The simulator's compiled run imports each enabled tissue part's kernels itself, one level (before: the
    tissue's own composed module, nested inside the run)."""
    model, _ = model_builder_from_parameters(PARAMETERS)(())
    config = {name: value for name, value in PARAMETERS.items() if name.startswith("tissue.")}
    tissue = build_tissue_model({**config, "tissue.enable": True, "tissue.insertion_profile.enable": True}, model)
    run = sys.modules[ContributionRun([tissue]).run.py_func.__module__]
    for k, kernels in enumerate((CONTACT_KERNELS, SHAFT_KERNELS, BEVEL_KERNELS, RESISTANCE_KERNELS)):
        for role, function in zip(Kernels._fields, kernels):
            assert getattr(run, f"{role}_{k}") is function, (role, k)


def assert_same(a, b, tolerance: float = 0.0, path: str = "force_states") -> None:
    """Equal values all the way down (tuples, objects' attributes, arrays with their dtypes and shapes, numbers);
    floating-point values within ``tolerance`` relative (:func:`relative_difference`), all others exactly."""
    assert type(a) is type(b), path
    if isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, path
        if a.dtype.kind == "f":
            assert relative_difference(a, b) <= tolerance, path
        else:
            assert np.array_equal(a, b), path
    elif isinstance(a, (tuple, list)):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, tolerance, f"{path}[{i}]")
    elif isinstance(a, dict):
        assert a.keys() == b.keys(), path
        for key in a:
            assert_same(a[key], b[key], tolerance, f"{path}.{key}")
    elif isinstance(a, TissueState):  # field by field
        assert_same(a.records, b.records, tolerance, path)
    elif hasattr(a, "__slots__"):  # the track
        assert_same(a.__reduce__()[1], b.__reduce__()[1], tolerance, path)
    elif hasattr(a, "__dict__"):
        assert_same(vars(a), vars(b), tolerance, path)
    elif isinstance(a, float):
        assert a == b or (a != a and b != b) or relative_difference(a, b) <= tolerance, path
    else:
        assert a == b or (a != a and b != b), path


def brute_force_projection(vertices: np.ndarray, arc: np.ndarray, end_tangent: np.ndarray, point: np.ndarray):
    """Closest distance and coordinate of a point on the polyline and its continuation, by checking every
    segment with numpy (independent of the compiled search)."""
    end = vertices[-1]
    beyond = max((point - end) @ end_tangent, 0.0)
    candidates = [(np.linalg.norm(point - end - beyond * end_tangent), arc[-1] + beyond)]
    for j in range(len(vertices) - 1):
        a, b = vertices[j], vertices[j + 1]
        length2 = (b - a) @ (b - a)
        fraction = np.clip((point - a) @ (b - a) / length2, 0.0, 1.0) if length2 > 0 else 0.0
        candidates.append((np.linalg.norm(point - a - fraction * (b - a)), arc[j] + fraction * (arc[j + 1] - arc[j])))
    return min(candidates, key=lambda candidate: candidate[0])


def test_the_pruned_track_projection_finds_the_closest_point():
    rng = np.random.default_rng(3)
    for trial in range(150):
        n = int(rng.integers(1, 120))
        steps = rng.normal(size=(n - 1, 3)) * 1e-4 + np.array([1e-4, 0.0, 0.0]) * (trial % 3)
        steps[rng.random(n - 1) < 0.1] = 0.0                    # repeated vertices
        vertices = np.vstack([np.zeros(3), np.cumsum(steps, axis=0)])
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(steps, axis=1))])
        end_tangent = rng.normal(size=3)
        end_tangent /= np.linalg.norm(end_tangent)
        points = vertices[rng.integers(0, n, 8)] + rng.normal(size=(8, 3)) * 10.0 ** rng.uniform(-7, -2)
        coordinate, distance = project_on_polyline(vertices, arc, end_tangent, points)
        for k, point in enumerate(points):
            best_distance, best_coordinate = brute_force_projection(vertices, arc, end_tangent, point)
            assert distance[k] == pytest.approx(best_distance, rel=1e-9, abs=1e-15)
            assert coordinate[k] == pytest.approx(best_coordinate, rel=1e-9, abs=1e-12)
