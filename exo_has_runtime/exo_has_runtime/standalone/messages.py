"""Message classes for the standalone backend, generated from message definitions.

Definitions come from two places: the Jazzy standard set shipped in rosbags' typestore
(std_msgs, sensor_msgs, diagnostic_msgs, rcl_interfaces, rmw_dds_common, ...), and the ``.msg``
files of the interface packages found on the interface search path (this workspace's
exo_has_msgs by default). Each type becomes a Cyclone DDS ``IdlStruct`` named as
rmw_cyclonedds_cpp names it (``pkg::msg::dds_::Name_``), keyless, with rosidl-style keyword
constructors, defaults, constants as class attributes and ``get_fields_and_field_types()``.
Their XCDR1 serialisation is byte-for-byte rosbags' ``serialize_cdr`` (tested).
"""

from __future__ import annotations

import dataclasses
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable, Iterable
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np
from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as _types
from cyclonedds.idl._main import IdlMeta as _IdlMeta
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.base import Nodetype  # type: ignore[attr-defined]
from rosbags.typesys.store import Typestore

from exo_has_runtime.arguments import load_yaml
from exo_has_runtime.errors import MessageDefinitionError, UnknownMessageTypeError
from exo_has_runtime.standalone.cdr import generate_codec

# The binding's type constructors are untyped; treat them as such.
IdlMeta: Any = _IdlMeta
types: Any = _types

#: Environment variable: extra interface package roots (or folders of them), os.pathsep-separated.
INTERFACE_PATH_ENV = 'EXO_HAS_INTERFACE_PATH'

_PRIMITIVES: dict[str, tuple[Any, Callable[[], object], str]] = {
    # ROS type: (Cyclone IDL type, Python default factory, numpy dtype)
    'bool': (bool, bool, 'bool'),
    'byte': (types.uint8, int, 'uint8'),
    'char': (types.uint8, int, 'uint8'),
    'uint8': (types.uint8, int, 'uint8'),
    'int8': (types.int8, int, 'int8'),
    'int16': (types.int16, int, 'int16'),
    'uint16': (types.uint16, int, 'uint16'),
    'int32': (types.int32, int, 'int32'),
    'uint32': (types.uint32, int, 'uint32'),
    'int64': (types.int64, int, 'int64'),
    'uint64': (types.uint64, int, 'uint64'),
    'float32': (types.float32, float, 'float32'),
    'float64': (types.float64, float, 'float64'),
}

_TYPE = r'(?P<type>[A-Za-z][A-Za-z0-9_]*(?:/[A-Za-z][A-Za-z0-9_]*){0,2}(?:<=\d+)?)' \
    r'(?P<array>\[(?:<=)?\d*\])?'
_FIELD_LINE = re.compile(
    _TYPE + r'\s+(?P<name>[a-z](?:[a-z0-9]|_(?!_))*)(?:\s+(?P<default>.+))?\Z')
_CONST_LINE = re.compile(_TYPE + r'\s+(?P<name>[A-Z][A-Z0-9_]*)\s*=\s*(?P<value>.+)\Z')


def dds_type_name(type_name: str) -> str:
    """Return the DDS type name rmw_cyclonedds_cpp uses for a ROS type.

    >>> dds_type_name('sensor_msgs/msg/JointState')
    'sensor_msgs::msg::dds_::JointState_'
    """
    package, kind, name = normalize_type_name(type_name).split('/')
    return f'{package}::{kind}::dds_::{name}_'


def ros_type_name(dds_name: str) -> str:
    """Return the ROS type name of a DDS type name, the inverse of :func:`dds_type_name`.

    >>> ros_type_name('sensor_msgs::msg::dds_::JointState_')
    'sensor_msgs/msg/JointState'
    """
    parts = dds_name.split('::')
    if len(parts) != 4 or parts[2] != 'dds_' or not parts[3].endswith('_'):
        return dds_name
    return f'{parts[0]}/{parts[1]}/{parts[3][:-1]}'


def normalize_type_name(type_name: str) -> str:
    """Return ``pkg/msg/Name`` for ``pkg/msg/Name`` or ``pkg/Name``.

    Raises
    ------
    UnknownMessageTypeError
        If the name has neither form.

    """
    parts = type_name.split('/')
    if len(parts) == 2 and all(parts):
        return f'{parts[0]}/msg/{parts[1]}'
    if len(parts) == 3 and all(parts) and parts[1] == 'msg':
        return type_name
    msg = f'malformed message type name {type_name!r}: expected "package/msg/Name"'
    raise UnknownMessageTypeError(msg)


