"""The offline tools' parameters come from the one parameter layer: the declared defaults, the params files (checked
as they are read) and the command line's overrides (checked once, against the same declarations)."""
from pathlib import Path

import pytest

from needle_common.parameters import ParameterError
from needle_sim_ros.offline.cli import main as offline_main
from needle_sim_ros.parameters.experiment import load_experiment, node_parameters
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def experiment(tmp_path):
    path = tmp_path / "config" / "experiments" / "mine.yaml"
    path.parent.mkdir(parents=True)
    path.write_text("needle_pipeline:\n  ros__parameters:\n    bag: bags/mine.mcap\n"
                    "needle_simulator:\n  ros__parameters:\n    needle.elements: 7\n    integrator.dt: 0.002\n")
    return load_experiment(path, REPO / "config")


def test_defaults_then_files_then_overrides(experiment):
    values = experiment.values("needle_simulator", {"integrator.dt": 5e-4, "use_sim_time": True})
    defaults = {spec.name: spec.default for spec in SIMULATOR_PARAMETERS}
    assert values["needle.elements"] == 7 and values["integrator.dt"] == 5e-4  # the file's; the override's
    assert values["needle.length"] == defaults["needle.length"] and set(values) == set(defaults)
    assert experiment.values("needle_simulator")["integrator.dt"] == 0.002
    assert node_parameters("needle_simulator", {"needle.elements": 6}) == {**defaults, "needle.elements": 6}


def test_overrides_are_checked_against_the_declarations(experiment):
    with pytest.raises(ParameterError, match="needle_simulator: unknown parameter 'needle.lenght' "
                                             r"\(did you mean 'needle.length'\?\)"):
        experiment.values("needle_simulator", {"needle.lenght": 0.2})
    with pytest.raises(ParameterError, match="parameter 'needle.elements' = 0: must be >= 1"):
        experiment.values("needle_simulator", {"needle.elements": 0})
    # the clamp offset's check is needle_common.transforms.unit_quaternion's rule (norm 1 within 1e-6)
    experiment.values("needle_simulator", {"flange_offset.orientation": [0.0, 0.0, 0.6, 0.8 + 5e-7]})
    with pytest.raises(ParameterError, match="'flange_offset.orientation' = .*: must be a unit quaternion"):
        experiment.values("needle_simulator", {"flange_offset.orientation": [0.0, 0.0, 0.6, 0.8 + 5e-6]})


def test_needle_offline_refuses_a_misspelled_override_in_one_line(tmp_path, capsys):
    status = offline_main([str(REPO / "bags" / "insertion.mcap"), "--set", "needle_compare:tolerence=1e-3",
                           "--output-dir", str(tmp_path / "out"), "--quiet"])
    error = capsys.readouterr().err
    assert status == 2 and error.count("\n") == 1 and "did you mean 'tolerance'" in error, error
    assert not (tmp_path / "out").exists()
