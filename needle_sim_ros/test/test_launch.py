"""The launch files (share/needle_sim_ros/launch): their arguments, the files and executables they name, and the
launch-time choices (needle_sim_ros.launch_support).

``launch``/``launch_ros`` are not on PyPI: the launch descriptions are loaded only where they are installed (a
stock ROS 2 install); everywhere, the files are checked at the syntax-tree level against the installed package.
"""
import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from ament_index_python.packages import get_package_prefix, get_package_share_directory

from needle_sim_ros.launch_support import (exit_error, experiment_file, failed_transition, flag, full_namespace,
                                           image_codec, image_transport, mode_settings, namespaced_params_file,
                                           player_arguments, unique_log_path)

SHARE = Path(get_package_share_directory("needle_sim_ros"))
LAUNCH_FILES = {"bringup.launch.py": {"mode", "bag", "keep_alive", "experiment", "stereo", "compare", "log",
                                      "log_dir", "pose_topic", "pose_frame", "wrench_topic", "haptic_topic",
                                      "namespace", "configure", "activate", "image_transport", "image_codec"},
                "needle_pipeline.launch.py": {"bag", "experiment", "stereo", "image_transport", "log", "log_dir"}}
SOURCE_CONFIG = Path(__file__).resolve().parents[2] / "config"


def tree(name: str) -> ast.Module:
    return ast.parse((SHARE / "launch" / name).read_text(), filename=name)


def declared_arguments(module: ast.Module) -> set[str]:
    """Names of the argument tables (ARGUMENTS/FORWARDED = {name: (default, description)}) turned into
    DeclareLaunchArgument, and of literal DeclareLaunchArgument("name", ...) calls."""
    names = set()
    for node in ast.walk(module):
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Dict) and \
                any(isinstance(t, ast.Name) and t.id in ("ARGUMENTS", "FORWARDED") for t in node.targets):
            names |= {key.value for key in node.value.keys}
        if isinstance(node, ast.Call) and getattr(node.func, "id", "") == "DeclareLaunchArgument" and \
                node.args and isinstance(node.args[0], ast.Constant):
            names.add(node.args[0].value)
    return names


@pytest.mark.parametrize("name", sorted(LAUNCH_FILES))
def test_launch_file_declares_its_arguments_and_uses_current_api(name):
    module = tree(name)
    assert declared_arguments(module) == LAUNCH_FILES[name]
    used = {n.id for n in ast.walk(module) if isinstance(n, ast.Name)} | \
           {a.name for n in ast.walk(module) if isinstance(n, ast.ImportFrom) for a in n.names}
    assert not used & {"LaunchConfigurationEquals", "LaunchConfigurationNotEquals"}, "deprecated conditions"
    text = (SHARE / "launch" / name).read_text()
    assert '"qos.wrench": "reliable"' not in text, "the wrench QoS comes from the config"


@pytest.mark.parametrize("name", sorted(LAUNCH_FILES))
def test_files_and_executables_named_by_a_launch_file_are_installed(name):
    module = tree(name)
    constants = [n.value for n in ast.walk(module) if isinstance(n, ast.Constant) and isinstance(n.value, str)]
    # a file is installed by the package that owns it (needle_stereo.yaml: needle_vision)
    shares = [SHARE, Path(get_package_share_directory("needle_vision"))]
    for match in (re.search(r"([\w.]+\.(?:yaml|launch\.py))$", c) for c in constants):
        if match:
            folder = "config" if match.group(1).endswith(".yaml") else "launch"
            assert any((share / folder / match.group(1)).is_file() for share in shares), \
                f"{name} names {match.group(1)}: not installed"
    for call in (n for n in ast.walk(module) if isinstance(n, ast.Call)):
        keywords = {k.arg: k.value.value for k in call.keywords if isinstance(k.value, ast.Constant)}
        if "executable" in keywords:
            package = keywords["package"]
            executable = Path(get_package_prefix(package)) / "lib" / package / keywords["executable"]
            assert executable.is_file(), f"{name}: {package} {keywords['executable']} is not installed"


