"""Suite-level fixtures: an isolated ROS 2 domain for tests that start real nodes in other processes."""
import os
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(scope="session")
def ros_env() -> dict:
    """Environment for child processes: a ROS domain of this test run only, discovery on this host only.

    The domain id is derived from the pid so that parallel test runs on one machine do not see each other
    (ids 1..100 keep within the range where every DDS port is valid).
    """
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(1 + os.getpid() % 100)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env["PYTHONUNBUFFERED"] = "1"
    os.environ.update({k: env[k] for k in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE")})
    return env
