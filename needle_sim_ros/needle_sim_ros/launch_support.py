"""Launch-time choices of the needle_sim launch files, without the launch package (testable anywhere).

The launch files (``share/needle_sim_ros/launch``) call these from an ``OpaqueFunction``.
"""
from __future__ import annotations

import atexit
import os
import tempfile
import time
from functools import partial
from pathlib import Path

import yaml

MODES = ("sim", "replay", "external", "hil")


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
    """What a bringup mode runs: simulated time with the built-in bag player (replay) or another /clock source
    (external: ``ros2 bag play --clock``), the measurement side by default in both; the haptic output (hil)."""
    if mode not in MODES:
        raise ValueError(f"launch argument 'mode' = '{mode}': must be one of {', '.join(MODES)}")
    if mode == "replay" and not bag:
        raise ValueError("launch argument 'bag' is empty: mode:=replay needs bag:=/path/to/bag.mcap")
    if mode == "replay" and not Path(bag).expanduser().exists():  # before any node starts (and a log is opened)
        raise ValueError(f"launch argument 'bag' = '{bag}': no such MCAP file or bag directory")
    if mode != "replay" and bag:
        raise ValueError(f"launch argument 'bag' = '{bag}': only mode:=replay plays a bag (mode:=external: "
                         "play it with 'ros2 bag play --clock')")
    recorded = mode in ("replay", "external")
    return {"use_sim_time": recorded, "player": mode == "replay", "stereo": recorded, "compare": recorded,
            "haptics": mode == "hil"}


def flag(name: str, value: str) -> bool:
    """A true/false launch argument; anything else is an error naming it."""
    if value.lower() not in ("true", "false"):
        raise ValueError(f"launch argument '{name}' = '{value}': must be true or false")
    return value.lower() == "true"


def full_namespace(pushed: str | None, namespace: str) -> str:
    """The nodes' namespace as launch_ros forms it: an absolute ``namespace`` as is, a relative one under the
    namespace a parent launch pushed (PushRosNamespace, launch configuration ``ros_namespace``); '/' for none."""
    tokens = [t for t in namespace.split("/") if t]
    if not namespace.startswith("/"):
        tokens = [t for t in (pushed or "").split("/") if t] + tokens
    return "/" + "/".join(tokens)


def namespaced_params_file(path: str) -> str:
    """A params file whose sections keyed by a bare node name (``needle_simulator:``) apply under any namespace:
    ``path`` itself if it has none, else a copy (in the temporary directory, removed when the launch process
    exits) with those keys as ``/**/needle_simulator``; rcl matches a bare name only in the root namespace."""
    if not path:
        return path
    document = yaml.safe_load(Path(path).read_text())
    if not isinstance(document, dict) or all(str(key).startswith("/") for key in document):
        return path  # nothing to rewrite; the nodes report a malformed file themselves
    rewritten = {key if str(key).startswith("/") else f"/**/{key}": value for key, value in document.items()}
    with tempfile.NamedTemporaryFile("w", prefix=f"{Path(path).stem}_", suffix=".yaml", delete=False) as stream:
        stream.write(f"# {path}, its node sections matched in any namespace (needle_sim bringup.launch.py)\n")
        yaml.safe_dump(rewritten, stream, sort_keys=False)
    atexit.register(Path(stream.name).unlink, missing_ok=True)
    return stream.name


def failed_transition(start_state: str, goal_state: str) -> bool:
    """A lifecycle transition event (state labels) that means a transition failed: configure refused
    (configuring -> unconfigured) or any callback's error (errorprocessing -> ...)."""
    return (start_state, goal_state) == ("configuring", "unconfigured") or start_state == "errorprocessing"


def exit_error(name: str, returncode: int, shutting_down: bool) -> str:
    """Why a node's exit fails the launch ('' if it does not): a non-zero status outside the launch's shutdown."""
    if returncode == 0 or shutting_down:
        return ""
    return f"{name} exited with status {returncode}: the launch stops"


# [s] the bag player waits at most this long for the nodes to match its topics: it plays as soon as they did, and a
# node compiling its kernels cold (an install built with NEEDLE_COMPILE_KERNELS=0, a cache from another CPU) takes
# minutes on 2 cores before it subscribes (30 s played the bag's start to nobody)
PLAYER_WAIT = 300.0


def player_arguments(bag: str, namespace: str, nodes: list[str], compress_images: str = "") -> list[str]:
    """``needle_replay``'s arguments in mode:=replay: the whole bag in simulated time (/clock), in ``namespace``,
    played once each of ``nodes`` (names in ``namespace``) has matched the bag's topics it subscribes to from its own
    side (discovery is two-sided); ``compress_images`` ('png', 'jpeg'): raw images as CompressedImage."""
    prefix = "/" + namespace.strip("/") if namespace.strip("/") else ""
    return [bag, "--clock", *(["--in-namespace"] if prefix else []), "--wait-for-subscribers", f"{PLAYER_WAIT:g}",
            "--wait-for-nodes", *(f"{prefix}/{node}" for node in nodes),
            *(["--compress-images", compress_images] if compress_images else [])]


def choice(name: str, value: str, allowed: tuple[str, ...]) -> str:
    """A launch argument that must be one of ``allowed``; anything else is an error naming it."""
    if value not in allowed:
        raise ValueError(f"launch argument '{name}' = '{value}': must be {' or '.join(allowed)}")
    return value


image_transport = partial(choice, "image_transport", allowed=("raw", "compressed"))
image_codec = partial(choice, "image_codec", allowed=("png", "jpeg"))
