"""Benchmark: seconds per diagnosis over the bench's records, side by side with another checkout.

The records, 20 s at 200 Hz each, are the bench's truth plants' (``test/``), none made by the
model the diagnosis fits:

- the first plant's hidden-effect draws, seeds 5000-5006 (each effect of its library once,
  none first) and the second plant's 6000-6002, with the bench's hip and knee files;
- the third plant's (a one-way pump switched by valves, an accumulator, a load cylinder that
  brakes both ways, the brake held where the motor keeps up), seeds 95000-95001 with the
  rig's own circuit in its file and 95002-95003 with the paper's;
- each of those twice: with every signal its plant logs, and from the position alone (the
  command, the position and the reference);
- ``rig_like.py``'s eight: six records of the third plant moving a few millimetres against
  brakes of 30-55 % of the thrust, and two of its ordinary ones.

Each record is diagnosed by ``exo-has diagnose`` in a fresh process, one at a time on every
core, with each checkout (this one, and with ``--against DIR`` the sources of DIR, e.g. ``git
worktree add DIR COMMIT``) taking turns record by record, so that both meet the same machine.
Per checkout: the median and the worst wall time with the pressures and from the position.

Usage (``./run shell``): ``python bench/diagnosis_speed.py --against /tmp/before``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path
from typing import Any

import detection
import rig_like
import third_rig
from common import describe_machine, write_results

ROOT = Path(__file__).resolve().parent.parent
DURATION = 20.0  # s
#: (plant, seeds) of detection.py's tasks: 'c' the third plant with its own circuit in the
#: file, 'c:paper' with the paper's.
DRAWS = (('a', range(5000, 5007)), ('b', range(6000, 6003)), ('c', range(95000, 95002)),
         ('c:paper', range(95002, 95004)))
#: The targets of one diagnosis on the 2-core machine [s]: with the pressures, from the position.
TARGETS = {True: 30.0, False: 60.0}


def make_records(folder: Path) -> list[tuple[str, Path, list[str], bool]]:
    """Write every record; return its label, path, options and whether the pressures are in."""
    out = []
    for plant, seeds in DRAWS:
        for seed in seeds:
            effect = detection.ensemble_effect(plant.partition(':')[0], seed)
            for sensors in ('full', 'position'):
                # A folder per mode: a draw's file name does not carry it.
                where = folder / sensors
                where.mkdir(exist_ok=True)
                drawn = detection.write_draw((plant, seed, effect, None, sensors, str(where),
                                              DURATION))
                out.append((f'{plant} {seed} {effect}', drawn['path'], drawn['arguments'],
                            sensors == 'full'))
    params = third_rig.write_rig_file(folder / 'paper.yaml', 'paper')
    out += [(label, path, ['--params', str(params)], logged)
            for label, path, logged in rig_like.make_records(folder)]
    return out


def run(against: Path | None) -> None:
    """Make the records, diagnose each with every checkout, write the results."""
    trees = {'this': ROOT} | ({'against': against} if against is not None else {})
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        records = make_records(folder)
        for name, tree in trees.items():  # numba compiles into each checkout's cache first
            label, path, arguments, _ = records[0]
            rig_like.diagnose(tree, path, arguments, folder / f'warm_{name}.json', None)
        results: list[dict[str, Any]] = []
        for label, path, arguments, logged in records:
            row: dict[str, Any] = {'record': label, 'logged': logged}
            for name, tree in trees.items():
                row[name] = rig_like.diagnose(tree, path, arguments,
                                              path.with_name(f'{path.stem}_{name}.json'), None)
                print(f'{label} ({"pressures" if logged else "position"}, {name}): '
                      f'{row[name]}', flush=True)
            results.append(row)
    lines = [f'bench/diagnosis_speed.py: {describe_machine()}', '',
             '| record | signals | ' + ' | '.join(f'{n}: exit, verdict, wall / CPU [s]'
                                                  for n in trees) + ' |',
             '|---|---|' + '---|' * len(trees)]
    for row in results:
        cells = [f'{row[n]["code"]}, {row[n].get("verdict", "-")}, '
                 f'{row[n]["wall"]:.1f} / {row[n]["cpu"]:.1f}' for n in trees]
        lines.append(f'| {row["record"]} | {"pressures" if row["logged"] else "position"} | '
                     + ' | '.join(cells) + ' |')
    lines.append('')
    summary: dict[str, Any] = {}
    for name in trees:
        for logged, what in ((True, 'with the pressures'), (False, 'from the position')):
            walls = [row[name]['wall'] for row in results if row['logged'] == logged]
            summary[f'{name}, {what}'] = {'median': statistics.median(walls),
                                          'worst': max(walls), 'records': len(walls),
                                          'target': TARGETS[logged]}
            lines.append(f'{name}, {what}: median {statistics.median(walls):.1f} s, worst '
                         f'{max(walls):.1f} s ({len(walls)} records; target '
                         f'{TARGETS[logged]:g} s)')
    if len(trees) == 2:
        ratios = [row['against']['wall'] / row['this']['wall'] for row in results]
        lines.append(f'against over this, per record: median {statistics.median(ratios):.2f}, '
                     f'{min(ratios):.2f} to {max(ratios):.2f}')
    write_results('diagnosis_speed', {'trees': {k: str(v) for k, v in trees.items()},
                                      'records': results, 'summary': summary}, lines)


def main() -> None:
    """Parse the arguments and run the benchmark."""
    parser = argparse.ArgumentParser(description=(__doc__ or '').splitlines()[0])
    parser.add_argument('--against', type=Path, metavar='DIR',
                        help='a checkout whose sources diagnose each record too')
    run(parser.parse_args().against)


if __name__ == '__main__':
    main()
