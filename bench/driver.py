"""Benchmark: the hardware driver on the CAN bus of the simulated devices, 200 Hz, four joints.

Command-to-frame latency, SYNC jitter and CPU share of the driver and the devices.

Each run starts the simulated devices (``exo_has_driver.devices.main``, waiting for ``can
devices ready``), then the driver node (waiting for ``driver ready``), both on a udp_multicast
bus of a random group, then publishes an ``exo_has_msgs/msg/HasCommand`` on every
``<joint>/has_command`` at 200 Hz (enable true, a slow sine of motor speed) for a warm-up and
``--duration`` seconds, recording each command's publish time (``time.time()``). The commands
come every 5 ms plus 5 ms over the window's number of periods (199.95 Hz for 20 s), so their
phase against the driver's SYNC slides by one period over the window and every phase is
sampled alike: at exactly the driver's rate, on the same clock, the latency would stay at
whatever phase a run happened to start with (a trial at exactly 200 Hz held it within 0.1 ms
for seconds). Every command's speed maps to a drive velocity
(:class:`~exo_has_driver.hardware.units.DriveUnits`, defaults) that no other command of the
last :data:`GRID` - 1 has: the sine is rounded to multiples of :data:`GRID` drive units and a
counter fills the remainder. A CAN listener in
this process (a bus from ``open_bus`` on the same group, in a thread) records every drive
RPDO1 (COB-ID 0x201 to 0x204) and SYNC (0x080) with its ``Message.timestamp``: on
udp_multicast the kernel's receive time (``SO_TIMESTAMPNS``, wall clock), taken on loopback
when the sender hands the datagram over.

Figures over the commands published and the SYNCs sent in the ``--duration`` window:

* latency of a command: the first RPDO1 of its joint's drive whose target velocity is the
  command's, minus the command's publish time (command-to-frame); and the SYNC after that
  RPDO1, at which the drive applies it (command-to-SYNC). A command superseded by the next
  before the driver's cycle took it never appears: counted apart, with any lost on the way;
* SYNC period: the intervals between SYNCs (median, deviation from 5 ms, maximum, intervals
  over 1.5 periods), :class:`~exo_has_common.timing.PeriodMonitor` fed the SYNC times (as the
  plants and ``bench/probe.py`` count: missed releases, ticks late by over half a period,
  lateness percentiles, the grid set by the first SYNC), and the lateness against the
  driver's own schedule (its grid restarts after a SYNC held up by a period or more, as
  ``Master._run`` does; the grid's phase is that of the earliest SYNC of each stretch);
* CPU share of the driver's and the devices' processes (and this one's) over the middle 60 %
  of the window, from /proc/<pid>/stat (utime + stime, % of one core), and the whole machine's
  busy time (/proc/stat, sampled at the scheduler tick: it can come out a few % under the sum
  of the three; a much larger figure means other jobs ran);
* datagrams the kernel dropped on each process's CAN socket (``/proc/net/udp``) in the window.

Run: ``.venv/bin/python bench/driver.py [--duration 20] [--repeats 3]``.
"""

from __future__ import annotations

import argparse
import bisect
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

import can
import numpy as np
import rclpy
from common import TICK, cpu_seconds, describe_machine, machine_ticks, on_this_machine
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from exo_has_common.timing import PeriodMonitor
from exo_has_common.topics import has_command_topic
from exo_has_driver import can_dictionary as cd
from exo_has_driver.hardware.bus import open_bus, random_multicast_group
from exo_has_driver.hardware.units import DriveUnits
from exo_has_msgs.msg import HasCommand
from exo_has_runtime.processes import NodeProcess

