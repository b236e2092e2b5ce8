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
:data:`RESET_WAIT` for the watchdog's RESET), else it refuses with a WARN event, so that the
controllers, which resume on the driver's RESET, never move the joints under the watchdog's
stop (:class:`ResetGate`). On shutdown the motors are stopped (quick stop) and the drives
disabled before the bus is closed. If the master's I/O thread ends (the bus failed for good),
the node logs FATAL and exits with status 1.
"""

from __future__ import annotations

import collections
import math
import sys
import time
from functools import partial
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Empty

from exo_has_driver import can_dictionary as cd
from exo_has_driver.errors import HardwareConfigError, MasterStoppedError
from exo_has_driver.events import Condition, Event, SafetyKind, Severity
from exo_has_driver.hardware.bus import open_bus
from exo_has_driver.hardware.config import (
    DEFAULT_ACCELERATION,
    DEFAULT_COMMAND_TIMEOUT,
    DEFAULT_MISSING_SYNCS,
    DEFAULT_QUICK_STOP_DECELERATION,
    JointConfig,
    JointSample,
    MasterConfig,
)
from exo_has_driver.hardware.master import Master
from exo_has_driver.hardware.units import DriveUnits
from exo_has_driver.node_parameters import checked_joints, joint_type_parameters
from exo_has_msgs.msg import HasCommand, HasState, SafetyEvent
from exo_has_runtime.execution import run_node
from exo_has_runtime.graph import PublisherWatch
from exo_has_runtime.joints import JOINT_NAMES, joint_type_of
from exo_has_runtime.profiles import SAFETY_EVENT_QOS
from exo_has_runtime.realtime import MAX_PRIORITY, set_realtime_priority
from exo_has_runtime.topics import (
    SAFETY_EVENT_TOPIC,
    SAFETY_RESET_TOPIC,
    has_command_topic,
    has_state_topic,
)

#: Own events remembered to recognise them on the shared topic.
OWN_EVENTS = 256
#: How long a reset waits for another node's (the watchdog's) release [s].
RESET_WAIT = 1.0
#: The interpreter's thread switch interval [s]. Python's default 5 ms, a whole SYNC period,
#: lets the executor thread hold the GIL long enough to delay the master's SYNC by a period.
SWITCH_INTERVAL = 5e-4


class ResetGate:
    """Holds a reset back while another node's (the watchdog's) stop is latched.

    The newest event from another node tells whether its stop is latched. A reset is passed on
    at once when it is not; otherwise it waits up to ``wait`` [s] for an event that says it
    was released (the watchdog answers the same reset), and is refused after that.
    """

    def __init__(self, wait: float = RESET_WAIT) -> None:
        self.wait = wait
        #: Text of the newest latched event of another node; None when none holds a stop.
        self.latched_by: str | None = None
        self._deadline: float | None = None

    def on_event(self, latched: bool, text: str) -> bool:
        """Take another node's event; return whether a waiting reset may go on now."""
        self.latched_by = text if latched else None
        if latched or self._deadline is None:
            return False
        self._deadline = None
        return True

    def on_reset(self, now: float) -> bool:
        """Take a reset request at ``now`` [s]; return whether it may go on now."""
        if self.latched_by is None:
            return True
        self._deadline = now + self.wait
        return False

    def expired(self, now: float) -> str | None:
        """Return the refusal text once a waiting reset ran out of time, else None."""
        if self._deadline is None or now <= self._deadline:
            return None
        self._deadline = None
        return f'reset refused: a stop latched by another node holds: {self.latched_by}'


def master_failure(running: bool, failure: BaseException | None) -> str | None:
    """Return the FATAL text for a master whose I/O thread ended, None while it runs."""
    if running:
        return None
    return f'the CAN master stopped: {failure if failure is not None else "no reason given"}'


def _floats(low: float, high: float) -> list[FloatingPointRange]:
    return [FloatingPointRange(from_value=low, to_value=high)]


def _integers(low: int, high: int) -> list[IntegerRange]:
    return [IntegerRange(from_value=low, to_value=high, step=1)]


