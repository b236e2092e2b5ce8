"""Benchmark: the diagnosis on records like a real rig's, side by side with another checkout.

The records are the third truth plant's (``test/third_truth_plant.py``: a one-way pump
switched by valves, an accumulator, a load cylinder that brakes both ways): the six of
``third_rig.RIG_LIKE`` (small strokes against brakes of 30-55 % of the thrust, 5-6 bar in the
accumulator, as the real rig whose records stopped the diagnosis), and two of its ordinary
records (seeds 9100 with the pressures and 9103 from the position, brakes held where the
motor keeps up). Each is diagnosed by ``exo-has diagnose`` with the paper's circuit in the
rig's file, as a user who kept the project's model would, in a fresh process, one at a time on
every core. With ``--against DIR`` each record is diagnosed by DIR's sources too (a checkout
of an earlier commit: ``git worktree add DIR COMMIT``), the two taking turns record by record
so that both meet the same machine.

Per record and checkout: the exit status, the verdict, the flow gain by direction's ratio and
whether it decides, wall and CPU seconds; then the median and worst wall time with the
pressures and from the position alone.

Usage (``./run shell``): ``python bench/rig_like.py --against /tmp/before [--time-budget S]``.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'test'))

import third_rig
from common import describe_machine, write_results

from exo_has_runtime.processes import Processes

ROOT = Path(__file__).resolve().parent.parent
#: Ordinary records of the third plant: seed, logged (else the position only).
ORDINARY = ((9100, True), (9103, False))
#: Packages whose sources a checkout lends the diagnosis (ROS-free; the process owner's tether
#: stays this checkout's).
PACKAGES = ('exo_has_common', 'exo_has_sim')
DIAGNOSE = 'import sys; from exo_has_sim.diagnosis.cli import main; sys.exit(main(sys.argv[1:]))'


def make_records(folder: Path) -> list[tuple[str, Path, bool]]:
    """Write every record's CSV; return each one's name, path and whether it is logged."""
    import third_truth_plant as rig

    out = []
    for seed, share, excursion, charge, logged in third_rig.RIG_LIKE:
        path, _ = third_rig.write_rig_like(folder, seed, share, excursion, charge, logged)
        out.append((f'rig-like {seed}', path, logged))
    for seed, logged in ORDINARY:
        draw = rig.draw(seed, effect='none', duration=20.0, brake_force=third_rig.held_brake(seed))
        path = folder / f'{seed}.csv'
        rig.write_csv(draw, path, columns=third_rig.LOGGED if logged else third_rig.POSITION_ONLY)
        out.append((f'ordinary {seed}', path, logged))
    return out


def diagnose(tree: Path, record: Path, arguments: list[str], out: Path,
             budget: float | None) -> dict[str, Any]:
    """Diagnose one record with a checkout's sources in a fresh process; what it gave.

    ``arguments``: the options of ``exo-has diagnose`` that describe the record (``--params``,
    ``--joint``, ...).
    """
    env = dict(os.environ)
    env['PYTHONPATH'] = os.pathsep.join([*(str(tree / p) for p in PACKAGES),
                                         env.get('PYTHONPATH', '')])
    command = [sys.executable, '-c', DIAGNOSE, str(record), *arguments,
               '--json', str(out), '-q']
    if budget is not None:
        command += ['--time-budget', str(budget)]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.monotonic()
    with Processes() as processes:
        code = processes.run(command, env=env).returncode
    wall = time.monotonic() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    result: dict[str, Any] = {'code': code, 'wall': wall, 'cpu': cpu}
    if out.is_file():
        doc = json.loads(out.read_text())
        gain = next((f for f in (doc.get('structure') or {}).get('findings', [])
                     if f['check'] == 'direction_gain'), None)
        result.update(verdict=doc['verdict'], causes=doc['causes'],
                      gain=None if gain is None else round(gain['value'], 3),
                      gain_decides=None if gain is None else gain['gating'])
    return result


def run(against: Path | None, budget: float | None) -> None:
    """Make the records, diagnose each with every checkout, write the results."""
    trees = {'this': ROOT} | ({'against': against} if against is not None else {})
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        params = third_rig.write_rig_file(folder / 'paper.yaml', 'paper')
        records = make_records(folder)
        # The budget is this checkout's option; another may not know it.
        budgets = {name: budget if name == 'this' else None for name in trees}
        for name, tree in trees.items():  # numba compiles into each checkout's cache first
            diagnose(tree, records[-2][1], ['--params', str(params)],
                     folder / f'warm_{name}.json', budgets[name])
        results: dict[str, dict[str, Any]] = {}
        for label, path, logged in records:
            results[label] = {'logged': logged}
            for name, tree in trees.items():
                results[label][name] = diagnose(tree, path, ['--params', str(params)],
                                                folder / f'{path.stem}_{name}.json',
                                                budgets[name])
                print(f'{label} ({name}): {results[label][name]}', flush=True)
    lines = [f'bench/rig_like.py{" --time-budget " + str(budget) if budget else ""}: '
             f'{describe_machine()}', '',
             '| record | signals | ' + ' | '.join(f'{n}: exit, verdict, flow gain (decides), '
                                                  'wall / CPU [s]' for n in trees) + ' |',
             '|---|---|' + '---|' * len(trees)]
    for label, row in results.items():
        cells = []
        for name in trees:
            r = row[name]
            gain = '-' if r.get('gain') is None else \
                f'{r["gain"]:.2f} ({"yes" if r["gain_decides"] else "no"})'
            cells.append(f'{r["code"]}, {r.get("verdict", "-")}, {gain}, '
                         f'{r["wall"]:.1f} / {r["cpu"]:.1f}')
        lines.append(f'| {label} | {"pressures" if row["logged"] else "position"} | '
                     + ' | '.join(cells) + ' |')
    lines.append('')
    for name in trees:
        for logged, what in ((True, 'with the pressures'), (False, 'from the position')):
            walls = [row[name]['wall'] for row in results.values() if row['logged'] == logged]
            lines.append(f'{name}, {what}: median {statistics.median(walls):.1f} s, worst '
                         f'{max(walls):.1f} s ({len(walls)} records)')
    write_results('rig_like' + ('_budget' if budget else ''),
                  {'trees': {k: str(v) for k, v in trees.items()}, 'budget': budget,
                   'records': results}, lines)


def main() -> None:
    """Parse the arguments and run the benchmark."""
    parser = argparse.ArgumentParser(description=(__doc__ or '').splitlines()[0])
    parser.add_argument('--against', type=Path, metavar='DIR',
                        help='a checkout whose sources diagnose each record too')
    parser.add_argument('--time-budget', type=float, metavar='S',
                        help="this checkout's --time-budget")
    args = parser.parse_args()
    run(args.against, args.time_budget)


if __name__ == '__main__':
    main()
