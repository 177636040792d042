"""Files a ROS package ships in its share directory, found through the ament index (never the source tree).

``package://<package>/<path>`` names such a file in a parameter (as camera_info_manager's URLs do), so a params
file works from any working directory (e.g. ``package://<package>/config/left.yaml``).
"""
from __future__ import annotations

from pathlib import Path

from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

SCHEME = "package://"


def share_file(package: str, relative: str | Path) -> Path:
    """``share/<package>/<relative>`` of the installed package; FileNotFoundError if the package is not installed."""
    try:
        return Path(get_package_share_directory(package)) / relative
    except PackageNotFoundError:
        raise FileNotFoundError(f"package '{package}' (for '{relative}') is not in any AMENT_PREFIX_PATH prefix "
                                "(source the workspace's setup file)") from None


def resolve_path(path: str | Path) -> Path:
    """The file a ``package://<package>/<path>`` name stands for; any other path unchanged (a relative path stays
    relative to the working directory)."""
    text = str(path)
    if not text.startswith(SCHEME):
        return Path(path)
    package, _, relative = text[len(SCHEME):].partition("/")
    if not package or not relative:
        raise FileNotFoundError(f"'{text}': expected {SCHEME}<package>/<path>")
    return share_file(package, relative)
