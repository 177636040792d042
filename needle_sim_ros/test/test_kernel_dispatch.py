"""The general step's kernels are called with arguments numba types in C (Ubuntu 24.04's numba 0.59 too).

numba 0.59 types a tuple argument in Python on every call from Python: with the model's nine constant tables
passed as a tuple, each Newton call cost 10-60 us more and the general step ran at 104 us against 40 us on the
newer numba (issue 38). ``model_tables`` is therefore one array. This test fails on numba 0.59 with a tuple there
(and passes either way on numba >= 0.60, which types tuples in C)."""
import math

import pytest
from numba.core.dispatcher import Dispatcher

from needle_sim_ros.compiled_advance import AdvancePlan
from needle_sim_ros.model import BaseMotion, Gravity, build_model, needle_properties
from needle_sim_ros.model.newton import model_tables, unpack_tables
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import NeedleSimulation, model_builder_from_parameters, simulation_from_parameters
from needle_sim_ros.tissue.factory import build_tissue_model

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}


def pitching(t: float) -> BaseMotion:
    angle = math.radians(5.0) * math.sin(math.pi * t)
    return BaseMotion((0.0, 0.0, 0.0), (0.0, math.sin(0.5 * angle), 0.0, math.cos(0.5 * angle)))


def typed_in_python(monkeypatch) -> list[str]:
    """The arguments numba types in Python from now on ("kernel: type"), collected into the returned list."""
    typed: list[str] = []
    original = Dispatcher.typeof_pyval

    def counting(self, value):
        typed.append(f"{self.py_func.__name__}: {type(value).__name__}")
        return original(self, value)
    monkeypatch.setattr(Dispatcher, "typeof_pyval", counting)
    return typed


@pytest.mark.parametrize("compiled", [False, True])
def test_the_general_step_and_the_compiled_run_type_no_argument_in_python(compiled, monkeypatch):
    model, integrator = model_builder_from_parameters(PARAMETERS)()
    simulation = NeedleSimulation.prescribed(model, integrator, 1e-3, pitching,
                                             model.straight_state(pitching(0.0)), [Gravity()])
    simulation.compiled_sequence = compiled
    simulation.advance_to(0.01)  # compiled or loaded, and every dispatcher's first call made
    typed = typed_in_python(monkeypatch)
    records = []
    for k in range(40):  # one run per step, as the live loop at the pose rate
        records += simulation.advance_to(0.011 + 1e-3 * k)
    assert len(records) == 40 and not typed, sorted(set(typed))


def pose_and_advance(simulation: NeedleSimulation, k: int) -> list:
    """The node's pose k (1 kHz, a pitching flange) and its advance."""
    angle = math.radians(5.0) * math.sin(math.pi * k * 1e-3)
    simulation.offer_pose(k * 1e-3, [0.0, 0.0, 0.0], [0.0, math.sin(0.5 * angle), 0.0, math.cos(0.5 * angle)])
    return simulation.advance(k * 1e-3, deterministic=True)


def test_the_node_path_from_the_poses_types_no_argument_in_python(monkeypatch):
    """The live loop's one compiled call per pose (``compiled_advance``: the trajectory's fit, the twist, the
    offset and the steps), as the node drives it at 1 kHz."""
    simulation = simulation_from_parameters(PARAMETERS)
    for k in range(20):
        pose_and_advance(simulation, k)
    typed = typed_in_python(monkeypatch)
    records = []
    for k in range(20, 60):
        records += pose_and_advance(simulation, k)
    assert len(records) == 40 and not typed, sorted(set(typed))


def test_the_node_paths_compiled_call_types_its_plan_once(monkeypatch):
    """The node path calls the compiled advance for its plan's types (``compiled_entry``): the dispatcher, which
    reads the plan record's ``_numba_type_`` on every call (~0.6 us: no C fingerprint for a record), types it once
    per plan, not per pose."""
    simulation = simulation_from_parameters(PARAMETERS)
    for k in range(20):
        pose_and_advance(simulation, k)
    reads = []
    numba_type = AdvancePlan._numba_type_
    monkeypatch.setattr(AdvancePlan, "_numba_type_", property(lambda plan: reads.append(1) or numba_type.fget(plan)))
    records = []
    for k in range(20, 60):
        records += pose_and_advance(simulation, k)
    assert len(records) == 40 and not reads
    simulation.set_point_load("new plan", 0.2, [0.0, 0.0, -0.01])
    assert pose_and_advance(simulation, 60) and reads  # a new plan is typed (once)


def test_the_tissue_run_types_no_argument_in_python(monkeypatch):
    """Through the tissue (the shaft, the bevel and the track cut): one compiled run per step, no tuple of the
    tissue's state or constants typed in Python (before: 2 per run, 7440 per 15 334 steps of an insertion)."""
    model, integrator = model_builder_from_parameters(PARAMETERS)()
    velocity = 0.01

    def inserting(t: float) -> BaseMotion:
        return BaseMotion((velocity * t, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0), linear_velocity=(velocity, 0.0, 0.0))
    tissue = build_tissue_model({**{n: v for n, v in PARAMETERS.items() if n.startswith("tissue.")},
                                 "tissue.enable": True, "tissue.entry_point": [0.272, 0.0, 0.0]}, model)
    simulation = NeedleSimulation.prescribed(model, integrator, 1e-3, inserting,
                                             model.straight_state(inserting(0.0)), [tissue])
    simulation.advance_to(0.05)
    typed = typed_in_python(monkeypatch)
    records = []
    for k in range(950):
        records += simulation.advance_to(0.051 + 1e-3 * k)
    assert len(records) == 950 and not typed, sorted(set(typed))
    assert simulation.data.force_states[0].records[0].punctured  # the run went through the tissue


@pytest.mark.parametrize("n_elements", [1, 3, 10])
def test_the_packed_tables_are_the_models_arrays(n_elements):
    model = build_model(needle_properties(PARAMETERS), n_elements)
    expected = (*model.elastic, model.mass_slots, *model.damping)
    unpacked = unpack_tables(model_tables(model))
    assert len(unpacked) == len(expected)
    for mine, theirs in zip(unpacked, expected):
        assert mine.shape == theirs.shape and (mine == theirs).all()
