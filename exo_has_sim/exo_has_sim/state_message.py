"""A joint's sample as exo_has_msgs/msg/HasState, and message stamps in nanoseconds.

The one ROS-facing module of exo_has_sim beside the plant node; the physics stays free of ROS.
A simulated joint's :class:`~exo_has_sim.plant.PlantSample` and the hardware driver's
:class:`~exo_has_driver.hardware.config.JointSample` carry the message's fields in its units;
what a source does not measure is NaN (the plant's motor current, the hardware's load force).
The nodes that stamp a message, or date one by its stamp, do it with :func:`set_stamp` and
:func:`stamp_ns` (the driver's safety events too).
"""

from __future__ import annotations

import math
from typing import Any, Protocol

from exo_has_msgs.msg import HasState

#: Nanoseconds per second.
NS_PER_S = 1_000_000_000


class StateSample(Protocol):
    """The fields of a HAS state that every source measures, in HasState's units."""

    @property
    def position(self) -> float:
        """Cylinder extension [m]."""

    @property
    def velocity(self) -> float:
        """Cylinder velocity [m/s]."""

    @property
    def pressure_a(self) -> float:
        """Rodless chamber gauge pressure [Pa]."""

    @property
    def pressure_b(self) -> float:
        """Rod chamber gauge pressure [Pa]."""

    @property
    def motor_speed(self) -> float:
        """Pump speed [rad/s]."""

    @property
    def motor_speed_command(self) -> float:
        """Commanded pump speed [rad/s]."""

    @property
    def valve_mode(self) -> int:
        """Valve mode, one of HasState's ``VALVE_*``."""


def nanoseconds(seconds: float) -> int:
    """Return a time [s] in whole nanoseconds, rounded down (a float's sub-ns digits dropped)."""
    whole = math.floor(seconds)
    return int(whole) * NS_PER_S + min(int((seconds - whole) * 1e9), NS_PER_S - 1)


def set_stamp(header: Any, stamp_ns: int) -> None:
    """Set a std_msgs/Header's stamp to a time in nanoseconds (as rclpy's Time.to_msg does)."""
    header.stamp.sec, header.stamp.nanosec = divmod(stamp_ns, NS_PER_S)


def stamp_ns(header: Any) -> int:
    """Return a std_msgs/Header's stamp in nanoseconds."""
    return int(header.stamp.sec) * NS_PER_S + int(header.stamp.nanosec)


def has_state(joint: str, stamp_ns: int, sample: StateSample, *,
              motor_current: float = math.nan, load_force: float = math.nan) -> HasState:
    """Return the HasState message of a joint's sample.

    Parameters
    ----------
    joint : str
        The joint.
    stamp_ns : int
        When the sample was taken [ns], on the clock the source stamps with.
    sample : StateSample
        The measured values.
    motor_current : float
        Motor current [A]; NaN where it is not measured (the plant).
    load_force : float
        External rod force [N]; NaN where it is not measured (the hardware).

    """
    state = HasState(joint=joint, position=sample.position, velocity=sample.velocity,
                     pressure_a=sample.pressure_a, pressure_b=sample.pressure_b,
                     motor_speed=sample.motor_speed,
                     motor_speed_command=sample.motor_speed_command,
                     motor_current=motor_current, load_force=load_force,
                     valve_mode=sample.valve_mode)
    set_stamp(state.header, stamp_ns)
    return state
