"""Benchmark: the closed loop through plant nodes, the CAN driver chain and the robot side.

The same walking-then-squatting session runs with the joints as plant nodes (issue 4,
``plants``), as simulated COPLEY-like drives and sensor boards on a udp_multicast CAN bus
behind the old chain of nodes, the hardware driver, the PD controller and the watchdog (issue
6, ``can``), and as the same devices behind the robot side of issue 28 (``robot``: the robot
loop, :mod:`exo_has_bringup.robot_main`, with bus, safety and PD law in the CANopen master's I/O
thread and no ROS, and its bridge node); the gait publisher and the recorder are the same for
all. The variants take turns ``--repeats`` times, so that they share the machine's moods.

Load beside the sessions, for the whole run: ``--busy N`` processes that spin, the i-th pinned
to core i modulo the cores (``--busy 2`` on a 2-core machine: one on every core); and with
``--joiner-period S`` a third-party ROS participant joins the session's domain every S seconds
from before the session starts until it has stopped, one at a time: a ``python -c`` that
starts rclpy on rmw_fastrtps_cpp's own LOCALHOST settings (shared memory and UDP,
``RMW_LOCALHOST_ENVIRONMENT``, as ``bench/joins.py``'s joiners and a ``ros2 topic echo``),
subscribes to ``/left_knee/has_state``, spins for ``JOINER_SPIN`` seconds and exits.
``--robot-cpus LIST`` keeps the robot loop and the simulated devices to those CPUs, as a robot
PC gives its loop an isolated core, and this script, and so every other process of the
sessions (joiners too; not the busy ones, pinned each to its core), to the others; the old
chain's driver, a ROS node whose DDS threads share its process, is not moved (its devices are).

Per session (the trials: from the first reference to the end of the last trial, unless said):

- ``gap_ms``, the longest gap between bus commands [ms]. ``robot``: the loop's own longest
  time between two of its periods (each period computes and writes every joint's command just
  before its SYNC), over the loop's whole run, start-up and stop included (its summary line in
  ``logs/robot_loop.log``): a superset of the trials. ``can``, ``plants``: the longest interval
  between two of a joint's commands (``has_command`` header stamps, the controller's clock at
  publishing), the most of the four joints; the driver hands each command to the master on
  arrival and the master writes the newest at every SYNC, so a gap in commands is a gap the
  bus repeats a stale command (a command the recorder missed, on its best-effort subscription,
  shows as a gap too).
- ``jitter_p99_ms``, period jitter p99 [ms]. ``robot``: the loop's release lateness p99 on the
  master's SYNC grid (:class:`~exo_has_common.timing.PeriodMonitor`, 0.1 ms bins, upper edge),
  over its whole run. ``can``, ``plants``: the p99 of ``|interval - period|`` of a joint's
  command stamps, the most of the four; ``command_lateness_p99_ms`` is their lateness on the
  timer's grid by the same PeriodMonitor as the loop's, the loop's definition.
- ``missed``: ``robot``: the loop's missed periods over its whole run (``missed_in_trials``:
  those in the trials, from its ``/diagnostics`` statuses in the bag, to their 1 s); ``can``,
  ``plants``: the periods without a command, sum of ``round(interval / period) - 1`` over a
  joint's intervals, the most of the four.
- ``bus_gap_ms``, ``bus_jitter_p99_ms``: the same for every variant, from the state samples'
  stamps (the kernel's receive time of each sensor board's TPDO1, which answers the SYNC; the
  robot's and the driver's alike): the longest interval and the p99 of ``|interval -
  period|``, the most of the four joints. This is the SYNC cadence on the bus, the master's
  thread in both chains, where ``gap_ms`` of ``can`` is the controller's. A state sample lost
  on its way (the recorder's best-effort subscription; the robot bridge's dropped datagrams)
  shows as a gap too.
- FATAL events (``analysis.read_session(bag).events``, severity FATAL or more), the lowest state
  rate [Hz] of the four joints, the tracking error per joint and trial (actual minus reference
  joint angle [deg]: RMS, minimum, maximum, the walk judged from ``--walk-from``), and each
  process's CPU share (percent of one core, /proc over the middle 60 % of the trials); the
  variant's own processes (``robot``: loop and bridge; ``can``: driver, controller, watchdog;
  ``plants``: plants, controller, watchdog) are summed as ``side``, the rest (devices, gait
  publisher, recorder) as ``shared``.
- ``robot`` only: the loop's cycle compute max [ms], and the datagrams it dropped (the bridge's
  socket queue full, or no bridge there yet or any more) over its whole run and in the trials.

What the platform did, with ``--witness-priority N`` (:mod:`witness`): cyclictest on the robot's
CPUs under SCHED_FIFO N (above the loop), waking every 1 ms through each session: its
lateness, and the steal time of those CPUs.
With ``--trace`` as well (root, one robot CPU; :mod:`kernel_trace`), the kernel's trace of
that CPU through the session: the spans it was absent (no event for over 1.5 ms, with the
witness's timer due every 1 ms: the host ran something else under the vCPU), and, for
``robot``, every gap of the loop's I/O thread (over a period and 1 ms between two of its runs)
with the absence in it: the platform's gap where the absence leaves no more than a period and
1 ms; both over the trials (where the bridge configures and activates the loop, its thread
waits on the devices' boot, which is no gap of the loop).

A session passes issue 28's acceptance if ``gap_ms`` is under two periods, ``jitter_p99_ms``
under 1 ms and it had no FATAL event; the printout gives each variant's medians over the
sessions, the worst session, and how many sessions passed.

Run (in ``./run shell``): ``python bench/closed_loop.py [--repeats 3] [--rate 200] [--hardware
plants can robot] [--results NAME]`` (results in ``bench/results/NAME.{json,txt}``,
``closed_loop`` by default). The conditions of ``test/test_can_session.py``: ``--hardware can
--rate 100 --realtime-priority 20 --walk-from 3``. ``--controller-priority 0 20`` runs the
``plants`` and ``can`` variants with the controller's thread at each of those SCHED_FIFO
priorities in turn (by default at ``--realtime-priority``, as the sessions run it); the robot
side has no controller node. Issue 28's acceptance: see bench/README.md, "The robot side
against the old chain".
"""

