"""Suite-level test helpers (message samples, tf2_msgs workspace) importable by the suite tests; the ROS test
environment (``ros_env``) comes from the repository's conftest.py."""
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).parent))
