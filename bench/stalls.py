"""Where the stalls of a session come from: the node process, the CPU share, or the machine.

A *stall* is a gap of over ``--gap`` seconds in the header stamps of one of a session's
streams (a plant's states, the controller's commands per joint, the gait reference): the
process that stamps them stood still. Beside each session run two plain Python watchers with
no ROS in them, each sleeping 1 ms at a time and noting every wake-up later than ``--gap``:

- ``fifo`` at SCHED_FIFO priority 60 (above the nodes): no task of this machine can keep it
  from running, so its gaps are the machine's own (the hypervisor, the kernel);
- ``normal`` at the nodes' own priority: its gaps also count the time the nodes' load kept it
  off both CPUs.

A stream stall that overlaps a ``fifo`` gap is the machine's; one that overlaps only a
``normal`` gap is CPU contention; one that overlaps neither is the node process's own (its
GIL, a blocking call in DDS). The watchers also sample the machine's steal time.

``--gc-freeze on off`` runs the sessions with and without the nodes' freezing of their
start-up objects (``EXO_HAS_GC_FREEZE``, :func:`exo_has_runtime.execution.freeze_startup_objects`),
taking turns; ``--announcement-periods 3 0.5`` with each period of the participants'
announcements [s] (:func:`exo_has_runtime.dds.localhost_profile`), taking turns likewise;
``--background none idle spin`` without and with a diagnosis per core running all along at
the lowest CPU priority (``tools/at_idle_priority``: what running the suite's slow tests beside
its process tests would cost the nodes), or a bare loop per core at that priority, which only
keeps the CPUs busy, taking turns likewise.

Run (in ``./run shell``, as root): ``python bench/stalls.py --sessions 5``.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import NoReturn

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from common import machine_ticks, write_results

from exo_has_bringup.analysis import read_session
from exo_has_bringup.plan import SessionConfig
from exo_has_bringup.runner import Session
from exo_has_runtime.dds import localhost_profile, write_profile
from exo_has_runtime.processes import Processes

WATCH_PRIORITY = 60  # SCHED_FIFO: above the plants' real-time priority option (50)
ROOT = Path(__file__).resolve().parents[1]
#: What ``--background idle`` diagnoses over and over: the worked example's bag.
EXAMPLE = ROOT / 'bags' / 'example_diagnosis'


def watch(gap_s: float, duration_s: float, fifo: bool) -> dict[str, object]:
    """Sleep 1 ms at a time for ``duration_s``; every wake-up later than ``gap_s`` [s].

    Returns the gaps as ``[start, length]`` pairs (wall clock [s]) and the steal and total
    CPU ticks of the machine over the run.
    """
    if fifo:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(WATCH_PRIORITY))
    _, steal0, total0 = machine_ticks()
    gaps: list[list[float]] = []
    end = time.time() + duration_s
    before = time.time()
    while before < end:
        time.sleep(0.001)
        now = time.time()
        if now - before > gap_s:
            gaps.append([before, now - before])
        before = now
    _, steal1, total1 = machine_ticks()
    return {'gaps': gaps, 'steal_ticks': steal1 - steal0, 'total_ticks': total1 - total0}


def spin() -> NoReturn:
    """Keep a CPU busy, touching no memory, until killed."""
    while True:
        pass


def burn(folder: Path) -> NoReturn:
    """Diagnose the worked example's bag over and over (``exo-has diagnose``) until killed."""
    from exo_has_sim.diagnosis.cli import main as diagnose

    while True:
        diagnose([str(EXAMPLE / 'bag'), '--joint', 'left_hip', '--params',
                  str(ROOT / 'test' / 'bench_rig' / 'hip.yaml'), '--load-mass', '50',
                  '--json', str(folder / f'{os.getpid()}.json'), '-q'])


def stream_stalls(bag: Path, gap_s: float) -> list[tuple[str, float, float]]:
    """Every gap of over ``gap_s`` [s] in a session's stamped streams: (stream, start, length)."""
    data = read_session(bag)
    streams = {'reference': data.reference_t}
    streams.update({f'{joint} state': s['t'] for joint, s in data.states.items()})
    streams.update({f'{joint} command': s['t'] for joint, s in data.commands.items()})
    stalls = []
    for name, stamps in streams.items():
        steps = np.diff(stamps)
        stalls += [(name, float(stamps[i]), float(steps[i]))
                   for i in np.flatnonzero(steps > gap_s)]
    return sorted(stalls, key=lambda s: s[1])


