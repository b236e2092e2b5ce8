"""The driver node in a process against the simulated devices' process on udp_multicast."""

import math
import re
import signal
import subprocess
import sys
import tempfile
import time
from contextlib import contextmanager
from pathlib import Path

import pytest
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from std_msgs.msg import Empty

from exo_has_common.topics import (
    SAFETY_EVENT_TOPIC,
    SAFETY_RESET_TOPIC,
    has_command_topic,
    has_state_topic,
)
from exo_has_driver.driver_node import master_failure
from exo_has_driver.hardware.bus import random_multicast_group
from exo_has_msgs.msg import HasCommand, HasState, SafetyEvent
from exo_has_runtime.processes import NodeProcess, tethered
from exo_has_runtime.profiles import SAFETY_EVENT_QOS

DRIVER = 'exo_has_driver.driver_node'
JOINTS = ('left_hip', 'right_knee')
PERIOD = 0.005
WAIT = 5.0  # s: four Python processes share two cores
# SCHED_FIFO for the devices and the driver's bus thread, as test/test_can_session.py runs
# them: under the default scheduler a devices' process held up for over 50 ms (10 SYNCs) on
# this VM was a FATAL 'no TPDO' stop in the middle of a test (a clean-clone run, 2026-11-26).
REALTIME_PRIORITY = 20
# Time for the peers to meet the driver: Fast DDS's discovery on loopback takes from 0.1 s to
# its 3 s announcement period, more on a loaded machine.
DISCOVERY_S = 10.0


def bus_args(group):
    return ['--ros-args', '-p', 'interface:=udp_multicast', '-p', f'channel:={group}',
            '-p', f'joints:=[{",".join(JOINTS)}]',
            '-p', f'realtime_priority:={REALTIME_PRIORITY}']


class Devices:
    """The simulated devices' process, with its stdin for fault injection."""

    def __init__(self, group):
        self.log = tempfile.NamedTemporaryFile(prefix='can_devices-', suffix='.log',
                                               delete=False)
        self.process = subprocess.Popen(
            tethered([sys.executable, '-u', '-m', 'exo_has_driver.devices.main', '--interface',
                      'udp_multicast', '--channel', group, '--joints', *JOINTS,
                      # under the bus thread
                      '--realtime-priority', str(REALTIME_PRIORITY - 1)]),
            stdin=subprocess.PIPE, stdout=self.log, stderr=subprocess.STDOUT, text=True,
            cwd=tempfile.gettempdir())

    @property
    def output(self):
        """Everything the process wrote so far."""
        return Path(self.log.name).read_text(encoding='utf-8', errors='replace')

    def wait_for(self, text, timeout=20.0):
        """Wait until the output contains ``text``."""
        deadline = time.monotonic() + timeout
        while text not in self.output:
            assert self.process.poll() is None and time.monotonic() < deadline, self.output
            time.sleep(0.05)

    def inject(self, line):
        """Send one fault injection command."""
        self.process.stdin.write(line + '\n')
        self.process.stdin.flush()

    def stop(self):
        """End the process (SIGINT, then SIGKILL)."""
        if self.process.poll() is None:
            self.process.send_signal(2)
            try:
                self.process.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        self.process.stdin.close()
        self.log.close()
        Path(self.log.name).unlink(missing_ok=True)


