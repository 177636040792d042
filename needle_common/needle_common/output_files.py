"""Output files of the command-line tools: checked before the work starts, written under a temporary name and renamed,
so that a failed or interrupted run leaves no half-written file behind."""
from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path
from typing import Callable


def _writable_folder(folder: Path, label: str) -> None:
    """Create ``folder`` (with its parents) if missing; ValueError starting with ``label`` if it cannot be written."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError) as error:
        raise ValueError(f"{label}: a file is in the way of folder '{folder}'") from error
    except OSError as error:
        raise ValueError(f"{label}: cannot create folder '{folder}': {error.strerror or error}") from error
    if not os.access(folder, os.W_OK):
        raise ValueError(f"{label}: folder '{folder}' is not writable")


def check_output_file(path: Path, what: str) -> Path:
    """``path`` if a file can be written there (its folder is created); ValueError naming ``what`` otherwise."""
    if path.is_dir():
        raise ValueError(f"{what} '{path}' is a directory, not a file")
    _writable_folder(path.parent, f"{what} '{path}'")
    return path


def check_output_dir(path: Path, what: str) -> Path:
    """``path`` as a writable folder (created if missing); ValueError naming ``what`` otherwise."""
    if path.exists() and not path.is_dir():
        raise ValueError(f"{what} '{path}' is a file, not a folder")
    _writable_folder(path, f"{what} '{path}'")
    return path


def write_atomically(path: Path, write: Callable[[Path], None]) -> None:
    """``write(temporary)`` into a hidden folder next to ``path`` under the same file name (writers that infer the
    format from the suffix, or record their file's name -- a rosbag2 MCAP's metadata --, see the final one), then
    rename it to ``path``; the folder is removed in any case."""
    staging = Path(tempfile.mkdtemp(prefix=f".{path.name}.partial-", dir=path.parent))
    try:
        temporary = staging / path.name
        write(temporary)
        os.replace(temporary, path)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