def _overlaps(start: float, length: float, gaps: list[list[float]], slack: float) -> bool:
    return any(g0 < start + length + slack and start < g0 + g1 + slack for g0, g1 in gaps)


def run(folder: Path, gap_s: float, durations: tuple[float, float],
        gc_freeze: str = 'on', announcement_period: float | None = None,
        background: str = 'none') -> dict[str, object]:
    """One walking and squatting session with the two watchers; its stalls, classified.

    ``announcement_period`` [s]: the nodes on the LOCALHOST profile announcing so often (None:
    the environment's discovery settings as they are). ``background``: ``idle`` runs a
    diagnosis per core at the lowest CPU priority from before the session starts to its end,
    ``spin`` a bare loop per core so.
    """
    config = SessionConfig(('walk', 'squat'), durations, 200.0)
    env = {'EXO_HAS_GC_FREEZE': '1' if gc_freeze == 'on' else '0'}
    if announcement_period is not None:
        profile = write_profile(localhost_profile(announcement_period=announcement_period))
        env |= {'FASTRTPS_DEFAULT_PROFILES_FILE': str(profile),
                'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SYSTEM_DEFAULT'}
    session = Session(config, folder, env=env)
    with Processes() as processes:
        if background != 'none':
            work = ['--spin']
            if background == 'idle':
                burns = folder.with_name(f'{folder.name}-burn')  # the diagnoses' documents
                burns.mkdir(parents=True)
                work = ['--burn', str(burns)]
            for _ in range(os.cpu_count() or 1):
                processes.start([str(ROOT / 'tools' / 'at_idle_priority'), sys.executable,
                                 __file__, *work],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        started = time.monotonic()
        session.start(show=lambda line: None)
        bring_up = time.monotonic() - started
        try:
            assert session.started_at is not None
            span = session.started_at - time.monotonic() + sum(durations) + 1.0
            watchers = {
                kind: processes.start(
                    [sys.executable, __file__, '--watch', kind, '--gap', f'{gap_s}',
                     '--duration', f'{span:.2f}'], stdout=subprocess.PIPE, text=True)
                for kind in ('fifo', 'normal')}
            time.sleep(span + 0.5)
        finally:
            session.stop()
        seen = {kind: json.loads(p.communicate(timeout=30.0)[0]) for kind, p in watchers.items()}
    assert session.bag is not None
    stalls = []
    for name, start, length in stream_stalls(session.bag, gap_s):
        # A stream's gap spans from the tick before the stall to the one after it.
        if _overlaps(start, length, seen['fifo']['gaps'], 0.005):
            cause = 'machine'
        elif _overlaps(start, length, seen['normal']['gaps'], 0.005):
            cause = 'contention'
        else:
            cause = 'process'
        stalls.append({'stream': name, 'start': start, 'length_s': round(length, 3),
                       'cause': cause})
    return {'gc_freeze': gc_freeze, 'announcement_period_s': announcement_period,
            'background': background, 'bring_up_s': round(bring_up, 3), 'stalls': stalls,
            'events': stall_events(stalls), 'watchers': seen}


def stall_events(stalls: list[dict[str, object]]) -> list[dict[str, object]]:
    """Merge the stream stalls that overlap in time into events (one process stalls many streams).

    Each event: its start, length [s] and the worst cause among its streams' (machine over
    contention over process).
    """
    events: list[dict[str, object]] = []
    rank = {'machine': 2, 'contention': 1, 'process': 0}
    for stall in sorted(stalls, key=lambda s: float(s['start'])):
        start, length = float(stall['start']), float(stall['length_s'])
        if events and start <= float(events[-1]['start']) + float(events[-1]['length_s']):
            last = events[-1]
            end = max(float(last['start']) + float(last['length_s']), start + length)
            last['length_s'] = round(end - float(last['start']), 3)
            if rank[str(stall['cause'])] > rank[str(last['cause'])]:
                last['cause'] = stall['cause']
        else:
            events.append({'start': start, 'length_s': length, 'cause': stall['cause']})
    return events


def main() -> None:
    """Parse the arguments; run the sessions (or one watcher) and write the results."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--sessions', type=int, default=5)
    parser.add_argument('--gap', type=float, default=0.05, help='a stall is longer [s]')
    parser.add_argument('--durations', type=float, nargs=2, default=(8.0, 8.0),
                        metavar=('WALK', 'SQUAT'), help='trial lengths [s]')
    parser.add_argument('--gc-freeze', nargs='+', choices=('on', 'off'), default=['on'],
                        help='nodes freeze their start-up objects (EXO_HAS_GC_FREEZE), in turn')
    parser.add_argument('--announcement-periods', type=float, nargs='+', default=[None],
                        metavar='S', help="the participants' announcement period [s], in turn "
                        "(default: the environment's settings)")
    parser.add_argument('--background', nargs='+', choices=('none', 'idle', 'spin'),
                        default=['none'], help='beside the session, at the lowest CPU '
                        'priority, a diagnosis per core (idle), a bare loop per core (spin) '
                        'or nothing, in turn')
    parser.add_argument('--results', default='stalls', help='results file name')
    parser.add_argument('--watch', choices=('fifo', 'normal'), help=argparse.SUPPRESS)
    parser.add_argument('--duration', type=float, help=argparse.SUPPRESS)
    parser.add_argument('--burn', type=Path, help=argparse.SUPPRESS)
    parser.add_argument('--spin', action='store_true', help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.spin:
        spin()
    if args.burn:
        burn(args.burn)
    if args.watch:
        print(json.dumps(watch(args.gap, args.duration, args.watch == 'fifo')))
        return
    if os.geteuid() != 0:
        parser.error('run as root: the machine watcher needs SCHED_FIFO')
    sessions = []
    with tempfile.TemporaryDirectory() as folder:
        for index in range(args.sessions):
            for freeze in args.gc_freeze:
                for k, period in enumerate(args.announcement_periods):
                    for background in args.background:
                        sessions.append(run(Path(folder) / f's{index}{freeze}{k}{background}',
                                            args.gap, tuple(args.durations), freeze, period,
                                            background))
    lines = [f'{args.sessions} sessions, walk {args.durations[0]:g} s + squat '
             f'{args.durations[1]:g} s at 200 Hz; a stall is a gap over {args.gap * 1e3:g} ms']
    for index, result in enumerate(sessions):
        w = result['watchers']
        steal = 100.0 * w['normal']['steal_ticks'] / max(w['normal']['total_ticks'], 1)
        period = result['announcement_period_s']
        lines.append(f'session {index} (gc freeze {result["gc_freeze"]}, announcements '
                     f'{"as set" if period is None else f"every {period:g} s"}, background '
                     f'{result["background"]}, bring-up '
                     f'{result["bring_up_s"]:.1f} s): steal '
                     f'{steal:.1f} % of CPU time; watcher gaps '
                     f'fifo {len(w["fifo"]["gaps"])} (max '
                     f'{max((g[1] for g in w["fifo"]["gaps"]), default=0) * 1e3:.0f} ms), '
                     f'normal {len(w["normal"]["gaps"])} (max '
                     f'{max((g[1] for g in w["normal"]["gaps"]), default=0) * 1e3:.0f} ms)')
        for stall in result['stalls']:
            lines.append(f'  {stall["stream"]:<18} {stall["length_s"] * 1e3:6.0f} ms  '
                         f'{stall["cause"]}')
    for freeze in args.gc_freeze:
        for period, background in itertools.product(args.announcement_periods,
                                                     args.background):
            runs = [r for r in sessions
                    if r['gc_freeze'] == freeze and r['announcement_period_s'] == period
                    and r['background'] == background]
            causes = [s['cause'] for r in runs for s in r['stalls']]
            events = [e['cause'] for r in runs for e in r['events']]
            longest = [max((s['length_s'] for s in r['stalls']), default=0.0) for r in runs]
            lines.append(
                f'gc freeze {freeze}, announcements '
                f'{"as set" if period is None else f"every {period:g} s"}, background '
                f'{background}: stream stalls by '
                'cause: ' + ', '.join(f'{c} {causes.count(c)}'
                                      for c in ('machine', 'contention', 'process'))
                + '; events (overlapping stalls merged) by cause: ' + ', '.join(
                    f'{c} {events.count(c)}' for c in ('machine', 'contention', 'process'))
                + f'; per session: stalls median {np.median([len(r["stalls"]) for r in runs]):g}'
                f', events median {np.median([len(r["events"]) for r in runs]):g}, longest '
                f'stall median {np.median(longest) * 1e3:.0f} ms, bring-up median '
                f'{np.median([r["bring_up_s"] for r in runs]):.1f} s')
    write_results(args.results, {'command': ' '.join(sys.argv), 'gap_s': args.gap,
                                 'durations_s': list(args.durations), 'sessions': sessions},
                  lines)


if __name__ == '__main__':
    main()
