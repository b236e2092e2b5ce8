"""Time, durations and clocks, shaped as ``rclpy.time``, ``rclpy.duration`` and ``rclpy.clock``.

A :class:`Clock` of type ROS_TIME reads the system clock until simulated time is activated, then
the newest ``/clock`` value (the node feeds it), as rclpy's TimeSource does with use_sim_time.
"""

from __future__ import annotations

import time
from enum import IntEnum
from typing import Any

_NS_PER_S = 1_000_000_000
_message_classes: dict[str, Any] = {}


def _message_class(type_name: str) -> Any:
    """Return the class of a builtin message type, looked up once (``to_msg`` runs often)."""
    cls = _message_classes.get(type_name)
    if cls is None:
        from exo_has_runtime.standalone.messages import get_message
        cls = _message_classes[type_name] = get_message(type_name)
    return cls


class ClockType(IntEnum):
    """Clock types, numbered as rcl."""

    UNINITIALIZED = 0
    ROS_TIME = 1
    SYSTEM_TIME = 2
    STEADY_TIME = 3


class Duration:
    """A signed span of time in nanoseconds."""

    __slots__ = ('_nanoseconds',)

    def __init__(self, *, seconds: float = 0, nanoseconds: int = 0) -> None:
        self._nanoseconds = round(seconds * _NS_PER_S) + int(nanoseconds)

    @property
    def nanoseconds(self) -> int:
        """The span [ns]."""
        return self._nanoseconds

    def to_msg(self) -> Any:
        """Return a builtin_interfaces/msg/Duration."""
        sec, nanosec = divmod(self._nanoseconds, _NS_PER_S)
        return _message_class('builtin_interfaces/msg/Duration')(sec=sec, nanosec=nanosec)

    @classmethod
    def from_msg(cls, msg: Any) -> Duration:
        """Build a Duration from a builtin_interfaces/msg/Duration."""
        return cls(nanoseconds=msg.sec * _NS_PER_S + msg.nanosec)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Duration) and other._nanoseconds == self._nanoseconds

    def __lt__(self, other: Duration) -> bool:
        return self._nanoseconds < other._nanoseconds

    def __le__(self, other: Duration) -> bool:
        return self._nanoseconds <= other._nanoseconds

    def __hash__(self) -> int:
        return hash(self._nanoseconds)

    def __repr__(self) -> str:
        return f'Duration(nanoseconds={self._nanoseconds})'


class Time:
    """A point in time of a given clock type, in nanoseconds since its epoch."""

    __slots__ = ('_clock_type', '_nanoseconds')

    def __init__(self, *, seconds: float = 0, nanoseconds: int = 0,
                 clock_type: ClockType = ClockType.SYSTEM_TIME) -> None:
        total = round(seconds * _NS_PER_S) + int(nanoseconds)
        if total < 0:
            msg = f'a Time cannot be negative, got {total} ns'
            raise ValueError(msg)
        self._nanoseconds = total
        self._clock_type = clock_type

    @property
    def nanoseconds(self) -> int:
        """Time since the epoch [ns]."""
        return self._nanoseconds

    @property
    def clock_type(self) -> ClockType:
        """Type of the clock the time was read from."""
        return self._clock_type

    def seconds_nanoseconds(self) -> tuple[int, int]:
        """Return whole seconds and the remaining nanoseconds."""
        sec, nanosec = divmod(self._nanoseconds, _NS_PER_S)
        return sec, nanosec

    @classmethod
    def _of(cls, nanoseconds: int, clock_type: ClockType) -> Time:
        """Build a Time without the checks of ``__init__``: for clock reads, which are valid."""
        instance = cls.__new__(cls)
        instance._nanoseconds = nanoseconds
        instance._clock_type = clock_type
        return instance

    def to_msg(self) -> Any:
        """Return a builtin_interfaces/msg/Time."""
        sec, nanosec = divmod(self._nanoseconds, _NS_PER_S)
        return _message_class('builtin_interfaces/msg/Time')(sec=sec, nanosec=nanosec)

    @classmethod
    def from_msg(cls, msg: Any, clock_type: ClockType = ClockType.ROS_TIME) -> Time:
        """Build a Time from a builtin_interfaces/msg/Time."""
        return cls(nanoseconds=msg.sec * _NS_PER_S + msg.nanosec, clock_type=clock_type)

    def __sub__(self, other: Time | Duration) -> Any:
        if isinstance(other, Time):
            return Duration(nanoseconds=self._nanoseconds - other._nanoseconds)
        return Time(nanoseconds=self._nanoseconds - other.nanoseconds, clock_type=self._clock_type)

    def __add__(self, other: Duration) -> Time:
        return Time(nanoseconds=self._nanoseconds + other.nanoseconds, clock_type=self._clock_type)

    __radd__ = __add__

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Time) and other._nanoseconds == self._nanoseconds

    def __lt__(self, other: Time) -> bool:
        return self._nanoseconds < other._nanoseconds

    def __le__(self, other: Time) -> bool:
        return self._nanoseconds <= other._nanoseconds

    def __hash__(self) -> int:
        return hash((self._nanoseconds, self._clock_type))

    def __repr__(self) -> str:
        return f'Time(nanoseconds={self._nanoseconds}, clock_type={self._clock_type.name})'


class Clock:
    """A clock; ROS_TIME follows simulated time once :meth:`set_ros_time_override` is called."""

    def __init__(self, *, clock_type: ClockType = ClockType.SYSTEM_TIME) -> None:
        self._clock_type = clock_type
        self._override_ns: int | None = None

    @property
    def clock_type(self) -> ClockType:
        """Type of this clock."""
        return self._clock_type

    @property
    def ros_time_is_active(self) -> bool:
        """Whether the clock follows simulated time."""
        return self._override_ns is not None

    def set_ros_time_override(self, time: Time | int | None) -> None:
        """Follow simulated time from now on (None: back to the system clock)."""
        if self._clock_type != ClockType.ROS_TIME:
            msg = 'only a ROS_TIME clock can follow simulated time'
            raise ValueError(msg)
        self._override_ns = time.nanoseconds if isinstance(time, Time) else time

    def now(self) -> Time:
        """Return the current time of this clock."""
        return Time._of(self.now_ns(), self._clock_type)

    def now_ns(self) -> int:
        """Return the current time of this clock [ns]: the standalone timers' hot path.

        Not rclpy API: node code calls :meth:`now`.
        """
        if self._override_ns is not None:
            return self._override_ns
        if self._clock_type == ClockType.STEADY_TIME:
            return time.monotonic_ns()
        return time.time_ns()


class ROSClock(Clock):
    """The clock of a node: ROS_TIME."""

    def __init__(self) -> None:
        super().__init__(clock_type=ClockType.ROS_TIME)