RESULTS = Path(__file__).resolve().parent / 'results'
DRIVER = 'exo_has_driver.driver_node'
DEVICES = 'exo_has_driver.devices.main'
JOINTS = tuple(cd.DRIVE_NODE_IDS)
#: SYNC and command period [s] and [ns]: the paper's 200 Hz.
PERIOD = cd.SYNC_PERIOD
PERIOD_NS = round(PERIOD * 1e9)
#: Sine of the commanded motor speed: amplitude [rad/s] and period [s].
SPEED_AMPLITUDE = 10.0
SPEED_PERIOD = 4.0
#: Drive velocity units the sine is rounded to; a counter of GRID - 1 values fills the rest, so
#: any GRID - 1 consecutive commands of a joint have distinct drive velocities.
GRID = 256
#: Commands before the measurement window [s], and after it [s] (so the last are matched).
WARM_UP = 1.0
TAIL = 0.3
#: Waits for the processes [s]: the devices' and the driver's start, the topics' matching.
DEVICES_TIMEOUT = 30.0
DRIVER_TIMEOUT = 60.0
MATCH_TIMEOUT = 10.0
#: Local port of every python-can udp_multicast socket (python-can's default).
CAN_PORT = 43113
NOTICE = re.compile(r'^(\[(WARN|ERROR|FATAL)\].*|.*\b(WARNING|ERROR|Traceback)\b.*)$', re.M)


def machine_busy_seconds() -> float:
    """CPU time all processors spent busy since boot [s] (/proc/stat: all but idle and iowait)."""
    busy, steal, _ = machine_ticks()
    return (busy + steal) / TICK


def can_socket_drops(pid: int) -> int | None:
    """Datagrams the kernel dropped on a process's udp_multicast CAN sockets, None if none.

    Reads the socket inodes in /proc/<pid>/fd and the ``drops`` column of /proc/net/udp for
    the sockets bound to :data:`CAN_PORT`.
    """
    inodes = set()
    folder = Path(f'/proc/{pid}/fd')
    for fd in folder.iterdir():
        try:
            target = os.readlink(fd)
        except OSError:
            continue  # closed meanwhile
        if target.startswith('socket:['):
            inodes.add(target[8:-1])
    drops = None
    for line in Path('/proc/net/udp').read_text().splitlines()[1:]:
        fields = line.split()
        if int(fields[1].rsplit(':', 1)[1], 16) == CAN_PORT and fields[9] in inodes:
            drops = (drops or 0) + int(fields[12])
    return drops


class CanCapture:
    """Record the SYNCs and the drives' RPDO1s of a bus, in a thread.

    Parameters
    ----------
    group : str
        The bus's multicast group.

    """

    WANTED = frozenset((cd.SYNC_COB_ID, *(cd.RPDO1_BASE + n for n in cd.DRIVE_NODE_IDS.values())))

    def __init__(self, group: str) -> None:
        self.bus = open_bus('udp_multicast', group, 1_000_000)
        #: (COB-ID, Message.timestamp [s], time.time() after recv returned [s], data).
        self.frames: list[tuple[int, float, float, bytes]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='can-capture', daemon=True)
        self._thread.start()

    def _run(self) -> None:
        recv, wanted, append = self.bus.recv, self.WANTED, self.frames.append
        while not self._stop.is_set():
            message = recv(0.1)
            if message is not None and message.arbitration_id in wanted:
                append((message.arbitration_id, message.timestamp, time.time(),
                        bytes(message.data)))

    def close(self) -> None:
        """End the thread and close the bus."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        self.bus.shutdown()


class Commands:
    """The commands of one run: a slow sine of motor speed, distinct in drive units.

    Parameters
    ----------
    units : DriveUnits
        The driver's unit conversion (its defaults).

    """

    def __init__(self, units: DriveUnits) -> None:
        self.units = units
        self.count = 0
        #: Per joint: publish times [s, wall clock] and drive velocities [drive units].
        self.times: dict[str, list[float]] = {joint: [] for joint in JOINTS}
        self.values: dict[str, list[int]] = {joint: [] for joint in JOINTS}

    def next_speed(self, t: float) -> tuple[float, int]:
        """Return the next command's motor speed [rad/s] at ``t`` [s] and its drive velocity."""
        per_rad_s = self.units.velocity_per_rad_s
        sine = SPEED_AMPLITUDE * math.sin(2.0 * math.pi * t / SPEED_PERIOD) * per_rad_s
        value = GRID * round(sine / GRID) + 1 + self.count % (GRID - 1)
        self.count += 1
        speed = value / per_rad_s
        assert self.units.velocity_to_drive(speed) == value, (speed, value)
        return speed, value


