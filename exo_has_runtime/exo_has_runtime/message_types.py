"""Message classes by type name, as rosidl generates them (``exo_has_msgs/msg/HasState``).

What ``rosidl_runtime_py.utilities.get_message`` does, which is not on PyPI: import the
package's ``msg`` module and take the class. For the code that learns a type at run time (the
recorder from the graph, replay and analyses from a bag).

:func:`deserialize` turns a bag's (or a raw subscription's) bytes into a message with rclpy,
which reads what rclpy wrote: rosbags' ``deserialize_cdr`` refuses a message rclpy (Fast CDR)
serialized with an empty sequence of 8-byte values, such as a ``JointState`` without efforts
("CDR message size mismatch"), because Fast CDR pads it with more trailing bytes than rosbags
accepts.
"""

from __future__ import annotations

import importlib
from typing import Any

from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.serialization import deserialize_message

from exo_has_common.errors import UnknownMessageTypeError
from exo_has_runtime.errors import MalformedMessageError


def split_type_name(type_name: str) -> tuple[str, str]:
    """Return the package and the message name of ``pkg/msg/Name`` (or ``pkg/Name``).

    Raises
    ------
    UnknownMessageTypeError
        If the name is not of that form.

    """
    parts = type_name.split('/')
    if all(parts) and (len(parts) == 2 or (len(parts) == 3 and parts[1] == 'msg')):
        return parts[0], parts[-1]
    msg = f'malformed message type name {type_name!r}: expected "package/msg/Name"'
    raise UnknownMessageTypeError(msg)


def message_class(type_name: str) -> Any:
    """Return the generated Python class of a message type.

    Parameters
    ----------
    type_name : str
        ``pkg/msg/Name`` (as the graph and bags give it) or ``pkg/Name``.

    Returns
    -------
    Any
        The class, e.g. ``exo_has_msgs.msg.HasState``.

    Raises
    ------
    UnknownMessageTypeError
        Naming the type, if its name is malformed, its package's Python module cannot be
        imported (not installed, or the workspace not sourced) or does not define it.

    """
    package, name = split_type_name(type_name)
    try:
        module = importlib.import_module(f'{package}.msg')
    except ImportError as exc:
        msg = (f'message type {type_name!r} is unknown here: cannot import {package}.msg '
               f'({exc}); is its package installed and the workspace sourced?')
        raise UnknownMessageTypeError(msg) from exc
    found = getattr(module, name, None)
    if not isinstance(found, type) or not hasattr(found, 'get_fields_and_field_types'):
        msg = f'message type {type_name!r} is unknown here: {package}.msg has no message {name}'
        raise UnknownMessageTypeError(msg)
    return found


def deserialize(data: bytes, type_name: str) -> Any:
    """Return the message of a type that CDR bytes (with their encapsulation header) hold.

    Raises
    ------
    UnknownMessageTypeError
        As :func:`message_class`.
    MalformedMessageError
        Naming the type, if the bytes are not such a message.

    """
    message_type = message_class(type_name)
    try:
        return deserialize_message(data, message_type)
    except rclpy_implementation.RMWError as exc:
        msg = f'{len(data)} bytes do not deserialize as {type_name!r}: {exc}'
        raise MalformedMessageError(msg) from exc
