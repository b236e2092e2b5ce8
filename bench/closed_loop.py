"""Benchmark: tracking of the closed loop through plant nodes and through the CAN driver.

The same walking-then-squatting session (PD controller, gait publisher, watchdog, recorder)
runs with the joints as plant nodes (issue 4) and as simulated COPLEY-like drives and sensor
boards behind the hardware driver on a udp_multicast CAN bus (issue 6), the two taking turns
``--repeats`` times. For each joint and trial it reports the tracking error (actual minus
reference joint angle, deg: RMS, minimum, maximum; the median over the repeats) side by side,
with the whole system's CPU share (percent of one core, /proc over the middle of the trials)
the FATAL events, the rate at which each joint's state was published (Hz, the lowest of
the four) and the longest gap between two of a joint's commands (ms, the longest of the four
over the trials: a period without control).

Run: ``.venv/bin/python bench/closed_loop.py [--repeats 3] [--rate 200] [--results NAME]``
(results in ``bench/results/NAME.{json,txt}``, ``closed_loop`` by default). The conditions of
``test/test_can_session.py``: ``--hardware can --rate 100 --stride-frequency 0.4
--realtime-priority 20 --walk-from 1``; ``--busy`` adds a process that spins on one core
for the whole run, as a loaded machine would. ``--controller-priority 0 20`` runs each
hardware with the controller's thread at each of those SCHED_FIFO priorities in turn (by default
at ``--realtime-priority``, as the sessions run it).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from common import describe_machine, on_this_machine, trial_cpu_shares

from exo_has_bringup.analysis import rates, read_session, tracking
from exo_has_bringup.plan import SessionConfig
from exo_has_bringup.report import segments_of
from exo_has_bringup.runner import Session

RESULTS = Path(__file__).resolve().parent / 'results'
MOTIONS, DURATIONS = ('walk', 'squat'), (10.0, 8.0)
HARDWARE = ('plants', 'can')


def run(hardware: str, controller_priority: int, folder: Path,
        args: argparse.Namespace) -> dict[str, Any]:
    """One session; its tracking rows, CPU share, FATAL events, lowest state rate."""
    session = Session(SessionConfig(
        MOTIONS, DURATIONS, args.rate, hardware=hardware,
        realtime_priority=args.realtime_priority,
        node_arguments={'gait_publisher': ('-p', f'stride_frequency:={args.stride_frequency}'),
                        'pd_controller': ('-p', f'realtime_priority:={controller_priority}')}),
        folder)
    session.start(show=lambda line: None)
    try:
        shares = trial_cpu_shares(session, sum(DURATIONS))
    finally:
        session.stop()
    assert session.bag is not None
    data = read_session(session.bag)
    windows = [(name, start + (args.walk_from if name.endswith('walk') else 0.0), end)
               for name, start, end in segments_of(MOTIONS, DURATIONS)]
    rows = tracking(data, windows)
    trials = (data.start, data.start + sum(DURATIONS))
    gaps = [np.diff(t[(t >= trials[0]) & (t <= trials[1])])
            for t in (data.commands[joint]['t'] for joint in data.commands)]
    return {
        'hardware': hardware,
        'controller_priority': controller_priority,
        'command_gap_ms': 1e3 * max((float(gap.max()) for gap in gaps if gap.size),
                                    default=float('nan')),
        'tracking_deg': {f'{r.joint} {r.segment}': {'rms': r.rms, 'min': r.minimum,
                                                     'max': r.maximum} for r in rows},
        'cpu_percent': {name: round(share, 1) for name, share in shares.items()},
        'fatal_events': sum(1 for e in data.events if e.severity >= 3),
        'state_rate_hz': min(value for topic, value in rates(data).items()
                             if topic.endswith('/has_state')),
    }


def main() -> None:
    """Run the sessions and write bench/results/NAME.{json,txt}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--rate', type=float, default=200.0, help='session rate [Hz]')
    parser.add_argument('--results', default='closed_loop', help='name of the results files')
    parser.add_argument('--hardware', nargs='+', choices=HARDWARE, default=list(HARDWARE),
                        help='joints as plant nodes, behind the CAN driver, or both in turn')
    parser.add_argument('--stride-frequency', type=float, default=0.85,
                        help='walking strides per second [Hz] (the paper: 0.85)')
    parser.add_argument('--realtime-priority', type=int, default=0,
                        help="SCHED_FIFO priority of the plants, or of the driver's bus "
                             'thread and the CAN devices (0: the default scheduler)')
    parser.add_argument('--walk-from', type=float, default=0.0,
                        help='time into the walk from which its tracking is judged [s]')
    parser.add_argument('--busy', action='store_true',
                        help='a process spinning on one core beside the sessions')
    parser.add_argument('--controller-priority', type=int, nargs='+',
                        help="SCHED_FIFO priorities of the controller's thread to take turns "
                             'with (default: --realtime-priority)')
    args = parser.parse_args()
    priorities = args.controller_priority or [args.realtime_priority]
    # What takes turns: each hardware, with each of the controller's priorities.
    variants = {(f'{hardware} controller {priority}' if len(priorities) > 1 else hardware):
                (hardware, priority) for hardware in args.hardware for priority in priorities}
    on_this_machine()
    runs = []
    busy = subprocess.Popen([sys.executable, '-c', 'while True: pass']) if args.busy else None
    try:
        with tempfile.TemporaryDirectory() as scratch:
            for repeat in range(args.repeats):
                for name, (hardware, priority) in variants.items():
                    folder = Path(scratch) / f'{hardware}_{priority}_{repeat}'
                    runs.append({'variant': name, **run(hardware, priority, folder, args)})
                    print(json.dumps(runs[-1]), flush=True)
    finally:
        if busy is not None:
            busy.kill()
            busy.wait()
    machine = describe_machine()
    medians: dict[str, dict[str, dict[str, float]]] = {}
    for name in variants:
        mine = [r for r in runs if r['variant'] == name]
        rows = [r['tracking_deg'] for r in mine]
        medians[name] = {key: {stat: float(np.median([row[key][stat] for row in rows]))
                               for stat in ('rms', 'min', 'max')} for key in rows[0]}
        for key in rows[0]:  # the worst over the repeats, as a test's bound sees it
            medians[name][key]['worst_peak'] = float(max(
                max(-row[key]['min'], row[key]['max']) for row in rows))
        medians[name]['system'] = {
            'cpu_percent': float(np.median([sum(r['cpu_percent'].values()) for r in mine])),
            'fatal_events': float(sum(r['fatal_events'] for r in mine)),
            'state_rate_hz': float(min(r['state_rate_hz'] for r in mine)),
            'command_gap_ms': float(np.median([r['command_gap_ms'] for r in mine])),
            'worst_command_gap_ms': float(max(r['command_gap_ms'] for r in mine))}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f'{args.results}.json').write_text(json.dumps(
        {'machine': machine, 'arguments': vars(args), 'medians': medians, 'runs': runs},
        indent=1) + '\n')
    lines = [f'bench/closed_loop.py {" ".join(sys.argv[1:])}: {machine}',
             'tracking error [deg], median over the repeats (and the worst peak of any '
             f'repeat): {" | ".join(variants)}',
             f'{"joint trial":24s}' + ' |'.join(
                 f' {"rms":>6s} {"min":>6s} {"max":>6s} {"worst":>6s}' for _ in variants)]
    first = next(iter(variants))
    for key in medians[first]:
        if key == 'system':
            continue
        lines.append(f'{key:24s}' + ' |'.join(
            ' {rms:6.2f} {min:6.2f} {max:6.2f} {worst_peak:6.2f}'.format(**medians[v][key])
            for v in variants))
    for name in variants:
        system = medians[name]['system']
        lines.append(f'{name}: whole system {system["cpu_percent"]:.1f} % of one core '
                     f'(median), FATAL events in all runs: {system["fatal_events"]:.0f}, '
                     f'state published at {system["state_rate_hz"]:.1f} Hz at least, '
                     f'longest gap between commands {system["command_gap_ms"]:.1f} ms '
                     f'(median; worst {system["worst_command_gap_ms"]:.1f} ms)')
    (RESULTS / f'{args.results}.txt').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))


if __name__ == '__main__':
    main()
