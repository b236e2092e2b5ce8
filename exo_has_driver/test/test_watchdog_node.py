"""The watchdog node in a process, its peers (plants, controllers) in the test process."""

import math
import time
from pathlib import Path

import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Empty

from exo_has_common.joints import JOINT_NAMES
from exo_has_common.topics import (
    DIAGNOSTICS_TOPIC,
    SAFETY_EVENT_TOPIC,
    SAFETY_RESET_TOPIC,
    has_command_topic,
    has_state_topic,
)
from exo_has_msgs.msg import HasCommand, HasState, SafetyEvent
from exo_has_runtime.processes import NodeProcess
from exo_has_runtime.profiles import SAFETY_EVENT_QOS
from exo_has_sim.parameters import load_parameters

MID = 0.5 * load_parameters('hip').stroke  # m, mid stroke (every joint's cylinder alike)

WATCHDOG = 'exo_has_driver.watchdog'
PERIOD = 0.005  # s: the rig plays plants and controllers at 200 Hz
# Time for a new participant to meet the watchdog: Fast DDS's discovery on loopback takes from
# 0.1 s to its 3 s announcement period, more on a loaded machine.
DISCOVERY_S = 10.0
# Stale after 20 periods (100 ms) rather than 10: the rig's Python loop shares the machine.
ARGS = ['--ros-args', '-p', 'stale_periods:=20', '-p', 'startup_grace:=3.0']
# Time from a fault reaching the watchdog to its stop commands reaching every joint; measured
# here at 4 to 7 ms (loopback, rclpy 7.1.6 on Fast DDS, the machine shared with other tests),
# bounded generously for loaded machines.
STOP_BOUND = 0.1  # s


def stamp_ns(message):
    """Return a message's header stamp in nanoseconds."""
    return message.header.stamp.sec * 1_000_000_000 + message.header.stamp.nanosec


class Rig:
    """The watchdog's peers in the test process: each joint's plant and controller."""

    def __init__(self, context, joints=JOINT_NAMES):
        self.node = Node('rig', context=context)
        # The events executor, as the nodes use: the rig takes about 2,000 messages a second.
        self.executor = EventsExecutor(context=context)
        self.executor.add_node(self.node)
        self.joints = joints
        self.states = {joint: {'position': MID, 'pressure_a': 5.0e6, 'pressure_b': 1.0e6,
                               'valve_mode': HasState.VALVE_ASSIST} for joint in joints}
        self.speeds = dict.fromkeys(joints, 10.0)
        self.silent = set()
        self.events = []  # (receive time [s, monotonic], SafetyEvent)
        self.stops = {joint: [] for joint in joints}  # receive times of stop commands
        self.stop_stamps = {joint: [] for joint in joints}  # (receive time, header stamp [ns])
        self.diagnostics = []
        self.state_publishers = {j: self.node.create_publisher(
            HasState, has_state_topic(j), qos_profile_sensor_data) for j in joints}
        self.command_publishers = {j: self.node.create_publisher(
            HasCommand, has_command_topic(j), qos_profile_sensor_data) for j in joints}
        self.reset_publisher = self.node.create_publisher(Empty, SAFETY_RESET_TOPIC, 10)
        for joint in joints:
            self.node.create_subscription(HasCommand, has_command_topic(joint),
                                          self._on_command, qos_profile_sensor_data)
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC,
                                      self.diagnostics.append, 10)

    def listen_to_events(self):
        """Subscribe to the safety events as a controller does, recording receive times."""
        self.node.create_subscription(
            SafetyEvent, SAFETY_EVENT_TOPIC,
            lambda event: self.events.append((time.monotonic(), event)), SAFETY_EVENT_QOS)

    def _on_command(self, command):
        if not command.enable:
            now = time.monotonic()
            self.stops[command.joint].append(now)
            self.stop_stamps[command.joint].append((now, stamp_ns(command)))

    def publish(self):
        """Publish one period of states (but the silent joints') and enabled commands."""
        for joint in self.joints:
            if joint not in self.silent:
                self.state_publishers[joint].publish(HasState(joint=joint, **self.states[joint]))
            self.command_publishers[joint].publish(
                HasCommand(joint=joint, motor_speed=self.speeds[joint], enable=True))

    def run(self, seconds, until=None):
        """Play the peers for ``seconds`` or until ``until()``; return ``until()``."""
        deadline = time.monotonic() + seconds
        next_publish = time.monotonic()
        while True:
            now = time.monotonic()
            if until is not None and until():
                return True
            if now >= deadline:
                return until() if until is not None else None
            if now >= next_publish:
                self.publish()
                next_publish += PERIOD
            self.executor.spin_once(timeout_sec=max(0.0, min(next_publish, deadline) - now))

    def wait_for_event(self, kind, after, seconds=2.0):
        """Play the peers until an event of ``kind`` arrives after ``after``; return it."""
        def found():
            return next((e for t, e in self.events if t >= after and e.kind == kind), None)
        assert self.run(seconds, found), (f'no event of kind {kind} in {seconds} s; got '
                                          f'{[e.text for _, e in self.events]}')
        return found()

    def stopped_all_after(self, t0):
        """Tell whether every joint received a stop command since t0."""
        return all(any(t >= t0 for t in times) for times in self.stops.values())

    def first_stops_after(self, t0):
        """Return each joint's first stop command receive time since t0."""
        return {j: min(t for t in times if t >= t0) for j, times in self.stops.items()}

    def reset(self):
        """Ask the watchdog to release its stop."""
        self.reset_publisher.publish(Empty())

    def close(self):
        """Destroy the executor and the node, before their context shuts down."""
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def make_rig(ros_context):
    """Give a function that builds a :class:`Rig` on the test's context, closed after it."""
    rigs = []

    def make(joints=JOINT_NAMES):
        rigs.append(Rig(ros_context, joints))
        return rigs[-1]
    yield make
    for rig in rigs:
        rig.close()


