"""Message definitions as a bag embeds them: rosbags' Jazzy set plus the ament prefixes' files.

Every topic's MCAP schema holds its type's full definition (encoding ``ros2msg``: the type's
``.msg`` text, comments included where the file is found, then one ``MSG:`` section per nested
type, as rosbag2 embeds it), so Jazzy's ``ros2 bag info/play``, Foxglove and Lichtblick read a
bag without our packages. Types come from rosbags' Jazzy typestore (``Stores.ROS2_JAZZY``, the
standard interfaces) and from the ``.msg`` files under ``<prefix>/share/<pkg>/msg/`` of each
prefix of ``AMENT_PREFIX_PATH``, where rosidl installs them (exo_has_msgs among them).
"""

from __future__ import annotations

import os
from functools import cache
from pathlib import Path
from typing import Any, cast

from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore
from rosbags.typesys.store import Typestore

from exo_has_common.errors import UnknownMessageTypeError

#: What separates the sections of a full message definition.
SEPARATOR = '=' * 80 + '\n'


def normalize_type_name(msgtype: str) -> str:
    """Return ``pkg/msg/Name`` for ``pkg/msg/Name`` or ``pkg/Name``.

    Raises
    ------
    UnknownMessageTypeError
        If the name is of neither form.

    """
    parts = msgtype.split('/')
    if len(parts) == 2 and all(parts):
        return f'{parts[0]}/msg/{parts[1]}'
    if len(parts) == 3 and all(parts) and parts[1] == 'msg':
        return msgtype
    msg = f'malformed message type name {msgtype!r}: expected "package/msg/Name"'
    raise UnknownMessageTypeError(msg)


@cache
def _msg_files(ament_prefix_path: str) -> dict[str, Path]:
    """Find ``share/<pkg>/msg/<Name>.msg`` under each prefix; the first prefix listed wins."""
    found: dict[str, Path] = {}
    for prefix in ament_prefix_path.split(os.pathsep):
        if not prefix:
            continue
        for source in sorted(Path(prefix, 'share').glob('*/msg/*.msg')):
            found.setdefault(f'{source.parent.parent.name}/msg/{source.stem}', source)
    return found


def msg_files() -> dict[str, Path]:
    """Return the ``.msg`` file of each type the prefixes of ``AMENT_PREFIX_PATH`` define."""
    return dict(_msg_files(os.environ.get('AMENT_PREFIX_PATH', '')))


def msg_file(msgtype: str) -> Path | None:
    """Return the ``.msg`` file defining a type, if a prefix of ``AMENT_PREFIX_PATH`` has one."""
    return _msg_files(os.environ.get('AMENT_PREFIX_PATH', '')).get(normalize_type_name(msgtype))


@cache
def default_typestore() -> Typestore:
    """Return the typestore bags are written and read with.

    rosbags' Jazzy set, plus every type of the ``.msg`` files of ``AMENT_PREFIX_PATH`` that the
    set lacks (as found on the first call). A file that does not parse is left out here; the
    error names it when its type is asked for (:func:`ensure_message_type`).
    """
    store = get_typestore(Stores.ROS2_JAZZY)
    for name in msg_files():
        if name not in store.fielddefs:
            try:
                ensure_message_type(name, store)
            except UnknownMessageTypeError:
                continue
    return store


def ensure_message_type(msgtype: str, typestore: Typestore) -> None:
    """Make sure the typestore knows a type and every type it nests, from ``.msg`` files.

    Raises
    ------
    UnknownMessageTypeError
        Naming the first type that neither the typestore nor a ``.msg`` file defines, or the
        file that does not parse.

    """
    pending = [normalize_type_name(msgtype)]
    while pending:
        name = pending.pop()
        if name in typestore.fielddefs:
            continue
        source = msg_file(name)
        if source is None:
            msg = (f'message type {name!r} is unknown: neither the Jazzy standard set nor a '
                   'share/<pkg>/msg/ folder of AMENT_PREFIX_PATH defines it (is the workspace '
                   'sourced?)')
            raise UnknownMessageTypeError(msg)
        try:
            typestore.register(get_types_from_msg(source.read_text(encoding='utf-8'), name))
        except (TypesysError, OSError, UnicodeDecodeError) as exc:
            msg = f'{source}: cannot read message definition of {name!r}: {exc}'
            raise UnknownMessageTypeError(msg) from exc
        for _, node in typestore.fielddefs[name][1]:
            nested = _nested_type(node)
            if nested is not None:
                pending.append(nested)


def _nested_type(node: object) -> str | None:
    """Return the message type a field definition refers to, through arrays and sequences."""
    kind, argument = cast('tuple[Nodetype, Any]', node)
    while kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        kind, argument = cast('tuple[Nodetype, Any]', argument[0])
    return str(argument) if kind == Nodetype.NAME else None


def message_definition(msgtype: str, typestore: Typestore | None = None) -> tuple[str, str]:
    """Return a type's full definition, as rosbag2 embeds it in a bag, and its type hash.

    Parameters
    ----------
    msgtype : str
        ``pkg/msg/Name``.
    typestore : Typestore or None
        Where the types are defined (default: :func:`default_typestore`).

    Returns
    -------
    tuple[str, str]
        The definition (``ros2msg``): the type's own text, then for each nested type a line of
        80 ``=``, ``MSG: pkg/Name`` and its text; each text is the ``.msg`` file's, comments
        included, where the file is found, else the typestore's. Then the REP 2011 hash
        (``RIHS01_<hex>``).

    Raises
    ------
    UnknownMessageTypeError
        If the type, or one it nests, is not defined anywhere.

    """
    store = typestore if typestore is not None else default_typestore()
    name = normalize_type_name(msgtype)
    ensure_message_type(name, store)
    generated, _ = store.generate_msgdef(name, ros_version=2)
    sections = []
    for index, section in enumerate(generated.split(SEPARATOR)):
        header, body = ('', section) if index == 0 else section.split('\n', 1)
        source = msg_file(name if index == 0 else header.removeprefix('MSG: '))
        if source is not None:
            body = source.read_text(encoding='utf-8').rstrip('\n') + '\n'
        sections.append(body if index == 0 else f'{header}\n{body}')
    return SEPARATOR.join(sections), store.hash_rihs01(name)


def definition_hash(msgtype: str, definition: str) -> str:
    """Return the REP 2011 hash of a type from its full ``ros2msg`` definition alone.

    Raises
    ------
    UnknownMessageTypeError
        If the definition does not parse, or misses a nested type.

    """
    store = get_typestore(Stores.EMPTY)
    try:
        store.register(get_types_from_msg(definition, normalize_type_name(msgtype)))
        return store.hash_rihs01(normalize_type_name(msgtype))
    except (TypesysError, KeyError, ValueError) as exc:
        msg = f'the definition of {msgtype!r} in the bag does not parse: {exc}'
        raise UnknownMessageTypeError(msg) from exc
