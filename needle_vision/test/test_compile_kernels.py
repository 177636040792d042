"""The stereo measurement's kernels are compiled before the first real pair: at install and at the node's start."""
import ast
import subprocess
import sys
from pathlib import Path


def test_the_install_hook_compiles_the_measurement_kernels_against_the_installed_package():
    """setup.py's install step (what colcon build runs) compiles them with a snippet of its own; on a fresh install
    without it the node's first pairs waited ~50 s for compilation and the main job compared 7 of 10."""
    setup = ast.parse((Path(__file__).resolve().parents[1] / "setup.py").read_text())
    snippet = next(node.value.value for node in setup.body if isinstance(node, ast.Assign)
                   and getattr(node.targets[0], "id", "") == "COMPILE_KERNELS")
    result = subprocess.run([sys.executable, "-c", snippet], capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr
    assert "compiled the measurement's numba kernels" in result.stdout