class Peers:
    """The driver's peers in the test process: controllers, the watchdog, a listener."""

    def __init__(self, context):
        self.node = Node('driver_peers', context=context)
        self.executor = EventsExecutor(context=context)
        self.executor.add_node(self.node)
        self.speeds = dict.fromkeys(JOINTS, 0.0)
        self.states = {joint: [] for joint in JOINTS}
        self.events = []
        self.commands = {j: self.node.create_publisher(HasCommand, has_command_topic(j),
                                                       qos_profile_sensor_data) for j in JOINTS}
        for joint in JOINTS:
            self.node.create_subscription(HasState, has_state_topic(joint),
                                          self.states[joint].append, qos_profile_sensor_data)
        self.node.create_subscription(SafetyEvent, SAFETY_EVENT_TOPIC, self.events.append,
                                      SAFETY_EVENT_QOS)
        self.watchdog = self.node.create_publisher(SafetyEvent, SAFETY_EVENT_TOPIC,
                                                   SAFETY_EVENT_QOS)
        self.reset_publisher = self.node.create_publisher(Empty, SAFETY_RESET_TOPIC, 10)

    def run(self, seconds, until=None):
        """Command every joint every 5 ms for ``seconds`` or until ``until()``."""
        deadline = time.monotonic() + seconds
        next_publish = time.monotonic()
        while True:
            now = time.monotonic()
            if until is not None and until():
                return True
            if now >= deadline:
                return until() if until is not None else None
            if now >= next_publish:
                for joint, publisher in self.commands.items():
                    publisher.publish(HasCommand(joint=joint, motor_speed=self.speeds[joint],
                                                 enable=True))
                next_publish += PERIOD
            self.executor.spin_once(timeout_sec=max(0.0, min(next_publish, deadline) - now))

    def event(self, kind, after=0):
        """Return the first event of ``kind`` among the events from index ``after``."""
        return next((e for e in self.events[after:] if e.kind == kind), None)

    def wait_event(self, kind, after=0):
        """Run until an event of ``kind`` arrives; return it."""
        assert self.run(WAIT, lambda: self.event(kind, after) is not None), \
            [e.text for e in self.events]
        return self.event(kind, after)

    def speeds_near(self, speed, tolerance):
        """Whether every joint's newest state reports a motor speed near ``speed``."""
        return all(states and abs(states[-1].motor_speed - speed) < tolerance
                   for states in self.states.values())

    def meet(self, driver):
        """Run until the driver subscribes to the commands and the reset."""
        assert self.run(DISCOVERY_S, lambda: all(
            p.get_subscription_count() for p in self.commands.values())
            and self.reset_publisher.get_subscription_count()), driver.output

    def close(self):
        """Destroy the executor and the node, before their context shuts down."""
        self.executor.shutdown()
        self.node.destroy_node()


@pytest.fixture
def group():
    return random_multicast_group()


@pytest.fixture
def peers(ros_context):
    peers = Peers(ros_context)
    yield peers
    peers.close()


