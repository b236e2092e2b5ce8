"""Benchmark: tracking of the closed loop through plant nodes and through the CAN driver.

The same walking-then-squatting session (PD controller, gait publisher, watchdog, recorder)
runs with the joints as plant nodes (issue 4) and as simulated COPLEY-like drives and sensor
boards behind the hardware driver on a udp_multicast CAN bus (issue 6), the two taking turns
``--repeats`` times. For each joint and trial it reports the tracking error (actual minus
reference joint angle, deg: RMS, minimum, maximum; the median over the repeats) side by side,
with the whole system's CPU share (percent of one core, /proc over the middle of the trials)
the FATAL events and the rate at which each joint's state was published (Hz, the lowest of
the four).

Run: ``.venv/bin/python bench/closed_loop.py [--repeats 3] [--rate 200] [--results NAME]``
(results in ``bench/results/NAME.{json,txt}``, ``closed_loop`` by default).
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from common import describe_machine, on_this_machine, trial_cpu_shares

from exo_has_control.analysis import rates, read_session, tracking
from exo_has_control.report import segments_of
from exo_has_control.session import Session, SessionConfig

RESULTS = Path(__file__).resolve().parent / 'results'
MOTIONS, DURATIONS = ('walk', 'squat'), (10.0, 8.0)


def run(hardware: str, folder: Path, rate: float) -> dict[str, Any]:
    """One session at ``rate`` [Hz]; its tracking rows, CPU share, FATAL events, state rate."""
    session = Session(SessionConfig(MOTIONS, DURATIONS, rate, hardware=hardware), folder)
    session.start(show=lambda line: None)
    try:
        shares = trial_cpu_shares(session, sum(DURATIONS))
    finally:
        session.stop()
    assert session.bag is not None
    data = read_session(session.bag)
    rows = tracking(data, segments_of(MOTIONS, DURATIONS))
    return {
        'hardware': hardware,
        'tracking_deg': {f'{r.joint} {r.segment}': {'rms': r.rms, 'min': r.minimum,
                                                     'max': r.maximum} for r in rows},
        'cpu_percent': {name: round(share, 1) for name, share in shares.items()},
        'fatal_events': sum(1 for e in data.events if e.severity >= 3),
        'state_rate_hz': min(value for topic, value in rates(data).items()
                             if topic.endswith('/has_state')),
    }


def main() -> None:
    """Run the sessions and write bench/results/closed_loop.{json,txt}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--rate', type=float, default=200.0, help='session rate [Hz]')
    parser.add_argument('--results', default='closed_loop', help='name of the results files')
    args = parser.parse_args()
    on_this_machine()
    runs = []
    with tempfile.TemporaryDirectory() as scratch:
        for repeat in range(args.repeats):
            for hardware in ('plants', 'can'):
                runs.append(run(hardware, Path(scratch) / f'{hardware}_{repeat}', args.rate))
                print(json.dumps(runs[-1]), flush=True)
    machine = describe_machine()
    medians: dict[str, dict[str, dict[str, float]]] = {}
    for hardware in ('plants', 'can'):
        mine = [r for r in runs if r['hardware'] == hardware]
        rows = [r['tracking_deg'] for r in mine]
        medians[hardware] = {key: {stat: float(np.median([row[key][stat] for row in rows]))
                                   for stat in ('rms', 'min', 'max')} for key in rows[0]}
        medians[hardware]['system'] = {
            'cpu_percent': float(np.median([sum(r['cpu_percent'].values()) for r in mine])),
            'fatal_events': float(sum(r['fatal_events'] for r in mine)),
            'state_rate_hz': float(min(r['state_rate_hz'] for r in mine))}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f'{args.results}.json').write_text(
        json.dumps({'machine': machine, 'medians': medians, 'runs': runs}, indent=1) + '\n')
    lines = [f'bench/closed_loop.py --repeats {args.repeats} --rate {args.rate:g}: {machine}',
             'tracking error [deg], median over the repeats: plant nodes | CAN driver',
             f'{"joint trial":24s} {"rms":>6s} {"min":>6s} {"max":>6s} | '
             f'{"rms":>6s} {"min":>6s} {"max":>6s}']
    for key in medians['plants']:
        if key == 'system':
            continue
        p, c = medians['plants'][key], medians['can'][key]
        lines.append(f'{key:24s} {p["rms"]:6.2f} {p["min"]:6.2f} {p["max"]:6.2f} | '
                     f'{c["rms"]:6.2f} {c["min"]:6.2f} {c["max"]:6.2f}')
    for hardware in ('plants', 'can'):
        system = medians[hardware]['system']
        lines.append(f'{hardware}: whole system {system["cpu_percent"]:.1f} % of one core '
                     f'(median), FATAL events in all runs: {system["fatal_events"]:.0f}, '
                     f'state published at {system["state_rate_hz"]:.1f} Hz at least')
    (RESULTS / f'{args.results}.txt').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))


if __name__ == '__main__':
    main()
