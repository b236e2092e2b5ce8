"""The ROS 2 command line: ``--ros-args`` parsing and ROS 2 parameters files.

Pure functions, free of any middleware. The accepted syntax is rcl's (Jazzy):
``--ros-args [-p|--param name:=value] [-r|--remap [node:]from:=to] [--params-file FILE]
[--log-level [logger:=]LEVEL] [-e|--enclave ENCLAVE] [--] ...``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from exo_has_runtime.errors import CommandLineError
from exo_has_runtime.names import RemapRule

#: A parameter value as ROS 2 stores it.
ParameterValue = (
    bool | int | float | str | bytes | list[bool] | list[int] | list[float] | list[str]
)

_LOG_LEVELS = ('debug', 'info', 'warn', 'error', 'fatal')


class RosYamlLoader(yaml.SafeLoader):
    """YAML loader that reads floats as rcl does: ``1e9`` and ``1.0e9`` are doubles.

    PyYAML follows YAML 1.1, where an exponent needs a dot and a sign (``1.0e+9``), so
    ``bulk_modulus: 1.0e9`` would otherwise arrive as a string.
    """


RosYamlLoader.add_implicit_resolver(
    'tag:yaml.org,2002:float',
    re.compile(r'^[-+]?(?:\d[\d_]*)?(?:\.\d*)?[eE][-+]?\d+$'),
    list('-+0123456789.'))


def load_yaml(text: str) -> object:
    """Parse YAML text with :class:`RosYamlLoader`."""
    return yaml.load(text, Loader=RosYamlLoader)


def read_yaml_file(path: Path, what: str = 'parameters file') -> object:
    """Read and parse a YAML file with :class:`RosYamlLoader`.

    Raises
    ------
    CommandLineError
        Naming the file when it cannot be read or is not YAML.

    """
    try:
        return load_yaml(path.read_text(encoding='utf-8'))
    except OSError as exc:
        msg = f'cannot read {what} {path}: {exc.strerror}'
        raise CommandLineError(msg) from exc
    except yaml.YAMLError as exc:
        msg = f'{what} {path} is not valid YAML: {exc}'
        raise CommandLineError(msg) from exc
_FLAGS_WITHOUT_VALUE = frozenset((
    '--enable-rosout-logs', '--disable-rosout-logs', '--enable-stdout-logs',
    '--disable-stdout-logs', '--enable-external-lib-logs', '--disable-external-lib-logs',
))


@dataclass(frozen=True)
class ParameterOverride:
    """A parameter value given on the command line or in a parameters file.

    Attributes
    ----------
    node_pattern : str
        Fully qualified node name the value applies to; ``*`` matches one name token and
        ``**`` any number of them (``/**`` applies to every node).
    name : str
        Parameter name, with dots between nested names.
    value : ParameterValue
        The value.
    origin : str
        Where the value came from (``-p`` or the parameters file), for error messages.

    """

    node_pattern: str
    name: str
    value: ParameterValue
    origin: str


@dataclass
class RosArguments:
    """What a ROS command line asks for.

    Attributes
    ----------
    remap_rules : list[RemapRule]
        Remap rules in command-line order.
    parameter_overrides : list[ParameterOverride]
        Parameter values in command-line order (parameters files expanded in place).
    log_levels : dict[str, str]
        Log level per logger name; the key '' is the default level.
    enclave : str
        Security enclave (only advertised; security is not implemented in the standalone backend).
    non_ros_args : list[str]
        The arguments outside ``--ros-args`` sections, program name first.

    """

    remap_rules: list[RemapRule] = field(default_factory=list)
    parameter_overrides: list[ParameterOverride] = field(default_factory=list)
    log_levels: dict[str, str] = field(default_factory=dict)
    enclave: str = '/'
    non_ros_args: list[str] = field(default_factory=list)


def parse_ros_args(argv: Sequence[str]) -> RosArguments:
    """Parse a command line the way ``rclpy.init(args=argv)`` does.

    Parameters
    ----------
    argv : Sequence[str]
        The whole command line, program name first.

    Returns
    -------
    RosArguments
        What the ``--ros-args`` sections ask for, and the other arguments.

    Raises
    ------
    CommandLineError
        On an unknown ROS argument, a missing value, a malformed rule or an unreadable
        parameters file.

    """
    result = RosArguments()
    in_ros = False
    i = 0
    while i < len(argv):
        arg = argv[i]
        i += 1
        if arg == '--ros-args':
            in_ros = True
            continue
        if not in_ros:
            result.non_ros_args.append(arg)
            continue
        if arg == '--':
            in_ros = False
            continue
        if arg in _FLAGS_WITHOUT_VALUE:
            continue
        if arg not in ('-p', '--param', '-r', '--remap', '--params-file', '--log-level',
                       '-e', '--enclave'):
            msg = f'unknown ROS argument {arg!r} (after --ros-args)'
            raise CommandLineError(msg)
        if i >= len(argv):
            msg = f'ROS argument {arg} needs a value'
            raise CommandLineError(msg)
        value = argv[i]
        i += 1
        if arg in ('-p', '--param'):
            result.parameter_overrides.append(_parse_param_rule(value))
        elif arg in ('-r', '--remap'):
            result.remap_rules.append(_parse_remap_rule(value))
        elif arg == '--params-file':
            result.parameter_overrides.extend(load_params_file(Path(value)))
        elif arg == '--log-level':
            logger, _, level = value.rpartition(':=')
            if level.lower() not in _LOG_LEVELS:
                msg = f'--log-level {value!r}: level must be one of {", ".join(_LOG_LEVELS)}'
                raise CommandLineError(msg)
            result.log_levels[logger] = level.lower()
        else:
            result.enclave = value
    return result


def _parse_remap_rule(text: str) -> RemapRule:
    lhs, sep, target = text.partition(':=')
    if not sep or not lhs or not target:
        msg = f'malformed remap rule {text!r}: expected [node:]from:=to'
        raise CommandLineError(msg)
    node, colon, source = lhs.rpartition(':')
    return RemapRule(source=source, target=target, node=node if colon else None)


def _parse_param_rule(text: str) -> ParameterOverride:
    name, sep, raw = text.partition(':=')
    if not sep or not name:
        msg = f'malformed parameter rule {text!r}: expected name:=value'
        raise CommandLineError(msg)
    try:
        loaded = load_yaml(raw) if raw else ''
    except yaml.YAMLError as exc:
        msg = f'parameter {name!r}: cannot parse value {raw!r}: {exc}'
        raise CommandLineError(msg) from exc
    return ParameterOverride('/**', name, _check_value(name, loaded, '-p'), '-p')


def load_params_file(path: Path) -> list[ParameterOverride]:
    """Read a ROS 2 parameters file.

    Parameters
    ----------
    path : Path
        YAML file whose top-level keys are node names (absolute, relative or with ``*``/``**``
        wildcards, possibly nested by namespace), each holding a ``ros__parameters`` mapping.

    Returns
    -------
    list[ParameterOverride]
        The values in file order, nested parameter names joined with dots.

    Raises
    ------
    CommandLineError
        If the file cannot be read, is not YAML, has no ``ros__parameters`` section, or holds a
        value ROS 2 parameters cannot take.

    """
    origin = str(path)
    document = read_yaml_file(path)
    if not isinstance(document, Mapping):
        msg = f'parameters file {origin}: expected a mapping of node names at the top level'
        raise CommandLineError(msg)
    overrides: list[ParameterOverride] = []
    _collect_nodes(document, [], origin, overrides)
    if not overrides and document:
        msg = f'parameters file {origin}: no "ros__parameters" section found'
        raise CommandLineError(msg)
    return overrides


def _collect_nodes(
    tree: Mapping[object, object], path: list[str], origin: str, out: list[ParameterOverride],
) -> None:
    for key, value in tree.items():
        if key == 'ros__parameters':
            if not path:
                msg = f'parameters file {origin}: "ros__parameters" must sit under a node name'
                raise CommandLineError(msg)
            if not isinstance(value, Mapping):
                where = '/'.join(path)
                msg = f'parameters file {origin}: "ros__parameters" of {where} is not a mapping'
                raise CommandLineError(msg)
            pattern = '/' + '/'.join(p.strip('/') for p in path)
            for name, item in _flatten(value, ''):
                value_checked = _check_value(name, item, origin)
                out.append(ParameterOverride(pattern, name, value_checked, origin))
        elif isinstance(value, Mapping):
            _collect_nodes(value, [*path, str(key)], origin, out)
        else:
            where = '/'.join([*path, str(key)])
            msg = f'parameters file {origin}: {where!r} is outside any "ros__parameters" section'
            raise CommandLineError(msg)


def _flatten(tree: Mapping[object, object], prefix: str) -> list[tuple[str, object]]:
    items: list[tuple[str, object]] = []
    for key, value in tree.items():
        name = f'{prefix}{key}'
        if isinstance(value, Mapping):
            items.extend(_flatten(value, name + '.'))
        else:
            items.append((name, value))
    return items


def _check_value(name: str, value: object, origin: str) -> ParameterValue:
    if isinstance(value, (bool, int, float, str, bytes)):
        return value
    if isinstance(value, list):
        if not value:
            msg = f'parameter {name!r} ({origin}): an empty list has no type; give one item'
            raise CommandLineError(msg)
        kinds = {type(item) for item in value}
        if len(kinds) == 1 and kinds <= {bool, int, float, str}:
            return value
        if kinds == {int, float}:
            msg = f'parameter {name!r} ({origin}): list mixes integers and floats (write 1.0)'
            raise CommandLineError(msg)
        msg = f'parameter {name!r} ({origin}): list items must all be bool, int, float or str'
        raise CommandLineError(msg)
    kind = 'null' if value is None else type(value).__name__
    msg = f'parameter {name!r} ({origin}): a {kind} value is not a ROS 2 parameter type'
    raise CommandLineError(msg)


def node_pattern_matches(pattern: str, fully_qualified_name: str) -> bool:
    """Tell whether a parameters-file node key matches a node.

    Parameters
    ----------
    pattern : str
        Node key: ``/ns/node``, ``node`` (taken from the root), with ``*`` for one token and
        ``**`` for any number of tokens.
    fully_qualified_name : str
        The node's fully qualified name, such as ``/exo/left_hip_plant``.

    Returns
    -------
    bool
        Whether the key applies to the node.

    """
    return _match_tokens(
        [t for t in pattern.split('/') if t], [t for t in fully_qualified_name.split('/') if t])


def _match_tokens(pattern: list[str], name: list[str]) -> bool:
    if not pattern:
        return not name
    head, rest = pattern[0], pattern[1:]
    if head == '**':
        return any(_match_tokens(rest, name[k:]) for k in range(len(name) + 1))
    if not name:
        return False
    return (head in ('*', name[0])) and _match_tokens(rest, name[1:])


def parameter_overrides_for(
    overrides: Sequence[ParameterOverride], fully_qualified_name: str,
) -> dict[str, ParameterOverride]:
    """Collect the parameter values that apply to one node.

    Wildcard keys are applied first and keys naming the node exactly after them, each group in
    command-line order, so a value for the node itself wins over a ``/**`` value.

    Parameters
    ----------
    overrides : Sequence[ParameterOverride]
        Everything the command line gave.
    fully_qualified_name : str
        The node's fully qualified name.

    Returns
    -------
    dict[str, ParameterOverride]
        The winning value per parameter name.

    """
    chosen: dict[str, ParameterOverride] = {}
    matching = [o for o in overrides if node_pattern_matches(o.node_pattern, fully_qualified_name)]
    for item in sorted(matching, key=lambda o: '*' not in o.node_pattern):
        chosen[item.name] = item
    return chosen
