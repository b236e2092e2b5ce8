"""Benchmark: where the whole suite's time goes, run by run and module by module, and its floor.

``./run test`` runs pytest twice: the quick and slow tests on a worker per core (pytest-xdist,
a module's tests on one worker), then the process tests one at a time with the cores to
themselves. ``--durations`` gives wall times, which hide a diagnosis pool's CPU in its module's
setup and count the other worker's load in each. This runs the README's test command as it is,
with a plugin in every pytest process (suite_time_plugin.py) that charges each test module with
its CPU seconds, its own and its child processes', and reads each run's wall time and the
machine's busy cores.

It prints per run the wall, the busy and stolen cores, the CPU of its modules, and the floor of
its wall at this content: a run on several workers cannot end before its CPU is spread over
the cores, one on a single process is its wall. The modules follow by CPU. The sum of the floors
is what the suite takes here however its tests are scheduled, unless they do less work.

Usage (in a checkout whose set-up ``./run`` has made or will make):
``python bench/suite_time.py [--records FILE] [--top N] [-- PYTEST ARGS]``; with ``--records``
of an earlier run, only the summary. Results in bench/results/suite_time.{json,txt}.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from common import RESULTS, describe_machine, write_results
from suite_time_plugin import OUT_VARIABLE

from exo_has_runtime.processes import Processes

ROOT = Path(__file__).resolve().parent.parent
BENCH = Path(__file__).resolve().parent
#: The modules listed by CPU, the heaviest first.
TOP = 15
#: The fields of each kind of record (suite_time_plugin.py).
FIELDS = {'module': {'part', 'module', 'worker', 'self', 'children', 'wall', 'tests'},
          'run': {'part', 'wall', 'busy_cores', 'steal_cores', 'cores', 'workers', 'exit'}}


def read_records(path: Path) -> list[dict[str, Any]]:
    """Return the plugin's records in a file, in their order.

    Raises
    ------
    ValueError
        If a line is not one of the plugin's records.

    """
    records = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        try:
            record = json.loads(line)
        except json.JSONDecodeError as error:
            msg = f'{path}:{number}: not a record of suite_time_plugin: {error}'
            raise ValueError(msg) from None
        fields = FIELDS.get(record.get('kind')) if isinstance(record, dict) else None
        if fields is None or not fields <= set(record):
            msg = f'{path}:{number}: not a record of suite_time_plugin: {line[:80]!r}'
            raise ValueError(msg)
        records.append(record)
    return records


def summarise(records: list[dict[str, Any]]) -> dict[str, Any]:
    """Return each run's figures and floor, its modules by CPU, and the suite's sums.

    A run's CPU is its modules' (``self`` and ``children``). Its floor is that CPU over the cores
    its workers could use where it ran on more than one worker, else its wall.
    """
    modules: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for record in records:
        if record['kind'] == 'module':
            modules[record['part']].append(record)
    runs = []
    for run in (r for r in records if r['kind'] == 'run'):
        own = modules.get(run['part'], [])
        cpu = sum(m['self'] + m['children'] for m in own)
        workers = len({m['worker'] for m in own})
        parallel = run['workers'] > 1 and workers > 1
        floor = cpu / min(run['workers'], run['cores']) if parallel else run['wall']
        runs.append({**run, 'cpu': cpu, 'tests': sum(m['tests'] for m in own),
                     'floor': floor, 'parallel': parallel,
                     'modules': sorted(own, key=lambda m: -(m['self'] + m['children']))})
    return {'runs': runs, 'wall': sum(r['wall'] for r in runs),
            'floor': sum(r['floor'] for r in runs),
            'tests': sum(r['tests'] for r in runs)}


def report(summary: dict[str, Any], top: int) -> list[str]:
    """Return the summary as printed lines."""
    lines = ['| run (-m) | tests | wall [s] | busy cores | stolen | CPU [s] | floor [s] |',
             '|---|---|---|---|---|---|---|']
    for run in summary['runs']:
        how = f'CPU / {min(run["workers"], run["cores"])} cores' if run['parallel'] else 'wall'
        lines.append(f'| {run["part"] or "(all)"} | {run["tests"]} | {run["wall"]:.1f} | '
                     f'{run["busy_cores"]:.2f} | {run["steal_cores"]:.2f} | {run["cpu"]:.1f} | '
                     f'{run["floor"]:.1f} ({how}) |')
    lines += ['', f'suite: {summary["tests"]} tests, {summary["wall"]:.1f} s of pytest, floor '
              f'{summary["floor"]:.1f} s at this content on this machine', '']
    for run in summary['runs']:
        lines += [f'run -m {run["part"] or "(all)"}: the {min(top, len(run["modules"]))} '
                  f'modules of most CPU', '',
                  '| module | tests | CPU own + children [s] | wall [s] |', '|---|---|---|---|']
        lines += [f'| {m["module"]} | {m["tests"]} | {m["self"]:.1f} + {m["children"]:.1f} | '
                  f'{m["wall"]:.1f} |' for m in run['modules'][:top]]
        lines.append('')
    return lines


def run_suite(records: Path, pytest_args: list[str]) -> int:
    """Run ``./run test`` with the plugin in every pytest process; return its exit status."""
    env = dict(os.environ)
    env[OUT_VARIABLE] = str(records)
    env['PYTHONPATH'] = os.pathsep.join(p for p in (str(BENCH), env.get('PYTHONPATH')) if p)
    env['PYTEST_ADDOPTS'] = ' '.join(p for p in (env.get('PYTEST_ADDOPTS'),
                                                 '-p suite_time_plugin') if p)
    with Processes() as processes:  # ended with its group if this ends early (Ctrl-C)
        code: int = processes.run([str(ROOT / 'run'), 'test', *pytest_args], env=env).returncode
    return code


def main() -> None:
    """Parse the arguments, run the suite (or read a run's records) and write the summary."""
    parser = argparse.ArgumentParser(description=(__doc__ or '').splitlines()[0])
    parser.add_argument('--records', type=Path, metavar='FILE',
                        help='summarise the records of an earlier run instead of running')
    parser.add_argument('--top', type=int, default=TOP, metavar='N',
                        help=f'modules listed per run ({TOP})')
    parser.add_argument('pytest_args', nargs='*', metavar='PYTEST_ARGS',
                        help='more arguments of ./run test (after --)')
    args = parser.parse_args()
    status = 0
    if args.records is None:
        RESULTS.mkdir(exist_ok=True)
        records = RESULTS / 'suite_time_records.jsonl'
        records.unlink(missing_ok=True)
        status = run_suite(records, args.pytest_args)
    else:
        records = args.records
    try:
        summary = summarise(read_records(records))
    except (OSError, ValueError) as error:
        sys.exit(f'suite_time: {error}')
    if not summary['runs']:
        sys.exit(f'suite_time: {records} holds no run: did pytest start?')
    lines = [f'bench/suite_time.py: {describe_machine()}; ./run test exit {status}', '',
             *report(summary, args.top)]
    write_results('suite_time', {'exit': status, **summary}, lines)
    sys.exit(status)


if __name__ == '__main__':
    main()