from __future__ import annotations

import argparse
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np
from common import (
    LOOP_SUMMARY,
    describe_machine,
    on_this_machine,
    raise_softirq_threads,
    restore_threads,
    start_busy,
    trial_cpu_shares,
)
from kernel_trace import GAP_SLACK, TRACE_FIGURES, CpuTrace, only_other_thread, trace_figures
from witness import WITNESS_FIGURES, Witness

from exo_has_bringup.analysis import SessionData, rates, read_session, tracking
from exo_has_bringup.plan import SessionConfig
from exo_has_bringup.report import segments_of
from exo_has_bringup.runner import Session
from exo_has_common.bag import default_typestore, read_messages
from exo_has_common.realtime import parse_cpus
from exo_has_common.timing import PeriodMonitor
from exo_has_runtime.dds import RMW_LOCALHOST_ENVIRONMENT
from exo_has_runtime.processes import Processes

RESULTS = Path(__file__).resolve().parent / 'results'
MOTIONS, DURATIONS = ('walk', 'squat'), (10.0, 8.0)
HARDWARE = ('plants', 'can', 'robot')
#: Each variant's own processes; every other process of its session is shared by all.
SIDE = {'plants': ('plants', 'pd_controller', 'watchdog'),
        'can': ('driver', 'pd_controller', 'watchdog'),
        'robot': ('robot_loop', 'robot_bridge')}
#: Issue 28's acceptance: longest gap under this many periods, jitter p99 under this [ms].
GAP_PERIODS, JITTER_MS = 2.0, 1.0
#: The trace's buffer per CPU [MB]: a session on a busy CPU at 1 kHz.
TRACE_MB = 300


#: How long a joiner spins once it has made its subscription [s].
JOINER_SPIN = 1.0
#: A joiner still running after this long is killed [s].
JOINER_TIMEOUT = 15.0
#: A third-party participant: rclpy, a node, a subscription to a session topic, a short spin.
JOINER = """
import sys, time
import rclpy
from rclpy.qos import qos_profile_sensor_data
from exo_has_msgs.msg import HasState
rclpy.init()
node = rclpy.create_node(sys.argv[1])
heard = []
node.create_subscription(HasState, '/left_knee/has_state', heard.append,
                         qos_profile_sensor_data)
end = time.monotonic() + float(sys.argv[2])
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.05)
print(f'heard {len(heard)}', flush=True)
node.destroy_node()
rclpy.shutdown()
"""