def interface_search_paths() -> list[Path]:
    """Return the folders searched for interface packages, in priority order.

    The folders of ``EXO_HAS_INTERFACE_PATH`` come first, then the workspace this module lives
    in (its source tree, as installed in development mode).
    """
    paths = [Path(p) for p in os.environ.get(INTERFACE_PATH_ENV, '').split(os.pathsep) if p]
    paths.append(Path(__file__).resolve().parents[3])
    return paths


def find_msg_files(search_paths: Iterable[Path]) -> dict[str, Path]:
    """Find the ``.msg`` files of the interface packages under the search paths.

    A folder is an interface package when it holds a ``package.xml`` and a ``msg/`` folder; the
    package name is read from the ``package.xml``. A path may be a package or hold packages.

    Returns
    -------
    dict[str, Path]
        ``pkg/msg/Name`` to file, the first path winning when a type is found twice.

    """
    found: dict[str, Path] = {}
    for root in search_paths:
        candidates = [root, *sorted(p for p in root.iterdir() if p.is_dir())] \
            if root.is_dir() else []
        for folder in candidates:
            manifest = folder / 'package.xml'
            if not (folder / 'msg').is_dir() or not manifest.is_file():
                continue
            package = _package_name(manifest)
            for msg_file in sorted((folder / 'msg').glob('*.msg')):
                found.setdefault(f'{package}/msg/{msg_file.stem}', msg_file)
    return found


def _package_name(manifest: Path) -> str:
    try:
        name = ET.parse(manifest).findtext('name')
    except ET.ParseError as exc:
        msg = f'{manifest}: malformed package.xml: {exc}'
        raise MessageDefinitionError(msg) from exc
    if not name:
        msg = f'{manifest}: package.xml has no <name>'
        raise MessageDefinitionError(msg)
    return name.strip()


def parse_msg_file(type_name: str, path: Path) -> tuple[dict[str, Any], dict[str, object]]:
    """Parse and check one ``.msg`` file.

    Parameters
    ----------
    type_name : str
        ``pkg/msg/Name`` the file defines.
    path : Path
        The file.

    Returns
    -------
    tuple[dict[str, Any], dict[str, object]]
        The rosbags type definitions, and the default values of the fields that declare one.

    Raises
    ------
    MessageDefinitionError
        Naming the file and line of the first line that is not a field or constant in the
        rosidl grammar, or the parser's complaint.

    """
    text = path.read_text(encoding='utf-8')
    defaults: dict[str, object] = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split('#', 1)[0].strip() if not _is_string_constant(raw) else raw.strip()
        if not line:
            continue
        field = _FIELD_LINE.match(line)
        if field is None and _CONST_LINE.match(line) is None:
            msg = (
                f'{path}:{number}: malformed line {raw.strip()!r}: expected "type name", '
                '"type name default" or "TYPE NAME=value" (field names lower_case, constant '
                'names UPPER_CASE)'
            )
            raise MessageDefinitionError(msg)
        if field is not None and field['default'] is not None:
            defaults[field['name']] = _parse_default(
                path, number, field['type'], field['array'], field['default'])
    try:
        definitions = get_types_from_msg(text, type_name)
    except TypesysError as exc:
        msg = f'{path}: cannot parse message definition: {exc}'
        raise MessageDefinitionError(msg) from exc
    return dict(definitions), defaults


def _is_string_constant(line: str) -> bool:
    return bool(re.match(r'\s*(w?string)(<=\d+)?\s+[A-Z][A-Z0-9_]*\s*=', line))


def _parse_default(path: Path, number: int, ros_type: str, array: str | None,
                   literal: str) -> object:
    base = ros_type.split('<=', 1)[0]
    if base in ('string', 'wstring') and not array:
        return literal.strip().strip('"\'')
    try:
        value = load_yaml(literal)
    except Exception as exc:
        msg = f'{path}:{number}: cannot parse default value {literal!r}: {exc}'
        raise MessageDefinitionError(msg) from exc
    items = value if array and isinstance(value, list) else [value]
    if array and not isinstance(value, list):
        items = [object()]
    expected: tuple[type, ...] = (str,) if base in ('string', 'wstring') else \
        (bool,) if base == 'bool' else (float, int) if base.startswith('float') else (int,)
    for item in items:
        if not isinstance(item, expected) or (isinstance(item, bool) and bool not in expected):
            msg = f'{path}:{number}: default value {literal!r} does not fit type {ros_type}' \
                f'{array or ""}'
            raise MessageDefinitionError(msg)
    return value