def wait_for_subscribers(publishers: dict[str, object]) -> None:
    """Wait until the driver's subscription matches every publisher.

    Raises
    ------
    TimeoutError
        Naming the topics without a subscriber.

    """
    deadline = time.monotonic() + MATCH_TIMEOUT
    while True:
        missing = [p.topic for p in publishers.values() if not p.get_subscription_count()]
        if not missing:
            return
        if time.monotonic() > deadline:
            msg = f'no subscriber on {", ".join(missing)} within {MATCH_TIMEOUT:g} s'
            raise TimeoutError(msg)
        time.sleep(0.05)


def publish(publishers: dict[str, object], commands: Commands, period: float, start: float,
            stop: float, at: dict[float, Callable[[], None]]) -> None:
    """Publish every joint's command each ``period`` [s] from ``start`` to ``stop`` [s].

    ``start`` and ``stop`` are on the monotonic clock; ``at`` maps monotonic times [s] to calls
    made at the first period from then on (the CPU and drop samples). Held up by more than a
    period, the loop resumes without a burst.
    """
    due = start
    pending = sorted(at)
    while due < stop:
        now = time.monotonic()
        if now < due:
            time.sleep(due - now)
        speed, value = commands.next_speed(due - start)
        for joint, publisher in publishers.items():
            message = HasCommand(joint=joint, motor_speed=speed, enable=True)
            t = time.time()
            publisher.publish(message)
            commands.times[joint].append(t)
            commands.values[joint].append(value)
        while pending and pending[0] <= due:
            at[pending.pop(0)]()
        due += period
        now = time.monotonic()
        if due < now - period:
            due = now


def _stats_ms(values: np.ndarray, digits: int = 3) -> dict[str, float | int | None]:
    if not values.size:
        return {'min': None, 'p50': None, 'p99': None, 'max': None, 'samples': 0}
    return {'min': round(float(values.min()) * 1e3, digits),
            'p50': round(float(np.median(values)) * 1e3, digits),
            'p99': round(float(np.percentile(values, 99)) * 1e3, digits),
            'max': round(float(values.max()) * 1e3, digits), 'samples': int(values.size)}


def latencies(commands: Commands, frames: list[tuple[int, float, float, bytes]],
              window: tuple[float, float]) -> dict[str, object]:
    """Command-to-frame and command-to-SYNC latencies of the commands published in ``window``.

    A command's frame is the first RPDO1 of its drive carrying its drive velocity; the frame
    is paired with the newest command of that value published before it, among the last
    GRID - 1 commands (where values are distinct).
    """
    syncs = sorted(t for cob, t, _, _ in frames if cob == cd.SYNC_COB_ID)
    to_frame: list[float] = []
    to_sync: list[float] = []
    published = superseded = not_enabled = 0
    for joint in JOINTS:
        t_pub, values = commands.times[joint], commands.values[joint]
        by_value: dict[int, list[int]] = {}
        for index, value in enumerate(values):
            by_value.setdefault(value, []).append(index)
        first: dict[int, float] = {}
        cob_id = cd.RPDO1_BASE + cd.DRIVE_NODE_IDS[joint]
        for cob, t, _, data in frames:
            if cob != cob_id:
                continue
            controlword, target = cd.DRIVE_RPDO1.unpack(data)
            if window[0] <= t <= window[1] and controlword != cd.CW_ENABLE_OPERATION:
                not_enabled += 1
            newest = bisect.bisect_right(t_pub, t) - 1
            same = by_value.get(target)
            if newest < 0 or not same:
                continue
            k = bisect.bisect_right(same, newest) - 1
            if k < 0 or newest - same[k] >= GRID - 1 or same[k] in first:
                continue
            first[same[k]] = t
        for index, t in enumerate(t_pub):
            if not window[0] <= t <= window[1]:
                continue
            published += 1
            frame = first.get(index)
            if frame is None:
                superseded += 1
                continue
            to_frame.append(frame - t)
            after = bisect.bisect_right(syncs, frame)
            if after < len(syncs):
                to_sync.append(syncs[after] - t)
    return {'command_to_frame_ms': _stats_ms(np.asarray(to_frame)),
            'command_to_sync_ms': _stats_ms(np.asarray(to_sync)),
            'commands': published, 'not_seen': superseded,
            'not_seen_percent': round(100.0 * superseded / max(published, 1), 2),
            'rpdo_not_enable_operation': not_enabled}


