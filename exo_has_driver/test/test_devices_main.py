"""The can_devices process: its stdin protocol, its arguments, and a run across processes."""

from __future__ import annotations

import math
import os
import queue
import signal
import struct
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import can
import pytest

from exo_has_driver import can_dictionary as cd
from exo_has_driver.devices import Rig
from exo_has_driver.devices.main import execute, main
from exo_has_driver.errors import FaultInjectionError
from exo_has_driver.hardware.bus import isolate_multicast, random_multicast_group
from exo_has_runtime.processes import tethered

TIMEOUT = 30.0  # s: a fresh interpreter imports numpy and the compiled model


@pytest.fixture
def rig() -> Iterator[Rig]:
    bus = can.Bus(interface='virtual', channel=f'devices-{uuid.uuid4().hex}')
    rig = Rig(bus, ['left_hip', 'left_knee'])
    try:
        yield rig
    finally:
        bus.shutdown()


def test_stdin_commands_change_the_rig(rig: Rig) -> None:
    hip, knee = rig.joints['left_hip'], rig.joints['left_knee']
    assert execute(rig, 'load left_knee 800') == 'left_knee load 800 N'
    assert knee.plant.load == 800.0
    assert execute(rig, 'sensor left_hip pressure_a nan') == 'left_hip pressure_a reads nan'
    assert math.isnan(hip.board.overrides['pressure_a'])
    assert execute(rig, 'sensor left_hip position 0.5') == 'left_hip position reads 0.5'
    assert execute(rig, 'heartbeat all off both') == 'all both heartbeat off'
    assert not knee.board.heartbeat_enabled and not hip.drive.heartbeat_enabled
    assert execute(rig, 'silence left_knee') == 'left_knee silence on'
    assert knee.drive.silent and not hip.drive.silent
    rig.start()
    try:
        assert execute(rig, 'fault left_hip 0x4310') == 'left_hip drive fault 0x4310'
        assert hip.drive.state == 'fault' and hip.drive.get(cd.ERROR_CODE) == 0x4310
        assert 'left_hip drive 1: pre-operational, fault, error 0x4310' in execute(rig, 'status')
    finally:
        rig.stop()
    assert execute(rig, 'clear all') == 'all cleared'
    assert knee.plant.load == pytest.approx(knee.default_load, abs=1e-9)
    assert not hip.board.overrides and not knee.drive.silent and knee.board.heartbeat_enabled


@pytest.mark.parametrize(('line', 'message'), [
    ('explode left_hip', 'unknown command'),
    ('fault', 'a joint'),
    ('fault left_elbow 0x2310', "no joint 'left_elbow'"),
    ('fault right_hip 0x2310', "no joint 'right_hip'"),
    ('fault left_hip', 'usage: fault'),
    ('fault left_hip hot', 'error code must be a number'),
    ('fault left_hip 0x12345', 'error code must be 0x0001 to 0xFFFF'),
    ('heartbeat left_hip maybe', 'expected on or off'),
    ('heartbeat left_hip off motor', 'unknown device'),
    ('sensor left_hip torque 1', 'unknown sensor channel'),
    ('sensor left_hip position inf', 'finite or NaN'),
    ('sensor all position nan', 'name one joint'),
    ('load left_hip heavy', 'load force must be a number'),
    ('load left_hip nan', 'must be finite'),
    ('silence left_hip loudly', 'expected on or off'),
])
def test_a_malformed_line_raises_a_message_naming_the_problem(rig: Rig, line: str,
                                                              message: str) -> None:
    with pytest.raises(FaultInjectionError, match=message):
        execute(rig, line)


def test_main_rejects_an_unknown_joint_and_a_bad_channel(
        capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as stopped:
        main(['--interface', 'virtual', '--joints', 'left_elbow'])
    assert stopped.value.code == 2
    assert 'unknown joint(s) left_elbow' in capsys.readouterr().err
    assert main(['--interface', 'udp_multicast', '--channel', 'not-a-group']) == 2
    assert "cannot open CAN interface 'udp_multicast' channel 'not-a-group'" in \
        capsys.readouterr().err
    with pytest.raises(SystemExit) as stopped:
        main(['--interface', 'virtual', '--realtime-priority', '99'])
    assert stopped.value.code == 2
    assert '--realtime-priority: a real-time priority must be an integer within 0 and 49, got 99' \
        in capsys.readouterr().err


def _lines(stream: subprocess.Popen[str], into: queue.Queue[str]) -> None:
    assert stream.stdout is not None
    for line in stream.stdout:
        into.put(line.rstrip('\n'))


def _expect(lines: queue.Queue[str], text: str) -> str:
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.5)
        except queue.Empty:
            continue
        if text in line:
            return line
    msg = f'no line containing {text!r} within {TIMEOUT} s'
    raise AssertionError(msg)


def _frame(bus: can.BusABC, cob_id: int) -> bytes:
    deadline = time.monotonic() + TIMEOUT
    while time.monotonic() < deadline:
        msg = bus.recv(timeout=0.5)
        if msg is not None and msg.arbitration_id == cob_id:
            return bytes(msg.data)
    msg_text = f'no frame 0x{cob_id:03X} within {TIMEOUT} s'
    raise AssertionError(msg_text)


def _policies(pid: int) -> list[int]:
    """Return the scheduling policy of every thread of process ``pid``."""
    return [os.sched_getscheduler(int(task.name)) for task in Path(f'/proc/{pid}/task').iterdir()]


@pytest.mark.process
def test_the_process_runs_the_devices_over_udp_multicast_and_takes_stdin_faults() -> None:
    group = random_multicast_group()
    bus = can.Bus(interface='udp_multicast', channel=group)
    assert isolate_multicast(bus)  # other tests on the machine use the same port
    process = subprocess.Popen(
        tethered([sys.executable, '-m', 'exo_has_driver.devices.main', '--interface',
                  'udp_multicast', '--channel', group, '--joints', 'left_hip',
                  '--realtime-priority', '10']),
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=_lines, args=(process, lines), daemon=True).start()
    try:
        assert 'left_hip' in _expect(lines, 'can devices ready')
        # The main thread, the bus's listener, the rig's timer and the stdin reader run as the
        # drives' firmware would (numpy's idle BLAS threads, started at import, stay as they
        # were), unless the machine refuses: then the process says so on stderr, read at the end.
        refused = os.sched_getscheduler(process.pid) == os.SCHED_OTHER
        if not refused:
            assert _policies(process.pid).count(os.SCHED_FIFO) >= 4
            assert os.sched_getparam(process.pid).sched_priority == 10
        assert _frame(bus, cd.HEARTBEAT_BASE + 1) in (b'\x00', b'\x7f')
        assert _frame(bus, cd.HEARTBEAT_BASE + 17) in (b'\x00', b'\x7f')
        assert process.stdin is not None
        process.stdin.write('this is not a command\n')
        process.stdin.flush()
        assert 'unknown command' in _expect(lines, 'error:')
        process.stdin.write('fault left_hip 0x2310\n')
        process.stdin.flush()
        assert _expect(lines, 'ok:') == 'ok: left_hip drive fault 0x2310'
        assert struct.unpack('<HB5x', _frame(bus, cd.EMCY_BASE + 1)) == (0x2310, 0x03)
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=TIMEOUT) == 0
        _expect(lines, 'can devices stopped')
        assert process.stderr is not None
        stderr = process.stderr.read()
        assert ('SCHED_FIFO' in stderr and 'under the default scheduler' in stderr) == refused
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(timeout=TIMEOUT)
        bus.shutdown()
