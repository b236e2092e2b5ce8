"""The standalone backend: rclpy's API on Cyclone DDS, wire-compatible with rmw_cyclonedds_cpp."""

from __future__ import annotations

from collections.abc import Sequence

from exo_has_runtime.standalone.clock import Clock, ClockType, Duration, ROSClock, Time
from exo_has_runtime.standalone.context import Context, get_default_context
from exo_has_runtime.standalone.executors import (
    SingleThreadedExecutor,
    get_global_executor,
    spin,
    spin_once,
    spin_paced,
)
from exo_has_runtime.standalone.logging import LoggingSeverity, get_logger
from exo_has_runtime.standalone.messages import get_message
from exo_has_runtime.standalone.node import Node, Publisher, Subscription, Timer
from exo_has_runtime.standalone.parameters import Parameter, SetParametersResult
from exo_has_runtime.standalone.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_parameter_events,
    qos_profile_parameters,
    qos_profile_sensor_data,
    qos_profile_services_default,
    qos_profile_system_default,
)


def init(args: Sequence[str] | None = None, *, context: Context | None = None) -> None:
    """Initialise the context from the command line (``sys.argv`` when args is None)."""
    (context or get_default_context()).init(args)


def ok(*, context: Context | None = None) -> bool:
    """Whether the context is initialised and not shut down."""
    return (context or get_default_context()).ok()


def shutdown(*, context: Context | None = None) -> None:
    """Shut the context down."""
    (context or get_default_context()).shutdown()
    get_global_executor(context).shutdown()


def try_shutdown(*, context: Context | None = None) -> None:
    """Shut the context down unless it is already."""
    (context or get_default_context()).try_shutdown()


def remove_ros_args(args: Sequence[str]) -> list[str]:
    """Return the command line without its ``--ros-args`` sections."""
    from exo_has_runtime.arguments import parse_ros_args
    return parse_ros_args(args).non_ros_args


__all__ = [
    'Clock', 'ClockType', 'Context', 'Duration', 'DurabilityPolicy', 'HistoryPolicy',
    'LivelinessPolicy', 'LoggingSeverity', 'Node', 'Parameter', 'Publisher', 'QoSProfile',
    'ROSClock', 'ReliabilityPolicy', 'SetParametersResult', 'SingleThreadedExecutor',
    'Subscription', 'Time', 'Timer', 'get_default_context', 'get_global_executor', 'get_logger',
    'get_message', 'init', 'ok', 'qos_profile_parameter_events', 'qos_profile_parameters',
    'qos_profile_sensor_data', 'qos_profile_services_default', 'qos_profile_system_default',
    'remove_ros_args', 'shutdown', 'spin', 'spin_once', 'spin_paced', 'try_shutdown',
]
