"""Fuzz-style: random and adversarial params files through the one loader and every executable that takes one
(issue 15). Seeded; every case asserts the exit status, a one-line message naming the file without a traceback,
and that nothing was written."""
import random
import subprocess
from pathlib import Path

import pytest

from needle_common.parameters import ParameterError, load_params_file
from needle_vision.parameters import SPECS as STEREO_PARAMETERS

from needle_sim_ros.parameters.compare import COMPARE_PARAMETERS
from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS

REPO = Path(__file__).resolve().parents[1]
SEED = 15
SIMULATOR_CONFIG = REPO / "config" / "needle_simulator.yaml"
SPECS = {"needle_simulator": SIMULATOR_PARAMETERS, "needle_compare": COMPARE_PARAMETERS,
         "needle_stereo": STEREO_PARAMETERS}

# (name, file contents, words the message must contain; None: a warning only, the file is accepted)
ADVERSARIAL = [
    ("malformed", "needle_simulator:\n  ros__parameters:\n    needle.length: [0.3\n", ["malformed YAML", "line"]),
    ("random_bytes", random.Random(SEED).randbytes(300), ["not UTF-8"]),
    ("list", "- 1\n- 2\n", ["expected a mapping", "list"]),
    ("scalar", "needle\n", ["expected a mapping", "str"]),
    ("mixed_list", "/**:\n  ros__parameters:\n    needle.gravity: [0, 0, -9.81]\n",
     ["needle.gravity", "one type", "write 1.0"]),
    ("no_ros_parameters", "needle_simulator:\n  needle.length: 0.3\n", ["needle_simulator", "ros__parameters"]),
    ("bare_ros_parameters", "ros__parameters:\n  needle.length: 0.3\n", ["under a node name"]),
    ("null_value", "/**:\n  ros__parameters:\n    needle.length:\n", ["needle.length", "null"]),
    ("nested_list", "/**:\n  ros__parameters:\n    needle.gravity: [[0.0], [1.0]]\n", ["needle.gravity", "list"]),
    ("topic_space", "/**:\n  ros__parameters:\n    topics.wrench: 'my wrench'\n", ["topics.wrench", "topic name"]),
    ("topic_digit", "/**:\n  ros__parameters:\n    topics.shape: 9shape\n", ["topics.shape", "topic name"]),
    ("topic_double_slash", "/**:\n  ros__parameters:\n    topics.path: a//b\n", ["topics.path", "topic name"]),
    ("clamp_one", "/**:\n  ros__parameters:\n    fixtures.clamp_interval: [0.2]\n", ["fixtures.clamp_interval"]),
    ("clamp_reversed", "/**:\n  ros__parameters:\n    fixtures.clamp_interval: [0.27, 0.1]\n",
     ["fixtures.clamp_interval", "s_start < s_end"]),
    ("clamp_string", "/**:\n  ros__parameters:\n    fixtures.clamp_interval: '0.1, 0.2'\n",
     ["fixtures.clamp_interval", "list of float"]),
    ("clamp_three", "/**:\n  ros__parameters:\n    fixtures.clamp_interval: [0.1, 0.2, 0.3]\n",
     ["fixtures.clamp_interval"]),
    ("typo", "/**:\n  ros__parameters:\n    needle.lenght: 0.3\n", ["needle.lenght", "did you mean 'needle.length'"]),
    ("int_for_float", "/**:\n  ros__parameters:\n    needle.length: 1\n", ["needle.length", "write 1.0"]),
    ("out_of_range", "/**:\n  ros__parameters:\n    needle.elements: 100000\n", ["needle.elements", "<= 200"]),
    ("nan", "/**:\n  ros__parameters:\n    integrator.dt: .nan\n", ["integrator.dt", "finite"]),
    ("huge_load", "/**:\n  ros__parameters:\n    loads.tip_force: [0.0, 0.0, -1.0e9]\n",
     ["loads.tip_force", "must be >= -100"]),
    ("empty", "", None),
    ("other_node", "needle_simulatr:\n  ros__parameters:\n    needle.length: 0.3\n", None),
]
MISSING = ("missing", None, ["no such file"])


def write_case(tmp_path: Path, name: str, content) -> Path:
    path = tmp_path / f"{name}.yaml"
    if name == "directory":
        path.mkdir()
    elif content is not None:
        path.write_bytes(content if isinstance(content, bytes) else content.encode())
    return path