def schedule_lateness(stamps_ns: np.ndarray) -> tuple[np.ndarray, int, int]:
    """Lateness of each SYNC against the driver's schedule [s], missed releases, restarts.

    The grid advances a period per SYNC; a SYNC a period or more after its release counts the
    releases it passed as missed and starts a new grid a period after itself, as
    ``Master._run``. Within each stretch the grid's phase is that of its earliest SYNC.
    """
    lateness = np.zeros(stamps_ns.size)
    missed = restarts = 0
    begin = 0
    release = int(stamps_ns[0])
    offsets = np.zeros(stamps_ns.size, dtype=np.int64)
    for index, stamp in enumerate(stamps_ns.tolist()):
        offset = stamp - release
        if index and offset >= PERIOD_NS:
            missed += offset // PERIOD_NS
            restarts += 1
            segment = offsets[begin:index]
            lateness[begin:index] = (segment - segment.min()) * 1e-9
            begin, offset, release = index, 0, stamp
        offsets[index] = offset
        release += PERIOD_NS
    segment = offsets[begin:]
    lateness[begin:] = (segment - segment.min()) * 1e-9
    return lateness, int(missed), restarts


def sync_timing(frames: list[tuple[int, float, float, bytes]],
                window: tuple[float, float]) -> dict[str, object]:
    """Period, jitter and missed periods of the SYNCs received in ``window``."""
    stamps = np.array(sorted(t for cob, t, _, _ in frames
                             if cob == cd.SYNC_COB_ID and window[0] <= t <= window[1]))
    if stamps.size < 2:
        return {'syncs': int(stamps.size)}
    intervals = np.diff(stamps)
    deviation = intervals - PERIOD
    stamps_ns = np.array([round(t * 1e9) for t in stamps], dtype=np.int64)
    monitor = PeriodMonitor(PERIOD_NS)
    for stamp in stamps_ns.tolist():
        monitor.tick(stamp)
    lateness, missed, restarts = schedule_lateness(stamps_ns)
    return {
        'syncs': int(stamps.size),
        'interval_median_ms': round(float(np.median(intervals)) * 1e3, 4),
        'interval_mean_ms': round(float(intervals.mean()) * 1e3, 4),
        'deviation_p1_ms': round(float(np.percentile(deviation, 1)) * 1e3, 3),
        'deviation_p99_ms': round(float(np.percentile(deviation, 99)) * 1e3, 3),
        'interval_min_ms': round(float(intervals.min()) * 1e3, 3),
        'interval_max_ms': round(float(intervals.max()) * 1e3, 3),
        'intervals_over_1_5_periods': int((intervals > 1.5 * PERIOD).sum()),
        'period_monitor': {
            'periods': monitor.ticks, 'missed': monitor.missed, 'late': monitor.late,
            'p99_ms': round(monitor.lateness_percentile(99.0) * 1e3, 1),
            'p99_9_ms': round(monitor.lateness_percentile(99.9) * 1e3, 1),
            'max_ms': round(monitor.max_lateness_ns * 1e-6, 1),
            'summary': monitor.summary()},
        'schedule': {
            'missed': missed, 'restarts': restarts,
            'late': int((lateness * 2 > PERIOD).sum()),
            'lateness_p50_ms': round(float(np.median(lateness)) * 1e3, 3),
            'lateness_p99_ms': round(float(np.percentile(lateness, 99)) * 1e3, 3),
            'lateness_p99_9_ms': round(float(np.percentile(lateness, 99.9)) * 1e3, 3),
            'lateness_max_ms': round(float(lateness.max()) * 1e3, 3)},
    }


