"""Benchmark: the whole exoskeleton as processes, at 200 Hz (the paper's rate) and at 1 kHz.

CPU share, reference-to-state latency and missed periods.

Each run is a walking session (four plants, PD controller, gait publisher, watchdog, recorder)
of ``--duration`` seconds. CPU shares come from /proc/<pid>/stat over the middle of the trial
(utime + stime, as a percentage of one core). The latency of a command is the time from the
stamp of the newest reference the controller had (the newest reference stamped before the
command) to the stamp of the first plant state that carries the command: reference age plus
the wait for the plant's next period. Missed periods are the plants' own counts (a period
whose tick came later than one period after the one before).

Run: ``.venv/bin/python bench/system.py [--duration 30] [--rates 200 1000]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import re
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(100, 200)))
os.environ.pop('CYCLONEDDS_URI', None)
os.environ['EXO_HAS_BACKEND'] = 'standalone'

from exo_has_control.analysis import read_session
from exo_has_control.session import Session, SessionConfig
from exo_has_runtime.topics import JOINT_NAMES

RESULTS = Path(__file__).resolve().parent / 'results'
TICK = os.sysconf('SC_CLK_TCK')


def cpu_seconds(pid: int) -> float:
    """User plus system CPU time of a process [s]."""
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK


def latencies(bag: Path) -> np.ndarray:
    """Reference-to-state latency of every command [s] (see the module docstring)."""
    data = read_session(bag)
    result = []
    for joint in JOINT_NAMES:
        commands, states = data.commands[joint], data.states[joint]
        index = {}
        for t, command in zip(states['t'], states['motor_speed_command'], strict=True):
            index.setdefault(float(command), []).append(float(t))
        for t_c, speed, enable in zip(commands['t'], commands['motor_speed'],
                                      commands['enable'], strict=True):
            k = np.searchsorted(data.reference_t, t_c, side='right') - 1
            applied = [t for t in index.get(float(speed), []) if t >= t_c]
            if k >= 0 and applied and enable:
                result.append(min(applied) - data.reference_t[k])
    return np.asarray(result)


def run(rate: float, duration: float, folder: Path) -> dict[str, object]:
    """One session at a rate; return its figures."""
    config = SessionConfig(('walk',), (duration,), rate)
    session = Session(config, folder)
    session.start(show=lambda line: None)
    try:
        assert session.started_at is not None
        time.sleep(max(0.0, session.started_at - time.monotonic()) + duration * 0.2)
        before = {name: cpu_seconds(p.process.pid) for name, p in session.processes.items()}
        t0 = time.monotonic()
        time.sleep(duration * 0.6)
        span = time.monotonic() - t0
        after = {name: cpu_seconds(p.process.pid) for name, p in session.processes.items()}
        time.sleep(max(0.0, session.started_at + duration + 0.5 - time.monotonic()))
    finally:
        session.stop()
    shares = {name: 100.0 * (after[name] - before[name]) / span for name in before}
    periods = missed = 0
    for joint in JOINT_NAMES:
        match = re.search(r'(\d+) periods, (\d+) missed', session.output(f'{joint}_plant'))
        assert match, session.output(f'{joint}_plant')
        periods += int(match.group(1))
        missed += int(match.group(2))
    assert session.bag is not None
    lat = latencies(session.bag)
    fatal = sum(1 for e in read_session(session.bag).events if e.severity >= 3)
    figures = ({'p50': round(float(np.median(lat)) * 1e3, 2),
                'p99': round(float(np.percentile(lat, 99)) * 1e3, 2),
                'max': round(float(lat.max()) * 1e3, 2), 'samples': int(lat.size)}
               if lat.size else {'p50': None, 'p99': None, 'max': None, 'samples': 0})
    return {
        'fatal_events': fatal,
        'rate_hz': rate, 'duration_s': duration,
        'cpu_percent_of_one_core': {k: round(v, 1) for k, v in shares.items()},
        'cpu_percent_total': round(sum(shares.values()), 1),
        'plant_periods': periods, 'plant_missed_periods': missed,
        'missed_percent': round(100.0 * missed / max(periods, 1), 3),
        'latency_ms': figures,
    }


def main() -> None:
    """Run the sessions and write bench/results/system.{json,txt}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--duration', type=float, default=30.0)
    parser.add_argument('--rates', type=float, nargs='+', default=[200.0, 1000.0])
    args = parser.parse_args()
    results = []
    with tempfile.TemporaryDirectory() as scratch:
        for rate in args.rates:
            results.append(run(rate, args.duration, Path(scratch) / f'rate_{rate:g}'))
            print(json.dumps(results[-1], indent=1), flush=True)
    machine = {'cpus': os.cpu_count(), 'machine': platform.machine(),
               'python': platform.python_version(), 'kernel': platform.release()}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / 'system.json').write_text(json.dumps({'machine': machine, 'runs': results},
                                                    indent=1) + '\n')
    lines = [f'bench/system.py --duration {args.duration:g}: {machine}']
    for r in results:
        lines.append(f"{r['rate_hz']:g} Hz: total CPU {r['cpu_percent_total']} % of one core, "
                     f"missed {r['plant_missed_periods']}/{r['plant_periods']} "
                     f"({r['missed_percent']} %), latency p50 {r['latency_ms']['p50']} ms "
                     f"p99 {r['latency_ms']['p99']} ms, fatal events {r['fatal_events']}; "
                     f"per node {r['cpu_percent_of_one_core']}")
    (RESULTS / 'system.txt').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))


if __name__ == '__main__':
    main()