@pytest.mark.parametrize("name, content, words", ADVERSARIAL + [MISSING, ("directory", None, ["is a directory"])])
def test_the_loader_names_file_parameter_and_problem(tmp_path, name, content, words):
    path = write_case(tmp_path, name, content)
    warnings = []
    if words is None:
        assert load_params_file(path, "needle_simulator", SIMULATOR_PARAMETERS, warn=warnings.append) == {}
        assert any(str(path) in w for w in warnings)
        if name == "other_node":
            assert any("did you mean 'needle_simulator'" in w for w in warnings)
        return
    with pytest.raises(ParameterError) as raised:
        load_params_file(path, "needle_simulator", SIMULATOR_PARAMETERS, warn=warnings.append)
    message = str(raised.value)
    assert "\n" not in message and str(path) in message
    for word in words:
        assert word in message


def mutations(text: str, rng: random.Random, count: int):
    """Seeded mutations of a valid params file: byte flips, truncations, deleted/duplicated lines, values
    replaced by adversarial ones."""
    values = ["", "[]", "[1, 2.0]", "{}", "null", ".inf", "-.inf", ".nan", "1e400", "'x'", "true", "[[1]]",
              "-1", "0", "1e-320", "99999999999999999999", "{a: 1}", "\"\\x00\"", "!!binary AAAA", "&a 1"]
    lines = text.splitlines()
    for _ in range(count):
        kind = rng.randrange(4)
        if kind == 0:
            data = bytearray(text.encode())
            for _ in range(rng.randint(1, 5)):
                data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
            yield bytes(data)
        elif kind == 1:
            yield text.encode()[:rng.randrange(len(text))]
        elif kind == 2:
            copy = list(lines)
            k = rng.randrange(len(copy))
            copy.insert(k, copy[k]) if rng.random() < 0.5 else copy.pop(k)
            yield "\n".join(copy).encode()
        else:
            copy = list(lines)
            candidates = [i for i, line in enumerate(copy) if ":" in line and not line.strip().startswith("#")]
            k = rng.choice(candidates)
            key = copy[k].split(":", 1)[0]
            copy[k] = f"{key}: {rng.choice(values)}"
            yield "\n".join(copy).encode()


def test_random_mutations_load_or_fail_with_a_parameter_error(tmp_path):
    rng = random.Random(SEED)
    text = SIMULATOR_CONFIG.read_text()
    path = tmp_path / "mutated.yaml"
    outcomes = {"loaded": 0, "refused": 0}
    for data in mutations(text, rng, 300):
        path.write_bytes(data)
        try:
            values = load_params_file(path, "needle_simulator", SIMULATOR_PARAMETERS, warn=lambda _: None)
        except ParameterError as error:
            assert "\n" not in str(error) and str(path) in str(error)
            outcomes["refused"] += 1
            continue
        by_name = {spec.name: spec for spec in SIMULATOR_PARAMETERS}
        for name, value in values.items():  # what loads is valid as the node declares it
            by_name[name].validate(value)
        outcomes["loaded"] += 1
    assert outcomes["loaded"] > 20 and outcomes["refused"] > 100, outcomes