class Joiners:
    """Third-party participants joining the domain every ``period`` seconds, one at a time.

    A context manager: the first joins on entry, the last is ended on exit. ``started`` counts
    them, ``heard`` those that received a state (so that joined the session's traffic).
    """

    def __init__(self, period: float, folder: Path) -> None:
        self.period = period
        self.folder = folder
        self.started = 0
        self.heard = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._environment = {**os.environ, **RMW_LOCALHOST_ENVIRONMENT}

    def __enter__(self) -> Joiners:
        self.folder.mkdir(parents=True, exist_ok=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        due = time.monotonic()
        while not self._stop.is_set():
            log = self.folder / f'joiner_{self.started}.log'
            # Started from this thread, which outlives it: its tether holds.
            with log.open('w') as out, Processes() as processes:
                process = processes.start(
                    [sys.executable, '-c', JOINER, f'joiner_{self.started}', f'{JOINER_SPIN}'],
                    stdout=out, stderr=subprocess.STDOUT, env=self._environment)
                self.started += 1
                try:
                    process.wait(JOINER_TIMEOUT)
                except subprocess.TimeoutExpired:
                    processes.end(process, first=signal.SIGKILL)
            found = re.search(r'heard (\d+)', log.read_text())
            self.heard += bool(found and int(found.group(1)) > 0)
            due += self.period
            self._stop.wait(max(0.0, due - time.monotonic()))
            due = max(due, time.monotonic())  # one at a time: a slow joiner delays the next


def stream_timing(t: np.ndarray, period: float) -> dict[str, float]:
    """Return the timing of a stream stamped ``t`` [s] that should come every ``period`` [s].

    Returns its longest interval and the p99 of ``|interval - period|`` [ms], the periods
    without a message, and the p99 lateness on its first message's grid by
    :class:`~exo_has_common.timing.PeriodMonitor` [ms].
    """
    if t.size < 2:
        return {'gap_ms': float('nan'), 'jitter_p99_ms': float('nan'), 'missed': float('nan'),
                'lateness_p99_ms': float('nan')}
    intervals = np.diff(t)
    monitor = PeriodMonitor(round(period * 1e9))
    for stamp in t:
        monitor.tick(round(float(stamp) * 1e9))
    return {'gap_ms': 1e3 * float(intervals.max()),
            'jitter_p99_ms': 1e3 * float(np.percentile(np.abs(intervals - period), 99.0)),
            'missed': float(np.maximum(np.rint(intervals / period) - 1.0, 0.0).sum()),
            'lateness_p99_ms': 1e3 * monitor.lateness_percentile(99.0)}


def worst_stream(table: dict[str, dict[str, np.ndarray]], trials: tuple[float, float],
                 period: float) -> dict[str, float]:
    """Return the worst of each joint's :func:`stream_timing` over the trials (NaN: no stream)."""
    timings = [stream_timing(t[(t >= trials[0]) & (t <= trials[1])], period)
               for t in (series['t'] for series in table.values())]
    keys = ('gap_ms', 'jitter_p99_ms', 'missed', 'lateness_p99_ms')
    return {key: max((timing[key] for timing in timings), default=float('nan'))
            for key in keys}


def loop_statuses(bag: Path) -> list[tuple[float, dict[str, str]]]:
    """Return the robot loop's statuses on ``/diagnostics`` in a bag: (stamp [s], values)."""
    typestore = default_typestore()
    statuses = []
    with read_messages(bag) as messages:
        for topic, msgtype, _t_ns, data in messages:
            if topic != '/diagnostics':
                continue
            array = typestore.deserialize_cdr(data, msgtype)
            stamp = array.header.stamp.sec + array.header.stamp.nanosec * 1e-9
            statuses += [(stamp, {kv.key: kv.value for kv in status.values})
                         for status in array.status if status.name == 'robot_loop'
                         and status.values]
    return sorted(statuses, key=lambda status: status[0])


def robot_figures(session: Session, data: SessionData,
                  trials: tuple[float, float]) -> dict[str, float]:
    """Return the robot loop's own figures: its summary line, its counts in the trials."""
    log = (session.logs / 'robot_loop.log').read_text()
    found = LOOP_SUMMARY.search(log)
    if found is None:
        msg = f'the robot loop printed no summary: {log[-2000:]}'
        raise RuntimeError(msg)
    summary = {key: float(value) for key, value in found.groupdict().items()}
    assert session.bag is not None
    statuses = loop_statuses(session.bag)
    # The last status before the trials and the first after them: their counts differ by
    # those of the trials (and of up to a diagnostics period either side).
    # Where the recorder stopped before the next status, the last one stands for it.
    before = [values for stamp, values in statuses if stamp <= trials[0]] \
        or [values for _, values in statuses[:1]]
    after = [values for stamp, values in statuses if stamp >= trials[1]] \
        or [values for _, values in statuses[-1:]]
    if before and after:
        missed = float(after[0]['missed']) - float(before[-1]['missed'])
        dropped = float(after[0]['datagrams dropped']) - float(before[-1]['datagrams dropped'])
    else:
        missed = dropped = float('nan')
    return {'gap_ms': summary['gap'], 'jitter_p99_ms': summary['p99'],
            'missed': summary['missed'], 'missed_in_trials': missed,
            'loop_periods': summary['periods'], 'loop_late': summary['late'],
            'loop_lateness_max_ms': summary['max'], 'compute_max_ms': summary['compute'],
            'dropped': summary['dropped'], 'dropped_in_trials': dropped,
            'statuses': float(len(statuses))}


def run(hardware: str, controller_priority: int, folder: Path,
        args: argparse.Namespace) -> dict[str, Any]:
    """One session and its figures (see the module docstring)."""
    durations = tuple(args.durations)
    gait = ('-p', f'stride_frequency:={args.stride_frequency}')
    arguments = {'gait_publisher': gait} if hardware == 'robot' else {
        'gait_publisher': gait,
        'pd_controller': ('-p', f'realtime_priority:={controller_priority}')}
    session = Session(SessionConfig(
        MOTIONS, durations, args.rate, hardware=hardware, can_bitrate=args.bitrate,
        robot_cpus=args.robot_cpus,
        realtime_priority=args.realtime_priority, node_arguments=arguments), folder)
    joiners: Joiners | None = None
    with ExitStack() as stack:
        if args.joiner_period:
            joiners = stack.enter_context(Joiners(args.joiner_period, folder / 'joiners'))
        witness = stack.enter_context(Witness(witness_cpus(args), args.witness_priority)) \
            if args.witness_priority else None
        trace = stack.enter_context(CpuTrace(witness_cpus(args), TRACE_MB)) \
            if args.trace else None
        tid = None
        session.start(show=lambda line: None)
        try:
            shares = trial_cpu_shares(session, sum(durations))
            if trace is not None and hardware == 'robot':  # the loop's I/O thread
                tid = only_other_thread(session.processes['robot_loop'].process.pid)
        finally:
            session.stop()
    assert session.bag is not None
    data = read_session(session.bag)
    clock_offset = time.time() - time.monotonic()  # the bag's clock less the trace's
    windows = [(name, start + (args.walk_from if name.endswith('walk') else 0.0), end)
               for name, start, end in segments_of(MOTIONS, durations)]
    rows = tracking(data, windows)
    trials = (data.start, data.start + sum(durations))
    period = 1.0 / args.rate
    bus = worst_stream(data.states, trials, period)
    if hardware == 'robot':
        figures = robot_figures(session, data, trials)
    else:
        commands = worst_stream(data.commands, trials, period)
        figures = {'gap_ms': commands['gap_ms'], 'jitter_p99_ms': commands['jitter_p99_ms'],
                   'missed': commands['missed'],
                   'command_lateness_p99_ms': commands['lateness_p99_ms']}
    cpu = {name: round(share, 1) for name, share in shares.items()}
    fatal = sum(1 for e in data.events if e.severity >= 3)
    return {
        'hardware': hardware,
        'controller_priority': None if hardware == 'robot' else controller_priority,
        **figures,
        'bus_gap_ms': bus['gap_ms'], 'bus_jitter_p99_ms': bus['jitter_p99_ms'],
        'fatal_events': fatal,
        'fatal_texts': [e.text for e in data.events if e.severity >= 3][:5],
        'passed': bool(figures['gap_ms'] < GAP_PERIODS * period * 1e3
                       and figures['jitter_p99_ms'] < JITTER_MS and fatal == 0),
        'state_rate_hz': min((value for topic, value in rates(data).items()
                              if topic.endswith('/has_state')), default=float('nan')),
        'tracking_deg': {f'{r.joint} {r.segment}': {'rms': r.rms, 'min': r.minimum,
                                                     'max': r.maximum} for r in rows},
        'cpu_percent': cpu,
        'cpu_side_percent': round(sum(v for k, v in cpu.items() if k in SIDE[hardware]), 1),
        'cpu_shared_percent': round(sum(v for k, v in cpu.items()
                                        if k not in SIDE[hardware]), 1),
        'joiners': None if joiners is None else {'started': joiners.started,
                                                 'heard': joiners.heard},
        **({} if witness is None else witness.figures(*trials)),
        **({} if trace is None else trace_figures(
            trace, tid, period, args.witness_priority,
            (trials[0] - clock_offset, trials[1] - clock_offset))),
    }


def witness_cpus(args: argparse.Namespace) -> frozenset[int]:
    """Return the CPUs the witness watches: the robot's, else all."""
    return parse_cpus(args.robot_cpus) if args.robot_cpus else \
        frozenset(range(os.cpu_count() or 1))


#: Figures summarised per variant: key, label, format; each as median (worst).
FIGURES = (('gap_ms', 'longest gap between bus commands [ms]', '.1f'),
           ('jitter_p99_ms', 'period jitter p99 [ms]', '.2f'),
           ('missed', 'missed periods', '.0f'),
           ('bus_gap_ms', 'bus: longest interval between samples [ms]', '.1f'),
           ('bus_jitter_p99_ms', 'bus: sample interval jitter p99 [ms]', '.2f'),
           ('command_lateness_p99_ms', 'commands: lateness p99 on their grid [ms]', '.2f'),
           ('missed_in_trials', 'loop: missed periods in the trials', '.0f'),
           ('compute_max_ms', 'loop: cycle compute max [ms]', '.2f'),
           ('dropped', 'loop: datagrams dropped, whole run', '.0f'),
           ('dropped_in_trials', 'loop: datagrams dropped in the trials', '.0f'),
           ('cpu_side_percent', 'CPU of its own processes [% of a core]', '.1f'),
           ('cpu_shared_percent', 'CPU of the shared processes [% of a core]', '.1f'),
           ('state_rate_hz', 'state rate, lowest joint [Hz] (worst: lowest)', '.1f'),
           *WITNESS_FIGURES,
           *TRACE_FIGURES)


def summarise(runs: list[dict[str, Any]], args: argparse.Namespace
              ) -> dict[str, dict[str, Any]]:
    """Each variant's medians over its sessions and its worst session, figure by figure."""
    summary: dict[str, dict[str, Any]] = {}
    for name in dict.fromkeys(r['variant'] for r in runs):
        mine = [r for r in runs if r['variant'] == name]
        rows = [r['tracking_deg'] for r in mine]
        tracking_summary = {key: {stat: float(np.median([row[key][stat] for row in rows]))
                                  for stat in ('rms', 'min', 'max')} for key in rows[0]}
        for key in rows[0]:  # the worst over the repeats, as a test's bound sees it
            tracking_summary[key]['worst_peak'] = float(max(
                max(-row[key]['min'], row[key]['max']) for row in rows))
        figures = {}
        for key, _, _ in FIGURES:
            values = [float(r[key]) for r in mine if key in r]
            if values:
                worst = min(values) if key == 'state_rate_hz' else max(values)
                figures[key] = {'median': float(np.median(values)), 'worst': worst}
        cpu = {process: float(np.median([r['cpu_percent'][process] for r in mine]))
               for process in mine[0]['cpu_percent']}
        summary[name] = {
            'sessions': len(mine), 'passed': sum(r['passed'] for r in mine),
            'fatal_events': sum(r['fatal_events'] for r in mine),
            'figures': figures, 'cpu_percent': cpu, 'tracking_deg': tracking_summary}
        if all('loop_gaps' in r for r in mine):
            summary[name]['traced'] = {
                'gaps': int(sum(r['loop_gaps'] for r in mine)),
                'platform': int(sum(r['loop_gaps_platform'] for r in mine)),
                'own_max_ms': max(r['loop_gap_own_max_ms'] for r in mine)}
    return summary


def report(summary: dict[str, dict[str, Any]], args: argparse.Namespace,
           machine: dict[str, object], command: str) -> list[str]:
    """Return the printout: figures per variant, acceptance, CPU by process, tracking."""
    period_ms = 1e3 / args.rate
    variants = list(summary)
    lines = [f'{command}: {machine}',
             f'{args.rate:g} Hz (period {period_ms:g} ms), busy processes {args.busy}, a '
             f'joiner every {args.joiner_period or "-"} s; per variant the median over the '
             'sessions (and the worst session)',
             f'{"figure":48s}' + ''.join(f' | {v:>20s}' for v in variants)]
    for key, label, form in FIGURES:
        cells = []
        for name in variants:
            figure = summary[name]['figures'].get(key)
            cells.append('-' if figure is None else
                         f'{figure["median"]:{form}} ({figure["worst"]:{form}})')
        if any(cell != '-' for cell in cells):
            lines.append(f'{label:48s}' + ''.join(f' | {cell:>20s}' for cell in cells))
    lines.append(f'{"FATAL events, all sessions":48s}' + ''.join(
        f' | {summary[v]["fatal_events"]:>20d}' for v in variants))
    lines.append(f'{"sessions passed / run":48s}' + ''.join(
        f' | {summary[v]["passed"]:>13d} / {summary[v]["sessions"]:<4d}' for v in variants))
    lines.append(f"acceptance (issue 28): each session's longest gap under {GAP_PERIODS:g} "
                 f'periods ({GAP_PERIODS * period_ms:g} ms), jitter p99 under {JITTER_MS:g} '
                 'ms, no FATAL event')
    for name in variants:
        s = summary[name]
        verdict = 'PASS' if s['passed'] == s['sessions'] else 'FAIL'
        cpu = ', '.join(f'{process} {share:.1f}' for process, share in s['cpu_percent'].items())
        lines.append(f'{name}: {verdict} ({s["passed"]} of {s["sessions"]} sessions); CPU '
                     f'median [% of a core]: {cpu}')
        if 'traced' in s:
            t = s['traced']
            lines.append(
                f"{name}: of the loop's {t['gaps']} gaps in the trials (over a period and "
                f"{GAP_SLACK * 1e3:g} ms), {t['platform']} were filled by its CPU's absence; "
                f"the others' longest, net of it, {t['own_max_ms']:.1f} ms")
    lines += ['tracking error [deg], median over the sessions (and the worst peak of any): '
              + ' | '.join(variants),
              f'{"joint trial":24s}' + ' |'.join(
                  f' {"rms":>6s} {"min":>6s} {"max":>6s} {"worst":>6s}' for _ in variants)]
    for key in summary[variants[0]]['tracking_deg']:
        lines.append(f'{key:24s}' + ' |'.join(
            ' {rms:6.2f} {min:6.2f} {max:6.2f} {worst_peak:6.2f}'.format(
                **summary[v]['tracking_deg'][key]) for v in variants))
    return lines


def main() -> None:
    """Run the sessions and write bench/results/NAME.{json,txt}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=3, help='sessions of each variant')
    parser.add_argument('--rate', type=float, default=200.0, help='session rate [Hz]')
    parser.add_argument('--durations', type=float, nargs=2, default=DURATIONS,
                        metavar=('WALK', 'SQUAT'), help='length of each trial [s]')
    parser.add_argument('--results', default='closed_loop', help='name of the results files')
    parser.add_argument('--hardware', nargs='+', choices=HARDWARE, default=['plants', 'can'],
                        help='plant nodes, the CAN driver chain, the robot side; each in turn')
    parser.add_argument('--stride-frequency', type=float, default=0.85,
                        help='walking strides per second [Hz] (the paper: 0.85)')
    parser.add_argument('--realtime-priority', type=int, default=0,
                        help="SCHED_FIFO priority of the plants, or of the driver's bus "
                             'thread (the robot loop) and the CAN devices (0: the default '
                             'scheduler)')
    parser.add_argument('--walk-from', type=float, default=0.0,
                        help='time into the walk from which its tracking is judged [s]')
    parser.add_argument('--busy', type=int, nargs='?', const=1, default=0, metavar='N',
                        help='processes spinning beside the sessions, one a core in turn '
                             '(--busy alone: one)')
    parser.add_argument('--joiner-period', type=float, default=0.0, metavar='S',
                        help='a third-party ROS participant joins the domain every S seconds '
                             '(0: none)')
    parser.add_argument('--controller-priority', type=int, nargs='+',
                        help="SCHED_FIFO priorities of the controller's thread to take turns "
                             'with (default: --realtime-priority)')
    parser.add_argument('--robot-cpus', default='', metavar='LIST',
                        help='CPUs of the robot loop and the simulated devices (1, 2-3), as a '
                             'robot PC isolates a core; this script, and so every other '
                             'process of the sessions, keeps to the other CPUs (default: none '
                             'apart)')
    parser.add_argument('--softirq-priority', type=int, default=0, metavar='N',
                        help="SCHED_FIFO priority of the kernel's softirq threads (ksoftirqd) "
                             'of the --robot-cpus for the run, as PREEMPT_RT runs softirqs; '
                             '0: left as they are (default)')
    parser.add_argument('--bitrate', type=int, default=1_000_000,
                        help='CAN bit rate [bit/s] the masters judge their bus load at '
                             '(default: %(default)s, classic CAN, at most about 370 Hz for 4 '
                             'joints; the simulated bus has none of its own)')
    parser.add_argument('--witness-priority', type=int, default=0, metavar='N',
                        help='run the witness (bench/witness.py: cyclictest) at SCHED_FIFO N '
                             'on the --robot-cpus (all CPUs if none) through each session, '
                             "to tell the platform's stalls from the loop's (0: none)")
    parser.add_argument('--trace', action='store_true',
                        help="trace the robot's CPU through each session (bench/kernel_trace.py"
                             '; root, one --robot-cpus and the witness needed): which of the '
                             "loop's gaps its CPU's absence fills")
    parser.add_argument('--folder', type=Path,
                        help="keep each session's folder (bag, logs, joiners' logs) under this "
                             'directory (default: a temporary one, removed)')
    parser.add_argument('--summarise', metavar='NAME',
                        help='only summarise bench/results/NAME.json again (its runs, its '
                             'arguments) into NAME.txt, as this script now reports')
    args = parser.parse_args()
    if args.summarise:
        saved = json.loads((RESULTS / f'{args.summarise}.json').read_text())
        write_report(saved['runs'], argparse.Namespace(**saved['arguments']),
                     saved['machine'], saved['command'])
        return
    if args.trace and not (args.witness_priority and args.robot_cpus
                           and len(parse_cpus(args.robot_cpus)) == 1):
        parser.error('--trace needs the witness (--witness-priority) and one --robot-cpus')
    priorities = args.controller_priority or [args.realtime_priority]
    # What takes turns: each hardware, with each of the controller's priorities (the robot
    # side has no controller node).
    variants = {}
    for hardware in args.hardware:
        for priority in ([0] if hardware == 'robot' else priorities):
            name = hardware if hardware == 'robot' or len(priorities) == 1 else \
                f'{hardware} controller {priority}'
            variants[name] = (hardware, priority)
    if args.robot_cpus:
        # Every other process of the sessions inherits this one's CPUs; the busy ones are
        # pinned to each core all the same.
        os.sched_setaffinity(0, set(range(os.cpu_count() or 1)) - parse_cpus(args.robot_cpus))
    on_this_machine()
    runs = []
    with ExitStack() as stack:
        start_busy(stack.enter_context(Processes()), args.busy)
        softirq = raise_softirq_threads(parse_cpus(args.robot_cpus), args.softirq_priority) \
            if args.softirq_priority and args.robot_cpus else {}
        stack.callback(restore_threads, softirq)
        scratch = stack.enter_context(tempfile.TemporaryDirectory())
        for repeat in range(args.repeats):
            for name, (hardware, priority) in variants.items():
                folder = Path(args.folder or scratch) / f'{hardware}_{priority}_{repeat}'
                runs.append({'variant': name, 'repeat': repeat,
                             **run(hardware, priority, folder, args)})
                print(json.dumps(runs[-1]), flush=True)
    write_report(runs, args, describe_machine(),
                 f'bench/closed_loop.py {" ".join(sys.argv[1:])}')


def write_report(runs: list[dict[str, Any]], args: argparse.Namespace,
                 machine: dict[str, object], command: str) -> None:
    """Summarise the runs; write bench/results/NAME.{json,txt} and print the report."""
    summary = summarise(runs, args)
    lines = report(summary, args, machine, command)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f'{args.results}.json').write_text(json.dumps(
        {'machine': machine, 'command': command, 'arguments': vars(args), 'summary': summary,
         'runs': runs}, indent=1, default=str) + '\n')
    (RESULTS / f'{args.results}.txt').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))


if __name__ == '__main__':
    main()
