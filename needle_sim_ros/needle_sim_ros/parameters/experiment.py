"""Parameters of the three pipeline nodes and of an experiment, read from ROS 2 params files without ROS.

An experiment file (``share/needle_sim_ros/config/experiments/<bag>.yaml``) is a ROS 2 params file with a section
per node (per-bag overrides) and a ``needle_pipeline`` section for the pipeline tools (bag, stereo on/off, plot
instants). The nodes get the node config files (``share/<package>/config/<node>.yaml``), then the experiment file,
later files overriding earlier ones as ``--params-file`` does; the offline pipeline reads them in the same order.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

from needle_common.package_files import share_file
from needle_common.parameters import ROS_BUILTIN, ParamSpec, load_params_file, unknown_name_error

#: The pipeline's nodes and the package whose share directory holds each node's config file.
NODE_PACKAGES = {"needle_simulator": "needle_sim_ros", "needle_stereo": "needle_vision",
                 "needle_compare": "needle_sim_ros"}
NODES = tuple(NODE_PACKAGES)
PIPELINE_SECTION = "needle_pipeline"


class ExperimentConfigError(ValueError):
    """The experiment file is unusable; the message names the file and key."""


def node_config_files(config_dir: Path | None = None) -> dict[str, list[Path]]:
    """The node config files that exist, per node: ``<config_dir>/<node>.yaml``, by default the file the node's
    package installs (``share/<package>/config/<node>.yaml``)."""
    paths = {node: config_dir / f"{node}.yaml" if config_dir else share_file(package, f"config/{node}.yaml")
             for node, package in NODE_PACKAGES.items()}
    return {node: [path] if path.is_file() else [] for node, path in paths.items()}


def node_specs(node: str) -> list[ParamSpec]:
    """The parameter declarations of a pipeline node."""
    if node == "needle_stereo":
        from needle_vision.parameters import SPECS
        return list(SPECS)
    if node == "needle_compare":
        from needle_sim_ros.parameters.compare import COMPARE_PARAMETERS
        return COMPARE_PARAMETERS
    from needle_sim_ros.parameters.simulator import SIMULATOR_PARAMETERS
    return SIMULATOR_PARAMETERS


def node_values(files: Sequence[Path], node: str) -> dict[str, Any]:
    """Parameter values for ``node`` from params files applied in order (``/**`` and the node's own section),
    each checked against the node's declarations as the node checks them (ParameterError naming the file); an
    experiment file need not have a section for every node."""
    values: dict[str, Any] = {}
    for path in files:
        values.update(load_params_file(path, node, node_specs(node), require_section=False))
    return values


def node_parameters(node: str, values: Mapping[str, Any], base: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """``base`` (default: the node's declared defaults) updated with ``values``, each checked against its
    declaration as the node checks it; a name the node does not declare (besides rclpy's own) is an error suggesting
    the nearest declared one."""
    specs = {spec.name: spec for spec in node_specs(node)}
    result = dict(base) if base is not None else {name: spec.default for name, spec in specs.items()}
    for name, value in values.items():
        if name in specs:
            result[name] = specs[name].validate(value)
        elif name not in ROS_BUILTIN:
            raise unknown_name_error(name, specs, f"{node}: ")
    return result


@dataclass(frozen=True)
class PipelineSettings:
    """The ``needle_pipeline`` section: bag (a relative path is taken from the directory holding ``config/``),
    stereo on/off, plot instants [s from the bag start] (empty: spread over the measurements)."""

    bag: Path
    stereo: bool = True
    plot_instants: tuple[float, ...] = ()
    description: str = ""


@dataclass(frozen=True)
class ExperimentConfig:
    """Everything an experiment run needs: its file, the pipeline settings and each node's parameter files."""

    path: Path
    settings: PipelineSettings
    files: dict[str, list[Path]] = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.path.stem

    def values(self, node: str, overrides: Mapping[str, Any] | None = None) -> dict[str, Any]:
        """Every parameter of ``node``: the declared default, the node config's and the experiment file's values
        (checked as they are read), then ``overrides`` (checked here)."""
        defaults = {spec.name: spec.default for spec in node_specs(node)}
        return node_parameters(node, overrides or {}, {**defaults, **node_values(self.files[node], node)})


def load_experiment(path: str | Path, config_dir: Path | None = None) -> ExperimentConfig:
    """Read an experiment file (``<root>/config/experiments/<name>.yaml``) with the node config files of
    ``config_dir`` (default: the installed ones, :func:`node_config_files`); raises ExperimentConfigError naming
    the problem. The path is not resolved through symbolic links: the bag is relative to ``<root>``."""
    path = Path(path).absolute()
    if not path.is_file():
        raise ExperimentConfigError(f"experiment file '{path}': no such file")
    raw = load_params_file(path, PIPELINE_SECTION)
    for node in NODES:  # every node's section checked now, before anything runs
        load_params_file(path, node, node_specs(node), require_section=False)
    if "bag" not in raw:
        raise ExperimentConfigError(f"'{path}': section {PIPELINE_SECTION}.ros__parameters needs 'bag'")
    instants = raw.get("plot_instants", [])
    if not isinstance(instants, list) or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in instants):
        raise ExperimentConfigError(f"'{path}': {PIPELINE_SECTION}.plot_instants must be a list of numbers [s]")
    bag = Path(raw["bag"])
    settings = PipelineSettings(bag if bag.is_absolute() else path.parents[2] / bag, bool(raw.get("stereo", True)),
                                tuple(float(v) for v in instants), str(raw.get("description", "")))
    files = {node: [*node_config_files(config_dir)[node], path] for node in NODES}
    return ExperimentConfig(path, settings, files)


def experiments_dir(config_dir: Path | None = None) -> Path:
    """``<config_dir>/experiments``, by default the directory needle_sim_ros installs
    (``share/needle_sim_ros/config/experiments/``)."""
    return config_dir / "experiments" if config_dir else share_file("needle_sim_ros", "config/experiments")


def experiment_for_bag(bag: str | Path, config_dir: Path | None = None) -> ExperimentConfig:
    """The experiment file of a bundled bag: ``<config_dir>/experiments/<bag stem>.yaml``, by default the one
    needle_sim_ros installs (``share/needle_sim_ros/config/experiments/``)."""
    path = experiments_dir(config_dir) / f"{Path(bag).stem}.yaml"
    if not path.is_file():
        raise ExperimentConfigError(f"no experiment file for bag '{bag}': expected '{path}'")
    return load_experiment(path, config_dir)
