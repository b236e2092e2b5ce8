"""The standalone Node: rclpy's Node API over Cyclone DDS with rmw_cyclonedds_cpp's conventions.

Topics are ``rt/<fully qualified name>``, types ``pkg::msg::dds_::Name_`` (XCDR1, keyless),
endpoints carry ``typehash=RIHS01_<hex>;`` in USER_DATA, and the QoS maps as in rmw.
"""

from __future__ import annotations

import inspect
import itertools
import struct
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from cyclonedds._clayer import ddspy_take, ddspy_write
from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader

from exo_has_runtime.arguments import ParameterOverride, parameter_overrides_for, parse_ros_args
from exo_has_runtime.errors import RuntimeSeamError
from exo_has_runtime.names import (
    normalize_namespace,
    remap_namespace,
    remap_node_name,
    resolve_topic_name,
    validate_node_name,
)
from exo_has_runtime.standalone.clock import Clock, ClockType, ROSClock, Time
from exo_has_runtime.standalone.context import (
    Context,
    delete_entity,
    get_default_context,
    gid_of,
)
from exo_has_runtime.standalone.logging import RcutilsLogger
from exo_has_runtime.standalone.messages import ros_type_name
from exo_has_runtime.standalone.parameters import (
    Parameter,
    ParameterStore,
    SetParametersCallback,
    SetParametersResult,
)
from exo_has_runtime.standalone.qos import QoSProfile, dds_qos, profile_from_dds, qos_from_depth

_NEW_SAMPLES = SampleState.Any | ViewState.Any | InstanceState.Any
_TAKE_BATCH = 64
# Every change of any node's entities gets a new number, so executors know to rebuild.
_generations = itertools.count(1)


class Publisher:
    """A ROS 2 publisher on one DDS writer."""

    def __init__(self, node: Node, msg_type: type[Any], topic: str, qos: QoSProfile,
                 writer: DataWriter[Any]) -> None:
        self.msg_type = msg_type
        self.topic_name = topic
        self.qos_profile = qos
        self._node = node
        self._writer = writer
        self.gid = gid_of(writer)

    @property
    def topic(self) -> str:
        """Fully qualified topic name."""
        return self.topic_name

    def publish(self, msg: Any) -> None:
        """Publish a message, or its CDR bytes (as rclpy accepts a serialized message).

        Raises
        ------
        TypeError
            If ``msg`` is neither of the publisher's type nor bytes.

        """
        if isinstance(msg, (bytes, bytearray, memoryview)):
            data = bytes(msg)
            ret = ddspy_write(self._writer._ref, data + b'\0' * (-len(data) % 4))
            if ret < 0:
                raise RuntimeSeamError(f'publishing raw bytes on {self.topic_name} failed ({ret})')
            return
        if type(msg) is not self.msg_type:
            wanted = self.msg_type.__ros_type__
            msg_text = (
                f'the publisher on {self.topic_name} takes {wanted}, '
                f'not {type(msg).__module__}.{type(msg).__name__}'
            )
            raise TypeError(msg_text)
        self._writer.write(msg)

    def get_subscription_count(self) -> int:
        """Return the number of matched subscriptions."""
        return len(self._writer.get_matched_subscriptions())

    def destroy(self) -> bool:
        """Destroy the publisher (rclpy API)."""
        return self._node.destroy_publisher(self)


def _wants_message_info(callback: Callable[..., Any]) -> bool:
    """Whether a callback takes (message, message_info), as rclpy decides it.

    Raises
    ------
    TypeError
        If it can be called with neither one nor two arguments.

    """
    try:
        signature = inspect.signature(callback)
    except (TypeError, ValueError):  # a builtin without a signature: assume one argument
        return False
    for count in (1, 2):
        try:
            signature.bind(*range(count))
        except TypeError:
            continue
        return count == 2
    msg = 'a subscription callback takes one argument (the message) or two (and its info)'
    raise TypeError(msg)


