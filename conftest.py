"""Shared by every test directory (package tests and suite tests): one isolated ROS 2 domain, a package's
install-time kernel compilation run as the install step runs it, and the tests that compile kernels from an empty
cache kept to one of ./test.sh's two runs."""
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


# ./test.sh's second run, on Ubuntu 24.04's versions (scripts/setup_env.sh with NEEDLE_LOCK=noble: install-noble/).
NOBLE_RUN = Path(os.environ.get("NEEDLE_INSTALL", "install")).name == "install-noble"


def pytest_runtest_setup(item: pytest.Item) -> None:
    """A ``compiles_from_empty`` test runs in the main lock's run only: it compiles a package's kernels from an empty
    cache (minutes), the same code on both locks, and the noble run's own build compiles the same kernels with
    numba 0.59 through the same install hooks; the two runs must fit in CI's 90 minutes."""
    if NOBLE_RUN and item.get_closest_marker("compiles_from_empty"):
        pytest.skip("compiles kernels from an empty cache: in the main lock's run only (the noble build compiled the "
                    "same kernels with numba 0.59 through the same install hook)")


@pytest.fixture(scope="session")
def ros_env() -> dict:
    """Environment for nodes in child processes: the test run's ROS domain (``ROS_TEST_ENV``), unbuffered output."""
    return dict(os.environ, **ROS_TEST_ENV, PYTHONUNBUFFERED="1")


@pytest.fixture(scope="session")
def run_install_hook() -> Callable[..., subprocess.CompletedProcess]:
    """``run(setup_py, timeout, then="")``: the ``COMPILE_KERNELS`` snippet of a package's setup.py (what its install
    step, run by colcon build, executes against the installed package), then the code ``then`` in the same
    interpreter, run in a child process; its output as text."""
    def run(setup_py: Path, timeout: float, then: str = "") -> subprocess.CompletedProcess:
        tree = ast.parse(setup_py.read_text())
        snippet = next(node.value.value for node in tree.body if isinstance(node, ast.Assign)
                       and getattr(node.targets[0], "id", "") == "COMPILE_KERNELS")
        return subprocess.run([sys.executable, "-c", snippet + then], capture_output=True, text=True,
                              timeout=timeout)
    return run
