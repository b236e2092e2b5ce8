"""The robot loop's process against the simulated CAN devices, fed over its sockets.

The devices (``exo_has_driver.devices.main``) and the loop (``exo_has_bringup.robot_main``) run
on a udp_multicast bus of their own, both under SCHED_FIFO where permitted, as in the CAN
session test. This test process plays the bridge's output side (it binds the bridge's socket
and reads the states, events and metrics); a process of its own sends the reference, so that
killing it is a bridge that died.
"""

from __future__ import annotations

import math
import queue
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from exo_has_bringup.plan import devices_priority
from exo_has_bringup.robot_exchange import bridge_end
from exo_has_bringup.robot_messages import EventMessage, Metrics, ResetRequest, States
from exo_has_common.joints import JOINT_NAMES, joint_type_of
from exo_has_driver.events import SafetyKind, Severity
from exo_has_driver.hardware import cia402
from exo_has_driver.hardware.bus import random_multicast_group
from exo_has_runtime.processes import tethered
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters

pytestmark = pytest.mark.process

RATE = 100.0  # Hz, as the CAN session test: the devices and the loop share two cores here
STALE_PERIODS = 20  # 0.2 s at 100 Hz
REALTIME_PRIORITY = 20
START_TIMEOUT = 30.0  # s: fresh interpreters import numpy, scipy and the compiled model
SENDER = Path(__file__).with_name('robot_reference_sender.py')
LINKAGES = {joint: Linkage.from_parameters(load_parameters(joint_type_of(joint)))
            for joint in JOINT_NAMES}
#: How far each joint is sent from where it stands [rad]: 5 deg.
STEP = math.radians(5.0)
#: Tracking within this of a constant reference counts as reached [rad]: 1.5 deg.
REACHED = math.radians(1.5)


class Process:
    """A child process whose stdout lines are collected by a thread."""

    def __init__(self, arguments: list[str]) -> None:
        self.popen = subprocess.Popen(tethered(arguments), stdout=subprocess.PIPE,
                                      stderr=subprocess.STDOUT, stdin=subprocess.PIPE, text=True)
        self.lines: queue.Queue[str] = queue.Queue()
        self.output: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        assert self.popen.stdout is not None
        for line in self.popen.stdout:
            self.lines.put(line.rstrip('\n'))

    def expect(self, text: str, timeout: float = START_TIMEOUT) -> str:
        """Return the first line containing ``text``; fail after ``timeout`` [s]."""
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                if self.popen.poll() is not None and self.lines.empty():
                    break
                continue
            self.output.append(line)
            if text in line:
                return line
        msg = f'no line with {text!r}; output: {self.output}'
        raise AssertionError(msg)

    def stop(self) -> None:
        """Kill the process if it runs, and reap it."""
        if self.popen.poll() is None:
            self.popen.kill()
        self.popen.wait(timeout=10.0)


@pytest.fixture
def socket_dir() -> Iterator[Path]:
    # Short: a Unix socket path takes at most 107 bytes.
    with tempfile.TemporaryDirectory(prefix='exo-loop-') as directory:
        yield Path(directory)


class Bridge:
    """The test's end of the exchange, keeping what the loop sent."""

    def __init__(self, directory: Path) -> None:
        self.exchange = bridge_end(directory)
        self.states: dict[str, list] = {joint: [] for joint in JOINT_NAMES}
        self.events: list = []
        self.metrics: list[Metrics] = []

    def pump(self, seconds: float, until=None) -> bool:
        """Take what the loop sends for ``seconds`` or until ``until()``; return until()."""
        deadline = time.monotonic() + seconds
        while True:
            for message in self.exchange.receive():
                if isinstance(message, States):
                    for sample in message.samples:
                        self.states[sample.joint].append(sample)
                elif isinstance(message, EventMessage):
                    self.events.append(message.event)
                elif isinstance(message, Metrics):
                    self.metrics.append(message)
            if until is not None and until():
                return True
            if time.monotonic() > deadline:
                return until is None
            time.sleep(0.01)

    def angle(self, joint: str) -> float:
        """Return a joint's newest angle [rad]."""
        return LINKAGES[joint].angle_at(self.states[joint][-1].position)


