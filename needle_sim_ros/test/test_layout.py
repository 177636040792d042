"""The package layout of issue 12: one ROS-free core per node, which the node and the offline stage both call.

``offline/`` never imports ``nodes/`` and ``nodes/`` never imports ``offline/`` (read from each file's syntax tree),
and the cores import neither rclpy nor any ROS message package, not even through other modules (checked by
importing them in a fresh interpreter in which those imports fail).
"""
import ast
import json
import subprocess
import sys
from pathlib import Path

import pytest

import needle_sim_ros

PACKAGE = Path(needle_sim_ros.__file__).parent  # the installed package: what the executables run
#: The ROS-free cores (packages and single modules of needle_sim_ros), as the README lists them.
ROS_FREE = ("model", "tissue", "identification", "simulation", "stepper", "clock_loop", "base_input", "base_trajectory",
            "comparison",
            "parameters", "recording", "scenarios", "launch_support", "messages.geometry", "messages.cdr")
#: Distributions of ROS 2 itself (the message packages are recognised by their suffixes).
ROS_PACKAGES = ("rclpy", "rcl_interfaces", "builtin_interfaces", "rosidl_runtime_py", "rpyutils")
ROS_SUFFIXES = ("_msgs", "_srvs", "_interfaces")


def imported_modules(source: str, package: str) -> set[str]:
    """Absolute names of the modules a source file of ``package`` imports, anywhere in it (relative imports
    resolved against the package)."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = package.rsplit(".", node.level - 1)[0] if node.level else ""
            module = ".".join(part for part in (base, node.module or "") if part)
            names |= {module} | {f"{module}.{alias.name}" for alias in node.names}
    return names


@pytest.mark.parametrize("importer, forbidden", [("offline", "needle_sim_ros.nodes"),
                                                 ("nodes", "needle_sim_ros.offline")])
def test_offline_and_nodes_do_not_import_each_other(importer, forbidden):
    files = sorted((PACKAGE / importer).glob("*.py"))
    assert files
    offending = {path.name: sorted(name for name in imported_modules(path.read_text(), f"needle_sim_ros.{importer}")
                                   if name == forbidden or name.startswith(forbidden + "."))
                 for path in files}
    assert {path: names for path, names in offending.items() if names} == {}


#: The simulator's layers, top down (issue 38): each imports none of the ones above it, and none imports the tissue.
SIMULATION_LAYERS = ("simulation", "base_input", "clock_loop", "stepper")


@pytest.mark.parametrize("layer", SIMULATION_LAYERS[1:])
def test_a_base_pose_goes_down_the_simulation_layers_without_climbing_back(layer):
    above = SIMULATION_LAYERS[:SIMULATION_LAYERS.index(layer)]
    forbidden = {f"needle_sim_ros.{name}" for name in above} | {"needle_sim_ros.tissue"}
    names = imported_modules((PACKAGE / f"{layer}.py").read_text(), "needle_sim_ros")
    assert sorted(name for name in names if any(name == f or name.startswith(f + ".") for f in forbidden)) == []


def test_imported_modules_sees_absolute_relative_and_nested_imports():
    # the checker itself must see every form of import the rule forbids
    source = "from ..nodes import runner\nfrom . import stages\ndef f():\n    import needle_sim_ros.nodes.bringup\n"
    assert imported_modules(source, "needle_sim_ros.offline") == {
        "needle_sim_ros.nodes", "needle_sim_ros.nodes.runner", "needle_sim_ros.offline",
        "needle_sim_ros.offline.stages", "needle_sim_ros.nodes.bringup"}


BLOCKING_IMPORTER = """
import importlib, json, pkgutil, sys
ROS, SUFFIXES = {ros!r}, {suffixes!r}

class BlockRos:
    def find_spec(self, name, path=None, target=None):
        top = name.split(".")[0]
        if top in ROS or top.endswith(SUFFIXES):
            raise ImportError(f"ROS module {{name}} imported")
        return None

