"""Hardware driver node: the HAS command and state topics on the CANopen bus of the joints.

Wiring only; the work is :class:`exo_has_driver.hardware.master.Master`. At start the node opens
the bus (``interface``, ``channel``, ``bitrate``), configures every drive and sensor board and
enables the drives (blocking, bounded; a device that does not answer ends the node with a
message naming it), then logs ``driver ready``::

    ros2 run exo_has_driver driver --ros-args -p interface:=socketcan -p channel:=can0

Threads: the master runs its own I/O thread, which alone owns the bus, sends the SYNC at
``rate`` and supervises the slaves: the SYNC must not jitter with the executor (DDS traffic,
logging, garbage collection: a drive applies its RPDO at the SYNC), and a fault must stop the
motors even if this process's executor is held up. The node hands each command to the master
as it arrives (the events executor runs a callback per message: the master writes the newest
at its next SYNC), and its timer, at the same rate, publishes the states and events that came
in. A state's sample is thus published within a period of its SYNC, and the command it
provokes is applied at the first SYNC after the command arrives: one period of loop delay, as
the plant node gives, where handing the commands over in a batch at the timer doubled it and
made the knees overshoot into their end stops on a loaded machine. SIGINT and SIGTERM end the
spin (:func:`exo_has_runtime.execution.run_node`); the node is then destroyed, which stops the
motors and joins the I/O thread before the process exits.

Topics: ``<joint>/has_command`` in (``qos_profile_sensor_data``), ``<joint>/has_state`` out
(stamped with the hardware receive time of the sensor board's TPDO; the load force is not
measured: NaN; the valve mode is inferred, see the master), ``safety_events`` out and in
(``SAFETY_EVENT_QOS``): a FATAL, latched event from another node (the watchdog) is an e-stop,
the driver's own events are ignored; a std_msgs/Empty on ``safety_reset`` asks to release the
latched stop. The watchdog answers the same reset: the driver releases only when the newest
event of another node says no stop is latched there (a reset that comes first waits up to
:data:`~exo_has_driver.reset_gate.RESET_WAIT` for the watchdog's RESET), else it refuses with a
WARN event, so that the controllers, which resume on the driver's RESET, never move the joints
under the watchdog's stop (:class:`~exo_has_driver.reset_gate.ResetGate`). A second commander
of a joint, or another publisher of its states, is a fault the master holds (the watchdog's
rule, :func:`~exo_has_driver.second_source.second_source`). On shutdown the motors are stopped
(quick stop) and the drives disabled before the bus is closed. If the master's I/O thread ends
(the bus failed for good), the node logs FATAL and exits with status 1.
"""

from __future__ import annotations

import collections
import math
import sys
import time
from functools import partial
from typing import Any

from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Empty

from exo_has_common.joints import JOINT_NAMES, joint_type_of
from exo_has_common.topics import (
    SAFETY_EVENT_TOPIC,
    SAFETY_RESET_TOPIC,
    has_command_topic,
    has_state_topic,
)
from exo_has_driver import can_dictionary as cd
from exo_has_driver.errors import HardwareConfigError, MasterStoppedError
from exo_has_driver.events import Event, SafetyKind, Severity
from exo_has_driver.hardware.bus import open_bus
from exo_has_driver.hardware.config import (
    DEFAULT_ACCELERATION,
    DEFAULT_COMMAND_TIMEOUT,
    DEFAULT_MISSING_SYNCS,
    DEFAULT_QUICK_STOP_DECELERATION,
    JointConfig,
    MasterConfig,
)
from exo_has_driver.hardware.master import Master
from exo_has_driver.hardware.units import DriveUnits
from exo_has_driver.messages import log_event, safety_event
from exo_has_driver.reset_gate import ResetGate
from exo_has_driver.second_source import second_source
from exo_has_driver.settings import checked_joints, joint_type_parameters
from exo_has_msgs.msg import HasCommand, HasState, SafetyEvent
from exo_has_runtime.execution import run_node
from exo_has_runtime.graph import PublisherWatch
from exo_has_runtime.node_parameters import (
    apply_realtime_priority,
    declare,
    declare_realtime_priority,
)
from exo_has_runtime.profiles import SAFETY_EVENT_QOS
from exo_has_sim.state_message import has_state, nanoseconds, stamp_ns

