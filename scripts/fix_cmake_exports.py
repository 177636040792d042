"""Rewrite the build machine's include paths in the ROS 2 wheels' CMake export files.

The ros-jazzy-* wheels on PyPI were built in a manylinux container; their
``export_*__rosidl_generator_pyExport.cmake`` files name that container's Python and
numpy include directories (``/opt/python/cp312-cp312/...``), so building an interface
package against them fails. This replaces those paths with the virtual environment's own.
"""
import re
import sys
import sysconfig
from pathlib import Path

import numpy

BUILD_MACHINE_PREFIX = re.compile(r"/opt/python/cp3\d+-cp3\d+/"
                                  r"(?:include/python3\.\d+|lib/python3\.\d+/site-packages/numpy/_core/include)")


def real_path(match: re.Match) -> str:
    python_include = "/include/python" in match.group(0) and "numpy" not in match.group(0)
    return sysconfig.get_paths()["include"] if python_include else numpy.get_include()


def main(venv: Path) -> int:
    changed = 0
    for path in (venv / "share").glob("*/cmake/*.cmake"):
        text = path.read_text()
        fixed = BUILD_MACHINE_PREFIX.sub(real_path, text)
        if fixed != text:
            path.write_text(fixed)
            changed += 1
    print(f"[setup] rewrote include paths in {changed} CMake export files")
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
