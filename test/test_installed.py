"""The installed executables as a user runs them: from an unrelated working directory, with only the underlay
(here the venv's ROS wheels, on a stock install /opt/ros/jazzy) and the workspace's install space sourced (no
source tree on PYTHONPATH). Each must find the config its package installs in share/<package>/config."""
from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

REPO = Path(__file__).resolve().parents[1]
INSTALL = Path(os.environ.get("NEEDLE_INSTALL", REPO / "install"))  # set by .venv*/needle_env.sh
VENV = Path(os.environ.get("VIRTUAL_ENV", REPO / ".venv"))
SHARE = {package: INSTALL / package / "share" / package for package in ("needle_sim_ros", "needle_vision")}


def executable(package: str, name: str) -> str:
    return str(INSTALL / package / "lib" / package / name)


@pytest.fixture(scope="module")
def install_env(tmp_path_factory) -> dict:
    """The environment of `source install/setup.bash` over the underlay, in a shell started with nothing else."""
    if not (INSTALL / "setup.bash").is_file():
        pytest.skip("no install space: run scripts/setup_env.sh (colcon build) first")
    home = tmp_path_factory.mktemp("home")
    base = {"HOME": str(home), "PATH": f"{VENV / 'bin'}:/usr/bin:/bin", "AMENT_PREFIX_PATH": str(VENV),
            "LANG": "C.UTF-8", "ROS_DOMAIN_ID": str(1 + (os.getpid() + 50) % 100),
            "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", "PYTHONUNBUFFERED": "1", "MPLBACKEND": "Agg"}
    if "NUMBA_CACHE_DIR" in os.environ:  # compiled kernels only: no source or config is read from there
        base["NUMBA_CACHE_DIR"] = os.environ["NUMBA_CACHE_DIR"]
    dump = subprocess.run(["bash", "-c", f"source '{INSTALL / 'setup.bash'}' && env -0"], env=base,
                          capture_output=True, check=True).stdout.decode()
    env = dict(line.split("=", 1) for line in dump.split("\0") if "=" in line)
    assert not any(str(REPO / p) in env.get("PYTHONPATH", "") for p in ("needle_sim_ros/needle_sim_ros", "config"))
    return env


@pytest.fixture
def elsewhere(tmp_path) -> Path:
    """An empty working directory outside the repository (no config/ to fall back on)."""
    assert not (tmp_path / "config").exists() and REPO not in tmp_path.parents
    return tmp_path


def _normalized(value):
    """A params-file value as the scenario's JSON writes it (non-finite numbers as strings)."""
    if isinstance(value, list):
        return [_normalized(v) for v in value]
    if isinstance(value, str) and value.lower() in ("inf", ".inf", "-inf", "-.inf", "nan", ".nan"):
        return str(float(value.replace(".", "")))
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    return value


def _flatten(prefix: str, value, out: dict) -> dict:
    if isinstance(value, dict):
        for key, item in value.items():
            _flatten(f"{prefix}.{key}" if prefix else key, item, out)
    else:
        out[prefix] = value
    return out


@pytest.mark.parametrize("package", ["needle_common", "needle_sim_ros", "needle_vision"])
def test_the_install_space_has_no_module_whose_source_is_gone(package):
    """Every installed module has its source: a module deleted from the sources is not importable from install/
    (colcon's install never removes a file; scripts/setup_env.sh builds a package whose files changed afresh)."""
    installed = INSTALL / package / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages"
    if not (installed / package).is_dir():
        pytest.skip(f"no install space of {package}: run scripts/setup_env.sh (colcon build) first")
    orphans = [str(module.relative_to(installed)) for module in sorted((installed / package).rglob("*.py"))
               if not (REPO / package / module.relative_to(installed)).is_file()]
    assert not orphans, f"installed without a source (run scripts/setup_env.sh again): {', '.join(orphans)}"



def test_the_install_space_has_no_interface_whose_source_is_gone():
    """Every installed message and service of needle_interfaces has its source: one deleted from the sources
    keeps its generated code in install/ unless the package is built afresh (scripts/setup_env.sh does)."""
    share = INSTALL / "needle_interfaces" / "share" / "needle_interfaces"
    if not share.is_dir():
        pytest.skip("no install space of needle_interfaces: run scripts/setup_env.sh (colcon build) first")
    orphans = [f"{kind}/{interface.name}" for kind in ("msg", "srv")
               for interface in sorted((share / kind).glob("*.idl"))
               if not (REPO / "needle_interfaces" / kind / f"{interface.stem}.{kind}").is_file()]
    assert not orphans, f"installed without a source (run scripts/setup_env.sh again): {', '.join(orphans)}"