sys.meta_path.insert(0, BlockRos())
failures = {{}}
for core in {cores!r}:
    names = ["needle_sim_ros." + core]
    try:
        module = importlib.import_module(names[0])
        if hasattr(module, "__path__"):
            names += [m.name for m in pkgutil.walk_packages(module.__path__, names[0] + ".")]
        for name in names:
            importlib.import_module(name)
    except ImportError as error:
        failures[core] = str(error)
print(json.dumps(failures))
"""


def blocked_import_failures(cores) -> dict[str, str]:
    script = BLOCKING_IMPORTER.format(ros=ROS_PACKAGES, suffixes=ROS_SUFFIXES, cores=tuple(cores))
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads(result.stdout.strip().splitlines()[-1])


def test_the_cores_import_no_ros():
    assert blocked_import_failures(ROS_FREE) == {}


def test_the_ros_blocker_catches_ros_imports():
    # the nodes and the message builders do use ROS: the same check must flag them
    failures = blocked_import_failures(("nodes", "messages.shape", "offline"))
    assert set(failures) == {"nodes", "messages.shape", "offline"}
    assert all("ROS module" in reason for reason in failures.values())


def test_the_compare_node_records_exactly_the_declared_topics():
    from needle_sim_ros.nodes.compare_node import LOGGABLE
    from needle_sim_ros.parameters.compare import LOGGABLE_TOPICS
    assert tuple(LOGGABLE) == LOGGABLE_TOPICS


def test_the_integrator_methods_offered_are_the_integrators(capsys):
    """needle_simulator's integrator.method and needle_scenario free_vibration --method offer model.integrators'."""
    from needle_sim_ros.model.integrators import METHODS
    from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
    from needle_sim_ros.scenarios.cli import main
    assert next(s for s in SIMULATOR_PARAMETERS if s.name == "integrator.method").choices == METHODS
    with pytest.raises(SystemExit):
        main(["free_vibration", "--help"])
    assert f"--method {{{','.join(METHODS)}}}" in capsys.readouterr().out


def test_every_qos_parameter_offers_the_profiles_of_the_one_mapping():
    """The QoS parameters of the three nodes offer needle_common's QOS_CHOICES, which qos_profile maps."""
    from rclpy.qos import ReliabilityPolicy

    from needle_common.parameters import QOS_CHOICES
    from needle_common.ros.ros_parameters import qos_profile
    from needle_sim_ros.parameters.compare import COMPARE_PARAMETERS
    from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
    from needle_vision.parameters import SPECS
    qos = [spec for spec in (*SIMULATOR_PARAMETERS, *COMPARE_PARAMETERS, *SPECS) if "qos" in spec.name]
    assert len(qos) == 5 and all(spec.choices == QOS_CHOICES for spec in qos), qos
    assert [qos_profile(name, 100).reliability for name in QOS_CHOICES] == [ReliabilityPolicy.BEST_EFFORT,
                                                                            ReliabilityPolicy.RELIABLE]


@pytest.mark.parametrize("quaternion", [[0.0, 0.0, 0.0, 1.0], [0.0, 0.0, 0.0, 2e-9], [0.0, 0.0, 0.0, 5e-10],
                                        [0.0, 0.0, 0.0, 0.0], [float("nan"), 0.0, 0.0, 1.0], [float("inf"), 0, 0, 1]])
def test_the_quaternion_parameters_accept_what_the_transform_takes(quaternion):
    """needle_compare's extrinsic.rotation and needle_stereo's output_transform: the quaternions that
    RigidTransform.from_xyz_quaternion (which both build) takes, no more, no less."""
    from needle_common.parameters import ParameterError
    from needle_common.transforms import RigidTransform
    from needle_sim_ros.parameters.compare import COMPARE_PARAMETERS
    from needle_vision.parameters import SPECS

    def accepted(call) -> bool:
        try:
            call()
        except (ValueError, ParameterError):
            return False
        return True
    takes = accepted(lambda: RigidTransform.from_xyz_quaternion([0.0, 0.0, 0.0, *quaternion]))
    specs = {spec.name: spec for spec in (*COMPARE_PARAMETERS, *SPECS)}
    assert accepted(lambda: specs["extrinsic.rotation"].validate(quaternion)) == takes
    assert accepted(lambda: specs["output_transform"].validate([0.0, 0.0, 0.0, *quaternion])) == takes