def start_rig(make_rig, watchdog, joints=JOINT_NAMES):
    watchdog.wait_for_output(r'watchdog ready', timeout_s=10.0)
    rig = make_rig(joints)
    rig.listen_to_events()

    def matched():
        return (all(p.get_subscription_count() for p in rig.state_publishers.values())
                and rig.reset_publisher.get_subscription_count()
                and rig.node.count_publishers(SAFETY_EVENT_TOPIC))
    assert rig.run(DISCOVERY_S, matched), watchdog.output
    return rig


@pytest.mark.process
@pytest.mark.parametrize('batch', [True, False], ids=['taken_at_each_check', 'by_callback'])
def test_a_fatal_fault_stops_every_joint_and_a_reset_on_the_topic_releases_it(make_rig, batch):
    with NodeProcess(WATCHDOG, [*ARGS, '-p', f'batch:={str(batch).lower()}']) as watchdog:
        rig = start_rig(make_rig, watchdog)
        rig.run(0.5)
        assert rig.events == [], [e.text for _, e in rig.events]
        assert not any(rig.stops.values())

        # A NaN command: INVALID_COMMAND, FATAL, and stop commands on every joint.
        t0 = time.monotonic()
        rig.speeds['right_hip'] = math.nan
        event = rig.wait_for_event(SafetyEvent.KIND_INVALID_COMMAND, t0)
        rig.speeds['right_hip'] = 10.0
        assert (event.joint, event.severity, event.latched) == (
            'right_hip', SafetyEvent.SEVERITY_FATAL, True)
        assert math.isnan(event.value) and math.isnan(event.limit)
        assert rig.run(1.0, lambda: rig.stopped_all_after(t0))

        # The reset releases the latch: a RESET event, then no more stop commands.
        t0 = time.monotonic()
        rig.reset()
        event = rig.wait_for_event(SafetyEvent.KIND_RESET, t0)
        assert (event.severity, event.latched) == (SafetyEvent.SEVERITY_INFO, False)
        assert 'stop released (latched by right_hip: invalid command' in event.text
        rig.run(0.1)
        t1 = time.monotonic()
        rig.run(0.3)
        assert not any(t > t1 for times in rig.stops.values() for t in times)

        # The safety valve opens: SAFETY_VALVE_OPEN, and every joint gets a stop command at once.
        rig.states['left_knee'].update(pressure_a=18.0e6, valve_mode=HasState.VALVE_RELIEF)
        t0 = time.monotonic()
        rig.publish()
        event = rig.wait_for_event(SafetyEvent.KIND_SAFETY_VALVE_OPEN, t0)
        assert rig.run(1.0, lambda: rig.stopped_all_after(t0))
        event_time = next(t for t, e in rig.events if e is event)
        stops = rig.first_stops_after(t0)
        latency = max(stops.values()) - t0
        assert (event.joint, event.severity, event.value, event.limit, event.latched) == (
            'left_knee', SafetyEvent.SEVERITY_FATAL, 18.0e6, 18.0e6, True)
        # Sent where the event was raised (the check that took the state, or its callback),
        # not at a later check: the same stamp.
        assert {j: min(s for t, s in stamps if t >= t0)
                for j, stamps in rig.stop_stamps.items()} == dict.fromkeys(JOINT_NAMES,
                                                                           stamp_ns(event))
        assert latency < STOP_BOUND, (f'event after {(event_time - t0) * 1e3:.1f} ms, stops '
                                      f'after {latency * 1e3:.1f} ms')

        # A reset is refused while the valve is still open, and granted once it closed.
        t0 = time.monotonic()
        rig.reset()
        refused = rig.wait_for_event(SafetyEvent.KIND_SAFETY_VALVE_OPEN, t0)
        assert (refused.severity, refused.latched) == (SafetyEvent.SEVERITY_WARN, True)
        assert 'reset refused: left_knee: safety valve still open' in refused.text
        rig.states['left_knee'].update(pressure_a=5.0e6, valve_mode=HasState.VALVE_ASSIST)
        rig.run(0.1)
        t0 = time.monotonic()
        rig.reset()
        assert rig.wait_for_event(SafetyEvent.KIND_RESET, t0).latched is False

        # One joint's plant dies: STALE_STATE for it alone.
        rig.silent.add('left_hip')
        t0 = time.monotonic()
        event = rig.wait_for_event(SafetyEvent.KIND_STALE_STATE, t0)
        assert (event.joint, event.severity, event.limit) == (
            'left_hip', SafetyEvent.SEVERITY_FATAL, pytest.approx(0.1))
        assert event.value > 0.1
        assert [e.kind for t, e in rig.events if t >= t0] == [SafetyEvent.KIND_STALE_STATE]

        # Diagnostics came once a second, one status per joint.
        assert rig.diagnostics
        statuses = rig.diagnostics[-1].status
        assert [s.name for s in statuses] == [f'watchdog: {j}' for j in JOINT_NAMES]
        assert {s.key for s in statuses[0].values} >= {'position [m]', 'pressure_a [Pa]',
                                                       'latched'}
    assert watchdog.process.returncode == 0, watchdog.output