def notices(output: str, after: str) -> list[str]:
    """Warning, error and traceback lines of a process's output from the line with ``after``."""
    tail = output[max(output.find(after), 0):]
    return [match.group(0) for match in NOTICE.finditer(tail)][:20]


def run(duration: float, index: int, scratch: Path) -> dict[str, object]:
    """One run: start the devices and the driver, command them, measure; return the figures.

    Raises
    ------
    TimeoutError
        If a process does not start or the topics do not match; its output is quoted.

    """
    group = random_multicast_group()
    units = DriveUnits()
    commands = Commands(units)
    t_launch = time.monotonic()
    devices = NodeProcess(DEVICES, ['--interface', 'udp_multicast', '--channel', group],
                          log_path=scratch / f'devices_{index}.log')
    driver: NodeProcess | None = None
    capture: CanCapture | None = None
    node: Node | None = None
    try:
        devices.wait_for_output('can devices ready', timeout_s=DEVICES_TIMEOUT)
        devices_start = time.monotonic() - t_launch
        capture = CanCapture(group)
        t_launch = time.monotonic()
        driver = NodeProcess(DRIVER, ['--ros-args', '-p', 'interface:=udp_multicast',
                                      '-p', f'channel:={group}'],
                             log_path=scratch / f'driver_{index}.log')
        driver.wait_for_output(r'driver ready', timeout_s=DRIVER_TIMEOUT)
        driver_start = time.monotonic() - t_launch
        node = Node(f'driver_bench_{index}')
        publishers = {joint: node.create_publisher(HasCommand, has_command_topic(joint),
                                                   qos_profile_sensor_data)
                      for joint in JOINTS}
        wait_for_subscribers(publishers)
        pids = {'driver': driver.process.pid, 'devices': devices.process.pid,
                'bench': os.getpid()}
        samples: list[tuple[float, dict[str, float], dict[str, int | None]]] = []

        def sample() -> None:
            cpu = {k: cpu_seconds(p) for k, p in pids.items()}
            cpu['machine'] = machine_busy_seconds()
            samples.append((time.monotonic(), cpu,
                            {k: can_socket_drops(p) for k, p in pids.items()}))

        start = time.monotonic()
        wall = time.time() - start  # wall clock minus monotonic clock [s]
        begin, end = start + WARM_UP, start + WARM_UP + duration
        period = PERIOD * (1.0 + PERIOD / duration)  # one period of phase over the window
        publish(publishers, commands, period, start, end + TAIL,
                {begin: sample, begin + 0.2 * duration: sample, begin + 0.8 * duration: sample,
                 end: sample})
        time.sleep(0.05)
    finally:
        if capture is not None:
            capture.close()
        if node is not None:
            node.destroy_node()
        driver_exit = driver.stop() if driver is not None else None
        devices_exit = devices.stop()
    (_, _, drops_begin), (t_a, cpu_a, _), (t_b, cpu_b, _), (_, _, drops_end) = samples
    span = t_b - t_a
    shares = {k: round(100.0 * (cpu_b[k] - cpu_a[k]) / span, 1) for k in cpu_a}
    window = (begin + wall, end + wall)
    frames = sorted(capture.frames, key=lambda frame: frame[1])
    user_delay = np.array([seen - t for _, t, seen, _ in frames if window[0] <= t <= window[1]])
    return {
        'group': group, 'duration_s': duration, 'command_rate_hz': round(1.0 / period, 4),
        'start_up_s': {'devices': round(devices_start, 2), 'driver': round(driver_start, 2)},
        'latency': latencies(commands, frames, window),
        'sync': sync_timing(frames, window),
        'cpu_percent_of_one_core': shares,
        'can_socket_drops': {k: None if drops_end[k] is None or drops_begin[k] is None
                             else drops_end[k] - drops_begin[k] for k in pids},
        'recv_delay_after_kernel_stamp_ms': _stats_ms(user_delay),
        'rpdo_frames': {joint: sum(1 for cob, t, _, _ in frames
                                   if cob == cd.RPDO1_BASE + cd.DRIVE_NODE_IDS[joint]
                                   and window[0] <= t <= window[1]) for joint in JOINTS},
        'exit_codes': {'driver': driver_exit, 'devices': devices_exit},
        'notices': {'driver': notices(driver.output, 'driver ready'),
                    'devices': notices(devices.output, 'can devices ready')},
    }


