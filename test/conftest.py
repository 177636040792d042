"""Suite-level test helpers (message samples, test-only workspaces) importable by the suite tests; the ROS test
environment (``ros_env``) comes from the repository's conftest.py."""
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

from workspaces import STOCK_LOCK, build_stock, environment_with, stock_absent  # noqa: E402


@pytest.fixture(scope="session")
def stock_env(ros_env) -> dict:
    """``ros_env`` with the stock Jazzy tooling (launch, launch_ros, ros2cli, tf2_ros) built from ../shared/ros2-src
    into build*/stock_ws, once per session (a stamp keeps it across sessions)."""
    if not STOCK_LOCK:
        pytest.skip("the stock-Jazzy tests run in the environment of a stock Jazzy's versions (./test.sh's "
                    "requirements-noble.lock run, .venv-noble); NEEDLE_STOCK_TESTS=1 runs them here")
    reason = stock_absent()
    if reason:
        pytest.skip(reason)
    return environment_with(build_stock(), ros_env)
