"""Launch-time choices of the needle_sim launch files, without the launch package (testable anywhere).

The launch files (``share/needle_sim_ros/launch``) call these from an ``OpaqueFunction``.
"""
from __future__ import annotations

import os
import time
from pathlib import Path

MODES = ("sim", "replay", "hil")


def experiment_file(value: str, config_dir: Path) -> str:
    """'' -> '' (none); an existing path -> that path; a name -> ``config_dir/experiments/<name>.yaml``."""
    if not value:
        return ""
    path = Path(value).expanduser()
    if path.suffix not in (".yaml", ".yml"):
        path = config_dir / "experiments" / f"{value}.yaml"
    if not path.is_file():
        known = sorted(p.stem for p in (config_dir / "experiments").glob("*.yaml"))
        raise ValueError(f"launch argument 'experiment' = '{value}': no file {path} "
                         f"(bundled experiments: {', '.join(known) or 'none'})")
    return str(path.resolve())


def unique_log_path(value: str, directory: str, stamp: float | None = None, pid: int | None = None) -> str:
    """The comparison log: ``value`` if given, else ``directory/needle_compare_<UTC time>_<pid>.mcap`` (a new name
    for every launch, so a second run never meets the first one's file)."""
    if value:
        return value
    moment = time.strftime("%Y%m%d_%H%M%S", time.gmtime(time.time() if stamp is None else stamp))
    return str(Path(directory).expanduser() / f"needle_compare_{moment}_{os.getpid() if pid is None else pid}.mcap")


def mode_settings(mode: str, bag: str) -> dict[str, bool]:
    """What a bringup mode runs: simulated time and the bag player (replay), the measurement side by default."""
    if mode not in MODES:
        raise ValueError(f"launch argument 'mode' = '{mode}': must be one of {', '.join(MODES)}")
    if mode == "replay" and not bag:
        raise ValueError("launch argument 'bag' is empty: mode:=replay needs bag:=/path/to/bag.mcap")
    return {"use_sim_time": mode == "replay", "player": mode == "replay", "stereo": mode == "replay",
            "compare": mode == "replay"}


PLAYER_WAIT = 30.0  # [s] the bag player waits at most this long for the nodes to match its topics


def player_arguments(bag: str, namespace: str, nodes: list[str]) -> list[str]:
    """``needle_replay``'s arguments in mode:=replay: the whole bag in simulated time (/clock), in ``namespace``
    where the nodes read it, played once each of ``nodes`` (names in ``namespace``) has matched, from its own side,
    the bag's topics it subscribes to: discovery is two-sided, and what is played before a subscriber has matched
    is lost."""
    prefix = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return [bag, "--clock", *(["--in-namespace"] if prefix else []), "--wait-for-subscribers", f"{PLAYER_WAIT:g}",
            "--wait-for-nodes", *(f"{prefix}/{node}" for node in nodes)]
