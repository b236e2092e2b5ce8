"""Benchmark: HAS command -> state round trip over DDS, the seam beside bare Cyclone DDS.

For each rate (200 Hz, 1 kHz) and each transport, an echo process answers every HasCommand of
four joints with a HasState carrying the command's send time, and a client process sends the
commands at the rate and times the answers (one clock, the client's). Transports:

- ``stock``: the cyclonedds Python API directly (participant, writer, reader, wait set) with
  the binding's own serialiser, as a plain cyclonedds user would write it;
- ``bare``: the same API with the seam's message classes and their generated serialiser, so
  the difference to ``seam`` is the seam's own cost (nodes, executor, QoS mapping);
- ``seam``: exo_has_runtime nodes (the demo's state_echo and a timer-driven client node).
All use the same QoS (best effort, keep last 5, XCDR1).

The runs alternate stock, bare, seam, stock, ... so all see the same machine load. It also
times per-message serialisation of the generated classes against rosbags' serialize_cdr.

Usage: ``.venv/bin/python bench/roundtrip.py [--duration S] [--repeats N] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

JOINTS = ('left_hip', 'left_knee', 'right_hip', 'right_knee')
BACKENDS = ('stock', 'bare', 'seam')
COMMAND = 'exo_has_msgs/msg/HasCommand'
STATE = 'exo_has_msgs/msg/HasState'
_NS = 1_000_000_000


def _bare_entities(participant, registry, write_type, read_type, write_suffix, read_suffix):
    from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState
    from cyclonedds.pub import DataWriter
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5),
              Policy.Durability.Volatile, Policy.DataRepresentation(use_cdrv0_representation=True))
    writers, readers = {}, []
    for joint in JOINTS:
        writers[joint] = DataWriter(participant, Topic(
            participant, f'rt/{joint}/{write_suffix}', registry.get_message(write_type)), qos=qos)
        reader = DataReader(participant, Topic(
            participant, f'rt/{joint}/{read_suffix}', registry.get_message(read_type)), qos=qos)
        readers.append((reader, ReadCondition(
            reader, SampleState.Any | ViewState.Any | InstanceState.Any)))
    return writers, readers


def _registry(stock: bool):
    from exo_has_runtime.standalone.messages import MessageRegistry, default_registry

    return MessageRegistry(generated_codec=False) if stock else default_registry()


def _bare_setup(stock: bool, write_type: str, read_type: str, write_suffix: str,
                read_suffix: str) -> tuple[Any, Any, dict[str, Any], list[Any]]:
    """Participant, message registry, writers by joint and readers of a bare transport."""
    from cyclonedds.core import WaitSet
    from cyclonedds.domain import DomainParticipant

    from exo_has_runtime.standalone.context import LOOPBACK_CONFIG, domain_id_from_environment

    os.environ.setdefault('CYCLONEDDS_URI', LOOPBACK_CONFIG)
    registry = _registry(stock)
    participant = DomainParticipant(domain_id_from_environment())
    writers, readers = _bare_entities(participant, registry, write_type, read_type,
                                      write_suffix, read_suffix)
    waitset = WaitSet(participant)
    for _, condition in readers:
        waitset.attach(condition)
    return waitset, registry, writers, readers


def bare_echo(duration_s: float, stock: bool) -> None:
    """Echo commands as states with the bare cyclonedds API."""
    waitset, registry, writers, readers = _bare_setup(stock, STATE, COMMAND, 'has_state',
                                                      'has_command')
    state_type = registry.get_message(STATE)
    print('READY', flush=True)
    end = time.monotonic() + duration_s
    while time.monotonic() < end:
        waitset.wait(100_000_000)
        for reader, _ in readers:
            for command in reader.take(N=16):
                state = state_type(joint=command.joint, motor_speed=command.motor_speed,
                                   motor_speed_command=command.motor_speed)
                state.header.stamp = command.header.stamp
                writers[command.joint].write(state)


def bare_client(rate_hz: float, duration_s: float, stock: bool) -> dict[str, object]:
    """Send commands at the rate with the bare API and time the echoed states."""
    waitset, registry, writers, readers = _bare_setup(stock, COMMAND, STATE, 'has_command',
                                                      'has_state')
    command_type = registry.get_message(COMMAND)
    while any(len(w.get_matched_subscriptions()) == 0 for w in writers.values()):
        time.sleep(0.01)
    time.sleep(0.2)
    period = int(_NS / rate_hz)
    rtts: list[int] = []
    sent = missed = 0
    start = time.perf_counter_ns()
    next_send = start
    stop_sending = start + int(duration_s * _NS)
    drain_until = stop_sending + _NS // 2
    while True:
        now = time.perf_counter_ns()
        if now >= drain_until:
            break
        if now >= next_send and now < stop_sending:
            late = (now - next_send) // period
            missed += late
            next_send += (late + 1) * period
            for joint, writer in writers.items():
                command = command_type(joint=joint, motor_speed=1.0, enable=True)
                stamp = time.perf_counter_ns()
                command.header.stamp.sec, command.header.stamp.nanosec = divmod(stamp, _NS)
                writer.write(command)
                sent += 1
        wait = (next_send if now < stop_sending else drain_until) - time.perf_counter_ns()
        if wait > 0:
            waitset.wait(wait)
        for reader, _ in readers:
            for state in reader.take(N=16):
                received = time.perf_counter_ns()
                rtts.append(received - (state.header.stamp.sec * _NS
                                        + state.header.stamp.nanosec))
    return {'sent': sent, 'rtt_ns': rtts, 'missed_periods': missed}


def seam_client(rate_hz: float, duration_s: float) -> dict[str, object]:
    """Send commands at the rate from a node timer and time the echoed states."""
    from exo_has_runtime import Node, get_message, init, qos_profile_sensor_data, try_shutdown
    from exo_has_runtime.standalone import SingleThreadedExecutor
    from exo_has_runtime.topics import has_command_topic, has_state_topic

    init(args=['seam_client'])
    node = Node('seam_client')
    command_type, state_type = get_message(COMMAND), get_message(STATE)
    publishers = {j: node.create_publisher(command_type, has_command_topic(j),
                                           qos_profile_sensor_data) for j in JOINTS}
    rtts: list[int] = []
    sent = 0

    def on_state(state: object) -> None:
        received = time.perf_counter_ns()
        stamp = state.header.stamp  # type: ignore[attr-defined]
        rtts.append(received - (stamp.sec * _NS + stamp.nanosec))

    def on_tick() -> None:
        nonlocal sent
        for joint, publisher in publishers.items():
            command = command_type(joint=joint, motor_speed=1.0, enable=True)
            stamp = time.perf_counter_ns()
            command.header.stamp.sec, command.header.stamp.nanosec = divmod(stamp, _NS)
            publisher.publish(command)
            sent += 1

    for joint in JOINTS:
        node.create_subscription(state_type, has_state_topic(joint), on_state,
                                 qos_profile_sensor_data)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    while any(p.get_subscription_count() == 0 for p in publishers.values()):
        executor.spin_once(timeout_sec=0.01)
    time.sleep(0.2)
    timer = node.create_timer(1.0 / rate_hz, on_tick)
    end = time.monotonic() + duration_s
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    timer.cancel()
    drain = time.monotonic() + 0.5
    while time.monotonic() < drain:
        executor.spin_once(timeout_sec=0.05)
    missed = timer.missed_periods
    node.destroy_node()
    try_shutdown()
    return {'sent': sent, 'rtt_ns': rtts, 'missed_periods': missed}


def serialisation_costs(repeats: int = 20000) -> dict[str, dict[str, float]]:
    """Median per-message serialise/deserialise time [us] of generated classes and rosbags."""
    from exo_has_runtime.standalone.messages import default_registry

    registry = default_registry()
    results = {}
    for type_name, fields in (
            (COMMAND, {'joint': 'left_hip', 'motor_speed': 1.0}),
            (STATE, {'joint': 'left_hip', 'position': 0.02, 'pressure_a': 1e7}),
            ('sensor_msgs/msg/JointState', {'name': list(JOINTS), 'position': [0.1] * 4})):
        message = registry.get_message(type_name)(**fields)
        results[type_name] = _codec_timings(registry, type_name, message, repeats)
    return results


def _codec_timings(registry: Any, type_name: str, message: Any,
                   repeats: int) -> dict[str, float]:
    """Median per-call time [us] of the four codecs on one message."""
    data = registry.serialize(message)
    rosbags_message = registry.to_rosbags(message)
    store = registry.typestore
    timings = {
        'seam_serialize_us': lambda: registry.serialize(message),
        'seam_deserialize_us': lambda: registry.deserialize(data, type_name),
        'rosbags_serialize_us': lambda: store.serialize_cdr(rosbags_message, type_name),
        'rosbags_deserialize_us': lambda: store.deserialize_cdr(data, type_name),
    }
    row = {}
    for label, function in timings.items():
        samples = []
        for _ in range(5):
            start = time.perf_counter()
            for _ in range(repeats // 5):
                function()
            samples.append((time.perf_counter() - start) / (repeats // 5) * 1e6)
        row[label] = statistics.median(samples)
    return row


def _summary(result: dict[str, object]) -> dict[str, float]:
    rtts = sorted(result['rtt_ns'])  # type: ignore[arg-type]
    sent = int(result['sent'])  # type: ignore[arg-type]
    count = len(rtts)

    def pct(q: float) -> float:
        return rtts[min(count - 1, int(q * count))] / 1e6 if count else float('nan')

    return {'sent': sent, 'received': count, 'lost': sent - count,
            'p50_ms': pct(0.5), 'p99_ms': pct(0.99), 'max_ms': rtts[-1] / 1e6 if count else 0.0,
            'missed_periods': int(result['missed_periods'])}  # type: ignore[arg-type]


def run_pair(backend: str, rate_hz: float, duration_s: float) -> dict[str, float]:
    """Run one echo process and one client process; return the client's summary."""
    here = Path(__file__).resolve()
    neutral = tempfile.gettempdir()
    if backend == 'seam':
        echo_cmd = [sys.executable, '-m', 'exo_has_runtime.demo.state_echo']
    else:
        echo_cmd = [sys.executable, str(here), '_bare_echo', str(duration_s + 30), backend]
    echo = subprocess.Popen(echo_cmd, cwd=neutral, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        client = subprocess.run(
            [sys.executable, str(here), '_client', str(rate_hz), str(duration_s), backend],
            cwd=neutral, capture_output=True, text=True, check=True, timeout=duration_s + 60)
        echo_cpu_s = _cpu_seconds(echo.pid)
    finally:
        echo.terminate()
        echo.wait(timeout=10)
    result = json.loads(client.stdout.strip().splitlines()[-1])
    return {**_summary(result), 'echo_cpu_s': echo_cpu_s, 'client_cpu_s': result['cpu_s']}


def _cpu_seconds(pid: int) -> float:
    """User plus system CPU time of a running process so far [s] (Linux /proc)."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def main() -> int:
    """Run the benchmark and print (and optionally write) the results."""
    if len(sys.argv) > 1 and sys.argv[1].startswith('_'):
        role = sys.argv[1]
        if role == '_bare_echo':
            bare_echo(float(sys.argv[2]), stock=sys.argv[3] == 'stock')
            return 0
        rate, duration, backend = float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
        result = seam_client(rate, duration) if backend == 'seam' else \
            bare_client(rate, duration, stock=backend == 'stock')
        print(json.dumps({**result, 'cpu_s': time.process_time()}))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=10.0, help='seconds per run (10)')
    parser.add_argument('--repeats', type=int, default=3, help='runs per transport and rate (3)')
    parser.add_argument('--out', type=Path, help='write the results as JSON here')
    args = parser.parse_args()
    os.environ.setdefault('ROS_DOMAIN_ID', str(150 + os.getpid() % 50))
    runs = []
    for rate in (200.0, 1000.0):
        for repeat in range(args.repeats):
            for backend in BACKENDS:
                summary = run_pair(backend, rate, args.duration)
                runs.append({'rate_hz': rate, 'backend': backend, 'repeat': repeat, **summary})
                print(f'{rate:6.0f} Hz {backend:5s} #{repeat}: p50 {summary["p50_ms"]:.3f} ms, '
                      f'p99 {summary["p99_ms"]:.3f} ms, max {summary["max_ms"]:.3f} ms, '
                      f'lost {summary["lost"]}/{summary["sent"]}, '
                      f'missed periods {summary["missed_periods"]}, CPU s echo '
                      f'{summary["echo_cpu_s"]:.2f} client {summary["client_cpu_s"]:.2f}',
                      flush=True)
    costs = serialisation_costs()
    for type_name, row in costs.items():
        print(f'{type_name}: ' + ', '.join(f'{k} {v:.2f}' for k, v in row.items()))
    for rate in (200.0, 1000.0):
        medians = {}
        for backend in BACKENDS:
            chosen = [r for r in runs if r['rate_hz'] == rate and r['backend'] == backend]
            medians[backend] = {key: statistics.median(r[key] for r in chosen)
                                for key in ('p50_ms', 'p99_ms', 'max_ms', 'lost', 'echo_cpu_s')}
        for backend, values in medians.items():
            print(f'{rate:6.0f} Hz {backend:5s} medians over runs: ' + ', '.join(
                f'{key} {value:.3f}' for key, value in values.items()))
        print(f'{rate:6.0f} Hz seam/bare p50 ratio '
              f'{medians["seam"]["p50_ms"] / medians["bare"]["p50_ms"]:.2f}, seam/stock '
              f'{medians["seam"]["p50_ms"] / medians["stock"]["p50_ms"]:.2f}')
    if args.out:
        args.out.write_text(json.dumps({
            'machine': {'platform': platform.platform(), 'cpus': os.cpu_count(),
                        'python': platform.python_version()},
            'duration_s': args.duration, 'runs': runs, 'serialisation': costs}, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
