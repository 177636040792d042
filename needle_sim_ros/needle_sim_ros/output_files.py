"""Output files of the command-line tools: checked before the work starts, written under a temporary name and renamed,
so that a failed or interrupted run leaves no half-written file behind."""
from __future__ import annotations

import os
from pathlib import Path
from typing import Callable


def check_output_file(path: Path, what: str) -> Path:
    """``path`` if a file can be written there (its folder is created); ValueError naming ``what`` otherwise."""
    if path.is_dir():
        raise ValueError(f"{what} '{path}' is a directory, not a file")
    folder = path.parent
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError) as error:
        raise ValueError(f"{what} '{path}': a file is in the way of its folder '{folder}'") from error
    except OSError as error:
        raise ValueError(f"{what} '{path}': cannot create its folder: {error.strerror or error}") from error
    if not os.access(folder, os.W_OK):
        raise ValueError(f"{what} '{path}': folder '{folder}' is not writable")
    return path


def write_atomically(path: Path, write: Callable[[Path], None]) -> None:
    """``write(temporary)`` next to ``path``, then rename it to ``path`` (the temporary is removed on failure)."""
    temporary = path.with_name(f".{path.name}.partial{path.suffix}")  # same suffix: writers that infer the format
    try:
        write(temporary)
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)
