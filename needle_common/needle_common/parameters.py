"""The one parameter system of the needle_sim suite, without ROS: declarations, params files, ROS arguments.

:class:`ParamSpec` declares a parameter; :func:`load_params_file` reads a ROS 2 params file as strictly as ``rcl``
does plus the specs' ranges, so a file that a node would refuse is refused by the offline tools too, with one
message naming the file, the parameter and the problem (:class:`ParameterError`); :func:`check_ros_arguments`
applies it to a node's command line before ``rclpy.init``. The nodes declare each spec with a
``ParameterDescriptor`` built from it (``needle_common.ros.ros_parameters``). :func:`flatten_tree` is the one
flattening of nested parameters into dotted names.

The declarations themselves live with their packages: ``needle_vision.parameters`` (the stereo node's) and
``needle_sim_ros.parameters`` (the simulator's, the comparison's, the experiment files').
"""
from __future__ import annotations

import difflib
import math
import re
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping, NamedTuple, Sequence

import numpy as np
import yaml

# Parameters every rclpy node has (accepted in any node's section).
ROS_BUILTIN = ("use_sim_time", "start_type_description_service")
QOS_CHOICES = ("sensor_data", "reliable")  # the nodes' qos parameters (needle_common.ros.ros_parameters.qos_profile)
# Nodes of the suite (a section for another name is probably a typo: warned) and the pipeline tools' section.
KNOWN_NODES = ("needle_simulator", "needle_stereo", "needle_compare", "needle_replay", "needle_pipeline")
_TOPIC_TOKEN = re.compile(r"^(~|[A-Za-z_][A-Za-z0-9_]*|\{[A-Za-z_][A-Za-z0-9_]*\})$")


class ParameterError(ValueError):
    """A parameter value or params file is invalid; the message names the file and parameter."""


def valid_topic_name(name: str) -> bool:
    """A ROS 2 topic name (relative, absolute or private): tokens of letters, digits and '_' not starting with a
    digit, separated by single '/', no trailing '/'."""
    if not isinstance(name, str) or not name or name.endswith("/") and name != "/":
        return False
    tokens = name[1:].split("/") if name.startswith("/") else name.split("/")
    return name != "/" and all(_TOPIC_TOKEN.match(t) for t in tokens) and "~" not in tokens[1:]


