"""The four ROS packages as a stock ROS 2 Jazzy user gets them: every package.xml key resolves with rosdep for
Ubuntu 24.04, and every third-party module and ROS package the code uses is declared in its package.xml."""
from __future__ import annotations

import ast
import re
import subprocess
import sys
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("needle_interfaces", "needle_common", "needle_sim_ros", "needle_vision")
PYTHON_PACKAGES = ("needle_common", "needle_sim_ros", "needle_vision")
ROSDEP_CHECK = Path("/work/shared/tools/rosdep-check")
ROSDEP_SNAPSHOT = Path("/work/shared/rosdep/rosdep/base.yaml")

#: Import name -> rosdep key of the third-party Python libraries (a key of the rosdistro's python.yaml).
#: mcap and zstandard have no key: they come with mcap-ros2-support (mcap-ros2-support requires mcap, which
#: requires zstandard and lz4); the README gives the pip line for users without rosdep.
PYTHON_KEYS = {
    "numpy": "python3-numpy", "scipy": "python3-scipy", "numba": "python3-numba", "yaml": "python3-yaml",
    "cv2": "python3-opencv", "matplotlib": "python3-matplotlib", "tqdm": "python3-tqdm",
    "mcap": "mcap-ros2-support", "mcap_ros2": "mcap-ros2-support", "zstandard": "mcap-ros2-support",
    "lz4": "mcap-ros2-support",
    "pytest": "python3-pytest", "rosbags": "python3-rosbags-pip", "pandas": "python3-pandas",
}
#: Libraries without a rosdep key, documented as a pip line in the README; needle_batch (their only user) exits 2
#: with that line when they are missing, and the rest of the package imports without them.
PIP_ONLY = {"dask", "distributed", "pyarrow"}
RUN_TAGS = ("depend", "exec_depend")
TEST_TAGS = RUN_TAGS + ("test_depend",)
# ROS packages named in strings: message types ("pkg/msg/Type"), share-directory look-ups, package:// paths.
_ROS_NAME_PATTERNS = (re.compile(r"\b([a-z][a-z0-9_]*)/(?:msg|srv|action)/[A-Z]\w*"),
                      re.compile(r"(?:share_file|get_package_share_directory|FindPackageShare)\(\s*\"(\w+)\""),
                      re.compile(r"package://(\w+)/"))


def declared(package_xml: Path, tags: tuple[str, ...]) -> set[str]:
    root = ElementTree.parse(package_xml).getroot()
    return {element.text.strip() for tag in tags for element in root.iter(tag)}


def imported_modules(source: str) -> set[str]:
    """Top-level names of the absolute imports of a Python source."""
    names = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def required_keys(files: list[Path], own: str, local: set[str]) -> dict[str, set[Path]]:
    """rosdep key -> the files needing it: imports (third-party via PYTHON_KEYS, else a ROS package of the same
    name), message types and package look-ups named in strings, and `ros2 bag` commands (ros2bag)."""
    needed: dict[str, set[Path]] = {}
    for path in files:
        text = path.read_text()
        python = imported_modules(text) if path.suffix == ".py" else set()
        modules = python - set(sys.stdlib_module_names) - local - PIP_ONLY - {own, "__future__"}
        keys = {PYTHON_KEYS.get(module, module) for module in modules}
        keys |= {name for pattern in _ROS_NAME_PATTERNS for name in pattern.findall(text)}
        if re.search(r"\"ros2\",\s*\"bag\"", text):
            keys.add("ros2bag")
        for key in keys - {own, "pkg", "package"}:  # "pkg/msg/Type" in docstrings is a placeholder
            needed.setdefault(key, set()).add(path)
    return needed


def undeclared(package: Path) -> list[str]:
    """The dependencies the package's code uses but its package.xml does not declare (tests may use test_depend)."""
    local = {p.stem for p in (package / "test").glob("*.py")}
    code = [p for p in package.rglob("*.py") if "test" not in p.relative_to(package).parts and p.name != "setup.py"]
    code += [p for p in (package / "config").rglob("*.yaml")] if (package / "config").is_dir() else []
    tests = list((package / "test").glob("*.py"))
    missing = []
    for files, tags in ((code, RUN_TAGS), (tests, TEST_TAGS)):
        keys = declared(package / "package.xml", tags)
        for key, users in sorted(required_keys(files, package.name, local).items()):
            if key not in keys:
                missing.append(f"{package.name}: '{key}' ({', '.join(sorted(p.name for p in users))}) is not "
                               f"declared as <{'|'.join(tags)}>")
    return missing


def interface_dependencies(package: Path) -> set[str]:
    """Packages whose types the .msg/.srv files of an interface package use (``pkg/Type`` fields)."""
    text = "\n".join(p.read_text() for p in package.rglob("*.msg")) + "\n".join(
        p.read_text() for p in package.rglob("*.srv"))
    return set(re.findall(r"^\s*([a-z][a-z0-9_]*)/[A-Z]\w*", text, re.MULTILINE))


@pytest.mark.skipif(not (ROSDEP_CHECK.is_file() and ROSDEP_SNAPSHOT.is_file()),
                    reason=f"{ROSDEP_CHECK} or the rosdistro snapshot next to it is not on this machine")
def test_every_rosdep_key_resolves_for_noble_and_jazzy():
    result = subprocess.run([str(ROSDEP_CHECK), *PACKAGES], cwd=REPO, capture_output=True, text=True, timeout=600)
    if result.returncode == 2:
        pytest.skip(f"rosdep-check could not run (no rosdep from PyPI?): {result.stderr.strip()[-300:]}")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "NO RULE" not in result.stdout


@pytest.mark.parametrize("name", PYTHON_PACKAGES)
def test_every_used_module_and_ros_package_is_declared(name):
    assert undeclared(REPO / name) == []


def test_the_interface_package_declares_the_packages_of_its_field_types():
    package = REPO / "needle_interfaces"
    assert interface_dependencies(package) <= declared(package / "package.xml", ("depend", "build_depend"))


def test_the_declaration_check_finds_an_undeclared_import(tmp_path):
    """The check can fail: a package that imports cv2 and names a tf2_msgs type without declaring them."""
    package = tmp_path / "demo_pkg"
    (package / "demo_pkg").mkdir(parents=True)
    (package / "test").mkdir()
    (package / "package.xml").write_text(
        "<package format='3'><name>demo_pkg</name><exec_depend>python3-numpy</exec_depend></package>")
    (package / "demo_pkg" / "core.py").write_text(
        "import os\nimport numpy\nimport cv2\nfrom demo_pkg import x\nTOPIC_TYPE = 'tf2_msgs/msg/TFMessage'\n")
    (package / "test" / "test_core.py").write_text("import pytest\n")
    missing = undeclared(package)
    assert len(missing) == 3 and {"'python3-opencv'", "'tf2_msgs'", "'python3-pytest'"} == {
        m.split()[1] for m in missing}


def test_the_repository_config_only_links_to_the_packages_config():
    """One source of truth: config/ holds symbolic links into the packages' config directories, which setup.py
    installs, and every file there is reachable from config/."""
    package_dirs = [REPO / name / "config" for name in PYTHON_PACKAGES]
    entries = list((REPO / "config").iterdir())
    assert entries and all(entry.is_symlink() and entry.exists() for entry in entries)
    assert all(any(d in entry.resolve().parents for d in package_dirs)
               for entry in entries)
    reachable = {p.resolve() for entry in entries for p in ([entry] if entry.is_file() else entry.rglob("*.yaml"))}
    assert reachable == {p.resolve() for d in package_dirs for p in d.rglob("*.yaml")}
