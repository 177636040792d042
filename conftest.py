"""Shared by every test directory (package tests and suite tests): one isolated ROS 2 domain, and a package's
install-time kernel compilation run as the install step runs it."""
import ast
import os
import subprocess
import sys
from pathlib import Path
from typing import Callable

import pytest


@pytest.fixture(scope="session")
def ros_env() -> dict:
    """Environment for nodes in child processes: a ROS domain of this test run only, discovery on this host only.

    The domain id is derived from the pid so that parallel test runs on one machine do not see each other
    (ids 1..100 keep within the range where every DDS port is valid). The test process itself joins the same
    domain (for rclpy nodes created in tests); its previous settings are restored at the end of the session.

    Fast DDS talks over UDP (loopback) only, never through its shared-memory transport: tests stop and kill
    processes, and a participant killed or stopped while it holds a lock of a shared-memory port can hang every
    participant created after it on the machine (eProsima/Fast-DDS#1144). A CI run hung that way after a failed
    test: the next test's node never came up.
    """
    env = dict(os.environ, ROS_DOMAIN_ID=str(1 + os.getpid() % 100), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               FASTDDS_BUILTIN_TRANSPORTS="UDPv4", PYTHONUNBUFFERED="1")
    saved = {key: os.environ.get(key) for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE",
                                                  "FASTDDS_BUILTIN_TRANSPORTS")}
    os.environ.update({key: env[key] for key in saved})
    yield env
    for key, value in saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value


@pytest.fixture(scope="session")
def run_install_hook() -> Callable[..., subprocess.CompletedProcess]:
    """``run(setup_py, timeout, env=None)``: the ``COMPILE_KERNELS`` snippet of a package's setup.py (what its install
    step, run by colcon build, executes against the installed package), run in a child interpreter with ``env``
    added to the environment; its output as text."""
    def run(setup_py: Path, timeout: float, env: dict | None = None) -> subprocess.CompletedProcess:
        tree = ast.parse(setup_py.read_text())
        snippet = next(node.value.value for node in tree.body if isinstance(node, ast.Assign)
                       and getattr(node.targets[0], "id", "") == "COMPILE_KERNELS")
        return subprocess.run([sys.executable, "-c", snippet], capture_output=True, text=True, timeout=timeout,
                              env={**os.environ, **(env or {})})
    return run