TOPIC_CHECK = (valid_topic_name, "not a valid ROS 2 topic name (letters, digits, '_' and '/', no leading digit)")


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: name, default (its type is the parameter's type), meaning with unit, valid values.

    ``low``/``high`` bound numbers (and every element of number arrays); ``choices`` lists valid values;
    ``length`` fixes an array's length; ``check`` is an extra predicate with the message shown when it fails (by
    returning false or raising ValueError: a rule's own check, e.g. :func:`needle_common.transforms.unit_quaternion`).
    ``dynamic`` parameters may change while a node runs; ``allow_infinite`` admits +-inf (e.g. "no limit").
    """

    name: str
    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: Sequence[Any] | None = None
    length: int | None = None
    check: tuple[Callable[[Any], bool], str] | None = None
    dynamic: bool = False
    allow_infinite: bool = False

    @property
    def is_list(self) -> bool:
        return isinstance(self.default, (list, tuple))

    @property
    def value_type(self) -> type:
        """bool, int, float or str (of the elements, for a list; an empty default list holds floats)."""
        sample = (self.default[0] if self.default else 0.0) if self.is_list else self.default
        return bool if isinstance(sample, bool) else int if isinstance(sample, int) else \
            float if isinstance(sample, float) else str

    def validate(self, value: Any, strict: bool = False) -> Any:
        """The value (converted to the parameter's type) if valid, else ParameterError naming the parameter.
        ``strict``: types as ROS 2 requires them (an integer is no float: write 1.0)."""
        def fail(reason: str) -> None:
            raise ParameterError(f"parameter '{self.name}' = {value!r}: {reason} ({self.description})")

        expected = self.value_type
        is_list = isinstance(value, (list, tuple, np.ndarray))
        if self.is_list != is_list:
            fail(f"expected a list of {expected.__name__}" if self.is_list else "expected a single value")
        values = list(value) if is_list else [value]
        for v in values:
            numeric = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
            integral = isinstance(v, (int, np.integer)) and not isinstance(v, bool)
            if expected is float and not (numeric and (integral is False or not strict)) \
                    or expected is int and not (integral or not strict and numeric and float(v).is_integer()) \
                    or expected in (str, bool) and not isinstance(v, expected):
                fail(f"expected {'a list of ' if self.is_list else ''}{expected.__name__}"
                     + (" (write 1.0, not 1)" if expected is float and integral else ""))
            if numeric and math.isnan(v) or numeric and math.isinf(v) and not self.allow_infinite:
                fail("must be finite")
            if numeric and self.low is not None and v < self.low:
                fail(f"must be >= {self.low:g}")
            if numeric and self.high is not None and v > self.high:
                fail(f"must be <= {self.high:g}")
        if self.length is not None and len(values) != self.length:
            fail(f"expected {self.length} values, got {len(values)}")
        if self.choices is not None and value not in self.choices:
            fail(f"must be one of {', '.join(map(str, self.choices))}")
        if self.check is not None:
            try:
                passed = self.check[0](value)
            except ValueError:
                passed = False
            if not passed:
                fail(self.check[1])
        return [expected(v) for v in values] if self.is_list else expected(value)


def _set_by_ros(name: str) -> bool:
    """Whether rclpy itself declares the parameter on every node (sim time, QoS overrides)."""
    return name in ROS_BUILTIN or name.startswith("qos_overrides.")


def _did_you_mean(name: str, known: Iterable[str]) -> str:
    """The hint " (did you mean 'Y'?)" naming the known name Y that ``name`` is probably a misspelling of (difflib,
    ratio >= 0.6); "" when there is none."""
    close = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return f" (did you mean '{close[0]}'?)" if close else ""


def unknown_name_error(name: str, known: Iterable[str], where: str = "") -> ParameterError:
    """'unknown parameter X (did you mean Y?)' with the nearest known name (difflib)."""
    return ParameterError(f"{where}unknown parameter '{name}'{_did_you_mean(name, known)}")


def _foreign(name: str, known: Iterable[str], where: str, warn: Callable[[str], None]) -> bool:
    """A name given to every node (a ``-p`` or a wildcard section) that resembles none of this node's: another
    package's (e.g. a parent launch's global ``robot_name``), ignored as rclpy ignores it, with a warning naming it.
    False for a probable misspelling (the caller refuses it with the suggestion)."""
    if _did_you_mean(name, known):
        return False
    _warn_once(warn, f"{where}parameter '{name}' is not one of this node's (nor close to one): ignored")
    return True


def _print_warning(message: str) -> None:
    print(f"warning: {message}", file=sys.stderr)


_warned: set[str] = set()


def _warn_once(warn: Callable[[str], None], message: str) -> None:
    if message not in _warned:
        _warned.add(message)
        warn(message)


class _RclLoader(getattr(yaml, "CSafeLoader", yaml.SafeLoader)):
    """YAML as rcl reads params files: also '1e9' and '1.0e9' are floats (YAML 1.1 needs an exponent sign). LibYAML's
    parser where PyYAML has it (PyPI wheels and Ubuntu's python3-yaml do): the shipped config files, mostly comments,
    parse in 0.55 instead of 8.4 ms each, and every node and offline run reads several."""


_RclLoader.add_implicit_resolver("tag:yaml.org,2002:float",
                                 re.compile(r"^[-+]?([0-9]+\.?[0-9]*|\.[0-9]+)[eE][-+]?[0-9]+$"), list("-+0123456789."))


def _read_document(path: Path) -> Any:
    """The parsed YAML of a params file; ParameterError naming the file for every way reading can fail."""
    if not path.exists():
        raise ParameterError(f"params file '{path}': no such file")
    if path.is_dir():
        raise ParameterError(f"params file '{path}': is a directory, not a file")
    try:
        text = path.read_bytes().decode("utf-8")
    except OSError as error:
        raise ParameterError(f"params file '{path}': cannot read: {error.strerror or error}") from error
    except UnicodeDecodeError as error:
        raise ParameterError(f"params file '{path}': not UTF-8 text (byte {error.start}); is it a YAML file?"
                             ) from error
    try:
        return yaml.load(text, Loader=_RclLoader)  # noqa: S506 - a SafeLoader subclass
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = getattr(error, "problem", None) or str(error).splitlines()[0]
        raise ParameterError(f"params file '{path}': malformed YAML{where}: {problem}") from error


def _sections(document: dict, path: Path, prefix: tuple[str, ...] = ()) -> list[tuple[tuple[str, ...], dict]]:
    """(node name pattern as tokens, ros__parameters tree) of every section, namespaces nested or in the key."""
    found = []
    for key, value in document.items():
        tokens = prefix + tuple(t for t in str(key).split("/") if t)
        name = "/" + "/".join(tokens)
        if key == "ros__parameters":
            if not prefix:
                raise ParameterError(f"params file '{path}': 'ros__parameters' must be under a node name "
                                     "(e.g. '/**:' or 'needle_simulator:')")
            if not isinstance(value, dict):
                raise ParameterError(f"params file '{path}': '{name}/ros__parameters' must be a mapping of "
                                     f"parameter names to values, got {type(value).__name__}")
            found.append((prefix, value))
        elif isinstance(value, dict) and value:
            found += _sections(value, path, tokens)
        else:
            owner = "/" + "/".join(prefix) if prefix else name
            node = prefix[-1] if prefix else key
            raise ParameterError(f"params file '{path}': section '{owner}' has no 'ros__parameters' (expected "
                                 f"'{node}: {{ros__parameters: {{name: value}}}}')")
    return found


def _pattern_matches(pattern: tuple[str, ...], tokens: tuple[str, ...]) -> bool:
    """rcl's node-name wildcards: '**' any number of tokens, '*' within one token."""
    if not pattern:
        return not tokens
    if pattern[0] == "**":
        return any(_pattern_matches(pattern[1:], tokens[k:]) for k in range(len(tokens) + 1))
    if not tokens:
        return False
    regex = "^" + ".*".join(map(re.escape, pattern[0].split("*"))) + "$"
    return bool(re.match(regex, tokens[0])) and _pattern_matches(pattern[1:], tokens[1:])


def flatten_tree(tree: Mapping, where: Callable[[str], str] | None = None, prefix: str = "") -> dict[str, Any]:
    """Nested parameters -> dotted names (``{"a": {"b": 1}}`` -> ``{"a.b": 1}``), values as they are. With ``where``
    (a dotted name -> the place an error names), each value is checked as rcl checks a params file's: a scalar or
    a list of one scalar type, no null, no empty mapping (ParameterError)."""
    flat: dict[str, Any] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and (value or where is None):
            flat.update(flatten_tree(value, where, name + "."))
        else:
            flat[name] = value if where is None else _rcl_value(value, where(name))
    return flat


def params_file_text(sections: Mapping[str, Mapping[str, Any]]) -> str:
    """A ROS 2 params file of ``{node: {dotted name: value}}``: each node's ``ros__parameters`` with the dotted
    names nested (the inverse of :func:`flatten_tree`), tuples written as lists."""
    document: dict[str, Any] = {}
    for node, values in sections.items():
        tree = document.setdefault(node, {"ros__parameters": {}})["ros__parameters"]
        for name, value in values.items():
            *groups, leaf = name.split(".")
            branch = tree
            for group in groups:
                branch = branch.setdefault(group, {})
            branch[leaf] = list(value) if isinstance(value, (list, tuple)) else value
    return yaml.safe_dump(document, sort_keys=False)


def _rcl_value(value: Any, where: str) -> Any:
    """``value`` if rcl takes it as a parameter's value (a scalar or a list of one scalar type), else
    ParameterError starting with ``where``."""
    if isinstance(value, Mapping):
        raise ParameterError(f"{where}: empty mapping has no value")
    items = value if isinstance(value, list) else [value]
    if value is None or any(v is None for v in items):
        raise ParameterError(f"{where}: no value (null)")
    kinds = {type(v) for v in items}
    if not kinds <= {bool, int, float, str}:
        raise ParameterError(f"{where}: lists may hold only numbers, strings or booleans, not "
                             f"{', '.join(sorted(k.__name__ for k in kinds - {bool, int, float, str}))}")
    if len(kinds) > 1:
        hint = " (write 1.0, not 1)" if kinds == {int, float} else ""
        raise ParameterError(f"{where} = {value!r}: a list must hold one type, not "
                             f"{' and '.join(sorted(k.__name__ for k in kinds))}{hint}")
    return value


def parameter_tree(source: str | Path | Mapping) -> Mapping:
    """The merged, flattened ``ros__parameters`` of a params file's (or its mapping's) top-level sections in file
    order, or the mapping itself if it has no such section; loose: no node name is matched, nothing validated.
    FileNotFoundError for a missing file, ParameterError for one that does not parse."""
    if isinstance(source, (str, Path)):
        path = Path(source)
        if not path.is_file():
            raise FileNotFoundError(f"parameter file not found: {path}")
        source = _read_document(path) or {}
    if not isinstance(source, Mapping):
        raise ParameterError(f"parameters must be a mapping, got {type(source).__name__}")
    sections = [v["ros__parameters"] for v in source.values() if isinstance(v, Mapping) and "ros__parameters" in v]
    if not sections:
        return source
    merged: dict[str, Any] = {}
    for section in sections:
        merged.update(flatten_tree(section))
    return merged


def load_params_file(path: str | Path, node_name: str, specs: Sequence[ParamSpec] | None = None,
                     namespace: str = "/", warn: Callable[[str], None] = _print_warning,
                     known_elsewhere: Iterable[str] = (), require_section: bool = True) -> dict[str, Any]:
    """The values for node ``node_name`` (in ``namespace``) from a ROS 2 params file, dotted names, sections applied in
    file order as rcl does. The whole file is checked as rcl checks it; with ``specs``
    the node's values are validated too: unknown names suggest the nearest known one, except that in a wildcard
    section (``/**``) names in ``known_elsewhere`` belong to other nodes started with the same file and names like
    none of the node's are another package's (warned about and ignored, as rclpy ignores them). An empty file, a
    section for no node of the suite or (``require_section``) a file without a section for this node is warned
    about. Raises ParameterError naming the file."""
    path = Path(path)
    document = _read_document(path)
    if document is None:
        _warn_once(warn, f"params file '{path}' is empty: no parameters set")
        return {}
    if not isinstance(document, dict):
        raise ParameterError(f"params file '{path}': expected a mapping of node names to "
                             f"{{ros__parameters: ...}}, got {type(document).__name__}")
    fq_tokens = tuple(t for t in namespace.split("/") if t) + (node_name,)
    by_name = {spec.name: spec for spec in specs or ()}
    others = set(known_elsewhere)
    values: dict[str, Any] = {}
    applied = False
    for pattern, tree in _sections(document, path):
        section = "/" + "/".join(pattern)
        flat = flatten_tree(tree, lambda name: f"params file '{path}', section '{section}': parameter '{name}'")
        if not any(_pattern_matches(pattern, (node,)) or _pattern_matches(pattern, fq_tokens) for node in KNOWN_NODES):
            _warn_once(warn, f"params file '{path}': section '{section}' is for no node of needle_sim"
                             f"{_did_you_mean(pattern[-1], KNOWN_NODES)}; ignored")
        if not _pattern_matches(pattern, fq_tokens):
            continue
        applied = True
        for name, value in flat.items():
            where = f"params file '{path}', node '{node_name}': "
            if specs is not None and name not in by_name:
                if _set_by_ros(name) or "*" in section and (name in others or _foreign(name, by_name, where, warn)):
                    continue
                raise unknown_name_error(name, by_name, where)
            try:
                values[name] = by_name[name].validate(value, strict=True) if specs is not None else value
            except ParameterError as error:
                raise ParameterError(where + str(error)) from error
    if not applied and require_section:
        _warn_once(warn, f"params file '{path}' has no section for node '{node_name}' (nor '/**'): it sets nothing")
    return values


class RosArguments(NamedTuple):
    """The parts of a command line's ``--ros-args`` that set a node's parameters, and the command line less its
    ``--params-file FILE`` pairs (``rcl_arguments``: rcl would parse the files' contents, which
    :func:`check_ros_arguments` checks with messages that name the problem)."""

    params_files: list[str]
    node_name: str | None                   # the __node remap, if any
    namespace: str
    overrides: list[tuple[str | None, str]]  # (node the rule is for, or None for every node; name) of -p/--param
    rcl_arguments: list[str]


def ros_arguments(argv: Sequence[str]) -> RosArguments:
    """Params files, node name remap, namespace and parameter overrides from the ``--ros-args`` parts of argv."""
    parsed = RosArguments([], None, "/", [], [])
    inside, k = False, 0
    while k < len(argv):
        arg, start = argv[k], k
        if arg == "--ros-args":
            inside = True
        elif arg == "--":
            inside = False
        elif inside and arg == "--params-file" and k + 1 < len(argv):
            parsed.params_files.append(argv[k + 1])
            k += 2
            continue
        elif inside and arg in ("-p", "--param") and k + 1 < len(argv):
            target, _, name = argv[k + 1].partition(":=")[0].rpartition(":")
            parsed.overrides.append((target or None, name))
            k += 1
        elif inside and arg in ("-r", "--remap") and k + 1 < len(argv):
            rule = argv[k + 1].split(":", 1)[-1] if argv[k + 1].count(":=") and ":__" in argv[k + 1] else argv[k + 1]
            if rule.startswith("__node:="):
                parsed = parsed._replace(node_name=rule.split(":=", 1)[1])
            elif rule.startswith("__ns:="):
                parsed = parsed._replace(namespace=rule.split(":=", 1)[1])
            k += 1
        k += 1
        parsed.rcl_arguments.extend(argv[start:k])
    return parsed


def check_ros_arguments(argv: Sequence[str], node_name: str, specs: Sequence[ParamSpec] | None,
                        warn: Callable[[str], None] = _print_warning,
                        known_elsewhere: Iterable[str] = ()) -> RosArguments:
    """Check every ``--params-file`` of a node's command line with :func:`load_params_file` before rclpy reads it (rcl's
    own parser would fail with a traceback), and the names of its ``-p name:=value`` overrides (rclpy would ignore an
    undeclared one silently); the parsed command line, or ParameterError. A ``-p`` rule without a node prefix reaches
    every node started with the command line: names in ``known_elsewhere`` belong to the others. A ``-p`` name (and a
    wildcard section's) that resembles none of the node's is warned about and ignored; a misspelling of one is refused
    with the suggestion."""
    parsed = ros_arguments(argv)
    node = parsed.node_name or node_name
    for path in parsed.params_files:
        load_params_file(path, node, specs, parsed.namespace, warn, known_elsewhere)
    names = {spec.name for spec in specs or ()}
    others = set(known_elsewhere)
    for target, name in parsed.overrides:
        if not names or target not in (None, node) or name in names or _set_by_ros(name) \
                or target is None and name in others:
            continue
        where = f"parameter override '-p {name}:=...' for node '{node}': "
        if not _foreign(name, names, where, warn):
            raise unknown_name_error(name, names, where)
    return parsed