class Subscription:
    """A ROS 2 subscription on one DDS reader.

    A callback of two arguments gets, as in rclpy, the message and a MessageInfo dictionary:
    ``source_timestamp`` (the publisher's clock at publication) and ``received_timestamp``
    (the system clock when taken) [ns].
    """

    def __init__(self, node: Node, msg_type: type[Any], topic: str, callback: Callable[..., Any],
                 qos: QoSProfile, reader: DataReader[Any], raw: bool) -> None:
        self.msg_type = msg_type
        self.topic_name = topic
        self.callback = callback
        self.wants_info = _wants_message_info(callback)
        self.qos_profile = qos
        self.raw = raw
        self._node = node
        self._reader = reader
        self.condition = ReadCondition(reader, _NEW_SAMPLES)
        self.gid = gid_of(reader)
        self.destroyed = False

    @property
    def topic(self) -> str:
        """Fully qualified topic name."""
        return self.topic_name

    def take(self) -> list[Any]:
        """Take every waiting message (CDR bytes when raw), oldest first."""
        return [message for message, _ in self._take()]

    def take_with_info(self) -> list[tuple[Any, dict[str, Any]]]:
        """Take every waiting message with its MessageInfo dictionary, oldest first."""
        received = time.time_ns()
        return [(message, {'source_timestamp': info.source_timestamp,
                           'received_timestamp': received,
                           'publication_sequence_number': None,
                           'reception_sequence_number': None})
                for message, info in self._take()]

    def _take(self) -> list[tuple[Any, Any]]:
        """Take every waiting sample with valid data: (message, DDS sample info)."""
        result: list[tuple[Any, Any]] = []
        while True:
            taken = ddspy_take(self._reader._ref, _NEW_SAMPLES, _TAKE_BATCH)
            if isinstance(taken, int):
                raise RuntimeSeamError(f'taking from {self.topic_name} failed ({taken})')
            for data, info in taken:
                if not info.valid_data:
                    continue
                message = data if self.raw else self._deserialize(data)
                if message is not None:
                    result.append((message, info))
            if len(taken) < _TAKE_BATCH:
                return result

    def _deserialize(self, data: bytes) -> Any:
        try:
            return self.msg_type.deserialize(data)
        except (ValueError, IndexError, struct.error) as exc:  # UnicodeError is a ValueError
            # A malformed sample from a peer must not take the node down.
            self._node.get_logger().error(
                f'dropped a malformed {self.msg_type.__ros_type__} on {self.topic_name}: '
                f'{exc}', throttle_duration_sec=1.0)
            return None

    def get_publisher_count(self) -> int:
        """Return the number of matched publishers."""
        return len(self._reader.get_matched_publications())

    def destroy(self) -> bool:
        """Destroy the subscription (rclpy API)."""
        return self._node.destroy_subscription(self)


@dataclass(frozen=True)
class TopicEndpointInfo:
    """A publisher or subscription seen in the graph, as ``rclpy.topic_endpoint_info``.

    The standalone backend does not map endpoints to nodes: ``node_name`` and
    ``node_namespace`` hold rmw's placeholders for an unknown node.
    """

    topic_type: str
    endpoint_type: str
    endpoint_gid: bytes
    qos_profile: QoSProfile
    node_name: str = '_NODE_NAME_UNKNOWN_'
    node_namespace: str = '_NODE_NAMESPACE_UNKNOWN_'