def source_version() -> dict[str, object]:
    """Return the repository's commit, and the driver's and runtime's files changed from it."""
    root = Path(__file__).resolve().parent.parent

    def git(*args: str) -> str:
        return subprocess.run(['git', *args], cwd=root, capture_output=True, text=True,
                              check=False).stdout.rstrip('\n')

    changed = git('status', '--porcelain', '--', 'exo_has_driver', 'exo_has_runtime')
    return {'commit': git('rev-parse', '--short', 'HEAD'),
            'sources_changed': [line[3:] for line in changed.splitlines()]}


def _median(runs: list[dict[str, object]], *path: str) -> float | None:
    values = []
    for r in runs:
        value: object = r
        for key in path:
            value = value[key]  # type: ignore[index]
        if value is not None:
            values.append(value)
    return round(float(np.median(values)), 4) if values else None


MEDIANS = {
    'command_to_frame_min_ms': ('latency', 'command_to_frame_ms', 'min'),
    'command_to_frame_p50_ms': ('latency', 'command_to_frame_ms', 'p50'),
    'command_to_frame_p99_ms': ('latency', 'command_to_frame_ms', 'p99'),
    'command_to_frame_max_ms': ('latency', 'command_to_frame_ms', 'max'),
    'command_to_sync_p50_ms': ('latency', 'command_to_sync_ms', 'p50'),
    'command_to_sync_p99_ms': ('latency', 'command_to_sync_ms', 'p99'),
    'command_to_sync_max_ms': ('latency', 'command_to_sync_ms', 'max'),
    'commands': ('latency', 'commands'),
    'not_seen': ('latency', 'not_seen'),
    'not_seen_percent': ('latency', 'not_seen_percent'),
    'sync_interval_median_ms': ('sync', 'interval_median_ms'),
    'sync_deviation_p1_ms': ('sync', 'deviation_p1_ms'),
    'sync_deviation_p99_ms': ('sync', 'deviation_p99_ms'),
    'sync_interval_max_ms': ('sync', 'interval_max_ms'),
    'sync_intervals_over_1_5_periods': ('sync', 'intervals_over_1_5_periods'),
    'sync_monitor_missed': ('sync', 'period_monitor', 'missed'),
    'sync_monitor_late': ('sync', 'period_monitor', 'late'),
    'sync_monitor_p99_ms': ('sync', 'period_monitor', 'p99_ms'),
    'sync_schedule_lateness_p99_ms': ('sync', 'schedule', 'lateness_p99_ms'),
    'sync_schedule_lateness_max_ms': ('sync', 'schedule', 'lateness_max_ms'),
    'cpu_driver_percent': ('cpu_percent_of_one_core', 'driver'),
    'cpu_devices_percent': ('cpu_percent_of_one_core', 'devices'),
    'cpu_bench_percent': ('cpu_percent_of_one_core', 'bench'),
    'cpu_machine_percent': ('cpu_percent_of_one_core', 'machine'),
}


