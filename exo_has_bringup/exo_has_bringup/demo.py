"""``exo-has demo``: a walking-then-squatting session of the simulated exoskeleton, reported.

Four HAS plants (or, with ``--hardware can``, the hardware driver in front of simulated CAN
drives and sensor boards), the PD controller, the gait publisher, the safety watchdog and the
recorder run as processes (with ``--hardware robot``, the robot loop and its bridge in place
of the driver, the controller and the watchdog) (no launch file; the four plants share one, see
:data:`exo_has_bringup.plan.COMPOSITION`) for about 20 s; the bag goes under
``bags/`` and a Markdown report with PNG plots next to it. The last line printed is the
report's path. Exit status: 0; :data:`STOPPED` when the session ended in a FATAL stop (still
latched at its end); :data:`FAILED` when a node did not exit cleanly, or the demo could not
start; 128 + N when signal N ended it.
"""

from __future__ import annotations

import argparse
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from exo_has_bringup.analysis import RecordedEvent, final_stop, read_session
from exo_has_bringup.errors import DomainInUseError, HostsUnavailableError
from exo_has_bringup.plan import HARDWARE, SessionConfig
from exo_has_bringup.report import write_report
from exo_has_bringup.runner import (
    Session,
    SessionInterrupted,
    interrupt_on_signals,
    refuse_if_occupied,
)

#: Exit status of a demo whose session ended in a FATAL stop.
STOPPED = 3
#: Exit status of a demo one of whose nodes did not exit cleanly (or that could not start).
FAILED = 1


def warm_up() -> float:
    """Compile (or load) the plant model's machine code once; return the seconds it took."""
    from exo_has_sim.plant import Plant

    start = time.monotonic()
    Plant('left_hip', 'hip').warm_up()
    return time.monotonic() - start


@dataclass(frozen=True)
class LinkFaults:
    """Faults on the link of a two-host demo, times from the first trial's start [s].

    Attributes
    ----------
    loss : float
        Share of the packets dropped each way, from ``loss_at`` on (0: none).
    loss_at : float
        When the loss starts.
    partition_at, partition_s : float or None
        When the link goes down, and for how long (None: no partition).
    reset_after : float or None
        Seconds after the link is back at which the operator asks for a reset (None: never).

    """

    loss: float = 0.0
    loss_at: float = 0.0
    partition_at: float | None = None
    partition_s: float = 2.0
    reset_after: float | None = 1.0

    def actions(self, session: Session) -> list[tuple[float, str, Callable[[], object]]]:
        """Return the session's timed actions that inject these faults."""
        hosts = session.hosts
        if hosts is None:
            return []
        done: list[tuple[float, str, Callable[[], object]]] = []
        if self.loss > 0.0:
            done.append((self.loss_at, f'link: losing {self.loss:.0%} of the packets each way',
                         lambda: hosts.set_loss(self.loss)))
        if self.partition_at is not None:
            back = self.partition_at + self.partition_s
            done.append((self.partition_at, f'link: down for {self.partition_s:g} s',
                         hosts.cut))
            done.append((back, 'link: up again', hosts.restore))
            if self.reset_after is not None:
                done.append((back + self.reset_after, 'operator: reset', session.reset))
        return done


@dataclass(frozen=True)
class Outcome:
    """How a demo session ended.

    Attributes
    ----------
    report : Path
        The report's path.
    stop : RecordedEvent or None
        The FATAL event whose stop still held at the end (:func:`final_stop`), None if none.
    failed : dict[str, int]
        Exit codes of the nodes that did not exit cleanly, by node name.

    """

    report: Path
    stop: RecordedEvent | None
    failed: dict[str, int]

    @property
    def status(self) -> int:
        """The demo's exit status: :data:`STOPPED`, :data:`FAILED` or 0."""
        return STOPPED if self.stop is not None else FAILED if self.failed else 0


def run(config: SessionConfig, folder: Path, faults: LinkFaults | None = None) -> Outcome:
    """Run a session into folder, write its report; return how it ended."""
    trials = ', '.join(f'{m} {d:g} s'
                       for m, d in zip(config.motions, config.durations, strict=True))
    joints = {'can': 'the hardware driver on simulated CAN devices',
              'robot': 'the robot loop and its bridge on simulated CAN devices'}.get(
                  config.hardware, 'four plant nodes')
    print(f'exo-has demo: {trials} at {config.rate:g} Hz, {joints}, into {folder}', flush=True)
    print(f'plant model ready in {warm_up():.1f} s (compiled once, then cached)', flush=True)
    refuse_if_occupied(config)
    session = Session(config, folder)
    session.start(show=lambda line: print(f'  {line}', flush=True))
    try:
        session.run(show=lambda line: print(f'  {line}', flush=True),
                    actions=(faults or LinkFaults()).actions(session))
    finally:
        codes = session.stop()
    failed = {name: code for name, code in codes.items() if code != 0}
    notes = [f'Joints: {joints}.', '']
    if session.robot_bag is not None:
        notes += [f'Two hosts: the robot side recorded its own bag, `{session.robot_bag}`.', '']
    if failed:
        notes += [f'Nodes that did not exit cleanly: {failed} (logs in `{session.logs}`).', '']
        print(f'exo-has demo: nodes that did not exit cleanly: {failed}', flush=True)
    assert session.bag is not None
    data = read_session(session.bag)
    report = write_report(data, folder / 'report', config.motions, config.durations,
                          bag=session.bag, notes=notes, files=config.params or None)
    return Outcome(report, final_stop(data.events), failed)


