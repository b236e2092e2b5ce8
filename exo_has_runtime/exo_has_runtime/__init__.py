"""The seam between exo_has nodes and ROS 2: rclpy where it is installed, Cyclone DDS elsewhere.

Node code imports everything ROS from here::

    from exo_has_runtime import rclpy_api as ros   # or: from exo_has_runtime import Node, ...

and runs unchanged on a robot PC with ROS 2 Jazzy (where every name below IS rclpy's, and
message classes are the rosidl-generated ones) and on a machine without ROS 2 (where the
standalone backend in :mod:`exo_has_runtime.standalone` provides them over Cyclone DDS, with
rmw_cyclonedds_cpp's wire conventions, so both kinds of node talk to each other).

The backend is chosen once, at import: ``EXO_HAS_BACKEND=rclpy`` or ``standalone`` forces one;
unset or ``auto`` takes rclpy when it can be imported.
"""

from __future__ import annotations

import importlib.util
import os

from exo_has_runtime.errors import BackendError


def _choose_backend() -> str:
    wanted = os.environ.get('EXO_HAS_BACKEND', 'auto').strip().lower() or 'auto'
    if wanted not in ('auto', 'rclpy', 'standalone'):
        msg = f'EXO_HAS_BACKEND={wanted!r}: expected auto, rclpy or standalone'
        raise BackendError(msg)
    has_rclpy = importlib.util.find_spec('rclpy') is not None
    if wanted == 'rclpy' and not has_rclpy:
        raise BackendError('EXO_HAS_BACKEND=rclpy but rclpy cannot be imported: source ROS 2')
    if wanted == 'auto':
        return 'rclpy' if has_rclpy else 'standalone'
    return wanted


#: 'rclpy' or 'standalone'.
BACKEND = _choose_backend()

if BACKEND == 'rclpy':  # pragma: no cover - exercised on a ROS 2 machine only
    from rcl_interfaces.msg import (
        FloatingPointRange,
        IntegerRange,
        ParameterDescriptor,
        SetParametersResult,
    )
    from rclpy import init, ok, shutdown, spin, spin_once, try_shutdown
    from rclpy.clock import Clock, ClockType
    from rclpy.duration import Duration
    from rclpy.exceptions import (
        InvalidParameterTypeException,
        InvalidParameterValueException,
        ParameterNotDeclaredException,
    )
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    from rclpy.logging import get_logger
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import (
        DurabilityPolicy,
        HistoryPolicy,
        QoSProfile,
        ReliabilityPolicy,
        qos_profile_sensor_data,
        qos_profile_system_default,
    )
    from rclpy.time import Time
    from rclpy.utilities import remove_ros_args
    from rosidl_runtime_py.utilities import get_message

    def spin_paced(node: Node) -> None:
        """rclpy.spin: the standalone backend's wake-up saving does not apply to rclpy."""
        spin(node)
else:
    from exo_has_runtime.errors import (
        ExternalShutdownException,
        InvalidParameterTypeException,
        InvalidParameterValueException,
        ParameterNotDeclaredException,
    )
    from exo_has_runtime.standalone import (
        Clock,
        ClockType,
        DurabilityPolicy,
        Duration,
        HistoryPolicy,
        Node,
        Parameter,
        QoSProfile,
        ReliabilityPolicy,
        SetParametersResult,
        SingleThreadedExecutor,
        Time,
        get_logger,
        get_message,
        init,
        ok,
        qos_profile_sensor_data,
        qos_profile_system_default,
        remove_ros_args,
        shutdown,
        spin,
        spin_once,
        spin_paced,
        try_shutdown,
    )

    FloatingPointRange = get_message('rcl_interfaces/msg/FloatingPointRange')
    IntegerRange = get_message('rcl_interfaces/msg/IntegerRange')
    ParameterDescriptor = get_message('rcl_interfaces/msg/ParameterDescriptor')

#: What a node's constructor raises on a bad configuration (an unknown name, a parameter of the
#: wrong type or out of range): ``main()`` logs it and exits non-zero instead of a traceback.
STARTUP_ERRORS: tuple[type[Exception], ...] = (
    ValueError, TypeError, LookupError, OSError, InvalidParameterTypeException,
    InvalidParameterValueException)

__all__ = [
    'BACKEND', 'STARTUP_ERRORS',
    'Clock', 'ClockType', 'Duration', 'DurabilityPolicy', 'ExternalShutdownException',
    'FloatingPointRange', 'HistoryPolicy', 'IntegerRange', 'InvalidParameterTypeException',
    'InvalidParameterValueException', 'Node', 'Parameter', 'ParameterDescriptor',
    'ParameterNotDeclaredException', 'QoSProfile', 'ReliabilityPolicy', 'SetParametersResult',
    'SingleThreadedExecutor', 'Time', 'get_logger', 'get_message', 'init', 'ok',
    'qos_profile_sensor_data', 'qos_profile_system_default', 'remove_ros_args', 'shutdown',
    'spin', 'spin_once', 'spin_paced', 'try_shutdown',
]