@pytest.mark.process
def test_a_late_joiner_learns_of_the_latched_stop_that_silence_caused(make_rig):
    args = ['--ros-args', '-p', 'joints:=[left_hip]', '-p', 'startup_grace:=0.3']
    with NodeProcess(WATCHDOG, args) as watchdog:
        watchdog.wait_for_output(r'left_hip: stale command', timeout_s=10.0)
        rig = make_rig(joints=('left_hip',))
        rig.listen_to_events()  # after the events: transient local delivers them
        rig.silent.add('left_hip')
        assert rig.run(DISCOVERY_S, lambda: len(rig.events) >= 2), watchdog.output
        assert [(e.kind, e.severity, e.latched, e.limit) for _, e in rig.events] == [
            (SafetyEvent.KIND_STALE_STATE, SafetyEvent.SEVERITY_FATAL, True, 0.3),
            (SafetyEvent.KIND_STALE_COMMAND, SafetyEvent.SEVERITY_FATAL, True, 0.3)]
        # Stop commands keep coming at the watchdog's rate (200 Hz), nobody else commanding.
        rig.joints = ()
        rig.stops['left_hip'].clear()
        rig.run(0.5)
        assert len(rig.stops['left_hip']) >= 50, len(rig.stops['left_hip'])


@pytest.mark.process
@pytest.mark.parametrize(('override', 'message'), [
    ('joints:=[left_hip,left_ankle]',
     "cannot start: parameter joints: unknown joint 'left_ankle': expected one of left_hip"),
    ('rate:=5000.0', r'cannot start: .*Parameter rate out of range Min: 1.0, Max: 2000.0'),
    ('rate:=fast', "cannot start: Trying to set parameter 'rate' to 'fast' of type 'STRING', "
                   "expecting type 'DOUBLE'"),
    ('joints:=[]', 'cannot start: parameter joints is empty'),
    ('knee.params:=hip', 'cannot start: parameter knee.params: hip is a hip parameter set'),
])
def test_a_bad_setting_ends_the_node_at_start_naming_it(override, message):
    with NodeProcess(WATCHDOG, ['--ros-args', '-p', override]) as watchdog:
        assert watchdog.wait(timeout_s=20.0) == 1
        watchdog.wait_for_output(message, timeout_s=0.1)
        assert 'Traceback' not in watchdog.output