def build_parser() -> argparse.ArgumentParser:
    """Return the command line's parser (tests parse the documentation's commands with it)."""
    parser = argparse.ArgumentParser(prog='exo-has demo', description=__doc__.splitlines()[0])
    parser.add_argument('--motions', nargs='+', default=['walk', 'squat'],
                        choices=['walk', 'squat', 'stand'], help='trials in order (walk squat)')
    parser.add_argument('--durations', nargs='+', type=float, default=[10.0, 8.0],
                        help='length of each trial in s (10 8)')
    parser.add_argument('--rate', type=float, default=200.0,
                        help="plant and reference rate in Hz (200, the paper's)")
    parser.add_argument('--output', type=Path, default=Path('bags'),
                        help='folder for the session folder (bags/)')
    parser.add_argument('--hardware', choices=HARDWARE, default='plants',
                        help='what moves the joints: plant nodes (plants); the hardware '
                             'driver, the PD controller and the watchdog on a simulated CAN bus '
                             'with simulated drives and sensor boards (can); or the robot loop '
                             'and its bridge on the same bus (robot)')
    parser.add_argument('--hosts', type=int, choices=[1, 2], default=1,
                        help='2: the robot side (joints, controller, watchdog, a recorder) and '
                             "the operator's (gait publisher, recorder) on two virtual hosts "
                             'joined by a link (root only)')
    parser.add_argument('--loss', type=float, default=0.0, metavar='SHARE',
                        help='with --hosts 2: drop this share of the packets each way (0-1)')
    parser.add_argument('--loss-at', type=float, default=0.0, metavar='S',
                        help='when the loss starts, in s from the first trial (0)')
    parser.add_argument('--partition', type=float, nargs=2, metavar=('AT', 'SECONDS'),
                        help='with --hosts 2: the link down at AT s for SECONDS s')
    parser.add_argument('--reset-after', type=float, default=1.0, metavar='S',
                        help='the operator resets S s after the link is back (1; negative: '
                             'never)')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the arguments and run the demo."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if len(args.motions) != len(args.durations):
        parser.error('give one duration per motion')
    if args.hosts == 1 and (args.loss or args.partition):
        parser.error('--loss and --partition act on the link of --hosts 2')
    if not 0.0 <= args.loss <= 1.0:
        parser.error('--loss is a share within 0 to 1')
    if args.partition and not (args.partition[0] >= 0.0 and args.partition[1] > 0.0):
        parser.error('--partition AT SECONDS: AT at least 0, SECONDS positive')
    if any(not d > 0 for d in args.durations) or not 1.0 <= args.rate <= 2000.0:
        parser.error('durations must be positive and the rate within 1 to 2000 Hz')
    folder = (args.output / f'demo_{datetime.now():%Y%m%d_%H%M%S}').resolve()
    config = SessionConfig(tuple(args.motions), tuple(args.durations), args.rate,
                           hardware=args.hardware, hosts=args.hosts)
    faults = LinkFaults(args.loss, args.loss_at,
                        args.partition[0] if args.partition else None,
                        args.partition[1] if args.partition else 0.0,
                        args.reset_after if args.reset_after >= 0.0 else None)
    try:
        with interrupt_on_signals():
            outcome = run(config, folder, faults)
    except (DomainInUseError, HostsUnavailableError) as exc:
        print(f'exo-has demo: not started: {exc}', file=sys.stderr, flush=True)
        return FAILED
    except KeyboardInterrupt as exc:
        signum = exc.signum if isinstance(exc, SessionInterrupted) else signal.SIGINT
        print(f'exo-has demo: interrupted by {signal.Signals(signum).name}: every node stopped, '
              f'no report; the bag (if it was started) is in {folder / "bag"}', flush=True)
        return 128 + signum
    print(f'exo-has demo: bag {folder / "bag"}')
    if outcome.stop is not None:
        print(f'exo-has demo: the session ended in a FATAL stop ({outcome.stop.text}); exit '
              f'status {STOPPED}', flush=True)
    print(outcome.report)
    return outcome.status


if __name__ == '__main__':
    sys.exit(main())