@pytest.mark.process
def test_the_driver_moves_the_joints_stops_on_the_watchdog_and_on_a_drive_fault(peers, group):
    devices = Devices(group)
    try:
        devices.wait_for('can devices ready')
        with NodeProcess(DRIVER, bus_args(group)) as driver:
            driver.wait_for_output(r'driver ready: left_hip, right_knee on udp_multicast',
                                   timeout_s=20.0)
            peers.meet(driver)

            # Commands reach the motors, states come back at about the SYNC rate.
            peers.speeds = dict.fromkeys(JOINTS, -20.0)
            assert peers.run(WAIT, lambda: peers.speeds_near(-20.0, 1.0)), driver.output
            for states in peers.states.values():
                states.clear()
            peers.run(1.0)
            for joint, states in peers.states.items():
                # 200 per second; the loaded machine may lose some.
                assert len(states) >= 100, (joint, len(states))
                last = states[-1]
                assert last.joint == joint
                assert last.motor_speed_command == pytest.approx(-20.0, abs=1e-3)
                assert last.valve_mode == HasState.VALVE_ASSIST
                assert math.isnan(last.load_force)
                stamp = last.header.stamp.sec + last.header.stamp.nanosec * 1e-9
                assert stamp == pytest.approx(time.time(), abs=1.0)
            assert peers.events == [], [e.text for e in peers.events]

            # A FATAL latched event of the watchdog is an e-stop: every motor stops.
            stop = SafetyEvent(kind=SafetyEvent.KIND_STALE_STATE,
                               severity=SafetyEvent.SEVERITY_FATAL, latched=True,
                               joint='left_hip', value=0.2, limit=0.1,
                               text='left_hip: stale state (test)')
            stop.header.stamp.sec = int(time.time()) + 1
            peers.watchdog.publish(stop)
            event = peers.wait_event(SafetyEvent.KIND_E_STOP)
            assert (event.severity, event.latched) == (SafetyEvent.SEVERITY_FATAL, True)
            assert event.text == 'emergency stop: left_hip: stale state (test)'
            assert peers.run(WAIT, lambda: peers.speeds_near(0.0, 0.5))
            peers.run(0.3)
            assert all(s[-1].valve_mode == HasState.VALVE_FREE for s in peers.states.values())
            # The driver does not take its own E_STOP event for another e-stop.
            assert [e.kind for e in peers.events].count(SafetyEvent.KIND_E_STOP) == 1

            # While the watchdog's newest event says latched, the driver refuses a reset.
            count = len(peers.events)
            peers.reset_publisher.publish(Empty())
            assert peers.run(WAIT, lambda: any(
                e.severity == SafetyEvent.SEVERITY_WARN for e in peers.events[count:])), \
                [e.text for e in peers.events[count:]]
            refused = next(e for e in peers.events[count:]
                           if e.severity == SafetyEvent.SEVERITY_WARN)
            assert refused.latched
            assert refused.text == ('reset refused: a stop latched by another node holds: '
                                    'left_hip: stale state (test)')
            assert peers.event(SafetyEvent.KIND_RESET, count) is None
            assert all(s[-1].valve_mode == HasState.VALVE_FREE for s in peers.states.values())

            # The watchdog releases on the same reset: so does the driver; the motors move.
            count = len(peers.events)
            peers.reset_publisher.publish(Empty())
            release = SafetyEvent(kind=SafetyEvent.KIND_RESET,
                                  severity=SafetyEvent.SEVERITY_INFO, latched=False,
                                  text='reset: stop released (test)')
            release.header.stamp.sec = int(time.time()) + 1
            peers.watchdog.publish(release)
            event = peers.wait_event(SafetyEvent.KIND_RESET, count)
            while event.text == 'reset: stop released (test)':  # the watchdog's own
                count = peers.events.index(event) + 1
                event = peers.wait_event(SafetyEvent.KIND_RESET, count)
            assert (event.severity, event.latched) == (SafetyEvent.SEVERITY_INFO, False)
            assert event.text.startswith('reset: stop released (latched by emergency stop')
            assert peers.run(WAIT, lambda: peers.speeds_near(-20.0, 1.0))

            # A drive fault in the devices' process: DRIVE_FAULT with its code, all stopped.
            count = len(peers.events)
            devices.inject('fault right_knee 0x4310')
            event = peers.wait_event(SafetyEvent.KIND_DRIVE_FAULT, count)
            assert (event.joint, event.value, event.latched) == ('right_knee', 0x4310, True)
            assert 'drive over-temperature' in event.text
            assert peers.run(WAIT, lambda: peers.speeds_near(0.0, 0.5))

            assert driver.stop() == 0
            assert 'Traceback' not in driver.output, driver.output
        # The driver stopped the motors on its way out; without its heartbeat the drives then
        # fault (8130h), as the specification wants.
        devices.inject('status')
        devices.wait_for('left_hip drive 1:')
        assert re.search(r'left_hip drive 1: operational, (switch on disabled|fault), .*motor '
                         r'-?0\.0 rad/s', devices.output), devices.output
    finally:
        devices.stop()


@contextmanager
def running_devices(group):
    """Run the simulated CAN devices until the block ends."""
    devices = Devices(group)
    try:
        devices.wait_for('can devices ready')
        yield devices
    finally:
        devices.stop()


def drive_every_joint(peers, driver, speed=-20.0):
    """Meet a started driver, then command every joint to ``speed`` until it runs there."""
    driver.wait_for_output(r'driver ready', timeout_s=20.0)
    peers.meet(driver)
    peers.speeds = dict.fromkeys(JOINTS, speed)
    assert peers.run(WAIT, lambda: peers.speeds_near(speed, 1.0)), driver.output


