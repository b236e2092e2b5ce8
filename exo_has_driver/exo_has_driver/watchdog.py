"""Safety watchdog node: watches every joint's HAS and stops them all on a fatal fault.

Feeds each joint's HasState and HasCommand and the joint references, with their receive time on
the node clock, to :class:`exo_has_driver.safety.Watchdog`, and checks staleness at ``rate``.
By default (``batch`` true) the messages are taken at each check, in order of reception, from
subscriptions no executor wakes for (:class:`exo_has_runtime.polling.Inbox`), each with the time
DDS received it: 200 wake-ups a second instead of some 1800, at the cost of judging a message
up to one check period (5 ms at 200 Hz) after it arrived (bench/README.md). With ``batch``
false each message has its callback, and a check judges every message taken before it. The
subscriptions keep a second of each topic (``DEEP_SENSOR_QOS``), so a watchdog held up still
sees each sample once it runs again.
A joint reference that stops coming while its publisher is still in the graph (the link to
the operator's machine lost) latches a hold, an ERROR: the controller holds every joint until
a reset (:mod:`exo_has_driver.safety`).
Its events go out on ``safety_events`` (reliable, transient local, so that a node started later
learns of a latched stop), a summary per joint on ``/diagnostics`` at 1 Hz, and, while a stop
is latched, stop commands (motor speed 0, drive disabled) on every joint's ``has_command`` at
``rate``, so the plants stop even if a controller is dead. A std_msgs/Empty on
``safety_reset`` asks to release the stop::

    ros2 run exo_has_driver watchdog --ros-args --params-file config/watchdog.yaml
    ros2 topic pub --once /safety_reset std_msgs/msg/Empty
"""

from __future__ import annotations

import time
from collections.abc import Callable
from functools import partial
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import Empty

from exo_has_common.joints import JOINT_NAMES, joint_type_of
from exo_has_common.topics import (
    DIAGNOSTICS_TOPIC,
    JOINT_REFERENCE_TOPIC,
    SAFETY_EVENT_TOPIC,
    SAFETY_RESET_TOPIC,
    has_command_topic,
    has_state_topic,
)
from exo_has_driver import joint_watch, safety, safety_limits
from exo_has_driver.errors import SafetyConfigError
from exo_has_driver.events import Event, Severity
from exo_has_driver.messages import log_event, safety_event
from exo_has_driver.settings import checked_joints, joint_type_parameters
from exo_has_msgs.msg import HasCommand, HasState, SafetyEvent
from exo_has_runtime.execution import run_node
from exo_has_runtime.graph import PublisherWatch
from exo_has_runtime.node_parameters import declare
from exo_has_runtime.polling import Inbox
from exo_has_runtime.profiles import DEEP_SENSOR_QOS, SAFETY_EVENT_QOS
from exo_has_sim.state_message import stamp_ns

# The core's levels are ints; the message's constants are one byte each (bytes in rclpy).
LEVELS = {joint_watch.LEVEL_OK: DiagnosticStatus.OK,
          joint_watch.LEVEL_WARN: DiagnosticStatus.WARN,
          joint_watch.LEVEL_ERROR: DiagnosticStatus.ERROR,
          joint_watch.LEVEL_STALE: DiagnosticStatus.STALE}