def test_launch_descriptions_load_where_launch_is_installed():
    launch = pytest.importorskip("launch", reason="launch/launch_ros are not on PyPI: install ROS 2 Jazzy "
                                 "(ros-jazzy-launch-ros) to load the launch descriptions")
    pytest.importorskip("launch_ros", reason="launch_ros is not installed (ros-jazzy-launch-ros)")
    from launch.actions import DeclareLaunchArgument
    from launch.launch_description_sources import get_launch_description_from_python_launch_file
    for name, arguments in LAUNCH_FILES.items():
        description = get_launch_description_from_python_launch_file(str(SHARE / "launch" / name))
        assert isinstance(description, launch.LaunchDescription)
        declared = {e.name for e in description.entities if isinstance(e, DeclareLaunchArgument)}
        assert declared == arguments


def test_experiment_argument_takes_a_name_or_a_path(tmp_path):
    assert experiment_file("", SOURCE_CONFIG) == ""
    by_name = experiment_file("dynamic_pitch", SOURCE_CONFIG)
    assert by_name == str((SOURCE_CONFIG / "experiments" / "dynamic_pitch.yaml").resolve())
    assert experiment_file(by_name, SOURCE_CONFIG) == by_name
    with pytest.raises(ValueError, match="launch argument 'experiment' = 'nope'.*bundled experiments: .*dynamic_pitch"):
        experiment_file("nope", SOURCE_CONFIG)
    with pytest.raises(ValueError, match="no file"):
        experiment_file(str(tmp_path / "missing.yaml"), SOURCE_CONFIG)


def test_every_launch_gets_a_new_log_name():
    first = unique_log_path("", "/tmp/logs", stamp=0.0, pid=10)
    assert first == "/tmp/logs/needle_compare_19700101_000000_10.mcap"
    assert unique_log_path("", "/tmp/logs", stamp=0.0, pid=11) != first  # two launches in the same second
    assert unique_log_path("", "/tmp/logs", stamp=1.0, pid=10) != first
    assert unique_log_path("mine.mcap", "/tmp/logs") == "mine.mcap"


def test_modes(tmp_path):
    bag = tmp_path / "a.mcap"
    bag.touch()
    assert mode_settings("replay", str(bag)) == {"use_sim_time": True, "player": True, "stereo": True,
                                                 "compare": True, "haptics": False}
    # external: the same nodes in simulated time, the clock and the bag from another player (ros2 bag play --clock)
    assert mode_settings("external", "") == {**mode_settings("replay", str(bag)), "player": False}
    # hil: wall clock, the haptic output on, nothing else
    assert mode_settings("hil", "") == {"use_sim_time": False, "player": False, "stereo": False, "compare": False,
                                        "haptics": True}
    assert not any(mode_settings("sim", "").values())
    with pytest.raises(ValueError, match="mode:=replay needs bag"):
        mode_settings("replay", "")
    with pytest.raises(ValueError, match="'bag' = '/absent.mcap': no such MCAP file or bag directory"):
        mode_settings("replay", "/absent.mcap")  # before: the nodes started, a comparison log was opened
    with pytest.raises(ValueError, match="only mode:=replay plays a bag .*ros2 bag play --clock"):
        mode_settings("external", "a.mcap")
    with pytest.raises(ValueError, match="must be one of sim, replay, external, hil"):
        mode_settings("real", "")


def test_flags_are_true_or_false():
    assert flag("keep_alive", "True") and not flag("keep_alive", "false")
    with pytest.raises(ValueError, match="launch argument 'keep_alive' = 'yes': must be true or false"):
        flag("keep_alive", "yes")


def test_the_namespace_comes_from_the_launch_context_as_launch_ros_forms_it():
    assert full_namespace(None, "") == "/"
    assert full_namespace(None, "psm1") == full_namespace("", "/psm1/") == "/psm1"
    assert full_namespace("/lab", "psm1") == "/lab/psm1"  # PushRosNamespace('lab') around namespace:=psm1
    assert full_namespace("/lab", "") == "/lab"
    assert full_namespace("/lab", "/psm1") == "/psm1"  # an absolute namespace is not prefixed


