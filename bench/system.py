"""Benchmark: the whole exoskeleton as processes, at 200 Hz (the paper's rate) and at 1 kHz.

CPU share, reference-to-state latency and missed periods.

Each run is a walking session (four plants, PD controller, gait publisher, watchdog, recorder)
of ``--duration`` seconds. CPU shares come from /proc/<pid>/stat over the middle of the trial
(utime + stime, as a percentage of one core). The latency of a command is the time from the
stamp of the newest reference the controller had (the newest reference stamped before the
command) to the stamp of the first plant state that carries the command: reference age plus
the wait for the plant's next period; commands superseded before a plant's tick are counted
apart. Missed periods are the plants' own counts (exo_has_common.timing: a release that passed
with no tick, what rclcpp's timers count as skipped), with the ticks late by over half a period
and the lateness percentiles of the worst plant. An idle node ticking at the same rate next to
the session (bench/probe.py) gives the machine's own floor at that moment.

With ``--executors events single`` the sessions take turns with every node on rclpy's
EventsExecutor (what exo_has ships) and on its SingleThreadedExecutor (``EXO_HAS_EXECUTOR``);
with ``--realtime-priorities 0 10``, with the plants' loops under the default scheduler and under
SCHED_FIFO at priority 10 (root only; see exo_has_common.realtime).

With ``--variants defaults watchdog.batch=false,recorder.poll_period=0``, with the nodes'
parameters as shipped and with those set (``node.parameter=value``, comma-separated).

With ``--transports udp rmw``, with every node on UDP alone (what exo_has ships,
exo_has_runtime.dds) and on rmw_fastrtps_cpp's LOCALHOST settings (shared memory and UDP).

Run (in ``./run shell``): ``python bench/system.py [--duration 30] [--rates 200 1000]
[--repeats 3] [--executors events single] [--realtime-priorities 0 10] [--variants ...]
[--transports udp rmw]``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from common import (
    describe_machine,
    on_this_machine,
    trial_cpu_shares,
    write_results,
)

from exo_has_bringup.analysis import read_session
from exo_has_bringup.plan import COMPOSITION, SessionConfig
from exo_has_bringup.runner import Session
from exo_has_common.joints import JOINT_NAMES
from exo_has_runtime.dds import RMW_LOCALHOST_ENVIRONMENT
from exo_has_runtime.processes import Processes


def latencies(bag: Path) -> tuple[np.ndarray, np.ndarray, int]:
    """Latencies of the commands the plants applied, and how many were never applied.

    Each state carries the command in force (``motor_speed_command``): the newest command with
    that speed stamped before the state. A command shows in the first state that carries it;
    one superseded before a plant's tick never shows and is counted apart.

    Returns
    -------
    reference_to_state : ndarray
        From the stamp of the newest reference before each applied command to the stamp of
        the first state carrying it [s].
    command_to_state : ndarray
        From each applied command's stamp to that state [s].
    superseded : int
        Commands never applied.

    """
    data = read_session(bag)
    reference_to_state: list[float] = []
    command_to_state: list[float] = []
    commanded = 0
    last_reference = data.reference_t[-1]
    for joint in JOINT_NAMES:
        commands, states = data.commands[joint], data.states[joint]
        t_c = np.asarray(commands['t'])
        speed = np.asarray(commands['motor_speed'])
        enable = np.asarray(commands['enable'], dtype=bool)
        commanded += int((enable & (t_c <= last_reference)).sum())
        previous = -1
        for t_s, applied in zip(states['t'], states['motor_speed_command'], strict=True):
            newest = int(np.searchsorted(t_c, t_s, side='right')) - 1
            # Look back a few commands only: a match further back is a repeated value.
            match = next((j for j in range(newest, max(newest - 8, -1), -1)
                          if speed[j] == applied), -1)
            if match <= previous or t_c[match] > last_reference:
                continue  # already counted; or past the trial, with no fresh reference
            previous = match
            k = int(np.searchsorted(data.reference_t, t_c[match], side='right')) - 1
            if k >= 0 and enable[match]:
                reference_to_state.append(t_s - data.reference_t[k])
                command_to_state.append(t_s - t_c[match])
    return (np.asarray(reference_to_state), np.asarray(command_to_state),
            commanded - len(command_to_state))


def _percentiles(values: np.ndarray) -> dict[str, float | int | None]:
    if not values.size:
        return {'p50': None, 'p99': None, 'max': None, 'samples': 0}
    return {'p50': round(float(np.median(values)) * 1e3, 2),
            'p99': round(float(np.percentile(values, 99)) * 1e3, 2),
            'max': round(float(values.max()) * 1e3, 2), 'samples': int(values.size)}


TIMING = re.compile(r'(\d+) periods, (\d+) missed, (\d+) late by over half a period, '
                    r'lateness p99 ([\d.]+) ms p99\.9 ([\d.]+) ms max ([\d.]+) ms')


def timing(output: str, joint: str = '') -> dict[str, float]:
    """Parse the timing summary a plant (of a joint) or the probe printed at its end."""
    match = re.search(rf'{joint} plant: ' + TIMING.pattern if joint else TIMING, output)
    assert match, output
    keys = ('periods', 'missed', 'late', 'p99_ms', 'p99_9_ms', 'max_ms')
    return {key: float(value) for key, value in zip(keys, match.groups(), strict=True)}


#: Ways to share the nodes among processes (``--compositions``): process name -> nodes.
COMPOSITIONS: dict[str, dict[str, tuple[str, ...]]] = {
    'separate': {},
    'plants': COMPOSITION,
    'plants,control': {**COMPOSITION, 'control': ('pd_controller', 'gait_publisher')},
    'plants+control': {'robot': (*COMPOSITION['plants'], 'pd_controller', 'gait_publisher')},
    'plants+controller': {'robot': (*COMPOSITION['plants'], 'pd_controller')},
    'plants+control,observers': {
        'robot': (*COMPOSITION['plants'], 'pd_controller', 'gait_publisher'),
        'observers': ('watchdog', 'recorder')},
}


#: DDS transports of the nodes (``--transports``): as shipped (UDP alone, exo_has_runtime.dds),
#: and rmw_fastrtps_cpp's LOCALHOST settings as they stand (shared memory and UDP).
TRANSPORTS: dict[str, dict[str, str]] = {'udp': {}, 'rmw': RMW_LOCALHOST_ENVIRONMENT}

#: The variant that keeps every node's parameters as shipped.
DEFAULTS = 'defaults'


def node_arguments(variant: str) -> dict[str, tuple[str, ...]]:
    """ROS arguments per node of a variant: ``watchdog.batch=false,recorder.poll_period=0``.

    Raises
    ------
    ValueError
        If a setting is not ``node.parameter=value``.

    """
    arguments: dict[str, tuple[str, ...]] = {}
    for setting in filter(None, variant.split(',')) if variant != DEFAULTS else ():
        node, dot, rest = setting.partition('.')
        name, equals, value = rest.partition('=')
        if not (dot and equals and node and name):
            msg = f'variant setting {setting!r}: expected node.parameter=value'
            raise ValueError(msg)
        arguments[node] = (*arguments.get(node, ()), '-p', f'{name}:={value}')
    return arguments


def run(rate: float, duration: float, folder: Path, priority: int = 0,
        executor: str = 'events', composition: str = 'plants',
        variant: str = DEFAULTS, transport: str = 'udp') -> dict[str, object]:
    """One session at a rate, on an executor, the plants at a real-time priority; its figures.

    ``variant``: node parameters set for this session (:func:`node_arguments`); ``transport``:
    the DDS transport of every node (:data:`TRANSPORTS`).
    """
    config = SessionConfig(('walk',), (duration,), rate, realtime_priority=priority,
                           composition=COMPOSITIONS[composition],
                           node_arguments=node_arguments(variant))
    env = {'EXO_HAS_EXECUTOR': executor, **TRANSPORTS[transport]}
    session = Session(config, folder, env=env)
    with Processes() as processes:
        session.start(show=lambda line: None)
        try:
            assert session.started_at is not None
            probe = processes.start(
                [sys.executable, str(Path(__file__).with_name('probe.py')), '--rate',
                 f'{rate:g}', '--duration',
                 f'{session.started_at - time.monotonic() + duration:.2f}'],
                stdout=subprocess.PIPE, text=True, env={**os.environ, **env})
            shares = trial_cpu_shares(session, duration)
        finally:
            session.stop()
        probe_output = probe.communicate(timeout=60.0)[0]
    plants = [timing(session.output(f'{joint}_plant'), joint) for joint in JOINT_NAMES]
    periods = int(sum(p['periods'] for p in plants))
    missed = int(sum(p['missed'] for p in plants))
    late = int(sum(p['late'] for p in plants))
    floor = timing(probe_output)
    assert session.bag is not None
    reference_to_state, command_to_state, superseded = latencies(session.bag)
    fatal = sum(1 for e in read_session(session.bag).events if e.severity >= 3)
    return {
        'fatal_events': fatal,
        'rate_hz': rate, 'duration_s': duration, 'realtime_priority': priority,
        'executor': executor, 'composition': composition, 'variant': variant,
        'transport': transport,
        'cpu_percent_of_one_core': {k: round(v, 1) for k, v in shares.items()},
        'cpu_percent_total': round(sum(shares.values()), 1),
        'plant_periods': periods, 'plant_missed_periods': missed,
        'missed_percent': round(100.0 * missed / max(periods, 1), 3),
        'plant_late_periods': late, 'late_percent': round(100.0 * late / max(periods, 1), 3),
        'plant_lateness_ms': {key: max(p[key] for p in plants)
                              for key in ('p99_ms', 'p99_9_ms', 'max_ms')},
        'probe': {**floor, 'missed_percent': round(100.0 * floor['missed'] / floor['periods'], 3),
                  'late_percent': round(100.0 * floor['late'] / floor['periods'], 3)},
        'latency_ms': {'reference_to_state': _percentiles(reference_to_state),
                       'command_to_state': _percentiles(command_to_state),
                       'superseded_commands': superseded},
    }


def main() -> None:
    """Run the sessions and write bench/results/system.{json,txt}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=30.0)
    parser.add_argument('--rates', type=float, nargs='+', default=[200.0, 1000.0])
    parser.add_argument('--repeats', type=int, default=1,
                        help='sessions per rate, the rates taking turns; medians are reported')
    parser.add_argument('--realtime-priorities', type=int, nargs='+', default=[0],
                        help="SCHED_FIFO priorities of the plants' loops to compare, taking "
                             'turns (0: the default scheduler; others need root)')
    parser.add_argument('--executors', nargs='+', default=['events'],
                        choices=('events', 'single'), help='executors to compare, taking turns')
    parser.add_argument('--compositions', nargs='+', default=['plants'],
                        choices=tuple(COMPOSITIONS),
                        help='nodes sharing a process (separate: none), taking turns')
    parser.add_argument('--results', default='system',
                        help='name of the results files under bench/results/')
    parser.add_argument('--transports', nargs='+', default=['udp'], choices=tuple(TRANSPORTS),
                        help="the nodes' DDS transports to compare, taking turns")
    parser.add_argument('--variants', nargs='+', default=[DEFAULTS],
                        help='node parameters to compare, taking turns: defaults, or '
                             'node.parameter=value[,node.parameter=value...]')
    args = parser.parse_args()
    on_this_machine()
    for variant in args.variants:
        node_arguments(variant)  # a malformed variant fails before any session runs
    variants = list(itertools.product(args.executors, args.compositions, args.variants,
                                      args.transports))
    results = []
    with tempfile.TemporaryDirectory() as scratch:
        for repeat in range(args.repeats):
            for rate in args.rates:
                for priority in args.realtime_priorities:
                    for index, (executor, composition, variant, transport) in enumerate(
                            variants):
                        folder = Path(scratch) / (f'rate_{rate:g}_{priority}_{index}_{repeat}')
                        results.append(run(rate, args.duration, folder, priority, executor,
                                           composition, variant, transport))
                        print(json.dumps(results[-1], indent=1), flush=True)
    medians = {}
    for rate, priority, (executor, composition, variant, transport) in itertools.product(
            args.rates, args.realtime_priorities, variants):
        runs = [r for r in results if r['rate_hz'] == rate
                and r['realtime_priority'] == priority and r['executor'] == executor
                and r['composition'] == composition and r['variant'] == variant
                and r['transport'] == transport]
        key = (f'{rate:g} Hz, {executor} executor, {composition} composed, {variant}, '
               f'{transport} transport, realtime priority {priority}')
        medians[key] = {
            name: float(np.median([r[name] for r in runs]))
            for name in ('cpu_percent_total', 'missed_percent', 'late_percent')}
        medians[key]['worst_lateness_ms'] = float(
            np.median([r['plant_lateness_ms']['max_ms'] for r in runs]))
        medians[key]['fatal_events'] = [r['fatal_events'] for r in runs]
        medians[key]['cpu_percent_per_node'] = {
            node: round(float(np.median([r['cpu_percent_of_one_core'].get(node, 0.0)
                                         for r in runs])), 1)
            for node in runs[0]['cpu_percent_of_one_core']}
        medians[key]['probe_missed_percent'] = float(
            np.median([r['probe']['missed_percent'] for r in runs]))
    machine = describe_machine()
    lines = [f'bench/system.py --duration {args.duration:g} --repeats {args.repeats} '
             f'--executors {" ".join(args.executors)} '
             f'--compositions {" ".join(args.compositions)} '
             f'--variants {" ".join(args.variants)} '
             f'--transports {" ".join(args.transports)} '
             f'--realtime-priorities {" ".join(map(str, args.realtime_priorities))}: {machine}']
    for key, median in medians.items():
        lines.append(f'{key}, median of {args.repeats}: total CPU '
                     f"{median['cpu_percent_total']:.1f} % of one core (per node "
                     f"{median['cpu_percent_per_node']}), missed "
                     f"{median['missed_percent']:.3f} %, late {median['late_percent']:.3f} %, "
                     f"worst plant lateness {median['worst_lateness_ms']:.1f} ms, fatal events "
                     f"{median['fatal_events']}, "
                     f"idle probe missed {median['probe_missed_percent']:.3f} %")
    for r in results:
        ref, cmd = r['latency_ms']['reference_to_state'], r['latency_ms']['command_to_state']
        lines.append(
            f"{r['rate_hz']:g} Hz, {r['executor']} executor, {r['composition']} composed, "
            f"{r['variant']}, {r['transport']} transport, realtime priority "
            f"{r['realtime_priority']}: total CPU "
            f"{r['cpu_percent_total']} % of one core; plants "
            f"missed {r['plant_missed_periods']}/{r['plant_periods']} ({r['missed_percent']} %), "
            f"late by over half a period {r['plant_late_periods']} ({r['late_percent']} %), "
            f"lateness of the worst plant {r['plant_lateness_ms']}; idle probe missed "
            f"{r['probe']['missed_percent']} %, late {r['probe']['late_percent']} %, max "
            f"{r['probe']['max_ms']} ms; latency reference-to-state p50 {ref['p50']} ms p99 "
            f"{ref['p99']} ms, command-to-state p50 {cmd['p50']} ms p99 {cmd['p99']} ms, "
            f"{r['latency_ms']['superseded_commands']} commands superseded; fatal events "
            f"{r['fatal_events']}; per node {r['cpu_percent_of_one_core']}")
    write_results(args.results, {'medians': medians, 'runs': results}, lines)


if __name__ == '__main__':
    main()
