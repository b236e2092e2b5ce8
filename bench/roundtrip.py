"""Benchmark: HAS command -> HAS state round trip on rclpy, against a running plant node.

For each rate (200 Hz, 1 kHz) and each executor of :mod:`exo_has_runtime.execution`, a plant
node process (``exo_has_sim.plant_node``, ticking at the rate) simulates one joint, and a client
process (an rclpy node spun by ``exo_has_runtime.execution.spin``) sends it a ``HasCommand`` every
period from a timer and times the ``HasState`` stream. Both use the executor under test
(``EXO_HAS_EXECUTOR``) and ``qos_profile_sensor_data``, as the controller and plants do.

Each command carries a speed the client has not sent in the last 4096 commands (small, of
alternating sign, so the joint stays put), and the plant reports the command in force in every
state (``motor_speed_command``). So:

- round trip: from publishing a command to receiving the first state that holds it. It
  includes the plant's wait for its next tick, up to one period (the plant integrates and
  publishes on its timer, not on a command): this is the delay a controller sees;
- unanswered: commands never seen in a state, lost on the way or overtaken by the next one
  before a tick (the plant holds only the latest command);
- state leg: from a state's stamp (the plant's tick, system clock) to its receipt (system
  clock, same machine), for every state received: the transport and executor cost alone;
- states missed: gaps in the stamps of the states received, in plant periods.

CPU: the plant's while the client runs (its start-up excluded), the client's whole run.

Runs alternate the executors, so both see the same machine load.

Usage: ``.venv/bin/python bench/roundtrip.py [--duration S] [--repeats N]
[--executors events,single] [--rates 200,1000] [--links loopback,veth] [--out FILE]`` (with the
workspace sourced). ``--links veth`` puts the plant on a robot host and the client on an
operator host, two network namespaces joined by a veth pair (root only).
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import ExitStack
from pathlib import Path

from common import cpu_seconds, describe_machine, on_this_machine

from exo_has_bringup.hosts import OPERATOR, ROBOT, VirtualHosts
from exo_has_runtime.processes import NodeProcess, Processes

JOINT = 'left_hip'
#: Distinct command speeds in flight before one repeats.
DISTINCT_COMMANDS = 4096
#: Time allowed after the last command for its answer to arrive [s].
DRAIN_S = 0.5
_NS = 1_000_000_000


def command_speed(sequence: int) -> float:
    """Return the motor speed [rad/s] that identifies a command: exact in binary, about 1-5."""
    magnitude = 1.0 + (sequence % DISTINCT_COMMANDS) / 1024.0
    return magnitude if sequence % 2 == 0 else -magnitude


def client(rate_hz: float, duration_s: float, executor_kind: str) -> dict[str, object]:
    """Send commands at the rate for the duration and time the states (in this process)."""
    import rclpy
    from rclpy.node import Node
    from rclpy.qos import qos_profile_sensor_data

    from exo_has_common.topics import has_command_topic, has_state_topic
    from exo_has_msgs.msg import HasCommand, HasState
    from exo_has_runtime.execution import make_executor, spin

    rclpy.init(args=['roundtrip_client'])
    node = Node('roundtrip_client')
    publisher = node.create_publisher(HasCommand, has_command_topic(JOINT),
                                      qos_profile_sensor_data)
    pending: dict[float, int] = {}  # command speed -> send time [ns]
    round_trips: list[int] = []
    state_legs: list[int] = []
    stamps: list[int] = []
    sends: list[int] = []
    stop = threading.Event()

    def on_state(state: HasState) -> None:
        received = time.time_ns()
        stamp = state.header.stamp.sec * _NS + state.header.stamp.nanosec
        stamps.append(stamp)
        state_legs.append(received - stamp)
        sent = pending.pop(state.motor_speed_command, None)
        if sent is not None:
            round_trips.append(received - sent)

    def send() -> None:
        speed = command_speed(len(sends))
        command = HasCommand(joint=JOINT, motor_speed=speed, enable=True)
        now = time.time_ns()
        command.header.stamp.sec, command.header.stamp.nanosec = divmod(now, _NS)
        pending[speed] = now
        sends.append(now)
        publisher.publish(command)

    node.create_subscription(HasState, has_state_topic(JOINT), on_state,
                             qos_profile_sensor_data)
    # Wait for the plant to be matched both ways, outside the measured time.
    deadline = time.monotonic() + 30.0
    while (publisher.get_subscription_count() == 0
           or node.count_publishers(has_state_topic(JOINT)) == 0):
        if time.monotonic() > deadline:
            msg = 'the plant node was not discovered within 30 s'
            raise RuntimeError(msg)
        time.sleep(0.05)
    time.sleep(0.2)
    start = time.monotonic()

    def on_tick() -> None:
        elapsed = time.monotonic() - start
        if elapsed < duration_s:
            send()
        elif elapsed >= duration_s + DRAIN_S:
            stop.set()

    node.create_timer(1.0 / rate_hz, on_tick)
    spin(node, make_executor(executor_kind), stop=stop)
    node.destroy_node()
    rclpy.try_shutdown()
    period_ns = _NS / rate_hz
    late_sends = sum(1 for a, b in itertools.pairwise(sends) if b - a > 1.5 * period_ns)
    ordered = sorted(stamps)
    states_missed = sum(max(0, round((b - a) / period_ns) - 1)
                        for a, b in itertools.pairwise(ordered))
    return {'sent': len(sends), 'round_trip_ns': round_trips, 'state_leg_ns': state_legs,
            'states': len(stamps), 'states_missed': states_missed, 'late_sends': late_sends}


def percentile_ms(values: list[int], q: float) -> float:
    """Return the q-quantile (nearest rank) of nanosecond values, in ms (NaN if none)."""
    if not values:
        return float('nan')
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))] / 1e6


def run_pair(executor_kind: str, rate_hz: float, duration_s: float,
             link: str = 'loopback') -> dict[str, float]:
    """Run one plant process and one client process; return the run's summary.

    ``link``: ``loopback`` (both on this host) or ``veth`` (the plant on a robot host, the
    client on an operator host, two network namespaces joined by a veth pair; root only).
    """
    with ExitStack() as stack:
        plant_env: dict[str, str] = {'EXO_HAS_EXECUTOR': executor_kind}
        client_env, prefix, netns = dict(plant_env), [], None
        if link == 'veth':
            hosts = stack.enter_context(VirtualHosts())
            netns = hosts.hosts[ROBOT].netns
            plant_env |= hosts.hosts[ROBOT].environment
            client_env |= hosts.hosts[OPERATOR].environment
            prefix = ['nsenter', f'--net={hosts.hosts[OPERATOR].netns}']
        return _run_pair(executor_kind, rate_hz, duration_s, plant_env, client_env, prefix,
                         netns)
    raise AssertionError  # pragma: no cover - ExitStack does not swallow exceptions


def _run_pair(executor_kind: str, rate_hz: float, duration_s: float, plant_env: dict[str, str],
              client_env: dict[str, str], prefix: list[str],
              netns: str | None) -> dict[str, float]:
    here = Path(__file__).resolve()
    with NodeProcess('exo_has_sim.plant_node', ['--ros-args', '-p', f'joint:={JOINT}', '-p',
                                                f'rate:={rate_hz}'],
                     env=plant_env, netns=netns) as plant:
        plant.wait_for_output('plant ready', timeout_s=120)
        plant_cpu_before = cpu_seconds(plant.process.pid)
        with Processes() as processes:
            client_run = processes.run(
                [*prefix, sys.executable, str(here), '_client', str(rate_hz), str(duration_s),
                 executor_kind], cwd=tempfile.gettempdir(),
                env={**os.environ, **client_env}, stdout=subprocess.PIPE,
                stderr=subprocess.PIPE, text=True, timeout=duration_s + 90)
        plant_cpu_s = cpu_seconds(plant.process.pid) - plant_cpu_before
        if client_run.returncode != 0:
            msg = (f'client failed ({client_run.returncode}):\n{client_run.stderr}\n'
                   f'plant output:\n{plant.output}')
            raise RuntimeError(msg)
    result = json.loads(client_run.stdout.strip().splitlines()[-1])
    round_trips, legs = result['round_trip_ns'], result['state_leg_ns']
    return {
        'sent': result['sent'], 'unanswered': result['sent'] - len(round_trips),
        'p50_ms': percentile_ms(round_trips, 0.5), 'p99_ms': percentile_ms(round_trips, 0.99),
        'max_ms': max(round_trips) / 1e6 if round_trips else float('nan'),
        'state_leg_p50_ms': percentile_ms(legs, 0.5),
        'state_leg_p99_ms': percentile_ms(legs, 0.99),
        'states': result['states'], 'states_missed': result['states_missed'],
        'late_sends': result['late_sends'], 'plant_cpu_s': plant_cpu_s,
        'client_cpu_s': result['cpu_s']}


def main() -> int:
    """Run the benchmark and print (and optionally write) the results."""
    if len(sys.argv) > 1 and sys.argv[1] == '_client':
        rate, duration, kind = float(sys.argv[2]), float(sys.argv[3]), sys.argv[4]
        result = client(rate, duration, kind)
        print(json.dumps({**result, 'cpu_s': time.process_time()}))
        return 0
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=10.0, help='seconds per run (10)')
    parser.add_argument('--repeats', type=int, default=3, help='runs per executor and rate (3)')
    parser.add_argument('--executors', default='events,single',
                        help='executors compared, comma-separated (events,single)')
    parser.add_argument('--rates', default='200,1000', help='rates [Hz], comma-separated')
    parser.add_argument('--links', default='loopback',
                        help='loopback (one host) and/or veth (plant and client on two virtual '
                             'hosts; root only), comma-separated, taking turns')
    parser.add_argument('--out', type=Path, help='write the results as JSON here')
    args = parser.parse_args()
    on_this_machine()
    links = [link.strip() for link in args.links.split(',') if link.strip()]
    if set(links) - {'loopback', 'veth'}:
        parser.error(f'--links: loopback or veth, got {args.links}')
    executors = [kind.strip() for kind in args.executors.split(',') if kind.strip()]
    rates = [float(rate) for rate in args.rates.split(',') if rate.strip()]
    runs = []
    for rate in rates:
        for repeat in range(args.repeats):
            for kind, link in itertools.product(executors, links):
                summary = run_pair(kind, rate, args.duration, link)
                runs.append({'rate_hz': rate, 'executor': kind, 'link': link, 'repeat': repeat,
                             **summary})
                print(f'{rate:6.0f} Hz {kind:6s} {link:8s} #{repeat}: round trip p50 '
                      f'{summary["p50_ms"]:.3f} ms, p99 {summary["p99_ms"]:.3f} ms, max '
                      f'{summary["max_ms"]:.3f} ms, unanswered {summary["unanswered"]}/'
                      f'{summary["sent"]}; state leg p50 {summary["state_leg_p50_ms"]:.3f} ms, '
                      f'p99 {summary["state_leg_p99_ms"]:.3f} ms; states missed '
                      f'{summary["states_missed"]}/{summary["states"]}, late sends '
                      f'{summary["late_sends"]}; CPU s plant {summary["plant_cpu_s"]:.2f} '
                      f'client {summary["client_cpu_s"]:.2f}', flush=True)
    keys = ('p50_ms', 'p99_ms', 'max_ms', 'unanswered', 'state_leg_p50_ms', 'state_leg_p99_ms',
            'states_missed', 'plant_cpu_s', 'client_cpu_s')
    for rate in rates:
        for kind, link in itertools.product(executors, links):
            chosen = [r for r in runs if r['rate_hz'] == rate and r['executor'] == kind
                      and r['link'] == link]
            medians = {key: statistics.median(r[key] for r in chosen) for key in keys}
            print(f'{rate:6.0f} Hz {kind:6s} {link:8s} medians over {len(chosen)} runs: '
                  + ', '.join(
                f'{key} {value:.3f}' for key, value in medians.items()))
    if args.out:
        args.out.write_text(json.dumps({
            'machine': describe_machine(), 'duration_s': args.duration, 'joint': JOINT,
            'runs': runs}, indent=1))
    return 0


if __name__ == '__main__':
    sys.exit(main())
