"""needle_common is the bottom of the suite: it imports neither needle_sim_ros nor needle_vision (read from each
file's syntax tree), its modules outside ``ros/`` import no ROS client library, and the simulation core of
needle_sim_ros (``simulation.py``, ``model/``, ``tissue/``) imports no needle_vision."""
import ast
import subprocess
import sys
from pathlib import Path

import pytest

import needle_common

PACKAGE = Path(needle_common.__file__).parent  # the installed package
REPO = Path(__file__).resolve().parents[2]


def imported_packages(path: Path) -> set[str]:
    """Top-level names of every absolute import anywhere in a source file."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def importers(files: list[Path], forbidden: set[str]) -> dict[str, set[str]]:
    found = {str(path): imported_packages(path) & forbidden for path in files}
    return {path: names for path, names in found.items() if names}


def test_needle_common_imports_neither_package_above_it():
    files = sorted(PACKAGE.rglob("*.py"))
    assert len(files) > 5
    assert importers(files, {"needle_sim_ros", "needle_vision"}) == {}


def test_the_simulation_core_imports_no_needle_vision():
    core = REPO / "needle_sim_ros" / "needle_sim_ros"
    layers = [core / f"{name}.py" for name in ("simulation", "stepper", "clock_loop", "base_input")]
    files = [*layers, *sorted((core / "model").rglob("*.py")), *sorted((core / "tissue").rglob("*.py"))]
    assert all(path.is_file() for path in files) and len(files) > 20
    assert importers(files, {"needle_vision"}) == {}


def test_the_check_sees_a_nested_import(tmp_path):
    # the check must be able to fail: an import inside a function counts
    source = tmp_path / "module.py"
    source.write_text("def f():\n    from needle_vision.parameters import SPECS\n    import needle_sim_ros.model\n")
    assert importers([source], {"needle_sim_ros", "needle_vision"}) == {str(source): {"needle_sim_ros",
                                                                                      "needle_vision"}}


@pytest.mark.parametrize("module", sorted(
    ".".join(path.relative_to(PACKAGE.parent).with_suffix("").parts) for path in PACKAGE.rglob("*.py")
    if "ros" not in path.relative_to(PACKAGE).parts[:-1]))
def test_the_modules_outside_ros_import_without_rclpy(module):
    blocker = ("import sys\nclass Block:\n    def find_spec(self, name, path=None, target=None):\n"
               "        if name.split('.')[0] in ('rclpy', 'rcl_interfaces'):\n"
               "            raise ImportError('ROS module ' + name)\nsys.meta_path.insert(0, Block())\n"
               f"import {module}\n")
    result = subprocess.run([sys.executable, "-c", blocker], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
