"""The bags of a batch: ``--bags`` as a folder, a glob or a manifest, and each bag's content hash. A manifest lists
one bag per line (relative to the manifest's folder), optionally followed by its experiment params file; ``#``
starts a comment. A listed bag that is missing becomes a failed row, not an error of the whole run.
"""
from __future__ import annotations

import glob
import hashlib
from dataclasses import dataclass
from pathlib import Path

CHUNK = 1 << 20


class BagListError(ValueError):
    """``--bags`` names nothing usable; the message says what."""


@dataclass(frozen=True)
class BagEntry:
    """A bag path and its experiment file (None: ``<config>/experiments/<bag stem>.yaml``)."""

    path: str
    experiment: str | None = None


def _is_bag(path: Path) -> bool:
    return path.suffix == ".mcap" or (path.is_dir() and (path / "metadata.yaml").is_file())


def read_manifest(path: Path) -> list[BagEntry]:
    entries = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        fields = line.split("#", 1)[0].split()
        if not fields:
            continue
        if len(fields) > 2:
            raise BagListError(f"manifest '{path}' line {number}: expected 'BAG [EXPERIMENT_FILE]'")
        resolved = [str(p if p.is_absolute() else path.parent / p) for p in map(Path, fields)]
        entries.append(BagEntry(resolved[0], resolved[1] if len(resolved) > 1 else None))
    return entries


def resolve_bags(spec: str) -> list[BagEntry]:
    """Folder (its ``*.mcap`` files and rosbag2 folders, sorted), glob (sorted matches) or manifest file."""
    path = Path(spec)
    if any(c in spec for c in "*?["):
        entries, empty = [BagEntry(str(Path(p))) for p in sorted(glob.glob(spec))], "the pattern matches no file"
    elif path.is_dir() and not _is_bag(path):
        entries = [BagEntry(str(p)) for p in sorted(path.iterdir()) if _is_bag(p)]
        empty = "the folder holds no .mcap bag"
    elif path.is_file() and path.suffix != ".mcap":
        entries, empty = read_manifest(path), "the manifest lists no bag"
    elif _is_bag(path) and path.exists():  # a missing bag is a failed row only in a manifest (module docstring)
        return [BagEntry(str(path))]
    else:
        raise BagListError(f"--bags '{spec}': no such folder, bag or manifest")
    if not entries:
        raise BagListError(f"--bags '{spec}': {empty}")
    return entries


def content_hash(path: str) -> str:
    """SHA-256 of the bag's bytes (a rosbag2 folder: of its files in name order); 'missing' if unreadable."""
    digest = hashlib.sha256()
    target = Path(path)
    try:
        files = sorted(p for p in target.rglob("*") if p.is_file()) if target.is_dir() else [target]
        for file in files:
            with open(file, "rb") as stream:
                while chunk := stream.read(CHUNK):
                    digest.update(chunk)
    except OSError:
        return "missing"
    return digest.hexdigest()
