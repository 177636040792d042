"""Shared by every test directory (package tests and suite tests): one isolated ROS 2 domain, and a package's
install-time kernel compilation run as the install step runs it."""
import ast
import os
import subprocess
import sys
from pathlib import Path
from typing import Callable

import pytest


# The ROS 2 settings of every participant of a test run, the test process's own and its children's.
ROS_TEST_ENV = {"ROS_DOMAIN_ID": str(1 + os.getpid() % 100), "ROS_AUTOMATIC_DISCOVERY_RANGE": "SYSTEM_DEFAULT",
                "FASTRTPS_DEFAULT_PROFILES_FILE": str(Path(__file__).with_name("test") / "fastdds_udp_localhost.xml")}


def pytest_configure(config: pytest.Config) -> None:
    """One isolated ROS 2 domain for the test run, set before anything in this process creates a participant (Fast
    DDS reads its profile file once, at the first).

    The domain id is derived from the pid so that parallel test runs on one machine do not see each other (ids
    1..100 keep within the range where every DDS port is valid); discovery stays on this host.

    Fast DDS talks over UDP on 127.0.0.1 only, never through its shared-memory transport: tests stop and kill
    processes, and a participant killed or stopped while it holds a lock of a shared-memory port can hang every
    participant created after it on the machine (eProsima/Fast-DDS#1144). rmw_fastrtps's LOCALHOST discovery range
    adds that transport itself (FASTDDS_BUILTIN_TRANSPORTS does not remove it), so the range is left to Fast DDS
    (SYSTEM_DEFAULT) and test/fastdds_udp_localhost.xml sets up localhost discovery without it.
    """
    os.environ.update(ROS_TEST_ENV)


@pytest.fixture(scope="session")
def ros_env() -> dict:
    """Environment for nodes in child processes: the test run's ROS domain (``ROS_TEST_ENV``), unbuffered output."""
    return dict(os.environ, **ROS_TEST_ENV, PYTHONUNBUFFERED="1")


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
