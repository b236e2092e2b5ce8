"""ROS 2 parameters for the standalone backend, with rclpy's semantics.

A :class:`ParameterStore` holds a node's declared parameters: values take the override from the
command line when there is one, keep their declared type (unless dynamic typing is on), respect
read-only flags and numeric ranges, and pass through the node's set-parameters callbacks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from enum import IntEnum
from typing import Any

from exo_has_runtime.arguments import ParameterOverride
from exo_has_runtime.errors import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterAlreadyDeclaredException,
    ParameterImmutableException,
    ParameterNotDeclaredException,
)
from exo_has_runtime.standalone.messages import get_message

_RANGE_TOLERANCE = 1e-6


class Parameter:
    """A named, typed parameter value, shaped as ``rclpy.parameter.Parameter``.

    Parameters
    ----------
    name : str
        Parameter name.
    type_ : Parameter.Type or None
        Type; inferred from the value when None.
    value : object
        The value (None for an unset parameter).

    """

    class Type(IntEnum):
        """Parameter types, numbered as rcl_interfaces/msg/ParameterType."""

        NOT_SET = 0
        BOOL = 1
        INTEGER = 2
        DOUBLE = 3
        STRING = 4
        BYTE_ARRAY = 5
        BOOL_ARRAY = 6
        INTEGER_ARRAY = 7
        DOUBLE_ARRAY = 8
        STRING_ARRAY = 9

        @classmethod
        def from_parameter_value(cls, value: object) -> Parameter.Type:
            """Infer the type of a Python value, as rclpy does."""
            if value is None:
                return cls.NOT_SET
            if isinstance(value, bool):
                return cls.BOOL
            if isinstance(value, int):
                return cls.INTEGER
            if isinstance(value, float):
                return cls.DOUBLE
            if isinstance(value, str):
                return cls.STRING
            if isinstance(value, bytes):
                return cls.BYTE_ARRAY
            if isinstance(value, (list, tuple)):
                if value and all(isinstance(v, bytes) for v in value):
                    return cls.BYTE_ARRAY
                if all(isinstance(v, bool) for v in value):
                    return cls.BOOL_ARRAY
                if all(isinstance(v, int) and not isinstance(v, bool) for v in value):
                    return cls.INTEGER_ARRAY
                if all(isinstance(v, float) for v in value):
                    return cls.DOUBLE_ARRAY
                if all(isinstance(v, str) for v in value):
                    return cls.STRING_ARRAY
            msg = f'{value!r} of type {type(value).__name__} is not a ROS 2 parameter type'
            raise TypeError(msg)

        def check(self, value: object) -> bool:
            """Tell whether a value is of this type."""
            try:
                inferred = Parameter.Type.from_parameter_value(value)
            except TypeError:
                return False
            empty_list = isinstance(value, (list, tuple)) and not value
            return inferred == self or (empty_list and self >= Parameter.Type.BYTE_ARRAY)

    def __init__(self, name: str, type_: Parameter.Type | None = None,
                 value: object = None) -> None:
        if type_ is None:
            type_ = Parameter.Type.from_parameter_value(value)
        if not isinstance(type_, Parameter.Type):
            msg = f'parameter {name!r}: type_ must be a Parameter.Type, not {type_!r}'
            raise TypeError(msg)
        if type_ != Parameter.Type.NOT_SET and not type_.check(value):
            msg = f'parameter {name!r}: value {value!r} is not of type {type_.name}'
            raise TypeError(msg)
        self._name = name
        self._type = type_
        self._value = value

    @property
    def name(self) -> str:
        """Parameter name."""
        return self._name

    @property
    def type_(self) -> Parameter.Type:
        """Parameter type."""
        return self._type

    @property
    def value(self) -> Any:
        """Parameter value."""
        return self._value

    def get_parameter_value(self) -> Any:
        """Return the value as an rcl_interfaces/msg/ParameterValue message."""
        value_msg = get_message('rcl_interfaces/msg/ParameterValue')()
        value_msg.type = int(self._type)
        field_name = {
            Parameter.Type.BOOL: 'bool_value',
            Parameter.Type.INTEGER: 'integer_value',
            Parameter.Type.DOUBLE: 'double_value',
            Parameter.Type.STRING: 'string_value',
            Parameter.Type.BYTE_ARRAY: 'byte_array_value',
            Parameter.Type.BOOL_ARRAY: 'bool_array_value',
            Parameter.Type.INTEGER_ARRAY: 'integer_array_value',
            Parameter.Type.DOUBLE_ARRAY: 'double_array_value',
            Parameter.Type.STRING_ARRAY: 'string_array_value',
        }.get(self._type)
        if field_name is not None:
            value: Any = self._value
            if self._type == Parameter.Type.BYTE_ARRAY:
                value = list(value if isinstance(value, bytes) else b''.join(value))
            elif self._type >= Parameter.Type.BOOL_ARRAY:
                value = list(value)
            setattr(value_msg, field_name, value)
        return value_msg

    def __repr__(self) -> str:
        return f'Parameter(name={self._name!r}, type_={self._type.name}, value={self._value!r})'


class SetParametersResult:
    """Outcome of a parameter change, shaped as rcl_interfaces/msg/SetParametersResult."""

    def __init__(self, successful: bool = False, reason: str = '') -> None:
        self.successful = successful
        self.reason = reason

    def __repr__(self) -> str:
        return f'SetParametersResult(successful={self.successful}, reason={self.reason!r})'


def parameter_descriptor(**fields: Any) -> Any:
    """Build an rcl_interfaces/msg/ParameterDescriptor (the class rclpy code imports)."""
    return get_message('rcl_interfaces/msg/ParameterDescriptor')(**fields)


SetParametersCallback = Callable[[list[Parameter]], Any]


class ParameterStore:
    """The declared parameters of one node.

    Parameters
    ----------
    node_name : str
        Fully qualified node name, for error messages.
    overrides : Mapping[str, ParameterOverride]
        Values from the command line and parameters files for this node.

    """

    def __init__(self, node_name: str, overrides: Mapping[str, ParameterOverride]) -> None:
        self._node_name = node_name
        self._overrides = dict(overrides)
        self._parameters: dict[str, Parameter] = {}
        self._descriptors: dict[str, Any] = {}
        self._callbacks: list[SetParametersCallback] = []

    def declare(self, name: str, value: object = None, descriptor: Any = None,
                ignore_override: bool = False) -> Parameter:
        """Declare a parameter, taking the command-line override if any.

        Raises
        ------
        ParameterAlreadyDeclaredException
            If the name is declared already.
        InvalidParameterTypeException
            If the override's type differs from the default's (without dynamic typing).
        InvalidParameterValueException
            If the value lies outside the descriptor's range or a callback rejects it.

        """
        if name in self._parameters:
            msg = f'parameter {name!r} of node {self._node_name} is already declared'
            raise ParameterAlreadyDeclaredException(msg)
        descriptor = descriptor if descriptor is not None else parameter_descriptor()
        if isinstance(value, Parameter.Type):
            # rclpy's idiom for a parameter without default: declare_parameter(name, Type.X).
            descriptor.type = int(value)
            value = None
        descriptor.name = name
        declared_type = _declared_type(name, value, descriptor)
        descriptor.type = int(declared_type)
        override = None if ignore_override else self._overrides.get(name)
        chosen = override.value if override is not None else value
        origin = f' (from {override.origin})' if override is not None else ''
        if not descriptor.dynamic_typing and declared_type != Parameter.Type.NOT_SET \
                and chosen is not None and not declared_type.check(chosen):
            msg = (
                f'parameter {name!r} of node {self._node_name}: value {chosen!r}{origin} is '
                f'of type {Parameter.Type.from_parameter_value(chosen).name}, expected '
                f'{declared_type.name}'
            )
            raise InvalidParameterTypeException(msg)
        parameter = Parameter(name, value=chosen)
        self._check_range(parameter, descriptor, origin)
        self._run_callbacks([parameter])
        self._descriptors[name] = descriptor
        self._parameters[name] = parameter
        return parameter

    def has(self, name: str) -> bool:
        """Tell whether a parameter is declared."""
        return name in self._parameters

    def get(self, name: str) -> Parameter:
        """Return a declared parameter.

        Raises
        ------
        ParameterNotDeclaredException
            If it was not declared.

        """
        try:
            return self._parameters[name]
        except KeyError:
            msg = f'parameter {name!r} of node {self._node_name} is not declared'
            raise ParameterNotDeclaredException(msg) from None

    def descriptor(self, name: str) -> Any:
        """Return the descriptor of a declared parameter."""
        self.get(name)
        return self._descriptors[name]

    def names(self) -> list[str]:
        """Return the declared parameter names, sorted."""
        return sorted(self._parameters)

    def add_callback(self, callback: SetParametersCallback) -> None:
        """Register a callback run before parameters change; it may reject the change."""
        self._callbacks.insert(0, callback)

    def remove_callback(self, callback: SetParametersCallback) -> None:
        """Unregister a callback."""
        self._callbacks.remove(callback)

    def set(self, parameters: Sequence[Parameter]) -> SetParametersResult:
        """Set declared parameters atomically, after checks and callbacks.

        Returns
        -------
        SetParametersResult
            Unsuccessful (nothing changed) with the reason when a check or callback fails.

        Raises
        ------
        ParameterNotDeclaredException
            If a parameter is not declared (as rclpy raises).

        """
        for parameter in parameters:
            self.get(parameter.name)
        try:
            for parameter in parameters:
                self._check_set(parameter)
            self._run_callbacks(list(parameters))
        except (InvalidParameterTypeException,
                InvalidParameterValueException, ParameterImmutableException) as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        for parameter in parameters:
            self._parameters[parameter.name] = parameter
        return SetParametersResult(successful=True)

    def _check_set(self, parameter: Parameter) -> None:
        current = self.get(parameter.name)
        descriptor = self._descriptors[parameter.name]
        if descriptor.read_only:
            msg = f'parameter {parameter.name!r} of node {self._node_name} is read-only'
            raise ParameterImmutableException(msg)
        declared = Parameter.Type(descriptor.type) if descriptor.type else current.type_
        if not descriptor.dynamic_typing and declared != Parameter.Type.NOT_SET \
                and parameter.type_ not in (declared, Parameter.Type.NOT_SET):
            msg = (
                f'parameter {parameter.name!r} of node {self._node_name}: value '
                f'{parameter.value!r} is of type {parameter.type_.name}, expected '
                f'{declared.name}'
            )
            raise InvalidParameterTypeException(msg)
        self._check_range(parameter, descriptor, '')

    def _check_range(self, parameter: Parameter, descriptor: Any, origin: str) -> None:
        ranges = list(descriptor.floating_point_range) + list(descriptor.integer_range)
        if not ranges or parameter.type_ not in (Parameter.Type.DOUBLE, Parameter.Type.INTEGER):
            return
        bounds = ranges[0]
        value = parameter.value
        if not _in_range(value, bounds.from_value, bounds.to_value, bounds.step):
            step = f' in steps of {bounds.step}' if bounds.step else ''
            msg = (
                f'parameter {parameter.name!r} of node {self._node_name}: value {value!r}{origin} '
                f'is outside [{bounds.from_value}, {bounds.to_value}]{step}'
            )
            raise InvalidParameterValueException(msg)

    def _run_callbacks(self, parameters: list[Parameter]) -> None:
        for callback in self._callbacks:
            result = callback(parameters)
            if not result.successful:
                names = ', '.join(repr(p.name) for p in parameters)
                msg = f'parameter {names} of node {self._node_name} rejected: {result.reason}'
                raise InvalidParameterValueException(msg)


def _declared_type(name: str, value: object, descriptor: Any) -> Parameter.Type:
    try:
        inferred = Parameter.Type.from_parameter_value(value)
    except TypeError as exc:
        msg = f'parameter {name!r}: {exc}'
        raise InvalidParameterTypeException(msg) from exc
    if inferred == Parameter.Type.NOT_SET and descriptor.type:
        return Parameter.Type(descriptor.type)
    return inferred


def _in_range(value: float, low: float, high: float, step: float) -> bool:
    if isinstance(value, float) and not math.isfinite(value):
        return False
    if not low - _RANGE_TOLERANCE * max(1.0, abs(low)) <= value \
            <= high + _RANGE_TOLERANCE * max(1.0, abs(high)):
        return False
    if step and not math.isclose(value, high):
        steps = (value - low) / step
        return math.isclose(steps, round(steps), abs_tol=_RANGE_TOLERANCE)
    return True