def run(command: list[str], cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def assert_refused(result: subprocess.CompletedProcess, path: Path, words: list[str]) -> None:
    output = result.stdout + result.stderr
    assert result.returncode == 2, output
    assert "Traceback" not in output
    line = next(line for line in output.splitlines() if str(path.name) in line and "error" in line.lower()
                or str(path.name) in line and "FATAL" in line)
    for word in words:
        assert word in line, line


# The executables, each with a params file argument; the cases run in a fresh directory (nothing written there).
EXECUTABLES = {
    "needle_simulator": lambda path, out: ["needle_simulator", "--ros-args", "--params-file", str(path)],
    "needle_compare": lambda path, out: ["needle_compare", "--ros-args", "--params-file", str(path)],
    "needle_stereo": lambda path, out: ["needle_stereo", "--ros-args", "--params-file", str(path)],
    "needle_scenario": lambda path, out: ["needle_scenario", "static", "--tip-mass", "0.0", "--params", str(path),
                                          "--json", str(out / "static.json")],
    "needle_offline": lambda path, out: ["needle_offline", str(REPO / "bags" / "insertion.mcap"), "--experiment",
                                         str(path), "--output-dir", str(out), "--quiet"],
    "needle_stereo_offline": lambda path, out: ["needle_stereo_offline", str(REPO / "bags" / "insertion.mcap"),
                                                "--params", str(path), "--output", str(out / "needle.csv")],
}
# The cases every executable must refuse (the loader's other cases are the same code path).
PROCESS_CASES = ["malformed", "random_bytes", "list", "mixed_list", "no_ros_parameters", "typo", "missing"]


@pytest.mark.slow
@pytest.mark.parametrize("executable", sorted(EXECUTABLES))
def test_every_executable_refuses_bad_params_files_with_exit_2(tmp_path, executable, ros_env):
    cases = {name: (content, words) for name, content, words in ADVERSARIAL + [MISSING]}
    for name in PROCESS_CASES:
        content, words = cases[name]
        if executable in ("needle_compare", "needle_stereo", "needle_stereo_offline") and name == "typo":
            content = content.replace("/**", {"needle_compare": "needle_compare", "needle_stereo": "needle_stereo",
                                              "needle_stereo_offline": "needle_stereo"}[executable])
            words = ["needle.lenght"]
        if executable == "needle_offline":  # an experiment file: the node sections
            content = content.replace("/**", "needle_simulator") if isinstance(content, str) else content
        path = write_case(tmp_path, name, content)
        out = tmp_path / f"out_{name}"
        out.mkdir()
        result = run(EXECUTABLES[executable](path, out), tmp_path, ros_env)
        assert_refused(result, path, [w for w in words if w != "did you mean 'needle.length'"
                                      or executable != "needle_compare"])
        assert not any(p.is_file() for p in out.rglob("*")), f"{executable} {name}: output left behind"


@pytest.mark.slow
def test_the_unknown_name_suggests_the_nearest_known_one_in_every_tool(tmp_path, ros_env):
    path = write_case(tmp_path, "typo", ADVERSARIAL[[c[0] for c in ADVERSARIAL].index("typo")][1])
    result = run(["needle_scenario", "static", "--params", str(path)], tmp_path, ros_env)
    assert result.returncode == 2 and "did you mean 'needle.length'" in result.stderr


def test_every_shipped_config_file_loads_cleanly(monkeypatch):
    monkeypatch.chdir(REPO)  # calibration file paths are relative to the repository root
    files = {REPO / "config" / f"{node}.yaml": [node] for node in SPECS}
    files[REPO / "config" / "tissue.yaml"] = ["needle_simulator"]
    files.update({path: list(SPECS) for path in (REPO / "config" / "experiments").glob("*.yaml")})
    for path, nodes in files.items():
        for node in nodes:
            warnings = []
            load_params_file(path, node, SPECS[node], warn=warnings.append, require_section=False)
            assert not warnings, warnings


MISSPELLINGS = {"needle_simulator": ("needle.lenght", "needle.length"), "needle_compare": ("tolerence", "tolerance"),
                "needle_stereo": ("detection.min_lenght", "detection.min_length")}


@pytest.mark.slow
@pytest.mark.parametrize("node", sorted(MISSPELLINGS))
def test_every_node_refuses_a_command_line_override_of_a_misspelled_name(tmp_path, node, ros_env):
    """``-p needle.lenght:=0.2``: rclpy would ignore the undeclared name and run with the default length."""
    typo, name = MISSPELLINGS[node]
    result = run([node, "--ros-args", "-p", f"{typo}:=0.2"], tmp_path, ros_env)
    output = result.stdout + result.stderr
    assert result.returncode == 2 and "Traceback" not in output, output
    assert f"unknown parameter '{typo}'" in output and f"did you mean '{name}'" in output, output


# Command lines rcl cannot parse (before: rclpy.init's traceback, exit 1) and an argument a node does not take (before:
# ignored, the node ran and waited: `needle_compare run.mcap` never ended)
BAD_COMMAND_LINES = {"unknown_flag": (["--ros-args", "--bogus"], "unknown ROS argument(s) ['--bogus']"),
                     "trailing_p": (["--ros-args", "-p"], "trailing -p flag"),
                     "trailing_params_file": (["--ros-args", "--params-file"], "trailing --params-file flag"),
                     "stray": (["run.mcap"], "unexpected argument 'run.mcap'")}


@pytest.mark.slow
@pytest.mark.parametrize("executable", ["needle_simulator", "needle_compare", "needle_stereo", "needle_replay",
                                        "needle_bringup"])
def test_every_node_refuses_a_malformed_command_line_with_exit_2(tmp_path, executable, ros_env):
    # a malformed params file: the other nodes in test_every_executable_refuses_bad_params_files_with_exit_2 (before:
    # needle_replay ended in rclpy.init's traceback)
    malformed = write_case(tmp_path, "malformed", ADVERSARIAL[0][1])
    cases = {**BAD_COMMAND_LINES, "params_file": (["--ros-args", "--params-file", str(malformed)], "malformed YAML")}
    for name, (arguments, words) in cases.items():
        if name == "stray" and executable in ("needle_replay", "needle_bringup"):  # they take a bag: see their tests
            continue
        bag = [str(REPO / "bags" / "insertion.mcap")] if executable == "needle_replay" else []
        result = run([executable, *bag, *arguments], tmp_path, ros_env)
        output = result.stdout + result.stderr
        assert result.returncode == 2 and "Traceback" not in output, f"{executable} {name}: {output}"
        lines = output.strip().splitlines()
        assert len(lines) == 1 and "FATAL" in lines[0] and words in lines[0], f"{executable} {name}: {output}"
