"""Declaring a node's parameters: one descriptor per parameter, its range from its bounds.

Every exo_has node declares its parameters through :func:`declare`, so that each carries a
description (with its SI unit), a range where it has one (``ros2 param describe`` shows it and
rclpy refuses a value outside it, naming the parameter) and is read-only unless the node can
apply a change while running. A parameter shared by several joints of one type (``hip.kp``) is
declared once, by the first joint that needs it. :func:`declare_realtime_priority` and
:func:`apply_realtime_priority` are the one ``realtime_priority`` parameter of the nodes with a
loop to schedule.
"""

from __future__ import annotations

from typing import TypeVar

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node

from exo_has_common.realtime import MAX_PRIORITY, set_realtime_priority

Value = TypeVar('Value')


def descriptor(description: str, bounds: tuple[float, float] | None = None, *,
               integer: bool = False, read_only: bool = True) -> ParameterDescriptor:
    """Return the descriptor of a parameter.

    Parameters
    ----------
    description : str
        What the parameter sets, with its unit.
    bounds : tuple of float, optional
        Smallest and largest value allowed (both included).
    integer : bool
        Whether the bounds are an integer range (step 1) rather than a floating-point one.
    read_only : bool
        Whether the value is fixed once the node is built.

    """
    ranges: dict[str, object] = {}
    if bounds is not None:
        low, high = bounds
        if integer:
            ranges['integer_range'] = [IntegerRange(from_value=int(low), to_value=int(high),
                                                    step=1)]
        else:
            ranges['floating_point_range'] = [FloatingPointRange(from_value=float(low),
                                                                 to_value=float(high))]
    return ParameterDescriptor(description=description, read_only=read_only, **ranges)


def declare(node: Node, name: str, default: Value, description: str,
            bounds: tuple[float, float] | None = None, *, read_only: bool = True) -> Value:
    """Declare parameter ``name`` of ``node`` unless it is declared already; return its value.

    The range is an integer range for an integer default, a floating-point range otherwise.
    A value given on the command line or in a parameters file that lies outside the bounds
    or is of another type makes rclpy raise, naming the parameter.
    """
    if not node.has_parameter(name):
        node.declare_parameter(name, default, descriptor(
            description, bounds, integer=isinstance(default, int) and not isinstance(
                default, bool), read_only=read_only))
    # get_parameter_or: an empty list given (joints:=[]) has no type in rcl and reads None,
    # where get_parameter would raise ParameterUninitializedException.
    value: Value = node.get_parameter_or(name).value
    return value


def declare_realtime_priority(node: Node, thread: str) -> int:
    """Declare ``realtime_priority``, the SCHED_FIFO priority of ``thread`` (0: none)."""
    return declare(node, 'realtime_priority', 0,
                   f'SCHED_FIFO priority of {thread} (0: the default scheduler; needs root, '
                   'CAP_SYS_NICE or an rtprio limit, see exo_has_common.realtime)',
                   (0, MAX_PRIORITY))


def apply_realtime_priority(node: Node, priority: int, thread_id: int = 0) -> None:
    """Put a thread (0: the calling one) under SCHED_FIFO at ``priority``; warn if refused."""
    problem = set_realtime_priority(priority, thread_id)
    if problem:
        node.get_logger().warning(f'realtime_priority: {problem}')