class Timer:
    """A periodic timer on a clock; the executor calls it when it is due.

    Periods missed because a callback or the system was late are skipped, not called in a burst,
    and counted in :attr:`missed_periods`.
    """

    def __init__(self, callback: Callable[[], Any], period_ns: int, clock: Clock,
                 autostart: bool = True) -> None:
        if period_ns <= 0:
            msg = f'a timer period must be positive, got {period_ns} ns'
            raise ValueError(msg)
        self.callback = callback
        self.timer_period_ns = period_ns
        self.clock = clock
        self.missed_periods = 0
        self._canceled = not autostart
        self._sim = clock.ros_time_is_active if isinstance(clock, Clock) else False
        self._next_ns = clock.now_ns() + period_ns

    def _rebase_if_time_source_changed(self, now: int) -> None:
        # A new time source, or time jumping back (a restarted simulation): restart the period.
        sim = self.clock.ros_time_is_active
        if sim != self._sim or now < self._next_ns - self.timer_period_ns:
            self._sim = sim
            self._next_ns = now + self.timer_period_ns

    def is_canceled(self) -> bool:
        """Whether the timer is cancelled."""
        return self._canceled

    def cancel(self) -> None:
        """Stop calling the timer until :meth:`reset`."""
        self._canceled = True

    def reset(self) -> None:
        """Restart the period from now."""
        self._canceled = False
        self._next_ns = self.clock.now_ns() + self.timer_period_ns

    def due_in(self, now: int) -> int | None:
        """Nanoseconds from ``now`` (a read of :attr:`clock`) to the next call; None if cancelled.

        The executor reads each clock once per pass and asks every timer with that reading.
        """
        if self._canceled:
            return None
        self._rebase_if_time_source_changed(now)
        return max(0, self._next_ns - now)

    def time_until_next_call(self) -> int | None:
        """Nanoseconds until the timer is due (None when cancelled)."""
        return self.due_in(self.clock.now_ns())

    def is_ready(self) -> bool:
        """Whether the timer is due."""
        return self.due_in(self.clock.now_ns()) == 0

    def call(self, now: int | None = None) -> None:
        """Advance to the next period and run the callback (``now``: a fresh clock read)."""
        if now is None:
            now = self.clock.now_ns()
        late_periods = (now - self._next_ns) // self.timer_period_ns
        if late_periods > 0:
            self.missed_periods += late_periods
        self._next_ns += (max(late_periods, 0) + 1) * self.timer_period_ns
        self.callback()

    def destroy(self) -> None:
        """Cancel the timer for good (rclpy API)."""
        self.cancel()


