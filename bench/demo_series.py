"""Benchmark: demo sessions back to back, and the safety events, rates and tracking of each.

Runs ``exo-has demo`` (:func:`exo_has_control.demo.run`, walking 10 s then squatting 8 s at
200 Hz on the four plant nodes, with its report) ``--sessions`` times in a row, then reads each
bag: every safety event of severity ERROR or FATAL (none is expected: the demo has no fault),
the rate of each joint's HAS state and command topics over the recording, and the tracking
peaks.
The printout and ``bench/results/demo_series.{json,txt}`` hold one line per session
(``demo_series_can.*`` with ``--hardware can``: the hardware driver on simulated CAN devices
in place of the plant nodes).

Run (in ``./run shell``): ``python bench/demo_series.py [--sessions 10] [--hardware can]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import tempfile
from pathlib import Path

from common import describe_machine, on_this_machine, write_results

from exo_has_control.analysis import rates, read_session, tracking
from exo_has_control.demo import run
from exo_has_control.report import segments_of
from exo_has_control.session import SessionConfig
from exo_has_runtime.joints import JOINT_NAMES

ERROR = 2  # SafetyEvent severity: ERROR and FATAL count


def session_figures(config: SessionConfig, folder: Path) -> dict[str, object]:
    """Run one demo session into folder; its events, rates and tracking peaks."""
    run(config, folder)
    data = read_session(folder / 'bag')
    rows = tracking(data, segments_of(config.motions, config.durations))
    rate = rates(data)
    return {
        'events': [e.text for e in data.events if e.severity >= ERROR],
        'state_rate_hz': {joint: round(rate.get(f'/{joint}/has_state', 0.0), 2)
                          for joint in JOINT_NAMES},
        'command_rate_hz': {joint: round(rate.get(f'/{joint}/has_command', 0.0), 2)
                            for joint in JOINT_NAMES},
        'tracking_peak_deg': {f'{r.joint} {r.segment}': round(r.peak, 2) for r in rows},
    }


def main() -> None:
    """Run the sessions and write bench/results/demo_series.{json,txt}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--sessions', type=int, default=10)
    parser.add_argument('--hardware', choices=('plants', 'can'), default='plants')
    args = parser.parse_args()
    on_this_machine()
    config = dataclasses.replace(SessionConfig(), hardware=args.hardware)
    results = []
    with tempfile.TemporaryDirectory() as scratch:
        for k in range(args.sessions):
            results.append(session_figures(config, Path(scratch) / f'demo_{k}'))
            print(json.dumps(results[-1]), flush=True)
    lines = [f'bench/demo_series.py --sessions {args.sessions} --hardware {args.hardware}: '
             f'{describe_machine()}']
    for k, r in enumerate(results):
        events, states, commands = r['events'], r['state_rate_hz'], r['command_rate_hz']
        assert isinstance(events, list)
        assert isinstance(states, dict) and isinstance(commands, dict)
        lines.append(f'session {k + 1}: {len(events)} ERROR/FATAL events '
                     f'{events}; state rates {min(states.values())}-'
                     f'{max(states.values())} Hz, command rates {min(commands.values())}-'
                     f'{max(commands.values())} Hz; tracking peaks {r["tracking_peak_deg"]}')
    clean = sum(1 for r in results if not r['events'])
    lines.append(f'{clean} of {len(results)} sessions without an ERROR or FATAL event')
    name = 'demo_series' if args.hardware == 'plants' else f'demo_series_{args.hardware}'
    write_results(name, {'hardware': args.hardware, 'sessions': results}, lines)


if __name__ == '__main__':
    main()