def main() -> None:
    """Run the benchmark and write bench/results/driver.{json,txt}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=20.0,
                        help='measured time per run [s], after start-up and a warm-up')
    parser.add_argument('--repeats', type=int, default=3, help='runs; medians are reported')
    args = parser.parse_args()
    on_this_machine()
    load = Path('/proc/loadavg').read_text().split()[:3]
    rclpy.init()
    results = []
    try:
        with tempfile.TemporaryDirectory() as folder:
            for index in range(args.repeats):
                try:
                    results.append(run(args.duration, index, Path(folder)))
                except BaseException:
                    for log in sorted(Path(folder).glob(f'*_{index}.log')):
                        print(f'--- {log.name}:\n{log.read_text(errors="replace")}',
                              file=sys.stderr)
                    raise
                print(json.dumps(results[-1], indent=1), flush=True)
    finally:
        rclpy.try_shutdown()
    medians = {key: _median(results, *path) for key, path in MEDIANS.items()}
    machine = {**source_version(), **describe_machine(), 'python_can': can.__version__,
               'loadavg_before': ' '.join(load),
               'loadavg_after': ' '.join(Path('/proc/loadavg').read_text().split()[:3])}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / 'driver.json').write_text(json.dumps(
        {'machine': machine, 'rate_hz': 1.0 / PERIOD, 'joints': list(JOINTS),
         'medians': medians, 'runs': results}, indent=1) + '\n')
    m = medians
    lines = [f'bench/driver.py --duration {args.duration:g} --repeats {args.repeats}: {machine}',
             f'median of {args.repeats} runs, 200 Hz, four joints: command-to-frame min '
             f"{m['command_to_frame_min_ms']} ms p50 {m['command_to_frame_p50_ms']} ms p99 "
             f"{m['command_to_frame_p99_ms']} ms max "
             f"{m['command_to_frame_max_ms']} ms; command-to-SYNC p50 "
             f"{m['command_to_sync_p50_ms']} ms p99 {m['command_to_sync_p99_ms']} ms max "
             f"{m['command_to_sync_max_ms']} ms; not seen (superseded) {m['not_seen']:g} of "
             f"{m['commands']:g} ({m['not_seen_percent']} %); SYNC interval median "
             f"{m['sync_interval_median_ms']} ms, deviation p1 {m['sync_deviation_p1_ms']} ms "
             f"p99 {m['sync_deviation_p99_ms']} ms, max {m['sync_interval_max_ms']} ms, "
             f"{m['sync_intervals_over_1_5_periods']:g} over 1.5 periods; PeriodMonitor missed "
             f"{m['sync_monitor_missed']:g}, late {m['sync_monitor_late']:g}, p99 "
             f"{m['sync_monitor_p99_ms']} ms; lateness on the driver's schedule p99 "
             f"{m['sync_schedule_lateness_p99_ms']} ms max "
             f"{m['sync_schedule_lateness_max_ms']} ms; CPU driver "
             f"{m['cpu_driver_percent']} %, devices {m['cpu_devices_percent']} %, bench "
             f"{m['cpu_bench_percent']} % of one core; whole machine {m['cpu_machine_percent']} % "
             f'of one core (of {100 * (os.cpu_count() or 1)} %)']
    for r in results:
        lat, sync = r['latency'], r['sync']
        frame, at_sync = lat['command_to_frame_ms'], lat['command_to_sync_ms']
        lines.append(
            f"run {r['group']}: start-up {r['start_up_s']} s; command-to-frame min "
            f"{frame['min']} ms p50 {frame['p50']} ms p99 {frame['p99']} ms max {frame['max']} "
            f"ms ({frame['samples']} "
            f"commands), command-to-SYNC p50 {at_sync['p50']} ms p99 {at_sync['p99']} ms max "
            f"{at_sync['max']} ms, not seen {lat['not_seen']}/{lat['commands']} "
            f"({lat['not_seen_percent']} %), RPDO1 not enable operation "
            f"{lat['rpdo_not_enable_operation']}; {sync['syncs']} SYNCs, interval median "
            f"{sync['interval_median_ms']} ms mean {sync['interval_mean_ms']} ms, deviation p1 "
            f"{sync['deviation_p1_ms']} ms p99 {sync['deviation_p99_ms']} ms, min "
            f"{sync['interval_min_ms']} ms max {sync['interval_max_ms']} ms, "
            f"{sync['intervals_over_1_5_periods']} over 1.5 periods; PeriodMonitor: "
            f"{sync['period_monitor']['summary']}; driver's schedule: {sync['schedule']}; CPU "
            f"{r['cpu_percent_of_one_core']} % of one core; CAN socket drops "
            f"{r['can_socket_drops']}; user-space receive after the kernel stamp "
            f"{r['recv_delay_after_kernel_stamp_ms']} ms; exit codes {r['exit_codes']}; "
            f"notices {r['notices']}")
    (RESULTS / 'driver.txt').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))


if __name__ == '__main__':
    main()