class MessageRegistry:
    """Message types known to the standalone backend, and their generated classes.

    Parameters
    ----------
    search_paths : Iterable[Path] or None
        Where to look for interface packages (default: :func:`interface_search_paths`).
    generated_codec : bool
        Serialise with code generated per type (default) rather than with the Cyclone DDS
        binding's interpreted serialiser (same bytes, several times slower; for benchmarks).

    Raises
    ------
    MessageDefinitionError
        If a ``.msg`` file is malformed or refers to a type that is not known.

    """

    def __init__(self, search_paths: Iterable[Path] | None = None,
                 generated_codec: bool = True) -> None:
        self.typestore: Typestore = get_typestore(Stores.ROS2_JAZZY)
        self._generated_codec = generated_codec
        self._defaults: dict[str, dict[str, object]] = {}
        self._files = find_msg_files(interface_search_paths() if search_paths is None
                                     else search_paths)
        definitions: dict[str, Any] = {}
        for type_name, path in self._files.items():
            parsed, defaults = parse_msg_file(type_name, path)
            definitions.update(parsed)
            self._defaults[type_name] = defaults
        self.typestore.register(definitions)
        for type_name in self._files:
            self._check_references(type_name)
        self._classes: dict[str, type[IdlStruct]] = {}

    def _check_references(self, type_name: str) -> None:
        for field_name, node in self.typestore.fielddefs[type_name][1]:
            referenced = _referenced_type(node)
            if referenced is not None and referenced not in self.typestore.fielddefs:
                msg = (
                    f'{self._files[type_name]}: field {field_name!r} has unknown type '
                    f'{referenced!r} (not in this workspace nor in the ROS 2 Jazzy standard set)'
                )
                raise MessageDefinitionError(msg)

    @property
    def local_types(self) -> list[str]:
        """Types defined by the ``.msg`` files found on the search path."""
        return sorted(self._files)

    def __contains__(self, type_name: str) -> bool:
        return normalize_type_name(type_name) in self.typestore.fielddefs

    def get_message(self, type_name: str) -> type[Any]:
        """Return the message class of a ROS type.

        Parameters
        ----------
        type_name : str
            ``pkg/msg/Name`` (or ``pkg/Name``).

        Raises
        ------
        UnknownMessageTypeError
            If no known package defines the type.

        """
        name = normalize_type_name(type_name)
        cls = self._classes.get(name)
        if cls is None:
            if name not in self.typestore.fielddefs:
                package = name.split('/')[0]
                known = sorted({t.split('/')[0] for t in self.typestore.fielddefs})
                hint = (f'package {package!r} has no message of that name' if package in known
                        else f'unknown package {package!r}; known packages: {", ".join(known)}')
                msg = f'unknown message type {type_name!r}: {hint}'
                raise UnknownMessageTypeError(msg)
            cls = self._build_class(name)
        return cls

    def type_name_of(self, message_class: type[Any]) -> str:
        """Return ``pkg/msg/Name`` of a generated message class."""
        name: str | None = getattr(message_class, '__ros_type__', None)
        if name is None or self._classes.get(name) is not message_class:
            msg = f'{message_class!r} is not a message class of this registry'
            raise UnknownMessageTypeError(msg)
        return name

    def type_hash(self, type_name: str) -> str:
        """Return the REP 2011 type hash, ``RIHS01_<64 hex digits>``."""
        return self.typestore.hash_rihs01(normalize_type_name(type_name))

    def serialize(self, message: Any) -> bytes:
        """Serialise a message to CDR as rmw_cyclonedds_cpp sends it (XCDR1, padded to 4)."""
        data: bytes = message.serialize(use_version_2=False)
        return data + bytes(-len(data) & 3)

    def deserialize(self, data: bytes, type_name: str) -> Any:
        """Deserialise CDR bytes (with their encapsulation header) to a message."""
        return self.get_message(type_name).deserialize(data)

    def to_rosbags(self, message: Any) -> Any:
        """Convert a message to the equivalent rosbags dataclass instance."""
        return self._to_rosbags(message, self.type_name_of(type(message)))

    def _to_rosbags(self, message: Any, type_name: str) -> Any:
        values = {}
        for field_name, node in self.typestore.fielddefs[type_name][1]:
            values[field_name] = self._value_to_rosbags(getattr(message, field_name), node)
        return self.typestore.types[type_name](**values)

    def _value_to_rosbags(self, value: Any, node: Any) -> Any:
        kind, arg = node
        if kind == Nodetype.NAME:
            return self._to_rosbags(value, arg)
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            (sub_kind, sub_arg), _ = arg
            if sub_kind == Nodetype.BASE and sub_arg[0] in _PRIMITIVES:
                return np.array(value, dtype=_PRIMITIVES[sub_arg[0]][2])
            return [self._value_to_rosbags(item, arg[0]) for item in value]
        return value

    def from_rosbags(self, obj: Any, type_name: str) -> Any:
        """Convert a rosbags dataclass instance to a message of this registry."""
        name = normalize_type_name(type_name)
        message = self.get_message(name)()
        for field_name, node in self.typestore.fielddefs[name][1]:
            setattr(message, field_name, self._value_from_rosbags(getattr(obj, field_name), node))
        return message

    def _value_from_rosbags(self, value: Any, node: Any) -> Any:
        kind, arg = node
        if kind == Nodetype.NAME:
            return self.from_rosbags(value, arg)
        if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
            if isinstance(value, np.ndarray):
                return value.tolist()
            return [self._value_from_rosbags(item, arg[0]) for item in value]
        return value

    def _build_class(self, type_name: str) -> type[IdlStruct]:
        constants, fields = self.typestore.fielddefs[type_name]
        package, _, short = type_name.split('/')
        typename = dds_type_name(type_name)
        namespace = IdlMeta.__prepare__(short, (IdlStruct,), typename=typename)
        defaults = self._defaults.get(type_name, {})
        field_types: dict[str, str] = {}
        for field_name, node in fields:
            idl_type, factory, ros_type = self._field_type(type_name, field_name, node)
            if field_name in defaults:
                factory = _constant_factory(defaults[field_name])
            namespace['__annotations__'][field_name] = idl_type
            namespace[field_name] = dataclasses.field(default_factory=factory)
            field_types[field_name] = ros_type
        cls: Any = dataclasses.dataclass(IdlMeta(short, (IdlStruct,), namespace,
                                                 typename=typename))
        cls.__module__ = f'{package}.msg'
        cls.__ros_type__ = type_name
        for const_name, _, value in constants:
            setattr(cls, const_name, value)
        cls.get_fields_and_field_types = classmethod(
            lambda _cls, _types=field_types: dict(_types))
        self._classes[type_name] = cls
        if self._generated_codec:
            # Replace the binding's interpreted serialiser by one generated for this type; the
            # DDS writer and reader call these two.
            serialize, deserialize = generate_codec(type_name, self.typestore.fielddefs,
                                                    self.get_message)
            cls.serialize = lambda message, buffer=None, endianness=None, use_version_2=None: \
                serialize(message)
            cls.deserialize = classmethod(
                lambda _cls, data, has_header=True, use_version_2=None: deserialize(data))
        built: type[IdlStruct] = cls
        return built

    def _field_type(self, owner: str, field_name: str,
                    node: Any) -> tuple[Any, Callable[[], object], str]:
        kind, arg = node
        if kind == Nodetype.BASE:
            base, bound = arg
            if base == 'string':
                return (types.bounded_str[bound] if bound else str), str, \
                    f'string<={bound}' if bound else 'string'
            if base not in _PRIMITIVES:
                msg = f'{owner}: field {field_name!r} of type {base!r} is not supported here'
                raise MessageDefinitionError(msg)
            idl_type, factory, _ = _PRIMITIVES[base]
            return idl_type, factory, base
        if kind == Nodetype.NAME:
            nested = self.get_message(arg)
            return nested, nested, arg.replace('/msg/', '/')
        sub_type, sub_factory, sub_ros = self._field_type(owner, field_name, arg[0])
        count = arg[1]
        if kind == Nodetype.ARRAY:
            return types.array[sub_type, count], _list_factory(sub_factory, count), \
                f'{sub_ros}[{count}]'
        if count:
            return types.sequence[sub_type, count], list, f'sequence<{sub_ros}, {count}>'
        return types.sequence[sub_type], list, f'sequence<{sub_ros}>'


def _referenced_type(node: Any) -> str | None:
    kind, arg = node
    if kind == Nodetype.NAME:
        return str(arg)
    if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        return _referenced_type(arg[0])
    return None


def _list_factory(item: Callable[[], object], count: int) -> Callable[[], list[object]]:
    return lambda: [item() for _ in range(count)]


def _constant_factory(value: object) -> Callable[[], object]:
    return lambda: list(value) if isinstance(value, list) else value


@cache
def default_registry() -> MessageRegistry:
    """Return the process-wide registry over :func:`interface_search_paths`."""
    return MessageRegistry()


def get_message(type_name: str) -> type[Any]:
    """Return the message class of a ROS type from the process-wide registry.

    The counterpart of ``rosidl_runtime_py.utilities.get_message`` on the standalone backend.
    """
    return default_registry().get_message(type_name)
