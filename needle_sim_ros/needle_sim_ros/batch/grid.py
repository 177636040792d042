"""Grid files of ``needle_batch sweep``: parameter sets as per-node overrides, named exactly as in the params files.

A grid file is YAML with a ``sweep:`` key (node sections whose parameters hold lists of values: their full factorial)
and/or a ``points:`` key (a list of node sections: a listed set)::

    sweep:
      needle_simulator:
        ros__parameters:
          damping.rayleigh_beta: [1.0e-4, 2.0e-4]
          tissue.layers.tip_stiffness: [[9.0e+3], [1.2e+4]]   # an array-valued parameter: a list of arrays

Nested keys are dotted as in a ROS 2 params file. ``name[i]`` sets element i of an array-valued parameter.
"""
from __future__ import annotations

import itertools
import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from needle_sim_ros.parameters.experiment import NODES, node_specs
from needle_common.parameters import ParameterError, ParamSpec, flatten_tree

ParameterSet = dict[str, dict[str, Any]]  # node -> parameter name -> value
SPECS: dict[str, dict[str, ParamSpec]] = {node: {s.name: s for s in node_specs(node)} for node in NODES}
INDEXED = re.compile(r"^(?P<name>[^\[\]]+)\[(?P<index>\d+)\]$")


class GridError(ValueError):
    """The grid file is unusable; the message names the file and the key."""


def split_index(name: str) -> tuple[str, int | None]:
    """``tissue.layers.tip_stiffness[0]`` -> (``tissue.layers.tip_stiffness``, 0); a plain name -> (name, None)."""
    match = INDEXED.match(name)
    return (match["name"], int(match["index"])) if match else (name, None)


def check_value(node: str, name: str, value: Any) -> Any:
    """``value`` validated as the node validates parameter ``name`` (an indexed name: one array element)."""
    if node not in SPECS:
        raise GridError(f"unknown node section '{node}' (expected one of {', '.join(NODES)})")
    base, index = split_index(name)
    spec = SPECS[node].get(base)
    if spec is None:
        raise GridError(f"{node}: no parameter '{base}' (names are those of the node's params file)")
    if index is not None:
        if not spec.is_list:
            raise GridError(f"{node}: '{base}' is not an array: '{name}' cannot index it")
        if isinstance(value, (list, dict)):
            raise GridError(f"{node}: '{name}' is one array element: give a number")
        return value
    try:
        spec.validate(list(value) if spec.is_list and isinstance(value, list) else value)
    except ParameterError as error:
        raise GridError(f"{node}: {error}") from error
    return value


def node_sections(document: Any, where: str) -> dict[str, dict[str, Any]]:
    """``{node: {ros__parameters: {...}}}`` -> ``{node: {dotted name: value}}``."""
    if not isinstance(document, dict):
        raise GridError(f"{where}: expected node sections ({', '.join(NODES)}) with ros__parameters")
    sections = {}
    for node, section in document.items():
        node = str(node).lstrip("/")
        if not isinstance(section, dict) or not isinstance(section.get("ros__parameters"), dict):
            raise GridError(f"{where}.{node}: expected a 'ros__parameters' mapping")
        sections[node] = flatten_tree(section["ros__parameters"])
    return sections


def sweep_sets(document: Any) -> list[ParameterSet]:
    """The full factorial of the ``sweep:`` sections, in file order (the last parameter varies fastest)."""
    axes: list[tuple[str, str, list[Any]]] = []
    for node, values in node_sections(document, "sweep").items():
        for name, options in values.items():
            base, index = split_index(name)
            if not isinstance(options, list) or not options:
                raise GridError(f"sweep.{node}.{name}: expected a non-empty list of values")
            spec = SPECS.get(node, {}).get(base)
            if spec is not None and spec.is_list and index is None and not all(isinstance(v, list) for v in options):
                raise GridError(f"sweep.{node}.{name}: an array-valued parameter is swept as a list of arrays, "
                                f"e.g. [[1.0], [2.0]]")
            axes.append((node, name, [check_value(node, name, v) for v in options]))
    sets = []
    for combination in itertools.product(*(options for _, _, options in axes)):
        parameter_set: ParameterSet = {}
        for (node, name, _), value in zip(axes, combination):
            parameter_set.setdefault(node, {})[name] = value
        sets.append(parameter_set)
    return sets


def point_sets(document: Any) -> list[ParameterSet]:
    if not isinstance(document, list) or not document:
        raise GridError("points: expected a non-empty list of node sections")
    return [{node: {name: check_value(node, name, v) for name, v in values.items()}
             for node, values in node_sections(point, f"points[{i}]").items()} for i, point in enumerate(document)]


@dataclass(frozen=True)
class Grid:
    """The parameter sets of a grid file and the swept columns (``node:name``) in file order."""

    parameter_sets: list[ParameterSet]
    columns: list[str]


def column(node: str, name: str) -> str:
    return f"{node}:{name}"


def load_grid(path: str | Path) -> Grid:
    """Read a grid file; raises GridError naming the file and the problem."""
    path = Path(path)
    try:
        document = yaml.safe_load(path.read_text())
    except OSError as error:
        raise GridError(f"grid file '{path}': {error.strerror}") from error
    except yaml.YAMLError as error:
        raise GridError(f"grid file '{path}': not YAML ({str(error).splitlines()[0]})") from error
    if not isinstance(document, dict) or not {"sweep", "points"} & set(document):
        raise GridError(f"grid file '{path}': expected a top-level 'sweep:' and/or 'points:' key")
    unknown = set(document) - {"sweep", "points"}
    if unknown:
        raise GridError(f"grid file '{path}': unknown top-level key(s) {', '.join(sorted(map(str, unknown)))}")
    try:
        sets = (sweep_sets(document["sweep"]) if "sweep" in document else []) + \
            (point_sets(document["points"]) if "points" in document else [])
    except GridError as error:
        raise GridError(f"grid file '{path}': {error}") from error
    columns = list(dict.fromkeys(column(node, name) for s in sets for node, values in s.items() for name in values))
    return Grid(sets, columns)


def canonical(parameter_set: ParameterSet) -> str:
    """A parameter set as canonical JSON (sorted keys): the same set, the same text."""
    return json.dumps(parameter_set, sort_keys=True, separators=(",", ":"))