class Driver(Node):
    """The HAS hardware driver: CANopen master of the joints' drives and sensor boards."""

    def __init__(self, **options: Any) -> None:
        # options: Node's keyword arguments (cli_args, context, ...), so that a container
        # can compose this node with others in one process (exo_has_runtime.container).
        super().__init__('driver', **options)
        declare = self.declare_parameter

        def read_only(description: str, **ranges: object) -> ParameterDescriptor:
            return ParameterDescriptor(description=description, read_only=True, **ranges)

        # An empty list (joints:=[]) has no type in rcl and reads None: checked_joints says so.
        joints = list(declare('joints', list(JOINT_NAMES), read_only(
            f'joints on the bus, among {", ".join(JOINT_NAMES)}')).value or ())
        interface = declare('interface', 'socketcan', read_only(
            'python-can interface: socketcan (robot), udp_multicast (between processes), '
            'virtual')).value
        channel = declare('channel', 'can0', read_only(
            'CAN channel: can0, or a multicast group such as 239.74.163.2')).value
        bitrate = declare('bitrate', 1_000_000, read_only(
            'bit rate [bit/s], for interfaces that set it',
            integer_range=_integers(10_000, 1_000_000))).value
        rate = declare('rate', 1.0 / cd.SYNC_PERIOD, read_only(
            'SYNC and publishing rate [Hz] (the paper: 200)',
            floating_point_range=_floats(10.0, 1000.0))).value
        encoder_counts = declare('encoder_counts', cd.ENCODER_COUNTS, read_only(
            'encoder counts per motor revolution',
            integer_range=_integers(1, 1 << 24))).value
        gear_ratio = declare('gear_ratio', cd.GEAR_RATIO, read_only(
            'motor revolutions per pump revolution',
            floating_point_range=_floats(0.01, 1000.0))).value
        velocity_unit = declare('velocity_unit', cd.VELOCITY_UNIT, read_only(
            'encoder counts/s per drive velocity unit (COPLEY: 0.1)',
            floating_point_range=_floats(1e-6, 1e6))).value
        current_unit = declare('current_unit', cd.CURRENT_UNIT, read_only(
            'amperes per drive current unit (COPLEY: 0.01)',
            floating_point_range=_floats(1e-6, 10.0))).value
        heartbeat_period = declare('heartbeat_period', cd.HEARTBEAT_PERIOD, read_only(
            'heartbeat producer time of every node [s]',
            floating_point_range=_floats(0.001, 10.0))).value
        heartbeat_timeout = declare('heartbeat_timeout', cd.HEARTBEAT_TIMEOUT, read_only(
            'heartbeat consumer time [s], over heartbeat_period',
            floating_point_range=_floats(0.002, 60.0))).value
        missing_syncs = declare('missing_syncs', DEFAULT_MISSING_SYNCS, read_only(
            'SYNC periods without a TPDO from a slave that are a bus fault',
            integer_range=_integers(1, 1000))).value
        priority = declare('realtime_priority', 0, read_only(
            'SCHED_FIFO priority of the I/O thread that sends the SYNC (0: the default '
            'scheduler; needs root or CAP_SYS_NICE, see exo_has_runtime.realtime)',
            integer_range=_integers(0, MAX_PRIORITY))).value
        acceleration = declare('acceleration', DEFAULT_ACCELERATION, read_only(
            'profile acceleration and deceleration of the pump [rad/s^2]',
            floating_point_range=_floats(1.0, 1e6))).value
        quick_stop = declare('quick_stop_deceleration', DEFAULT_QUICK_STOP_DECELERATION,
                             read_only('quick stop deceleration of the pump [rad/s^2]',
                                       floating_point_range=_floats(1.0, 1e6))).value
        command_timeout = declare('command_timeout', DEFAULT_COMMAND_TIMEOUT, read_only(
            'age of the newest command after which the drive holds zero speed [s]',
            floating_point_range=_floats(0.001, 60.0))).value
        # Dynamically typed: an empty list default would otherwise fix the type to a byte array.
        stop_sources = declare('stop_sources', ['/watchdog'], ParameterDescriptor(
            description='full names of the nodes that may publish stop commands beside the '
                        'controller (string array)', read_only=True,
            dynamic_typing=True)).value or []
        source_period = declare('source_check_period', 0.1, read_only(
            "period of the search of the ROS graph for a second publisher of a joint's state "
            'or commands [s]', floating_point_range=_floats(0.05, 10.0))).value
        if not isinstance(stop_sources, list) or not all(
                isinstance(name, str) and name.startswith('/') for name in stop_sources):
            msg = f'parameter stop_sources must list full node names, got {stop_sources!r}'
            raise HardwareConfigError(msg)
        sources = {kind: declare(f'params_{kind}', kind, read_only(
            f'{kind} HAS parameter set (stroke, relief and valve settings): {kind} or a '
            'parameters YAML file')).value for kind in ('hip', 'knee')}
        self._joints = checked_joints(joints, HardwareConfigError)
        ids = {joint: (declare(f'{joint}.drive_id', cd.DRIVE_NODE_IDS[joint], read_only(
            f'CANopen node ID of the {joint} drive', integer_range=_integers(1, 127))).value,
                       declare(f'{joint}.sensor_id', cd.SENSOR_NODE_IDS[joint], read_only(
            f'CANopen node ID of the {joint} sensor board',
            integer_range=_integers(1, 127))).value)
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
        problem = set_realtime_priority(priority, self._master.io_thread_id or 0)
        if problem:
            self.get_logger().warning(f'realtime_priority: {problem}')
        for joint in self._joints:
            self.create_subscription(HasCommand, has_command_topic(joint),
                                     partial(self._on_command, joint), qos_profile_sensor_data)
        self.create_subscription(Empty, SAFETY_RESET_TOPIC, self._on_reset, 10)
        self.create_subscription(SafetyEvent, SAFETY_EVENT_TOPIC, self._on_event,
                                 SAFETY_EVENT_QOS)
        self.create_timer(1.0 / rate, self._on_tick)
        # A second commander of a joint (beside the controller and stop_sources), or any other
        # publisher of the states this driver publishes: a fault the master latches and holds.
        self._commanders = PublisherWatch(
            self, [has_command_topic(j) for j in self._joints], ignore=stop_sources)
        self._state_sources = PublisherWatch(self, [has_state_topic(j) for j in self._joints])
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
        held = []
        for topic, names in self._commanders.poll(now).items():
            if len(names) > 1:
                joint = self._joint_of_topic[topic]
                held.append(Condition(topic, joint, SafetyKind.SECOND_SOURCE, len(names), 1.0,
                                      f'{joint}: second source: {len(names)} commanders on '
                                      f'{topic} ({", ".join(names)}), where one is allowed'))
        for topic, names in self._state_sources.poll(now).items():
            if names:
                joint = self._joint_of_topic[topic]
                held.append(Condition(topic, joint, SafetyKind.SECOND_SOURCE,
                                      len(names) + 1, 1.0,
                                      f'{joint}: second source: {", ".join(names)} publishing '
                                      f'on {topic} beside this driver'))
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
        stamp_ns = event.header.stamp.sec * 1_000_000_000 + event.header.stamp.nanosec
        if stamp_ns < self._start_ns:
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
            self._state_publishers[sample.joint].publish(_state(sample))
        events = master.take_events()
        refused = self._gate.expired(time.monotonic())
        if refused is not None:
            events.append(Event('', SafetyKind.E_STOP, Severity.WARN, math.nan,
                                       math.nan, True, refused))
        if events:
            self._emit(events)
        fatal = master_failure(master.running, master.failure)
        if fatal is not None:
            self.get_logger().fatal(fatal)
            raise MasterStoppedError(fatal)

    def _emit(self, events: list[Event]) -> None:
        stamp = self.get_clock().now().to_msg()
        logger = self.get_logger()
        for event in events:
            message = SafetyEvent(joint=event.joint, kind=event.kind, severity=event.severity,
                                  value=event.value, limit=event.limit, latched=event.latched,
                                  text=event.text)
            message.header.stamp = stamp
            self._own.append(_signature(message))
            self._event_publisher.publish(message)
            if event.severity >= Severity.ERROR:
                logger.error(event.text)
            elif event.severity == Severity.WARN:
                logger.warning(event.text)
            else:
                logger.info(event.text)

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


def _state(sample: JointSample) -> HasState:
    state = HasState(joint=sample.joint, position=sample.position, velocity=sample.velocity,
                     pressure_a=sample.pressure_a, pressure_b=sample.pressure_b,
                     motor_speed=sample.motor_speed,
                     motor_speed_command=sample.motor_speed_command,
                     motor_current=sample.motor_current, load_force=math.nan,
                     valve_mode=sample.valve_mode)
    seconds = math.floor(sample.stamp)
    state.header.stamp.sec = int(seconds)
    state.header.stamp.nanosec = min(int((sample.stamp - seconds) * 1e9), 999_999_999)
    return state


def main(args: list[str] | None = None) -> None:
    """Run the driver until interrupted; exit with status 1 if the CAN master stops."""
    sys.setswitchinterval(SWITCH_INTERVAL)  # see SWITCH_INTERVAL: the SYNC must not wait 5 ms
    try:
        run_node(Driver, args, name='driver')
    except MasterStoppedError:
        raise SystemExit(1) from None  # logged FATAL by the node, which is destroyed by now


if __name__ == '__main__':
    main()