@pytest.mark.process
def test_sigterm_ends_the_driver_cleanly_and_it_stops_the_motors_on_its_way_out(peers, group):
    with running_devices(group) as devices:
        with NodeProcess(DRIVER, bus_args(group)) as driver:
            drive_every_joint(peers, driver)
            # The master's I/O thread runs on: the signal must still end the process.
            driver.process.send_signal(signal.SIGTERM)
            assert driver.wait(timeout_s=WAIT) == 0, driver.output
            assert 'Traceback' not in driver.output, driver.output
        devices.inject('status')
        devices.wait_for('right_knee drive 4:')
        assert re.search(r'right_knee drive 4: operational, (switch on disabled|fault), .*motor '
                         r'-?0\.0 rad/s', devices.output), devices.output


@pytest.mark.process
def test_a_second_source_of_a_joints_state_stops_every_joint_until_it_is_gone(peers, group):
    with running_devices(group), NodeProcess(DRIVER, bus_args(group)) as driver:
        drive_every_joint(peers, driver)
        # A plant left running beside the hardware, say: it publishes the hip's states.
        rogue = peers.node.create_publisher(HasState, has_state_topic('left_hip'),
                                            qos_profile_sensor_data)
        event = peers.wait_event(SafetyEvent.KIND_SECOND_SOURCE)
        assert (event.joint, event.severity, event.latched) == (
            'left_hip', SafetyEvent.SEVERITY_FATAL, True)
        assert event.text == ('left_hip: second source: 2 publishers on /left_hip/has_state '
                              '(/driver_peers, this driver), where one is allowed')
        assert peers.run(WAIT, lambda: peers.speeds_near(0.0, 0.5)), driver.output
        # A reset is refused while it is there, and accepted once it is gone.
        count = len(peers.events)
        peers.reset_publisher.publish(Empty())
        refused = peers.wait_event(SafetyEvent.KIND_SECOND_SOURCE, count)
        assert refused.severity == SafetyEvent.SEVERITY_WARN
        assert refused.text.startswith('reset refused: left_hip: second source')
        peers.node.destroy_publisher(rogue)
        count = len(peers.events)

        sent = -math.inf

        def released():
            # A reset every 0.1 s until the driver sees the source gone, as an operator would
            # press again; not one per message the peers take (30 in 0.1 s in a failed run).
            nonlocal sent
            if time.monotonic() - sent >= 0.1:
                sent = time.monotonic()
                peers.reset_publisher.publish(Empty())
            return peers.event(SafetyEvent.KIND_RESET, count)
        assert peers.run(WAIT, lambda: released() is not None), \
            [e.text for e in peers.events[count:]]
        assert peers.run(WAIT, lambda: peers.speeds_near(-20.0, 1.0)), driver.output


@pytest.mark.process
@pytest.mark.parametrize(('override', 'message'), [
    ('joints:=[left_hip,left_ankle]',
     "cannot start: parameter joints: unknown joint 'left_ankle': expected one of left_hip"),
    ('knee.params:=hip', 'cannot start: parameter knee.params: hip is a hip parameter set'),
    ('missing_syncs:=0', 'cannot start: .*Parameter missing_syncs out of range. Min: 1'),
    ('rate:=200', "cannot start: Trying to set parameter 'rate' to '200' of type 'INTEGER', "
                  "expecting type 'DOUBLE'"),
])
def test_a_bad_setting_ends_the_driver_at_start_naming_it(override, message):
    # The bus is opened after the parameters are checked: nothing is sent.
    with NodeProcess(DRIVER, ['--ros-args', '-p', override]) as driver:
        assert driver.wait(timeout_s=30.0) == 1
        driver.wait_for_output(message, timeout_s=0.1)
        assert 'Traceback' not in driver.output


def test_a_master_whose_io_thread_ended_is_fatal_with_its_failure():
    assert master_failure(True, None) is None
    assert master_failure(False, OSError('bus down')) == 'the CAN master stopped: bus down'