@pytest.mark.process
def test_a_malformed_params_file_ends_the_node_at_start_in_one_line(tmp_path):
    params = tmp_path / 'watchdog.yaml'
    params.write_text('/**:\n  ros__parameters:\n    rate: [200.0,\n', encoding='utf-8')
    with NodeProcess(WATCHDOG, ['--ros-args', '--params-file', str(params)]) as watchdog:
        assert watchdog.wait(timeout_s=20.0) == 2
        watchdog.wait_for_output(r'\[FATAL\] \[watchdog\]: cannot start: bad ROS arguments: .*'
                                 r"Couldn't parse params file", timeout_s=0.1)
        assert 'Traceback' not in watchdog.output


def test_messages_taken_after_a_hold_up_inside_a_check_are_dated_when_they_came(
        ros_context, monkeypatch):
    # A check reads the clock, then takes the queued messages. Held up in between (the process
    # descheduled: a two-host session saw 0.5 s), it dated each message by its age at the end of
    # the hold-up, from the clock read before it: every one too early by the hold-up, so that
    # at that check every joint looked stale (a FATAL stop in test_two_hosts.py, 2026-11-26).
    from exo_has_driver.watchdog import WatchdogNode
    from exo_has_runtime.polling import Taken

    node = WatchdogNode(context=ros_context)
    try:
        queued = [Taken(has_state_topic(joint), HasState(
            joint=joint, position=MID, pressure_a=5.0e6, pressure_b=1.0e6,
            valve_mode=HasState.VALVE_ASSIST), time.time_ns()) for joint in JOINT_NAMES]

        def held_up_drain():
            time.sleep(0.3)
            return queued
        monkeypatch.setattr(node._inbox, 'drain', held_up_drain)
        node._on_tick()
        t = node._last_check
        for joint in JOINT_NAMES:
            assert node._core._joints[joint].state_time == pytest.approx(t, abs=0.05), joint
    finally:
        node.destroy_node()


def test_the_shipped_parameters_file_sets_parameters_the_node_declares(ros_context, tmp_path):
    # rclpy ignores a name the node does not declare (a misspelt or renamed one) in silence.
    # A joint type's parameter set is hip.params and knee.params, as in the controller: the
    # file nests them under hip and knee.
    from rclpy.parameter import parameter_dict_from_yaml_file, parameter_value_to_python

    from exo_has_driver.errors import SafetyConfigError
    from exo_has_driver.watchdog import WatchdogNode

    path = Path(__file__).resolve().parents[1] / 'config' / 'watchdog.yaml'
    written = {name: parameter_value_to_python(parameter.value) for name, parameter
               in parameter_dict_from_yaml_file(str(path), use_wildcard=True).items()}
    assert written['hip.params'] == 'hip' and written['knee.params'] == 'knee'
    node = WatchdogNode(context=ros_context, cli_args=['--ros-args', '--params-file', str(path)])
    try:
        assert [name for name in written if not node.has_parameter(name)] == []
        assert {name: node.get_parameter(name).value for name in written} == written
    finally:
        node.destroy_node()
    wrong = tmp_path / 'watchdog.yaml'
    wrong.write_text(path.read_text().replace('knee:\n      params: knee',
                                              'knee:\n      params: hip'))
    with pytest.raises(SafetyConfigError, match=r'parameter knee\.params: hip is a hip parameter'):
        WatchdogNode(context=ros_context, cli_args=['--ros-args', '--params-file', str(wrong)])