def test_needle_scenario_insertion_uses_the_installed_tissue_config(install_env, elsewhere):
    shipped = _flatten("", yaml.safe_load((SHARE["needle_sim_ros"] / "config" / "tissue.yaml").read_text())
                       ["/**"]["ros__parameters"], {})
    # The scenario sets the entry point and enables the tissue itself; the rest comes from the file.
    compared = {k: _normalized(v) for k, v in shipped.items() if k not in ("tissue.entry_point", "tissue.enable")}
    result = subprocess.run([executable("needle_sim_ros", "needle_scenario"), "insertion", "--depth", "0.004",
                             "--gap", "0.001", "--json", "out.json"], cwd=elsewhere, env=install_env,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    written = json.loads((elsewhere / "out.json").read_text())
    assert Path(written["params_files"][0]) == (SHARE["needle_sim_ros"] / "config" / "tissue.yaml").resolve()
    assert {k: _normalized(written["parameters"]["tissue"][k]) for k in compared} == compared


def test_needle_scenario_reports_a_missing_tissue_file(install_env, elsewhere):
    result = subprocess.run([executable("needle_sim_ros", "needle_scenario"), "insertion", "--params",
                             "missing.yaml"], cwd=elsewhere, env=install_env, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 2 and "missing.yaml" in result.stderr and "Traceback" not in result.stderr


def test_needle_offline_runs_a_bundled_bag_with_the_installed_experiment(install_env, elsewhere):
    command = executable("needle_sim_ros", "needle_offline")
    help_text = subprocess.run([command, "--help"], cwd=elsewhere, env=install_env, capture_output=True, text=True,
                               timeout=120)
    assert help_text.returncode == 0 and "usage: needle_offline" in help_text.stdout
    result = subprocess.run([command, str(REPO / "bags" / "insertion.mcap"), "--duration", "0.3",
                             "--quiet", "--output-dir", "out"], cwd=elsewhere, env=install_env, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    summary = json.loads((elsewhere / "out" / "summary.json").read_text())
    assert Path(summary["experiment"]) == SHARE["needle_sim_ros"] / "config" / "experiments" / "insertion.yaml"
    assert summary["comparison"]["compared"] > 0


def test_needle_stereo_offline_measures_with_the_installed_params_and_calibration(install_env, elsewhere):
    """A straight needle along world +x rendered by the sample rig the shipped params and calibration describe:
    the measured samples lie on the x axis within [0, L]."""
    from needle_vision.render import NEEDLE_LENGTH, NEEDLE_RADIUS, default_rig, make_scene, \
        render_background_pair, render_stereo_pair
    params = yaml.safe_load((SHARE["needle_vision"] / "config" / "needle_stereo.yaml").read_text())
    background = params["/**"]["ros__parameters"]["background"]["frames"]
    rig = default_rig()
    scene = make_scene(rig, np.random.default_rng(0))
    needle = np.column_stack([np.linspace(0.0, NEEDLE_LENGTH, 541), np.zeros(541), np.zeros(541)])
    pairs = [render_background_pair(rig, np.random.default_rng(k), scene=scene) for k in range(background)]
    pairs.append(render_stereo_pair(rig, needle, NEEDLE_RADIUS, np.random.default_rng(99), scene=scene))
    for side, index in (("left", 0), ("right", 1)):
        (elsewhere / "frames" / side).mkdir(parents=True)
        for k, pair in enumerate(pairs):
            cv2.imwrite(str(elsewhere / "frames" / side / f"{k:04d}.png"), pair[index])
    result = subprocess.run([executable("needle_vision", "needle_stereo_offline"), "frames", "--params",
                             str(SHARE["needle_vision"] / "config" / "needle_stereo.yaml"), "--quiet",
                             "--output-frame", "world", "--output", "needle.csv"], cwd=elsewhere, env=install_env,
                            capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stdout + result.stderr
    rows = np.loadtxt(elsewhere / "needle.csv", delimiter=",", skiprows=2, ndmin=2)  # frame/units line, header
    assert len(rows) > 10 and set(rows[:, 0]) == {background}
    points = rows[:, 4:7]
    assert np.max(np.hypot(points[:, 1], points[:, 2])) < 1e-3  # on the x axis (1 mm: far beyond the noise)
    assert -1e-3 < points[:, 0].min() and points[:, 0].max() < NEEDLE_LENGTH + 1e-3


def test_needle_stereo_node_loads_the_installed_calibration(install_env, elsewhere):
    params = SHARE["needle_vision"] / "config" / "needle_stereo.yaml"
    process = subprocess.Popen([executable("needle_vision", "needle_stereo"), "--ros-args", "--params-file",
                                str(params)], cwd=elsewhere, env=install_env, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True)
    output, deadline = [], time.monotonic() + 120
    try:
        for line in process.stdout:
            output.append(line)
            if "needle_stereo ready" in line or time.monotonic() > deadline:
                break
    finally:
        process.send_signal(signal.SIGINT)
        rest, _ = process.communicate(timeout=30)
    text = "".join(output) + rest
    assert "needle_stereo ready: raw images, calibration from calibration files" in text, text
