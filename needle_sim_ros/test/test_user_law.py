"""A user's force law written once (``docs/examples/shaft_drag.py``, not in the product) runs on the general path
and in the simulator's compiled run, each checked against the closed form of a needle dragged sideways at constant
speed v through a medium of quadratic drag c: in steady state every point moves with the base, the drag is a
uniform load q = c v^2 per length, the holder carries F = -q L (along the motion's opposite) and the moment
M = -q L^2 / 2 about A (about the axis normal to the needle and the motion), and the tip trails the base by
q L^4 / (8 E I) (Euler-Bernoulli cantilever under a uniform load)."""
import importlib.util
import sys
from pathlib import Path

import pytest

from needle_sim_ros.model import BaseMotion, Integrator
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
from needle_sim_ros.simulation import NeedleSimulation, model_builder_from_parameters
from needle_sim_ros.tissue.factory import build_tissue_model

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "examples" / "shaft_drag.py"
PARAMETERS = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
SPEED, COEFFICIENT, SECONDS = 0.1, 3.0, 1.0  # [m/s], [N s^2/m^3]: q = 0.03 N/m, ~1 mm tip lag


def example():
    """The example module, imported from its file (registered as a module: numba's cache refers to it by name)."""
    if "shaft_drag" not in sys.modules:
        spec = importlib.util.spec_from_file_location("shaft_drag", EXAMPLE)
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
    return sys.modules["shaft_drag"]


def moving(t: float) -> BaseMotion:
    return BaseMotion((0.0, SPEED * t, 0.0), (0.0, 0.0, 0.0, 1.0), linear_velocity=(0.0, SPEED, 0.0))


def drag(law_module, model, share: float = 1.0):
    (coefficient,) = law_module.PARAMETERS
    return law_module.shaft_drag_from_parameters({coefficient.name: coefficient.validate(share * COEFFICIENT)}, model)


def untouched_tissue(model):
    """The shipped tissue with its entry surface 1 m beyond the tip: stateful, advanced every step, never reached."""
    tissue = {name: value for name, value in PARAMETERS.items() if name.startswith("tissue.")}
    return build_tissue_model({**tissue, "tissue.enable": True, "tissue.entry_point": [1.3, 0.0, 0.0]}, model)


COMPOSITIONS = {  # the contributions besides gravity, from the model and the example module
    "drag": lambda law, model: [drag(law, model)],
    "tissue and drag": lambda law, model: [untouched_tissue(model), drag(law, model)],
    "drag split in two around the tissue": lambda law, model: [drag(law, model, 1 / 3), untouched_tissue(model),
                                                                drag(law, model, 2 / 3)],
}


@pytest.mark.parametrize("compiled", [False, True])
@pytest.mark.parametrize("composition", COMPOSITIONS)
def test_the_users_drag_law_holds_the_closed_form_on_both_paths(composition, compiled, monkeypatch):
    """Compiled: one run composes every contribution (2 or 3 of them with the tissue, stateful or not)."""
    model, integrator = model_builder_from_parameters(PARAMETERS)()
    forces = COMPOSITIONS[composition](example(), model)
    simulation = NeedleSimulation.prescribed(model, integrator, 1e-3, moving, model.straight_state(moving(0.0)),
                                             forces)
    simulation.compiled_sequence = compiled
    general = []
    step = Integrator.step
    monkeypatch.setattr(Integrator, "step", lambda *args, **kwargs: general.append(1) or step(*args, **kwargs))
    records = simulation.advance_to(SECONDS)
    steps = round(SECONDS * 1e3)
    assert len(records) == steps
    assert len(general) == (1 if compiled else steps)  # compiled: all but the first step (no accelerations yet)
    if compiled:
        assert simulation.stepper._run_plan.contributions == tuple(forces)
    load, length = COEFFICIENT * SPEED**2, model.props.length
    wrench = records[-1].wrench
    assert wrench.force_world[1] == pytest.approx(-load * length, rel=1e-4)
    assert wrench.torque_world[2] == pytest.approx(-load * length**2 / 2.0, rel=1e-3)
    tip_lag = simulation.state.q[-5] - SPEED * SECONDS
    assert tip_lag == pytest.approx(-load * length**4 / (8.0 * model.props.EI), rel=0.02)