#: Own events remembered to recognise them on the shared topic.
OWN_EVENTS = 256
#: The interpreter's thread switch interval [s]. Python's default 5 ms, a whole SYNC period,
#: lets the executor thread hold the GIL long enough to delay the master's SYNC by a period.
SWITCH_INTERVAL = 5e-4


def master_failure(running: bool, failure: BaseException | None) -> str | None:
    """Return the FATAL text for a master whose I/O thread ended, None while it runs."""
    if running:
        return None
    return f'the CAN master stopped: {failure if failure is not None else "no reason given"}'


class Driver(Node):
    """The HAS hardware driver: CANopen master of the joints' drives and sensor boards."""

    def __init__(self, **options: Any) -> None:
        # options: Node's keyword arguments (cli_args, context, ...), so that a container
        # can compose this node with others in one process (exo_has_runtime.container).
        super().__init__('driver', **options)
        # An empty list (joints:=[]) has no type in rcl and reads None: checked_joints says so.
        joints = list(declare(self, 'joints', list(JOINT_NAMES),
                              f'joints on the bus, among {", ".join(JOINT_NAMES)}') or ())
        interface = declare(self, 'interface', 'socketcan',
                            'python-can interface: socketcan (robot), udp_multicast (between '
                            'processes), virtual')
        channel = declare(self, 'channel', 'can0',
                          'CAN channel: can0, or a multicast group such as 239.74.163.2')
        bitrate = declare(self, 'bitrate', 1_000_000,
                          'bit rate [bit/s], for interfaces that set it', (10_000, 1_000_000))
        rate = declare(self, 'rate', 1.0 / cd.SYNC_PERIOD,
                       'SYNC and publishing rate [Hz] (the paper: 200)', (10.0, 1000.0))
        encoder_counts = declare(self, 'encoder_counts', cd.ENCODER_COUNTS,
                                 'encoder counts per motor revolution', (1, 1 << 24))
        gear_ratio = declare(self, 'gear_ratio', cd.GEAR_RATIO,
                             'motor revolutions per pump revolution', (0.01, 1000.0))
        velocity_unit = declare(self, 'velocity_unit', cd.VELOCITY_UNIT,
                                'encoder counts/s per drive velocity unit (COPLEY: 0.1)',
                                (1e-6, 1e6))
        current_unit = declare(self, 'current_unit', cd.CURRENT_UNIT,
                               'amperes per drive current unit (COPLEY: 0.01)', (1e-6, 10.0))
        heartbeat_period = declare(self, 'heartbeat_period', cd.HEARTBEAT_PERIOD,
                                   'heartbeat producer time of every node [s]', (0.001, 10.0))
        heartbeat_timeout = declare(self, 'heartbeat_timeout', cd.HEARTBEAT_TIMEOUT,
                                    'heartbeat consumer time [s], over heartbeat_period',
                                    (0.002, 60.0))
        missing_syncs = declare(self, 'missing_syncs', DEFAULT_MISSING_SYNCS,
                                'SYNC periods without a TPDO from a slave that are a bus fault',
                                (1, 1000))
        priority = declare_realtime_priority(self, 'the I/O thread that sends the SYNC')
        acceleration = declare(self, 'acceleration', DEFAULT_ACCELERATION,
                               'profile acceleration and deceleration of the pump [rad/s^2]',
                               (1.0, 1e6))
        quick_stop = declare(self, 'quick_stop_deceleration', DEFAULT_QUICK_STOP_DECELERATION,
                             'quick stop deceleration of the pump [rad/s^2]', (1.0, 1e6))
        command_timeout = declare(self, 'command_timeout', DEFAULT_COMMAND_TIMEOUT,
                                  'age of the newest command after which the drive holds zero '
                                  'speed [s]', (0.001, 60.0))
        # An empty list (stop_sources:=[]) reads None, as joints does.
        stop_sources = declare(self, 'stop_sources', ['/watchdog'],
                               'full names of the nodes that may publish stop commands beside '
                               'the controller (string array)') or []
        source_period = declare(self, 'source_check_period', 0.1,
                                'period of the search of the ROS graph for a second publisher '
                                "of a joint's state or commands [s]", (0.05, 10.0))
        if not isinstance(stop_sources, list) or not all(
                isinstance(name, str) and name.startswith('/') for name in stop_sources):
            msg = f'parameter stop_sources must list full node names, got {stop_sources!r}'
            raise HardwareConfigError(msg)
        sources = {kind: declare(self, f'{kind}.params', kind,
                                 f'{kind} HAS parameter set (stroke, relief and valve settings): '
                                 f'{kind} or a parameters YAML file')
                   for kind in ('hip', 'knee')}
        self._joints = checked_joints(joints, HardwareConfigError)
        ids = {joint: (declare(self, f'{joint}.drive_id', cd.DRIVE_NODE_IDS[joint],
                               f'CANopen node ID of the {joint} drive', (1, 127)),
                       declare(self, f'{joint}.sensor_id', cd.SENSOR_NODE_IDS[joint],
                               f'CANopen node ID of the {joint} sensor board', (1, 127)))
               for joint in self._joints}
        params = {kind: joint_type_parameters(kind, source, HardwareConfigError)
                  for kind, source in sources.items()}
        config = MasterConfig(
            tuple(JointConfig.from_parameters(joint, params[joint_type_of(joint)], *ids[joint])
                  for joint in self._joints),
            units=DriveUnits(encoder_counts, gear_ratio, velocity_unit, current_unit),
            period=1.0 / rate, heartbeat_period=heartbeat_period,
            heartbeat_timeout=heartbeat_timeout, missing_syncs=missing_syncs,
            acceleration=acceleration, quick_stop_deceleration=quick_stop,
            command_timeout=command_timeout, bitrate=bitrate)

        self._start_ns = self.get_clock().now().nanoseconds
        self._own: collections.deque[tuple[object, ...]] = collections.deque(maxlen=OWN_EVENTS)
        self._history: SafetyEvent | None = None
        self._gate = ResetGate()
        self._event_publisher = self.create_publisher(SafetyEvent, SAFETY_EVENT_TOPIC,
                                                      SAFETY_EVENT_QOS)
        self._state_publishers = {
            joint: self.create_publisher(HasState, has_state_topic(joint),
                                         qos_profile_sensor_data)
            for joint in self._joints}
        self._bus = open_bus(interface, channel, bitrate)
        self._master: Master | None = Master(self._bus, config)
        try:
            self._master.start()
        except BaseException:
            self._close_bus()
            raise
        apply_realtime_priority(self, priority, self._master.io_thread_id or 0)
        for joint in self._joints:
            self.create_subscription(HasCommand, has_command_topic(joint),
                                     partial(self._on_command, joint), qos_profile_sensor_data)
        self.create_subscription(Empty, SAFETY_RESET_TOPIC, self._on_reset, 10)
        self.create_subscription(SafetyEvent, SAFETY_EVENT_TOPIC, self._on_event,
                                 SAFETY_EVENT_QOS)
        self.create_timer(1.0 / rate, self._on_tick)
        # A second commander of a joint (beside the controller and stop_sources), or any other
        # publisher of the states this driver publishes: a fault the master latches and holds.
        self._stop_sources = tuple(stop_sources)
        self._commanders = PublisherWatch(self, [has_command_topic(j) for j in self._joints])
        self._state_sources = PublisherWatch(self, [has_state_topic(j) for j in self._joints],
                                             source=True)
        self._joint_of_topic = {
            topic: joint for watch in (self._commanders, self._state_sources)
            for topic, joint in zip(watch.topics, self._joints, strict=True)}
        self.create_timer(source_period, self._on_source_check)
        self.get_logger().info(
            f'driver ready: {", ".join(self._joints)} on {interface}:{channel}, drives '
            f'{[ids[j][0] for j in self._joints]} and sensor boards '
            f'{[ids[j][1] for j in self._joints]} enabled; SYNC at {rate:g} Hz, heartbeats '
            f'{heartbeat_period * 1e3:.0f}/{heartbeat_timeout * 1e3:.0f} ms, bus silent after '
            f'{missing_syncs} SYNCs')

    def _on_source_check(self) -> None:
        if self._master is None:
            return
        now = time.monotonic()
        found = [second_source(self._joint_of_topic[topic], topic, names,
                               stop_sources=self._stop_sources)
                 for topic, names in self._commanders.poll(now).items()]
        found += [second_source(self._joint_of_topic[topic], topic, names, own='this driver')
                  for topic, names in self._state_sources.poll(now).items()]
        held = [condition for condition in found if condition is not None]
        self._master.hold_conditions(held)

    def _on_command(self, joint: str, command: HasCommand) -> None:
        if self._master is not None:
            self._master.set_command(joint, command.motor_speed, command.enable)

    def _on_reset(self, _: Empty) -> None:
        if self._master is not None and self._gate.on_reset(time.monotonic()):
            self._master.request_reset()

    def _on_event(self, event: SafetyEvent) -> None:
        if self._master is None or _signature(event) in self._own:
            return
        if stamp_ns(event.header) < self._start_ns:
            # History of a transient-local topic: only whether a stop is still latched counts.
            self._history = event
            self._gate.on_event(event.latched, event.text)
            return
        if event.severity == Severity.FATAL and event.latched:
            self._master.request_stop(event.text)
        if self._gate.on_event(event.latched, event.text):
            self._master.request_reset()

    def _on_tick(self) -> None:
        master = self._master
        if master is None:
            return
        history, self._history = self._history, None
        if history is not None and history.latched:
            master.request_stop(f'a stop latched before the driver started: {history.text}')
        for sample in master.take_samples():
            self._state_publishers[sample.joint].publish(has_state(
                sample.joint, nanoseconds(sample.stamp), sample,
                motor_current=sample.motor_current))
        events = master.take_events()
        refused = self._gate.expired(time.monotonic())
        if refused is not None:
            events.append(Event('', SafetyKind.E_STOP, Severity.WARN, math.nan, math.nan, True,
                                refused))
        if events:
            self._emit(events)
        fatal = master_failure(master.running, master.failure)
        if fatal is not None:
            self.get_logger().fatal(fatal)
            raise MasterStoppedError(fatal)

    def _emit(self, events: list[Event]) -> None:
        now_ns = self.get_clock().now().nanoseconds
        logger = self.get_logger()
        for event in events:
            message = safety_event(event, now_ns)
            self._own.append(_signature(message))
            self._event_publisher.publish(message)
            log_event(logger, event)

    def _close_bus(self) -> None:
        master, self._master = self._master, None
        if master is not None:
            master.close()
        self._bus.shutdown()

    def destroy_node(self) -> None:
        """Stop the motors, disable the drives and close the bus, then destroy the node."""
        if self._master is not None:
            self._close_bus()
        super().destroy_node()


def _signature(event: SafetyEvent) -> tuple[object, ...]:
    stamp = event.header.stamp
    return (stamp.sec, stamp.nanosec, event.kind, event.joint, event.text)


def main(args: list[str] | None = None) -> None:
    """Run the driver until interrupted; exit with status 1 if the CAN master stops."""
    sys.setswitchinterval(SWITCH_INTERVAL)  # see SWITCH_INTERVAL: the SYNC must not wait 5 ms
    try:
        run_node(Driver, args, name='driver')
    except MasterStoppedError:
        raise SystemExit(1) from None  # logged FATAL by the node, which is destroyed by now


if __name__ == '__main__':
    main()