class WatchdogNode(Node):
    """Safety watchdog of the HAS joints: events, diagnostics and stop commands."""

    def __init__(self, **options: Any) -> None:
        # options: Node's keyword arguments (cli_args, context, ...), so that a container
        # can compose this node with others in one process (exo_has_runtime.container).
        super().__init__('watchdog', **options)
        # An empty list (joints:=[]) has no type in rcl and reads None: checked_joints says so.
        joints = list(declare(self, 'joints', list(JOINT_NAMES),
                              f'joints watched, among {", ".join(JOINT_NAMES)}') or ())
        rate = declare(self, 'rate', 200.0, 'staleness check and stop-command rate [Hz]',
                       (1.0, 2000.0))
        stale_periods = declare(self, 'stale_periods', safety_limits.DEFAULT_STALE_PERIODS,
                                'control periods without a state or command before it is stale',
                                (1, 10000))
        control_rate = declare(self, 'control_rate', 200.0,
                               'control rate that sets a period [Hz] (the paper: 200)',
                               (1.0, 10000.0))
        tracking_limit = declare(self, 'tracking_error_limit',
                                 safety_limits.DEFAULT_TRACKING_ERROR_LIMIT,
                                 'joint tracking error that is a fault [rad] (0.35: 20 deg, the '
                                 "paper's squatting error is within -1.5/+2.5 deg)", (0.01, 3.2))
        tracking_time = declare(self, 'tracking_error_time',
                                safety_limits.DEFAULT_TRACKING_ERROR_TIME,
                                'how long the tracking error must stay over its limit [s]',
                                (0.0, 10.0))
        ratio = declare(self, 'over_pressure_ratio', safety_limits.DEFAULT_OVER_PRESSURE_RATIO,
                        'over-pressure warning threshold as a fraction of the relief pressure',
                        (0.5, 1.0))
        margin = declare(self, 'stroke_margin', safety_limits.DEFAULT_STROKE_MARGIN,
                         'distance from a cylinder end at which it counts as reached [m]',
                         (0.0, 0.01))
        grace = declare(self, 'startup_grace', safety_limits.DEFAULT_STARTUP_GRACE,
                        'time for the first state and command after start or reset [s]',
                        (0.0, 600.0))
        source_period = declare(self, 'source_check_period', 0.1,
                                'period of the search of the ROS graph for a second publisher '
                                "of a joint's state or command [s]", (0.05, 10.0))
        batch = declare(self, 'batch', True,
                        'take states, commands and references at each check, in order of '
                        'reception (true), or by a callback per message (false: a wake-up each)')
        sources = {kind: declare(self, f'{kind}.params', kind,
                                 f'{kind} HAS parameter set: hip, knee or a parameters YAML file')
                   for kind in ('hip', 'knee')}
        self._joints = checked_joints(joints, SafetyConfigError)
        params = {kind: joint_type_parameters(kind, source, SafetyConfigError)
                  for kind, source in sources.items()}
        self._limits = {joint: safety_limits.SafetyLimits.from_parameters(
            params[joint_type_of(joint)], over_pressure_ratio=ratio, stroke_margin=margin,
            tracking_error_limit=tracking_limit, tracking_error_time=tracking_time,
            stale_periods=stale_periods, control_rate=control_rate, startup_grace=grace)
            for joint in self._joints}
        # Built at the first non-zero clock reading: under use_sim_time the clock reads 0
        # until /clock arrives, and the start-up grace must run from the real start.
        self._core: safety.Watchdog | None = None
        self._shortest_timeout = min(min(limit.state_timeout, limit.command_timeout)
                                     for limit in self._limits.values())
        self._period = 1.0 / rate
        self._last_check: float | None = None
        self._reading_system_ns = 0  # system clock [ns] at the last _reading
        self._deferred = False
        self._last_stop_ns = -1
        self._released_ns = -1

        self._event_publisher = self.create_publisher(SafetyEvent, SAFETY_EVENT_TOPIC,
                                                      SAFETY_EVENT_QOS)
        self._diagnostics_publisher = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                                            10)
        self._stop_publishers = {
            joint: self.create_publisher(HasCommand, has_command_topic(joint),
                                         qos_profile_sensor_data)
            for joint in self._joints}
        # Messages are judged by a handler taking (message, now, receive time [s], core).
        self._handlers: dict[str, Callable[[Any, Time, float, safety.Watchdog], None]] = {}
        self._inbox = Inbox(self) if batch else None
        for joint in self._joints:
            self._watch(HasState, has_state_topic(joint), partial(self._take_state, joint))
            self._watch(HasCommand, has_command_topic(joint),
                        partial(self._take_command, joint))
        self._watch(JointState, JOINT_REFERENCE_TOPIC, self._take_reference)
        self.create_subscription(Empty, SAFETY_RESET_TOPIC, self._on_reset, 10)
        self.create_timer(self._period, self._on_tick)
        self.create_timer(1.0, self._on_diagnostics)
        topics = {has_state_topic(j): j for j in self._joints} | {
            has_command_topic(j): j for j in self._joints}
        self._sources = PublisherWatch(self, list(topics))
        self._joint_of_topic = dict(zip(self._sources.topics, topics.values(), strict=True))
        self.create_timer(source_period, self._on_source_check)
        first = next(iter(self._limits.values()))
        self.get_logger().info(
            f'watchdog ready: {", ".join(self._joints)}; checks and stops at {rate:g} Hz, '
            f'messages taken {"at each check" if batch else "as they arrive"}, '
            f'stale after {self._shortest_timeout * 1e3:.0f} ms ({stale_periods} periods at '
            f'{control_rate:g} Hz), start-up grace {grace:g} s, relief '
            f'{first.relief_pressure * 1e-6:g} MPa, warning '
            f'{first.warning_pressure * 1e-6:g} MPa, tracking {tracking_limit:g} rad for '
            f'{tracking_time:g} s')

    def _reading(self) -> tuple[Time, float, safety.Watchdog] | None:
        """Return the time now, in seconds, and the core; None before the clock runs."""
        now = self.get_clock().now()
        # The system clock at the same instant, against which receptions are dated: read
        # later (after a drain that the process was held up in), it would date every message
        # queued before the hold-up too early by its length, and they would look stale.
        self._reading_system_ns = time.time_ns()
        if now.nanoseconds == 0:
            return None
        t = now.nanoseconds * 1e-9
        if self._core is None:
            self._core = safety.Watchdog(self._limits, t)
        return now, t, self._core

    def _watch(self, message_type: type, topic: str,
               handler: Callable[[Any, Time, float, safety.Watchdog], None]) -> None:
        """Subscribe to a topic whose every message the watchdog judges."""
        if self._inbox is not None:
            self._inbox.subscribe(topic, message_type, topic, DEEP_SENSOR_QOS)
            self._handlers[topic] = handler
        else:
            self.create_subscription(message_type, topic, partial(self._on_message, handler),
                                     DEEP_SENSOR_QOS)

    def _on_message(self, handler: Callable[[Any, Time, float, safety.Watchdog], None],
                    message: Any) -> None:
        reading = self._reading()
        if reading is not None:
            now, t, core = reading
            handler(message, now, t, core)

    def _take_batch(self, now: Time, t: float, core: safety.Watchdog) -> None:
        """Judge every message queued since the last check, at its time of reception."""
        if self._inbox is None:
            return
        taken = self._inbox.drain()
        if not taken:
            return
        # DDS stamps receptions on the system clock; the node clock may be simulated, so a
        # message is dated by its age at the reading of t, not by the stamp itself (one that
        # came after the reading is dated t).
        for message in taken:
            age = max(0, self._reading_system_ns - message.received_ns) * 1e-9
            self._handlers[message.topic](message.data, now, t - age, core)

    def _take_state(self, joint: str, state: HasState, now: Time, t: float,
                    core: safety.Watchdog) -> None:
        self._emit(now, core.on_state(joint, t, state.position, state.pressure_a,
                                      state.pressure_b, state.valve_mode))

    def _take_command(self, joint: str, command: HasCommand, now: Time, t: float,
                      core: safety.Watchdog) -> None:
        if not command.enable and command.motor_speed == 0.0 \
                and stamp_ns(command.header) <= self._released_ns:
            return  # one of our own stop commands, still in flight when the stop was released
        self._emit(now, core.on_command(joint, t, command.motor_speed, command.enable))

    def _take_reference(self, reference: JointState, now: Time, t: float,
                        core: safety.Watchdog) -> None:
        if len(reference.position) != len(reference.name):
            self.get_logger().warning(
                f'ignored a joint reference with {len(reference.name)} names and '
                f'{len(reference.position)} positions', throttle_duration_sec=1.0)
            return
        angles = dict(zip(reference.name, reference.position, strict=True))
        self._emit(now, core.on_reference(t, angles))

    def _on_reset(self, _: Empty) -> None:
        reading = self._reading()
        if reading is None:
            return
        now, t, core = reading
        self._take_batch(now, t, core)  # judge the reset on every state received before it
        was_stopped = core.stopped
        events = core.reset(t)
        if was_stopped and not core.stopped:
            self._released_ns = now.nanoseconds
        self._emit(now, events)

    def _on_tick(self) -> None:
        reading = self._reading()
        if reading is None:
            return
        now, t, core = reading
        self._take_batch(now, t, core)
        held_up = (self._last_check is not None
                   and t - self._last_check > self._period + self._shortest_timeout)
        self._last_check = t
        if held_up and not self._deferred:
            # The watchdog itself was held up (scheduling, GC): judge staleness at the next
            # tick, once the messages queued meanwhile have been taken, not on stale evidence.
            self._deferred = True
        else:
            self._deferred = False
            self._emit(now, core.check(t))
            self._emit(now, core.check_reference(t, self._reference_source_present))
        if core.stopped:
            self._send_stop(now)

    def _reference_source_present(self) -> bool:
        """Whether a publisher of the joint reference is in the graph (asked when stale)."""
        return self.count_publishers(JOINT_REFERENCE_TOPIC) > 0

    def _on_source_check(self) -> None:
        """Look for more than one publisher on each joint's state and command topics."""
        reading = self._reading()
        if reading is None:
            return
        now, t, core = reading
        for topic, names in self._sources.poll(t).items():
            self._emit(now, core.on_sources(self._joint_of_topic[topic], topic, names))

    def _on_diagnostics(self) -> None:
        reading = self._reading()
        if reading is None:
            return
        now, t, core = reading
        array = DiagnosticArray()
        array.header.stamp = now.to_msg()
        array.status = [
            DiagnosticStatus(level=LEVELS[summary.level],
                             name=f'{self.get_name()}: {summary.joint}',
                             message=summary.message, hardware_id=summary.joint,
                             values=[KeyValue(key=key, value=value)
                                     for key, value in summary.values])
            for summary in core.diagnostics(t)]
        self._diagnostics_publisher.publish(array)

    def _emit(self, now: Time, events: list[Event]) -> None:
        """Publish and log events; a fatal one sends the stop commands at once."""
        logger = self.get_logger()
        for event in events:
            self._event_publisher.publish(safety_event(event, now.nanoseconds))
            log_event(logger, event)
        if any(event.severity == Severity.FATAL for event in events):
            self._send_stop(now)

    def _send_stop(self, now: Time) -> None:
        """Command every joint to stop, once per instant."""
        if now.nanoseconds == self._last_stop_ns:
            return
        self._last_stop_ns = now.nanoseconds
        for joint, publisher in self._stop_publishers.items():
            command = HasCommand(joint=joint, motor_speed=0.0, enable=False)
            command.header.stamp = now.to_msg()
            publisher.publish(command)

    def destroy_node(self) -> None:
        """Leave the graph with the inbox node that holds the subscriptions."""
        inbox, self._inbox = getattr(self, '_inbox', None), None
        if inbox is not None:
            inbox.destroy()
        super().destroy_node()


def main(args: list[str] | None = None) -> None:
    """Run the watchdog until interrupted."""
    run_node(WatchdogNode, args, name='watchdog')


if __name__ == '__main__':
    main()
