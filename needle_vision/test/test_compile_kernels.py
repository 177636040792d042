"""The stereo measurement's kernels are compiled before the first real pair: at install and at the node's start."""
from pathlib import Path


def test_the_install_hook_compiles_the_measurement_kernels_against_the_installed_package(run_install_hook):
    """setup.py's install step (what colcon build runs) compiles them with a snippet of its own; on a fresh install
    without it the node's first pairs waited ~50 s for compilation and the main job compared 7 of 10."""
    result = run_install_hook(Path(__file__).resolve().parents[1] / "setup.py", 900)
    assert result.returncode == 0, result.stderr
    assert "compiled the measurement's numba kernels" in result.stdout
