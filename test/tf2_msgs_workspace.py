"""A test-only ``tf2_msgs`` interface package, built into ``build/test_ws`` (never installed by the product).

``tf2_msgs`` has no PyPI wheel; the nodes then publish ``tf2_msgs/msg/TFMessage`` themselves when the type is
importable. The package below carries the official definition (ros2/geometry2, ``tf2_msgs/msg/TFMessage.msg``:
``geometry_msgs/TransformStamped[] transforms``) so that the /tf path runs in real processes here. Built once per
source hash with colcon, like the product's workspace.
"""
from __future__ import annotations

import hashlib
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TEST_WS = REPO / "build" / "test_ws"
FILES = {
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


def build_tf2_msgs() -> Path:
    """Build (if its sources changed) and return the install prefix of the test-only tf2_msgs."""
    digest = hashlib.sha256(repr(sorted(FILES.items())).encode()).hexdigest()
    prefix = TEST_WS / "install" / "tf2_msgs"
    stamp = TEST_WS / "stamp"
    if stamp.exists() and stamp.read_text() == digest and prefix.is_dir():
        return prefix
    source = TEST_WS / "src" / "tf2_msgs"
    for name, text in FILES.items():
        (source / name).parent.mkdir(parents=True, exist_ok=True)
        (source / name).write_text(text)
    result = subprocess.run(
        ["colcon", "--log-base", "log", "build", "--base-paths", "src", "--build-base", "build", "--install-base",
         "install", "--cmake-args", "-DBUILD_TESTING=OFF", f"-DPython3_EXECUTABLE={sys.executable}"],
        cwd=TEST_WS, capture_output=True, text=True, timeout=900)
    if result.returncode != 0:
        raise RuntimeError(f"building the test-only tf2_msgs failed:\n{result.stdout[-3000:]}\n{result.stderr[-3000:]}")
    stamp.write_text(digest)
    return prefix


def environment_with(prefix: Path, env: dict) -> dict:
    """``env`` with the test-only package's prefix added (what sourcing its local_setup would do)."""
    env = dict(env)
    site = next((prefix / "lib").glob("python3*/site-packages"))

    def prepend(key: str, value: Path) -> None:
        env[key] = os.pathsep.join([str(value), *filter(None, [env.get(key, "")])])

    prepend("AMENT_PREFIX_PATH", prefix)
    prepend("PYTHONPATH", site)
    prepend("LD_LIBRARY_PATH", prefix / "lib")
    return env
