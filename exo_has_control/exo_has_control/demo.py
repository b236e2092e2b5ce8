"""``exo-has demo``: a walking-then-squatting session of the simulated exoskeleton, reported.

Four HAS plants (or, with ``--hardware can``, the hardware driver in front of simulated CAN
drives and sensor boards), the PD controller, the gait publisher, the safety watchdog and the
recorder run as processes (no launch file; the four plants share one, see
:data:`exo_has_control.session.COMPOSITION`) for about 20 s; the bag goes under
``bags/`` and a Markdown report with PNG plots next to it. The last line printed is the
report's path.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from collections.abc import Sequence
from datetime import datetime
from pathlib import Path

from exo_has_control.analysis import read_session
from exo_has_control.errors import DomainInUseError
from exo_has_control.report import write_report
from exo_has_control.session import (
    Session,
    SessionConfig,
    SessionInterrupted,
    interrupt_on_signals,
    refuse_if_occupied,
)


def warm_up() -> float:
    """Compile (or load) the plant model's machine code once; return the seconds it took."""
    from exo_has_sim.plant import Plant

    start = time.monotonic()
    Plant('left_hip', 'hip').warm_up()
    return time.monotonic() - start


def run(config: SessionConfig, folder: Path) -> Path:
    """Run a session into folder, write its report; return the report's path."""
    trials = ', '.join(f'{m} {d:g} s'
                       for m, d in zip(config.motions, config.durations, strict=True))
    joints = ('the hardware driver on simulated CAN devices' if config.hardware == 'can'
              else 'four plant nodes')
    print(f'exo-has demo: {trials} at {config.rate:g} Hz, {joints}, into {folder}', flush=True)
    print(f'plant model ready in {warm_up():.1f} s (compiled once, then cached)', flush=True)
    refuse_if_occupied(config)
    session = Session(config, folder)
    session.start(show=lambda line: print(f'  {line}', flush=True))
    try:
        session.run(show=lambda line: print(f'  {line}', flush=True))
    finally:
        codes = session.stop()
    failed = {name: code for name, code in codes.items() if code != 0}
    notes = [f'Joints: {joints}.', '']
    if failed:
        notes += [f'Nodes that did not exit cleanly: {failed} (logs in `{session.logs}`).', '']
        print(f'exo-has demo: nodes that did not exit cleanly: {failed}', flush=True)
    assert session.bag is not None
    data = read_session(session.bag)
    return write_report(data, folder / 'report', config.motions, config.durations,
                        bag=session.bag, notes=notes)


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the arguments and run the demo."""
    parser = argparse.ArgumentParser(prog='exo-has demo', description=__doc__.splitlines()[0])
    parser.add_argument('--motions', nargs='+', default=['walk', 'squat'],
                        choices=['walk', 'squat', 'stand'], help='trials in order (walk squat)')
    parser.add_argument('--durations', nargs='+', type=float, default=[10.0, 8.0],
                        help='length of each trial in s (10 8)')
    parser.add_argument('--rate', type=float, default=200.0,
                        help="plant and reference rate in Hz (200, the paper's)")
    parser.add_argument('--output', type=Path, default=Path('bags'),
                        help='folder for the session folder (bags/)')
    parser.add_argument('--hardware', choices=['plants', 'can'], default='plants',
                        help='what moves the joints: plant nodes (plants), or the hardware '
                             'driver on a simulated CAN bus with simulated drives and sensor '
                             'boards (can)')
    args = parser.parse_args(argv)
    if len(args.motions) != len(args.durations):
        parser.error('give one duration per motion')
    if any(not d > 0 for d in args.durations) or not 1.0 <= args.rate <= 2000.0:
        parser.error('durations must be positive and the rate within 1 to 2000 Hz')
    folder = (args.output / f'demo_{datetime.now():%Y%m%d_%H%M%S}').resolve()
    config = SessionConfig(tuple(args.motions), tuple(args.durations), args.rate,
                           hardware=args.hardware)
    try:
        with interrupt_on_signals():
            report = run(config, folder)
    except DomainInUseError as exc:
        print(f'exo-has demo: not started: {exc}', file=sys.stderr, flush=True)
        return 1
    except KeyboardInterrupt as exc:
        signum = exc.signum if isinstance(exc, SessionInterrupted) else signal.SIGINT
        print(f'exo-has demo: interrupted by {signal.Signals(signum).name}: every node stopped, '
              f'no report; the bag (if it was started) is in {folder / "bag"}', flush=True)
        return 128 + signum
    print(f'exo-has demo: bag {folder / "bag"}')
    print(report)
    return 0


if __name__ == '__main__':
    sys.exit(main())
