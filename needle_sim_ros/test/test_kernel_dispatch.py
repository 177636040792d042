"""The general step's kernels are called with arguments numba types in C (Ubuntu 24.04's numba 0.59 too).

numba 0.59 types a tuple argument in Python on every call from Python: with the model's nine constant tables
passed as a tuple, each Newton call cost 10-60 us more and the general step ran at 104 us against 40 us on the
newer numba (issue 38). ``model_tables`` is therefore one array. This test fails on numba 0.59 with a tuple there
(and passes either way on numba >= 0.60, which types tuples in C)."""
import math

import pytest
from numba.core.dispatcher import Dispatcher

from needle_sim_ros.model import BaseMotion, Gravity, build_model
from needle_sim_ros.model.newton import model_tables, unpack_tables
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import NeedleSimulation, model_builder_from_parameters, needle_properties

PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}


def pitching(t: float) -> BaseMotion:
    angle = math.radians(5.0) * math.sin(math.pi * t)
    return BaseMotion((0.0, 0.0, 0.0), (0.0, math.sin(0.5 * angle), 0.0, math.cos(0.5 * angle)))


def test_the_general_step_types_no_argument_in_python(monkeypatch):
    model, integrator = model_builder_from_parameters(PARAMETERS)()
    simulation = NeedleSimulation.prescribed(model, integrator, 1e-3, pitching,
                                             model.straight_state(pitching(0.0)), [Gravity()])
    simulation.compiled_sequence = False
    simulation.advance_to(0.01)  # compiled or loaded, and every dispatcher's first call made
    typed_in_python: list[str] = []
    original = Dispatcher.typeof_pyval

    def counting(self, value):
        typed_in_python.append(f"{self.py_func.__name__}: {type(value).__name__}")
        return original(self, value)
    monkeypatch.setattr(Dispatcher, "typeof_pyval", counting)
    records = simulation.advance_to(0.05)
    assert len(records) == 40 and not typed_in_python, sorted(set(typed_in_python))


@pytest.mark.parametrize("n_elements", [1, 3, 10])
def test_the_packed_tables_are_the_models_arrays(n_elements):
    model = build_model(needle_properties(PARAMETERS), n_elements)
    expected = (*model.elastic, model.mass_slots, *model.damping)
    unpacked = unpack_tables(model_tables(model))
    assert len(unpacked) == len(expected)
    for mine, theirs in zip(unpacked, expected):
        assert mine.shape == theirs.shape and (mine == theirs).all()