def test_the_loop_process_tracks_a_reference_and_holds_when_its_sender_dies(socket_dir):
    group = random_multicast_group()
    bridge = Bridge(socket_dir)
    devices = loop = sender = None
    try:
        devices = Process([sys.executable, '-m', 'exo_has_driver.devices.main', '--interface',
                           'udp_multicast', '--channel', group,
                           '--realtime-priority', f'{devices_priority(REALTIME_PRIORITY)}'])
        devices.expect('can devices ready')
        loop = Process([sys.executable, '-m', 'exo_has_bringup.robot_main', '--interface',
                        'udp_multicast', '--channel', group, '--rate', f'{RATE}',
                        '--stale-periods', f'{STALE_PERIODS}', '--socket-dir', str(socket_dir),
                        '--realtime-priority', f'{REALTIME_PRIORITY}', '--activate'])
        loop.expect('robot loop ready')
        assert bridge.pump(5.0, lambda: all(bridge.states.values()))
        # Its memory locked where permitted (root here), and no threads but its main one and
        # the master's I/O thread (no BLAS threads).
        status = Path(f'/proc/{loop.popen.pid}/status').read_text()
        locked = re.search(r'VmLck:\s+(\d+) kB', status)
        assert locked is not None and (int(locked.group(1)) > 0 or any(
            'cannot lock memory' in line for line in loop.output)), loop.output
        assert len(list(Path(f'/proc/{loop.popen.pid}/task').iterdir())) == 2
        # Each joint is sent 5 deg from where it stood, toward the middle of its range.
        start = {joint: bridge.angle(joint) for joint in JOINT_NAMES}
        reference = {}
        for joint, angle in start.items():
            middle = sum(LINKAGES[joint].angle_range()) / 2.0
            reference[joint] = angle + math.copysign(STEP, middle - angle)
        sender = Process([sys.executable, str(SENDER), str(socket_dir), '50',
                          *(f'{joint}={angle!r}' for joint, angle in reference.items())])
        sender.expect('sending')

        def reached() -> bool:
            return all(abs(bridge.angle(j) - reference[j]) < REACHED for j in JOINT_NAMES)

        assert bridge.pump(10.0, reached), {j: math.degrees(bridge.angle(j) - reference[j])
                                            for j in JOINT_NAMES}
        bridge.pump(1.0)
        assert reached()
        assert [e.text for e in bridge.events if e.severity >= Severity.ERROR] == []

        # The sender dies: the loop holds every joint where it stands, under control.
        sender.popen.send_signal(signal.SIGKILL)
        sender.stop()
        killed = time.monotonic()

        def held() -> bool:
            return any(e.kind == SafetyKind.STALE_REFERENCE for e in bridge.events) \
                and bool(bridge.metrics) and bridge.metrics[-1].holding

        assert bridge.pump(2.0, held), [e.text for e in bridge.events]
        assert time.monotonic() - killed < 1.0  # 0.2 s stale bound, 0.1 s metrics period
        [hold] = [e for e in bridge.events if e.kind == SafetyKind.STALE_REFERENCE]
        assert hold.severity == Severity.ERROR and hold.latched
        where = {joint: bridge.angle(joint) for joint in JOINT_NAMES}
        bridge.pump(1.0)
        for joint in JOINT_NAMES:
            assert bridge.states[joint][-1].drive_state == cia402.OPERATION_ENABLED
            assert abs(bridge.angle(joint) - where[joint]) < REACHED

        # A sender again (3 deg further on) does not move them; a reset does.
        moved = {joint: angle + math.copysign(math.radians(3.0), angle - start[joint])
                 for joint, angle in reference.items()}
        sender = Process([sys.executable, str(SENDER), str(socket_dir), '50',
                          *(f'{joint}={angle!r}' for joint, angle in moved.items())])
        sender.expect('sending')
        bridge.pump(1.0)
        assert bridge.metrics[-1].holding
        for joint in JOINT_NAMES:
            assert abs(bridge.angle(joint) - where[joint]) < REACHED
        bridge.exchange.send(ResetRequest())
        assert bridge.pump(2.0, lambda: any(e.kind == SafetyKind.RESET for e in bridge.events)
                           and not bridge.metrics[-1].holding), [e.text for e in bridge.events]
        assert bridge.pump(10.0, lambda: all(abs(bridge.angle(j) - moved[j]) < REACHED
                                             for j in JOINT_NAMES))

        loop.popen.send_signal(signal.SIGTERM)
        assert loop.popen.wait(timeout=10.0) == 0, loop.output
        summary = loop.expect('robot loop stopped')
        print(summary)
        assert [e.text for e in bridge.events if e.severity == Severity.FATAL] == []
        assert re.search(r'(\d+) periods, (\d+) missed', summary)
    finally:
        for process in (sender, loop, devices):
            if process is not None:
                if process is devices and process.popen.poll() is None:
                    process.popen.send_signal(signal.SIGTERM)
                    try:
                        process.popen.wait(timeout=10.0)
                    except subprocess.TimeoutExpired:
                        pass
                process.stop()
        bridge.exchange.close()


def test_the_loop_process_imports_nothing_of_ros():
    code = ('import sys, exo_has_bringup.robot_main; '
            "print(sorted({m.split('.')[0] for m in sys.modules if m.split('.')[0] in "
            "('rclpy', 'rcl_interfaces', 'std_msgs', 'sensor_msgs', 'exo_has_msgs', "
            "'exo_has_runtime', 'rmw')}))")
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                            timeout=START_TIMEOUT, check=True)
    assert result.stdout.strip() == '[]', result.stdout
