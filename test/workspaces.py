"""Test-only colcon workspaces over the project's environment, under build*/ (never installed by the product).

- ``build_stock()``: the stock Jazzy tooling a ROS 2 install has and PyPI has not (launch, launch_ros, the ``ros2``
  command line, composition_interfaces, rosidl_runtime_py, tf2/tf2_msgs/tf2_py/tf2_ros_py), built from their
  unmodified sources in ``../shared/ros2-src`` (its README), for the tests that run the stock path: ``ros2 launch``,
  ``ros2 lifecycle``, ``ros2 param``, tf2_ros.
- ``build_tf2_msgs()``: only ``tf2_msgs/msg/TFMessage``, for the /tf tests where that folder is absent. It has no
  PyPI wheel; the nodes then publish ``tf2_msgs/msg/TFMessage`` themselves when the type is importable. The package
  below carries the official definition (ros2/geometry2, ``tf2_msgs/msg/TFMessage.msg``:
  ``geometry_msgs/TransformStamped[] transforms``).

Each is built once per content hash (sources, Python interpreter), into the build folder of the environment in use
(``build/`` for .venv, ``build-noble/`` for .venv-noble); ``environment_with`` gives a child process its packages.
"""
from __future__ import annotations

import functools
import hashlib
import os
import shlex
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
# The build folder next to the install folder of the environment in use (scripts/setup_env.sh: NEEDLE_INSTALL).
BUILD = REPO / Path(os.environ.get("NEEDLE_INSTALL", REPO / "install")).name.replace("install", "build")
ROS2_SRC = Path(os.environ.get("NEEDLE_ROS2_SRC", REPO.parent / "shared" / "ros2-src")).resolve()
STOCK_FOLDERS = ("launch", "launch_ros", "ros2cli", "rcl_interfaces", "rosidl_runtime_py", "geometry2")
# Where a stock Jazzy's versions are tested (requirements-noble.lock, .venv-noble); NEEDLE_STOCK_TESTS=1: any lock.
STOCK_LOCK = BUILD.name == "build-noble" or os.environ.get("NEEDLE_STOCK_TESTS") == "1"
TF2_MSGS_FILES = {
    "msg/TFMessage.msg": "geometry_msgs/TransformStamped[] transforms\n",
    "CMakeLists.txt": """cmake_minimum_required(VERSION 3.8)
project(tf2_msgs)
find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
find_package(geometry_msgs REQUIRED)
rosidl_generate_interfaces(${PROJECT_NAME} "msg/TFMessage.msg" DEPENDENCIES geometry_msgs)
ament_export_dependencies(rosidl_default_runtime)
ament_package()
""",
    "package.xml": """<?xml version="1.0"?>
<package format="3">
  <name>tf2_msgs</name>
  <version>0.0.0</version>
  <description>TEST ONLY: tf2_msgs/msg/TFMessage for the needle_sim tests (the real one comes with ROS 2).</description>
  <maintainer email="dev@needle-sim.invalid">needle_sim developers</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
  <depend>geometry_msgs</depend>
  <exec_depend>rosidl_default_runtime</exec_depend>
  <member_of_group>rosidl_interface_packages</member_of_group>
  <export><build_type>ament_cmake</build_type></export>
</package>
""",
}


def _colcon_build(workspace: Path, digest: str, what: str) -> Path:
    """Build ``workspace/src`` (unless its stamp says ``digest`` was built) and return its install folder."""
    install, stamp = workspace / "install", workspace / "stamp"
    if stamp.exists() and stamp.read_text() == digest and (install / "local_setup.bash").is_file():
        return install
    stamp.unlink(missing_ok=True)
    result = subprocess.run(
        ["colcon", "--log-base", "log", "build", "--base-paths", "src", "--build-base", "build", "--install-base",
         "install", "--cmake-args", "-DBUILD_TESTING=OFF", f"-DPython3_EXECUTABLE={sys.executable}"],
        cwd=workspace, capture_output=True, text=True, timeout=900)
    if result.returncode != 0:
        raise RuntimeError(f"building {what} failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}")
    stamp.write_text(digest)
    return install


@functools.cache
def build_tf2_msgs() -> Path:
    """The install folder of the test-only tf2_msgs (built if its sources changed)."""
    workspace = BUILD / "test_ws"
    digest = hashlib.sha256(repr((sorted(TF2_MSGS_FILES.items()), sys.executable)).encode()).hexdigest()
    for name, text in TF2_MSGS_FILES.items():
        (workspace / "src" / "tf2_msgs" / name).parent.mkdir(parents=True, exist_ok=True)
        (workspace / "src" / "tf2_msgs" / name).write_text(text)
    return _colcon_build(workspace, digest, "the test-only tf2_msgs")


def stock_absent() -> str:
    """Why the stock workspace cannot be built here ('' if it can)."""
    missing = [f for f in STOCK_FOLDERS if not (ROS2_SRC / f).is_dir()]
    if missing:
        return (f"the stock Jazzy sources are absent ({ROS2_SRC}: no {', '.join(missing)}; see "
                "../shared/ros2-src/README.md, or NEEDLE_ROS2_SRC)")
    return ""


@functools.cache
def build_stock() -> Path:
    """The install folder of the stock Jazzy tooling built from ../shared/ros2-src (once per source snapshot)."""
    workspace = BUILD / "stock_ws"
    (workspace / "src").mkdir(parents=True, exist_ok=True)
    for folder in STOCK_FOLDERS:  # links: the sources stay where they are
        link = workspace / "src" / folder
        if not link.is_symlink() or link.resolve() != ROS2_SRC / folder:
            link.unlink(missing_ok=True)
            link.symlink_to(ROS2_SRC / folder, target_is_directory=True)
    digest = hashlib.sha256(repr(((ROS2_SRC / "SOURCES.txt").read_text(), STOCK_FOLDERS, sys.executable)).encode())
    return _colcon_build(workspace, digest.hexdigest(), "the stock Jazzy workspace (../shared/ros2-src)")


def environment_with(install: Path, env: dict) -> dict:
    """``env`` with a workspace's packages added, as sourcing its ``local_setup.bash`` does."""
    script = f"source {shlex.quote(str(install / 'local_setup.bash'))} && env -0"
    result = subprocess.run(["bash", "-c", script], env=env, capture_output=True, text=True, timeout=60, check=True)
    return dict(line.split("=", 1) for line in result.stdout.split("\0") if "=" in line)