def test_experiment_sections_apply_in_any_namespace(tmp_path):
    """Bare node-name sections become /**/<node> (rcl applies a bare name in the root namespace only); our own
    loader still finds them for the node in the root namespace and in /psm1."""
    from needle_common.parameters import load_params_file
    from needle_sim_ros.parameters.experiment import node_specs
    source = SOURCE_CONFIG / "experiments" / "dynamic_pitch.yaml"
    rewritten = Path(namespaced_params_file(str(source)))
    assert rewritten != source and rewritten.parent != source.parent
    document = yaml.safe_load(rewritten.read_text())
    assert list(document) == [f"/**/{key}" for key in yaml.safe_load(source.read_text())]
    for namespace in ("/", "/psm1", "/lab/psm1"):
        values = load_params_file(rewritten, "needle_simulator", node_specs("needle_simulator"), namespace=namespace)
        assert values["fixtures.clamp_interval"] == [0.162, 0.27] and values["qos.wrench"] == "reliable"
    rewritten.unlink()
    already = tmp_path / "any.yaml"
    already.write_text("/**/needle_simulator:\n  ros__parameters:\n    qos.wrench: reliable\n")
    assert namespaced_params_file(str(already)) == str(already)  # nothing to rewrite: the user's file itself
    assert namespaced_params_file("") == ""


def test_the_rewritten_experiment_file_is_removed_when_the_launch_process_exits():
    source = SOURCE_CONFIG / "experiments" / "dynamic_pitch.yaml"
    script = ("import sys; from needle_sim_ros.launch_support import namespaced_params_file; "
              "path = namespaced_params_file(sys.argv[1]); print(path); assert open(path).read()")
    result = subprocess.run([sys.executable, "-c", script, str(source)], capture_output=True, text=True, timeout=60)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() and not Path(result.stdout.strip()).exists()


def test_only_an_unexpected_failure_fails_the_launch():
    assert exit_error("needle_replay", 0, shutting_down=False) == ""
    assert exit_error("needle_simulator", -2, shutting_down=True) == ""  # Ctrl+C on the launch
    assert exit_error("needle_simulator", 2, shutting_down=False) == \
        "needle_simulator exited with status 2: the launch stops"


def test_the_bag_player_waits_for_the_nodes_that_read_the_bag():
    """mode:=replay plays the whole bag (ground truth for RViz too) once each node has matched its inputs."""
    assert player_arguments("a.mcap", "", ["needle_simulator", "needle_stereo"]) == [
        "a.mcap", "--clock", "--wait-for-subscribers", "300", "--wait-for-nodes", "/needle_simulator", "/needle_stereo"]
    for namespace in ("robot1", "/robot1", "/robot1/"):  # the bag's topics go where the namespaced nodes read them
        assert player_arguments("a.mcap", namespace, ["needle_compare"]) == [
            "a.mcap", "--clock", "--in-namespace", "--wait-for-subscribers", "300", "--wait-for-nodes",
            "/robot1/needle_compare"]
    assert player_arguments("a.mcap", "/", ["needle_compare"])[-1] == "/needle_compare"
    assert player_arguments("a.mcap", "", ["needle_stereo"], "png")[-3:] == ["/needle_stereo", "--compress-images",
                                                                              "png"]


def test_image_transport_arguments_are_checked():
    assert (image_transport("compressed"), image_codec("jpeg")) == ("compressed", "jpeg")
    with pytest.raises(ValueError, match="launch argument 'image_transport' = 'theora': must be raw or compressed"):
        image_transport("theora")
    with pytest.raises(ValueError, match="launch argument 'image_codec' = 'webp': must be png or jpeg"):
        image_codec("webp")


def test_a_failed_transition_is_told_from_the_normal_ones():
    """rcl_lifecycle's states: configure refused goes configuring -> unconfigured, a callback's error through
    errorprocessing; a cleanup also ends in unconfigured (from cleaningup) and is normal."""
    assert failed_transition("configuring", "unconfigured")
    assert failed_transition("errorprocessing", "unconfigured") and failed_transition("errorprocessing", "finalized")
    assert not failed_transition("cleaningup", "unconfigured")
    assert not failed_transition("configuring", "inactive") and not failed_transition("activating", "active")