class Node:
    """A ROS 2 node, as ``rclpy.node.Node``.

    Parameters
    ----------
    node_name : str
        Node name (``-r __node:=`` may change it).
    context : Context or None
        The context (default: the process-wide one).
    cli_args : Sequence[str] or None
        Node-specific ROS arguments, as ``['--ros-args', '-p', 'x:=1']``.
    namespace : str or None
        Namespace (``-r __ns:=`` may change it).
    use_global_arguments : bool
        Whether the process's ROS arguments apply to this node.
    parameter_overrides : Sequence[Parameter] or None
        Values that win over every command-line value.
    allow_undeclared_parameters : bool
        Accepted for compatibility; undeclared parameters are always refused here.
    automatically_declare_parameters_from_overrides : bool
        Declare every parameter the command line gives a value for.

    """

    def __init__(self, node_name: str, *, context: Context | None = None,
                 cli_args: Sequence[str] | None = None, namespace: str | None = None,
                 use_global_arguments: bool = True, enable_rosout: bool = True,
                 start_parameter_services: bool = True,
                 parameter_overrides: Sequence[Parameter] | None = None,
                 allow_undeclared_parameters: bool = False,
                 automatically_declare_parameters_from_overrides: bool = False) -> None:
        self.context = context if context is not None else get_default_context()
        if not self.context.ok():
            raise RuntimeError('the context is not initialised: call init() before a node')
        local = parse_ros_args(['node', '--ros-args', *cli_args[1:]] if cli_args
                               and cli_args[0] == '--ros-args' else ['node', *(cli_args or [])])
        global_args = self.context.arguments if use_global_arguments else None
        self._remap_rules = [*(local.remap_rules),
                             *(global_args.remap_rules if global_args else [])]
        self._original_name = validate_node_name(node_name)
        self._name = remap_node_name(self._remap_rules, node_name)
        self._namespace = remap_namespace(self._remap_rules, node_name,
                                          normalize_namespace(namespace or ''))
        overrides: list[ParameterOverride] = [
            *(global_args.parameter_overrides if global_args else []),
            *local.parameter_overrides]
        chosen = parameter_overrides_for(overrides, self.get_fully_qualified_name())
        for parameter in parameter_overrides or ():
            chosen[parameter.name] = ParameterOverride(
                '/**', parameter.name, parameter.value, 'parameter_overrides')
        self._logger = RcutilsLogger(self.get_fully_qualified_name().lstrip('/').replace('/', '.'))
        self._parameters = ParameterStore(self.get_fully_qualified_name(), chosen)
        self._clock = ROSClock()
        self._publishers: list[Publisher] = []
        self._subscriptions: list[Subscription] = []
        self._timers: list[Timer] = []
        self._clock_subscription: Subscription | None = None
        self.entities_version = next(_generations)
        self._destroyed = False
        self.context.add_node(id(self), self._name, self._namespace)
        try:
            self._parameters.add_callback(self._on_use_sim_time)
            self.declare_parameter('use_sim_time', False)
            self._apply_use_sim_time(bool(self.get_parameter('use_sim_time').value))
            if automatically_declare_parameters_from_overrides:
                for name, override in chosen.items():
                    if not self._parameters.has(name):
                        self.declare_parameter(name, override.value)
        except BaseException:
            self.destroy_node()  # leave the graph: this node never came to be
            raise

    # --- names, logger, clock -------------------------------------------------------------

    def get_name(self) -> str:
        """Return the node name."""
        return self._name

    def get_namespace(self) -> str:
        """Return the node namespace."""
        return self._namespace

    def get_fully_qualified_name(self) -> str:
        """Return ``/namespace/name``."""
        return self._namespace.rstrip('/') + '/' + self._name

    def get_logger(self) -> RcutilsLogger:
        """Return the node's logger."""
        return self._logger

    def get_clock(self) -> Clock:
        """Return the node's ROS_TIME clock."""
        return self._clock

    def resolve_topic_name(self, topic: str, *, only_expand: bool = False) -> str:
        """Return the fully qualified (and, unless only_expand, remapped) topic name."""
        rules = [] if only_expand else self._remap_rules
        return resolve_topic_name(rules, topic, self._name, self._namespace, self._original_name)

    # --- parameters --------------------------------------------------------------------------

    def declare_parameter(self, name: str, value: Any = None, descriptor: Any = None,
                          ignore_override: bool = False) -> Parameter:
        """Declare a parameter; the command line's value, if any, wins over ``value``."""
        return self._parameters.declare(name, value, descriptor, ignore_override)

    def declare_parameters(self, namespace: str, parameters: Sequence[tuple[Any, ...]],
                           ignore_override: bool = False) -> list[Parameter]:
        """Declare ``(name, value[, descriptor])`` tuples under ``namespace.``."""
        prefix = f'{namespace}.' if namespace else ''
        declared = []
        for item in parameters:
            name, value = item[0], item[1] if len(item) > 1 else None
            descriptor = item[2] if len(item) > 2 else None
            declared.append(self.declare_parameter(prefix + name, value, descriptor,
                                                   ignore_override))
        return declared

    def has_parameter(self, name: str) -> bool:
        """Whether the parameter is declared."""
        return self._parameters.has(name)

    def get_parameter(self, name: str) -> Parameter:
        """Return a declared parameter."""
        return self._parameters.get(name)

    def get_parameters(self, names: Sequence[str]) -> list[Parameter]:
        """Return declared parameters."""
        return [self._parameters.get(name) for name in names]

    def get_parameter_or(self, name: str, alternative_value: Parameter | None = None) -> Parameter:
        """Return a parameter, or the alternative when it is not declared."""
        if self._parameters.has(name):
            return self._parameters.get(name)
        return alternative_value if alternative_value is not None else Parameter(name)

    def get_parameters_by_prefix(self, prefix: str) -> dict[str, Parameter]:
        """Return the parameters under ``prefix.``, keyed by the rest of their name."""
        start = f'{prefix}.' if prefix else ''
        return {name[len(start):]: self._parameters.get(name)
                for name in self._parameters.names() if name.startswith(start)}

    def describe_parameter(self, name: str) -> Any:
        """Return the descriptor of a declared parameter."""
        return self._parameters.descriptor(name)

    def set_parameters(self, parameter_list: Sequence[Parameter]) -> list[SetParametersResult]:
        """Set parameters one by one; each result says whether it was taken."""
        return [self._parameters.set([parameter]) for parameter in parameter_list]

    def set_parameters_atomically(
            self, parameter_list: Sequence[Parameter]) -> SetParametersResult:
        """Set parameters all or none."""
        return self._parameters.set(list(parameter_list))

    def add_on_set_parameters_callback(
            self, callback: SetParametersCallback) -> SetParametersCallback:
        """Register a callback that may reject parameter changes; it is returned as a handle."""
        self._parameters.add_callback(callback)
        return callback

    def remove_on_set_parameters_callback(self, callback: SetParametersCallback) -> None:
        """Unregister a set-parameters callback."""
        self._parameters.remove_callback(callback)

    def _on_use_sim_time(self, parameters: list[Parameter]) -> SetParametersResult:
        for parameter in parameters:
            if parameter.name == 'use_sim_time':
                if parameter.type_ != Parameter.Type.BOOL:
                    return SetParametersResult(successful=False, reason='use_sim_time is a bool')
                if self._parameters.has('use_sim_time'):
                    self._apply_use_sim_time(bool(parameter.value))
        return SetParametersResult(successful=True)

    def _apply_use_sim_time(self, enabled: bool) -> None:
        if enabled and self._clock_subscription is None:
            from exo_has_runtime.standalone.qos import ReliabilityPolicy
            clock_type = self.context.message_registry.get_message('rosgraph_msgs/msg/Clock')
            # rclpy's TimeSource: /clock, keep last 1, best effort.
            self._clock_subscription = self.create_subscription(
                clock_type, '/clock', self._on_clock,
                QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
            # As rclpy: simulated time is 0 until the first /clock arrives.
            self._clock.set_ros_time_override(0)
        elif not enabled and self._clock_subscription is not None:
            self.destroy_subscription(self._clock_subscription)
            self._clock_subscription = None
            self._clock.set_ros_time_override(None)

    def _on_clock(self, msg: Any) -> None:
        stamp = Time.from_msg(msg.clock, ClockType.ROS_TIME)
        self._clock.set_ros_time_override(stamp.nanoseconds)

    # --- entities ----------------------------------------------------------------------------

    def _message_type_name(self, msg_type: type[Any]) -> str:
        return self.context.message_registry.type_name_of(msg_type)

    def _dds_endpoint(self, msg_type: type[Any], topic: str,
                      qos: QoSProfile) -> tuple[str, Any, Any]:
        type_name = self._message_type_name(msg_type)
        fq_topic = self.resolve_topic_name(topic)
        # rmw_cyclonedds_cpp uses the expanded name as it is when asked to avoid conventions.
        dds_name = fq_topic if qos.avoid_ros_namespace_conventions else 'rt' + fq_topic
        dds_topic = self.context.topic(dds_name, type_name, msg_type)
        type_hash = self.context.message_registry.type_hash(type_name)
        return fq_topic, dds_topic, dds_qos(qos, f'typehash={type_hash};'.encode())

    def create_publisher(self, msg_type: type[Any], topic: str, qos_profile: QoSProfile | int,
                         **_: Any) -> Publisher:
        """Create a publisher (callback groups and event callbacks are not supported)."""
        qos = qos_from_depth(qos_profile)
        fq_topic, dds_topic, dds = self._dds_endpoint(msg_type, topic, qos)
        writer = DataWriter(self.context.participant, dds_topic, qos=dds)
        publisher = Publisher(self, msg_type, fq_topic, qos, writer)
        self._publishers.append(publisher)
        self.context.add_endpoint(id(self), publisher.gid, is_writer=True)
        return publisher

    def create_subscription(self, msg_type: type[Any], topic: str,
                            callback: Callable[[Any], Any], qos_profile: QoSProfile | int, *,
                            raw: bool = False, **_: Any) -> Subscription:
        """Create a subscription; with ``raw=True`` the callback gets the CDR bytes."""
        qos = qos_from_depth(qos_profile)
        fq_topic, dds_topic, dds = self._dds_endpoint(msg_type, topic, qos)
        reader = DataReader(self.context.participant, dds_topic, qos=dds)
        subscription = Subscription(self, msg_type, fq_topic, callback, qos, reader, raw)
        self._subscriptions.append(subscription)
        self.entities_version = next(_generations)
        self.context.add_endpoint(id(self), subscription.gid, is_writer=False)
        return subscription

    def create_timer(self, timer_period_sec: float, callback: Callable[[], Any],
                     callback_group: Any = None, clock: Clock | None = None,
                     autostart: bool = True) -> Timer:
        """Create a timer on the node's clock (or the given one)."""
        timer = Timer(callback, round(timer_period_sec * 1e9), clock or self._clock,
                      autostart)
        self._timers.append(timer)
        self.entities_version = next(_generations)
        return timer

    def create_rate(self, frequency: float, clock: Clock | None = None) -> Any:
        """Not supported: a Rate needs a second thread spinning the node."""
        raise NotImplementedError('create_rate is not supported by the standalone backend; '
                                  'use a timer')

    @property
    def publishers(self) -> list[Publisher]:
        """The node's publishers."""
        return list(self._publishers)

    @property
    def subscriptions(self) -> list[Subscription]:
        """The node's subscriptions."""
        return list(self._subscriptions)

    @property
    def timers(self) -> list[Timer]:
        """The node's timers."""
        return list(self._timers)

    def destroy_publisher(self, publisher: Publisher) -> bool:
        """Destroy a publisher of this node."""
        if publisher not in self._publishers:
            return False
        self._publishers.remove(publisher)
        self.context.remove_endpoint(id(self), publisher.gid)
        delete_entity(publisher._writer)
        return True

    def destroy_subscription(self, subscription: Subscription) -> bool:
        """Destroy a subscription of this node."""
        if subscription not in self._subscriptions:
            return False
        self._subscriptions.remove(subscription)
        self.entities_version = next(_generations)
        self.context.remove_endpoint(id(self), subscription.gid)
        subscription.destroyed = True
        delete_entity(subscription.condition)
        delete_entity(subscription._reader)
        return True

    def destroy_timer(self, timer: Timer) -> bool:
        """Destroy a timer of this node."""
        if timer not in self._timers:
            return False
        timer.cancel()
        self._timers.remove(timer)
        self.entities_version = next(_generations)
        return True

    def destroy_node(self) -> None:
        """Destroy every entity of the node and leave the graph."""
        if self._destroyed:
            return
        for publisher in list(self._publishers):
            self.destroy_publisher(publisher)
        for subscription in list(self._subscriptions):
            self.destroy_subscription(subscription)
        for timer in list(self._timers):
            self.destroy_timer(timer)
        self._destroyed = True
        self.context.remove_node(id(self))

    # --- graph -------------------------------------------------------------------------------

    def count_publishers(self, topic_name: str) -> int:
        """Return the number of publishers (in any process) on a topic."""
        dds_name = 'rt' + self.resolve_topic_name(topic_name)
        return sum(1 for e in self.context.endpoints(dds_name) if e.is_writer)

    def count_subscribers(self, topic_name: str) -> int:
        """Return the number of subscriptions (in any process) on a topic."""
        dds_name = 'rt' + self.resolve_topic_name(topic_name)
        return sum(1 for e in self.context.endpoints(dds_name) if not e.is_writer)

    def get_publishers_info_by_topic(self, topic_name: str,
                                     no_mangle: bool = False) -> list[TopicEndpointInfo]:
        """Return the publishers (in any process) on a topic, with their offered QoS."""
        return self._endpoints_info(topic_name, no_mangle, is_writer=True)

    def get_subscriptions_info_by_topic(self, topic_name: str,
                                        no_mangle: bool = False) -> list[TopicEndpointInfo]:
        """Return the subscriptions (in any process) on a topic, with their requested QoS."""
        return self._endpoints_info(topic_name, no_mangle, is_writer=False)

    def _endpoints_info(self, topic_name: str, no_mangle: bool,
                        is_writer: bool) -> list[TopicEndpointInfo]:
        fq_topic = topic_name if no_mangle else self.resolve_topic_name(topic_name)
        dds_name = fq_topic if no_mangle else 'rt' + fq_topic
        return [TopicEndpointInfo(
            ros_type_name(e.type_name), 'PUBLISHER' if is_writer else 'SUBSCRIPTION', e.key,
            profile_from_dds(e.qos) if e.qos is not None else QoSProfile())
            for e in self.context.endpoints(dds_name) if e.is_writer == is_writer]

    def get_topic_names_and_types(self) -> list[tuple[str, list[str]]]:
        """Return the ROS topics seen in the graph with their types."""
        found: dict[str, set[str]] = {}
        for endpoint in self.context.endpoints():
            if endpoint.topic_name.startswith('rt/'):
                found.setdefault(endpoint.topic_name[2:], set()).add(
                    ros_type_name(endpoint.type_name))
        return sorted((topic, sorted(kinds)) for topic, kinds in found.items())
