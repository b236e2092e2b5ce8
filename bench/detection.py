"""Benchmark: false alarms and detection limits of ``exo-has diagnose`` on two truth plants.

How often the diagnosis names an effect that is not there, and the smallest size of each
effect it names in 90 % of draws (its detection limit).

The data come from the two truth plants of the tests, written apart from the project's model
and from each other (``test/truth_plant.py``: the paper's structure, compact valve, PD
controller; ``test/second_truth_plant.py``: rod side to a tank through a line, second-order
motor loop, PI controller, quantised sensors), each drawing its hard-to-know parameters around
the parameter file's values (+-30 %; the second plant also the motor lag, the flow gain and the
dead volume), its excitation, load and sensor noise from the seed. Every draw is 30 s at
200 Hz, written as a CSV log and diagnosed by the command as a user would (``--joint``,
``--load-mass``), with the joint type's parameter file as the user's belief.

``--null N``: N effect-free draws, the plants taking turns; the false-alarm rate is the share
that names any cause. ``--limits``: for each effect and each size of :data:`LIMIT_SIZES`,
``--draws`` draws (the plants taking turns); a size is detected when the effect is named
(alone or first); the limit is the smallest size from which every larger one is named in at
least 90 % of its draws. ``--twins N``: N effect-free draws (the plants taking turns) give each
record's own detection limits (:mod:`exo_has_sim.diagnosis.limits`); every effect with a limit
is then put into the draw's twins (the same seed: the same nuisance, excitation, load and
noise) two sizes of the limit's ladder stronger and two weaker, and diagnosed in full: the
stated limit holds when the stronger is named and the weaker not. ``--sensors position``
keeps only the command and the position (the paper's own logging, section 4.2).

``--file-limits N`` (with ``--files shipped``: the hip and knee files the project ships,
12 mm bore and 40 mm stroke, instead of the bench's 14 mm, 130 mm of test/rigs.py; the plants'
excitations shrink by the ratio of the strokes, :func:`rigs.motion_scale`, the load keeps its
pressures and its 50 kg): N effect-free draws of 30 s from ``--first-seed``, the plants a and
b taking turns; per parameters file the false alarms, each record's stated limits, and each
effect put into the draw's twin at ``--factors`` times its stated limit: the share named.
A fresh draw (``--first-seed`` :data:`FIRST_FRESH_SEED`, ``--factors 1``) checks that a
stated limit holds in at least 80 % of records on seeds chosen after it was stated.

``--holdout N``: as ``--null``, on other seeds: a rule chosen on the null ensemble's draws
is checked on draws it was not chosen on.

``--hidden`` diagnoses the 21 draws of test/test_hidden_effects.py (20 s each) and lists
each outcome: named, missed, another cause named (with the hidden effect reported beside it
or not), or, for an effect the signals cannot identify, nothing named.

``--single PLANT/SEED[/EFFECT] ...`` diagnoses draws one after another, each alone on every
core, and gives each one's wall time, CPU time and peak memory (the speed of one record's
diagnosis, as a user on the robot PC would wait for it); the effect is the one the seed's
ensemble gives it (``--hidden``'s, ``--third``'s), else none.

Usage (``./run shell``): ``python bench/detection.py --null 40``, ``python bench/detection.py
--limits --draws 10``, ``python bench/detection.py --twins 6`` and ``python
bench/detection.py --hidden --sensors position``. The draws are diagnosed as a batch of
``exo-has diagnose`` (:mod:`exo_has_sim.diagnosis.batch`): ``--workers N`` (or ``--jobs``)
worker processes (default: one per CPU), or ``--scheduler ADDRESS``, a Dask cluster whose
workers see this machine's temporary folder at the same path.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import os
import resource
import sys
import tempfile
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / 'test'))

import numpy as np
import second_truth_plant as plant_b
import third_rig
import third_truth_plant as plant_c
import truth_plant as plant_a
from common import describe_machine, write_results
from rigs import SHIPPED_DIR, rig_file

from exo_has_runtime.tether import tie_to_parent
from exo_has_sim.diagnosis.batch import ProgressBar, run_batch
from exo_has_sim.diagnosis.cli import STRUCTURE_STATUS
from exo_has_sim.diagnosis.cli import main as diagnose_main
from exo_has_sim.diagnosis.records import Options, Record
from exo_has_sim.diagnosis.structure import normalised_error
from exo_has_sim.diagnosis.summary import SummaryFolder
from exo_has_sim.parameters import load_parameters

DURATION = 30.0  # s
LOAD_MASS = 50.0  # kg, both plants' default
PLANTS = {'a': plant_a, 'b': plant_b}
JOINT_NAMES = ('hip', 'knee')
FIRST_NULL_SEED = 70000
#: Effect-free draws apart from the null ensemble's, on which a rule chosen there is checked.
FIRST_HOLDOUT_SEED = 75000
FIRST_LIMIT_SEED = 80000
FIRST_TWIN_SEED = 90000
FIRST_THIRD_SEED = 95000
FIRST_LIMIT_CHECK_SEED = 97000
FIRST_LOW_RELIEF_SEED = 98000
#: --file-limits on the shipped files: the ensemble whose records' limits are measured, and
#: the fresh draw that checks them (its seeds chosen after the first's table was written).
FIRST_FILE_LIMIT_SEED = 100000
FIRST_FRESH_SEED = 110000
#: The fresh draw of the transport delay's limit alone (its twins only), fixed before it ran:
#: the first fresh draw stated a delay limit in 4 of 14 records, too few to judge 80 %.
FIRST_DELAY_FRESH_SEED = 120000
#: The fresh draw of entrained air's limit alone, fixed before it ran: with the open loop on
#: ROS34PW2 the first fresh draw's hip held it in 3 of 5 records.
FIRST_AIR_FRESH_SEED = 130000
#: The fresh draw of entrained air's limit with the margin decided on the draw above (three
#: ladder steps), fixed before it ran.
FIRST_AIR_CHECK_SEED = 140000
#: Parameters files the truth plants draw around and the diagnoses are given (--files): the
#: bench's (test/rigs.py) or the shipped hip and knee (exo_has_sim/config).
FILES: dict[str, Path | None] = {'bench': None, 'shipped': SHIPPED_DIR}
RIG: dict[str, Path | None] = {'folder': None}
#: With --low-relief: the crack pressures, as shares of the parameters file's relief setting
#: (18 MPa), spread evenly over the draws: the hold-out plant's missed valve cracked at 23 %.
LOW_RELIEF_SHARES = (0.2, 0.3)
#: Environment variable that passes --constant-load to the diagnoses.
CONSTANT_LOAD = 'EXO_HAS_BENCH_CONSTANT_LOAD'
#: The hidden-effect test's draws (test/test_hidden_effects.py): plant, draws, first seed;
#: the effects take turns over each plant's draws.
HIDDEN_DRAWS = (('a', 14, 5000), ('b', 7, 6000))
HIDDEN_DURATION = 20.0  # s
EFFECT_CHOICES = plant_a.EFFECT_CHOICES
#: Ladder steps between the stated limit and the twins' sizes (about 1.6 times a step).
TWIN_STEPS = 2
#: Sizes tried per effect, in its unit (SI), from well below the truth plants' ranges to
#: their middle.
LIMIT_SIZES: dict[str, tuple[float, ...]] = {
    'coulomb_friction': (10.0, 20.0, 40.0, 80.0),
    'pump_deadzone': (1.0, 2.0, 4.0, 8.0),
    'transport_delay': (1e-3, 2e-3, 4e-3, 8e-3),
    'quadratic_leakage': (2.5e-21, 5e-21, 1e-20, 2e-20),
    'relief_valve': (13e6, 12e6, 11e6, 10e6),
    'entrained_air': (0.01, 0.02, 0.05, 0.1),
}
#: With ``--sensors position``, sizes for the effects that stay identifiable: the per-record
#: limits of effect-free position-only draws lie above the full set's sizes.
POSITION_LIMIT_SIZES: dict[str, tuple[float, ...]] = {
    'pump_deadzone': (4.0, 8.0, 16.0, 32.0),
    'transport_delay': (4e-3, 8e-3, 16e-3, 32e-3),
}
#: Columns kept with ``--sensors position``.
POSITION_ONLY = ('time', 'motor_speed_command', 'position', 'reference')


def _draw(plant: str, seed: int, effect: str, size: float | None, duration: float) -> Any:
    module = PLANTS[plant]
    if RIG['folder'] is None:
        return module.draw(seed, effect=effect, size=size, duration=duration,
                           load_mass=LOAD_MASS)
    return module.draw(seed, effect=effect, size=size, duration=duration, load_mass=LOAD_MASS,
                       rig=RIG['folder'])


#: A draw to diagnose: plant, seed, effect, size (None: drawn), sensors, folder, duration [s].
Task = tuple[str, int, str, float | None, str, str, float]


def write_draw(task: Task) -> dict[str, Any]:
    """Draw one data set and write it as a CSV log; what diagnoses it, and the draw's facts.

    The third plant (``'c'``, and ``'c:paper'`` for its rig described with the paper's
    circuit) is diagnosed with its rig's parameters file (test/third_rig.py), its brake held
    where the motor keeps up (:data:`third_rig.HELD_BRAKES`), from the columns the rig logs;
    the first two with the bench's file of the joint type and the load mass, as a user would
    (``--joint``, ``--params``, ``--load-mass``).

    Returns
    -------
    dict
        ``path``, ``arguments`` (of ``exo-has diagnose``), ``record`` (the same as a
        :class:`~exo_has_sim.diagnosis.records.Record`) and ``row`` (the draw's facts).

    """
    plant, seed, effect, size, sensors, folder, duration = task
    path = Path(folder) / f'{plant.replace(":", "_")}_{seed}_{effect}_{size}.csv'
    if plant.startswith('c'):
        circuit = plant.partition(':')[2] or 'switched'
        draw = plant_c.draw(seed, effect=effect, size=size, duration=duration,
                            brake_force=third_rig.held_brake(seed))
        columns = third_rig.LOGGED if sensors == 'full' else POSITION_ONLY
        params = third_rig.write_rig_file(Path(folder) / f'{plant.replace(":", "_")}_{seed}.yaml',
                                          circuit)
        arguments = ['--params', str(params)]
        record = Record(path, None, Options(params=params))
    else:
        draw = _draw(plant, seed, effect, size, duration)
        columns = plant_a.COLUMNS if sensors == 'full' else POSITION_ONLY
        params = rig_file(draw.joint_type, RIG['folder'])
        arguments = ['--joint', draw.joint_type, '--params', str(params),
                     '--load-mass', f'{LOAD_MASS}']
        record = Record(path, draw.joint_type, Options(params=params, load_mass=LOAD_MASS))
    if os.environ.get(CONSTANT_LOAD):
        arguments.append('--constant-load')
        record = replace(record, options=replace(record.options, constant_load=True))
    table = np.column_stack([draw.columns[name] for name in columns])
    np.savetxt(path, table, fmt='%.17g', delimiter=',', header=','.join(columns), comments='')
    stroke = load_parameters(record.options.params).stroke
    return {'path': path, 'arguments': arguments, 'record': record,
            'row': {'plant': plant, 'seed': seed, 'joint': draw.joint_type,
                    'excitation': draw.excitation, 'effect': effect, 'size': draw.size,
                    'sensors': sensors,
                    # The measured position's range as shares of the file's stroke.
                    'stroke_used': [float(np.min(draw.columns['position'])) / stroke,
                                    float(np.max(draw.columns['position'])) / stroke]}}


def diagnose_draw(task: Task, quiet: bool = True) -> dict[str, Any]:
    """Draw one data set, write it as CSV, diagnose it by the command: the verdict, the truth."""
    drawn = write_draw(task)
    out = drawn['path'].with_suffix('.json')
    started = time.perf_counter()
    code = diagnose_main([str(drawn['path']), *drawn['arguments'], *(['-q'] if quiet else []),
                          '--json', str(out)])
    wall = time.perf_counter() - started
    doc = json.loads(out.read_text()) if code in (0, STRUCTURE_STATUS) else {}
    return _row(drawn['row'], code, doc, wall)


def _row(facts: dict[str, Any], code: int, doc: dict[str, Any], wall: float) -> dict[str, Any]:
    """Return a draw's result: its facts, and what its diagnosis's document says."""
    judged = doc.get('structure') or {}
    return {**facts, 'code': code, 'verdict': doc.get('verdict'),
            'structure_failed': [{key: f[key] for key in ('check', 'value', 'threshold')}
                                 for f in judged.get('findings', [])
                                 if f['gating'] and not f['passed']],
            'direction_gain': next((f['value'] for f in judged.get('findings', [])
                                    if f['check'] == 'direction_gain'), None),
            'suggestion': judged.get('suggestion'), 'alike': judged.get('alike', []),
            'model_error': _model_error(doc.get('fits', {}).get('baseline', {})),
            'alternatives': {a['name']: a['error'] for a in judged.get('alternatives', [])},
            'fits': doc.get('fits', {}).get('extended', {}),
            'causes': doc.get('causes', []),
            'sizes': doc.get('sizes', {}), 'indistinguishable': doc.get('indistinguishable', []),
            'structure': doc.get('baseline_structure', []),
            'unidentifiable': sorted(doc.get('unidentifiable', {})),
            'limits': {effect: limit['limit']
                       for effect, limit in doc.get('detection_limits', {}).items()},
            'ladders': {effect: limit['sizes']
                        for effect, limit in doc.get('detection_limits', {}).items()},
            'leaders': [{key: step[0][key] for key in ('effect', 'cost_ratio', 'score',
                                                       'p_value', 'significant')}
                        for step in doc.get('steps', []) if step],
            'wall_s': round(wall, 1)}


def _model_error(fits: dict[str, float]) -> float | None:
    """Return the normalised error of the baseline's validated fits, None without them."""
    return normalised_error(fits, tuple(fits)) if fits else None


#: Where the batches of :func:`run_tasks` run: local worker processes, or a Dask scheduler's
#: cluster (--workers, --scheduler).
WHERE: dict[str, Any] = {'workers': os.cpu_count() or 1, 'scheduler': None}


def run_tasks(tasks: Sequence[Task], jobs: int) -> list[dict[str, Any]]:
    """Write the draws on ``jobs`` processes, then diagnose them as ``exo-has diagnose`` would.

    The diagnoses are a batch of the command (:func:`exo_has_sim.diagnosis.batch.run_batch`),
    on :data:`WHERE`'s worker processes or Dask cluster, into ``summary/`` of the draws'
    folder; a line per result.
    """
    if not tasks:
        return []
    if jobs > 1:
        os.environ['EXO_HAS_THREADS'] = '1'
    # Tethered: a process ends with this one, even one killed by SIGKILL.
    with multiprocessing.get_context('fork').Pool(jobs, tie_to_parent, (os.getpid(),)) as pool:
        drawn = pool.map(write_draw, tasks)
    folder = Path(tasks[0][5]) / 'summary'
    outcome = run_batch([d['record'] for d in drawn], folder, WHERE['workers'],
                        WHERE['scheduler'], ProgressBar())
    documents = SummaryFolder(folder)
    by_record = {row.record: row for row in outcome.rows}
    results = []
    for d in drawn:
        row = by_record[d['record']]
        doc = documents.done(row.id) or {}
        code = (STRUCTURE_STATUS if row.verdict == 'structure' else 0
                if row.verdict in ('effect', 'none') else 1)
        results.append(_row(d['row'], code, doc if code != 1 else {}, row.seconds or 0.0))
        print(json.dumps(results[-1]), flush=True)
    if outcome.interrupted:
        raise KeyboardInterrupt
    return results


def null_ensemble(count: int, sensors: str, jobs: int, first_seed: int = FIRST_NULL_SEED,
                  name: str = 'null') -> None:
    """Measure the false-alarm rate over ``count`` effect-free draws from ``first_seed``."""
    with tempfile.TemporaryDirectory() as folder:
        tasks = [('ab'[i % 2], first_seed + i, 'none', None, sensors, folder, DURATION)
                 for i in range(count)]
        results = sorted(run_tasks(tasks, jobs), key=lambda r: r['seed'])
    alarms = [r for r in results if r['causes']]
    judged = [r for r in results if r['verdict'] == 'structure']
    failed = [r for r in results if r['code'] not in (0, STRUCTURE_STATUS)]
    lines = [f'bench/detection.py --{name} {count} --sensors {sensors}: {describe_machine()}',
             f'false alarms: {len(alarms)} of {len(results)} effect-free draws '
             f'({100.0 * len(alarms) / len(results):.1f} %); diagnoses that failed: '
             f'{len(failed)}; wall per diagnosis median '
             f'{float(np.median([r["wall_s"] for r in results])):.1f} s',
             f"structure verdicts (the model's structure does describe these plants): "
             f'{len(judged)} of {len(results)}',
             *(f'  seed {r["seed"]} plant {r["plant"]}: '
               + ', '.join(f'{f["check"]} {f["value"]:.3g}' for f in r['structure_failed'])
               for r in judged),
             'flow gain by direction, data over model: '
             + _spread([r['direction_gain'] for r in results])]
    for plant in PLANTS:
        mine = [r for r in results if r['plant'] == plant]
        lines.append(f'  plant {plant}: {sum(bool(r["causes"]) for r in mine)} of {len(mine)}; '
                     f'a second-order motor loop taken in '
                     f'{sum("second_order_motor" in r["structure"] for r in mine)}')
    lines += [f'  seed {r["seed"]} plant {r["plant"]} {r["joint"]} {r["excitation"]}: named '
              f'{", ".join(r["causes"])} {r["sizes"]}'
              + (f'; beside it: {", ".join(r["indistinguishable"])}'
                 if r['indistinguishable'] else '') for r in alarms]
    lines.append("each record's own detection limits (exo_has_sim.diagnosis.limits), median and "
                 'range over the draws that named nothing (None: not named at the strongest '
                 'size tried):')
    quiet = [r for r in results if not r['causes']]
    for effect in LIMIT_SIZES:
        for plant in PLANTS:
            mine = [r for r in quiet if r['plant'] == plant]
            values = [r['limits'].get(effect) for r in mine
                      if effect not in r.get('unidentifiable', [])]
            if not values and mine:
                lines.append(f'  {effect}, plant {plant}: not identifiable from these signals '
                             f'in {len(mine)} of {len(mine)}')
                continue
            found = [v for v in values if v is not None]
            spread = (f'median {float(np.median(found)):.3g}, {min(found):.3g} to '
                      f'{max(found):.3g}' if found else 'none found')
            lines.append(f'  {effect}, plant {plant}: {spread}; not named at the strongest '
                         f'in {values.count(None)} of {len(values)}')
    write_results(f'detection_{name}_{_tag(sensors)}', {'draws': results}, lines)


def detection_limits(draws: int, sensors: str, jobs: int) -> None:
    """Measure the share of draws naming each effect at each size, and the limit (90 %)."""
    table_sizes = LIMIT_SIZES | (POSITION_LIMIT_SIZES if sensors == 'position' else {})
    with tempfile.TemporaryDirectory() as folder:
        tasks = [('ab'[k % 2], FIRST_LIMIT_SEED + 1000 * e + k, effect, size, sensors, folder,
                  DURATION)
                 for e, (effect, sizes) in enumerate(table_sizes.items())
                 for size in sizes for k in range(draws)]
        results = run_tasks(tasks, jobs)
    lines = [f'bench/detection.py --limits --draws {draws} --sensors {sensors}: '
             f'{describe_machine()}', 'effect: named share per size; limit (90 %); draws '
             'naming another cause, and of those the ones reporting the effect beside it']
    table = {}
    for effect, sizes in table_sizes.items():
        shares = []
        wrong = [r for r in results if r['effect'] == effect and set(r['causes']) - {effect}]
        hedged = [r for r in wrong if effect in r['indistinguishable']]
        unidentifiable = sum(effect in r.get('unidentifiable', []) for r in results
                             if r['effect'] == effect)
        for size in sizes:
            mine = [r for r in results if r['effect'] == effect and r['size'] == size]
            named = sum(bool(r['causes']) and r['causes'][0] == effect for r in mine)
            shares.append(named / max(len(mine), 1))
        limit = None
        for i in range(len(sizes)):
            if all(share >= 0.9 for share in shares[i:]):
                limit = sizes[i]
                break
        table[effect] = {'sizes': list(sizes), 'named_share': shares, 'limit': limit,
                         'other_cause': len(wrong), 'other_cause_hedged': len(hedged),
                         'unidentifiable': unidentifiable}
        lines.append(f'{effect}: ' + ', '.join(f'{size:g}: {share:.0%}' for size, share
                                               in zip(sizes, shares, strict=True))
                     + f'; limit {"above the sizes tried" if limit is None else f"{limit:g}"}'
                     + f'; another cause in {len(wrong)} of {draws * len(sizes)} '
                     f'({len(hedged)} with the effect beside it)'
                     + (f'; reported unidentifiable in {unidentifiable}' if unidentifiable
                        else ''))
    write_results(f'detection_limits_{sensors}', {'table': table, 'draws': results}, lines)


def _tag(sensors: str) -> str:
    """Name the sensor set of a results file, --constant-load and --files shipped."""
    return (sensors + ('_constant_load' if os.environ.get(CONSTANT_LOAD) else '')
            + ('' if RIG['folder'] is None else '_shipped'))


def _spread(values: Sequence[float | None]) -> str:
    """Say the median and range of the values that are not None."""
    found = [v for v in values if v is not None]
    return (f'median {float(np.median(found)):.3g}, {min(found):.3g} to {max(found):.3g} '
            f'({len(found)} of {len(values)})' if found else 'none')


def _outcome_line(r: dict[str, Any]) -> str:
    """Say a draw's excitation, hidden effect, outcome, what was named and what failed."""
    sizes = ', '.join(f'{k} {v:.3g}' for k, v in r['sizes'].items())
    error = (f' ({r["sizes"][r["effect"]] / r["size"] - 1.0:+.1%})'
             if r['effect'] in r['sizes'] else '')
    return (f'{r["excitation"]} {r["effect"]} {r["size"]:.3g}: {r["outcome"]}; named '
            f'{sizes or "none"}{error}'
            + (f'; beside: {", ".join(r["indistinguishable"])}' if r['indistinguishable']
               else '')
            + ''.join(f'; {f["check"]} {f["value"]:.3g}' for f in r['structure_failed']))


def _outcome(row: dict[str, Any]) -> str:
    """Say what a diagnosis made of its draw's hidden effect (or of its absence)."""
    if row['verdict'] == 'structure':
        return 'structure verdict'
    truth = [] if row['effect'] == 'none' else [row['effect']]
    if row['causes'] == truth:
        return 'right'
    if not row['causes']:
        return ('unidentifiable, nothing named' if row['effect'] in row['unidentifiable']
                else 'missed')
    if row['effect'] in row['indistinguishable']:
        return 'another cause, the effect beside it'
    return 'another cause'


def low_relief(count: int, sensors: str, jobs: int) -> None:
    """Diagnose second-plant draws whose relief valve cracks far below its setting.

    ``count`` draws, the crack pressures spread over :data:`LOW_RELIEF_SHARES` of the
    parameters file's setting; the share of them that name the valve.
    """
    setting = float(load_parameters(rig_file('hip')).relief_pressure)
    low, high = LOW_RELIEF_SHARES
    shares = np.linspace(low, high, count) if count > 1 else np.array([low])
    with tempfile.TemporaryDirectory() as folder:
        tasks = [('b', FIRST_LOW_RELIEF_SEED + i, 'relief_valve', float(share * setting),
                  sensors, folder, HIDDEN_DURATION) for i, share in enumerate(shares)]
        results = run_tasks(tasks, jobs)
    results.sort(key=lambda r: r['seed'])
    for r in results:
        r['outcome'] = _outcome(r)
    named = sum(r['outcome'] == 'right' for r in results)
    lines = [f'bench/detection.py --low-relief {count} --sensors {_tag(sensors)}: '
             f'{describe_machine()}',
             f'{len(results)} draws of the second plant, {HIDDEN_DURATION:g} s, a relief valve '
             f'cracking at {low:.0%} to {high:.0%} of its {setting / 1e6:g} MPa setting: named '
             f'{named} of {len(results)} ({named / max(len(results), 1):.0%}); wall per '
             f'diagnosis median {float(np.median([r["wall_s"] for r in results])):.1f} s']
    lines += [f'  {r["plant"]} {r["seed"]} {r["joint"]} {_outcome_line(r)}' for r in results]
    write_results(f'detection_low_relief_{_tag(sensors)}', {'draws': results}, lines)


def ensemble_effect(plant: str, seed: int) -> str:
    """Return the effect a seed's ensemble hides in its draw (none outside them)."""
    for name, count, first in HIDDEN_DRAWS:
        if plant == name and first <= seed < first + count:
            return EFFECT_CHOICES[(seed - first) % len(EFFECT_CHOICES)]
    if plant.startswith('c') and seed >= FIRST_THIRD_SEED:
        return EFFECT_CHOICES[(seed - FIRST_THIRD_SEED) % len(EFFECT_CHOICES)]
    return 'none'


def hidden_draws(sensors: str, jobs: int) -> None:
    """Diagnose the hidden-effect test's draws (test/test_hidden_effects.py) with ``sensors``."""
    with tempfile.TemporaryDirectory() as folder:
        tasks = [(plant, first + i, ensemble_effect(plant, first + i), None, sensors, folder,
                  HIDDEN_DURATION) for plant, count, first in HIDDEN_DRAWS for i in range(count)]
        results = run_tasks(tasks, jobs)
    results.sort(key=lambda r: r['seed'])
    outcomes: dict[str, list[dict[str, Any]]] = {
        'right': [], 'unidentifiable, nothing named': [], 'missed': [],
        'another cause, the effect beside it': [], 'another cause': [],
        'structure verdict': []}
    for r in results:
        r['outcome'] = _outcome(r)
        outcomes[r['outcome']].append(r)
    lines = [f'bench/detection.py --hidden --sensors {_tag(sensors)}: {describe_machine()}',
             f'{len(results)} draws of {HIDDEN_DURATION:g} s; wall per diagnosis median '
             f'{float(np.median([r["wall_s"] for r in results])):.1f} s',
             *(f'  {key}: {len(rows)}' for key, rows in outcomes.items())]
    lines += [f'  {r["plant"]} {r["seed"]} {r["joint"]} {_outcome_line(r)}' for r in results]
    write_results(f'detection_hidden_{_tag(sensors)}', {'draws': results}, lines)


def third_plant(count: int, circuit: str, sensors: str, jobs: int) -> None:
    """Diagnose draws of the third plant, its rig described with ``circuit``'s file.

    The effects take turns over the draws (none first); with the rig's own circuit the
    outcomes are those of :func:`hidden_draws`, with the paper's the structure's verdict is
    the right one for every draw, whatever its hidden effect.
    """
    plant = 'c' if circuit == 'switched' else f'c:{circuit}'
    with tempfile.TemporaryDirectory() as folder:
        tasks = [(plant, seed, ensemble_effect(plant, seed), None, sensors, folder,
                  HIDDEN_DURATION)
                 for seed in range(FIRST_THIRD_SEED, FIRST_THIRD_SEED + count)]
        results = sorted(run_tasks(tasks, jobs), key=lambda r: r['seed'])
    for r in results:
        r['outcome'] = _outcome(r)
    counts: dict[str, int] = {}
    for r in results:
        counts[r['outcome']] = counts.get(r['outcome'], 0) + 1
    lines = [f'bench/detection.py --third {count} --circuit {circuit} --sensors {sensors}: '
             f'{describe_machine()}',
             f'{len(results)} draws of {HIDDEN_DURATION:g} s of the third plant, brakes '
             f'{third_rig.HELD_BRAKES[0]:g}-{third_rig.HELD_BRAKES[1]:g} N; wall per diagnosis '
             f'median {float(np.median([r["wall_s"] for r in results])):.1f} s, longest '
             f'{max(r["wall_s"] for r in results):.1f} s',
             *(f'  {key}: {value}' for key, value in counts.items()),
             'flow gain by direction, data over model: '
             + _spread([r['direction_gain'] for r in results])]
    lines += [f'  {r["seed"]} {_outcome_line(r)}'
              + (f'; unidentifiable: {", ".join(r["unidentifiable"])}'
                 if r['unidentifiable'] else '')
              + (f'; suggested {r["suggestion"]}' if r.get('suggestion') else '')
              for r in results]
    write_results(f'detection_third_{circuit}_{sensors}', {'draws': results}, lines)


def single(specs: Sequence[str], sensors: str, progress: bool) -> None:
    """Diagnose each ``plant/seed[/effect]`` alone, on every core; wall, CPU and memory."""
    results = []
    with tempfile.TemporaryDirectory() as folder:
        for spec in specs:
            plant, seed_text, *rest = spec.split('/')
            seed = int(seed_text)
            effect = rest[0] if rest else ensemble_effect(plant, seed)
            cpu = time.process_time()
            row = diagnose_draw((plant, seed, effect, None, sensors, folder, HIDDEN_DURATION),
                                quiet=not progress)
            row['outcome'] = _outcome(row)
            row['cpu_s'] = round(time.process_time() - cpu, 1)
            # The process's peak so far: the largest of the diagnoses up to this one.
            row['peak_rss_mib'] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
                                        / 1024.0)
            print(json.dumps(row), flush=True)
            results.append(row)
    lines = [f'bench/detection.py --single --sensors {_tag(sensors)}: {describe_machine()}',
             *(f'  {r["plant"]} {r["seed"]} {r["effect"]}: wall {r["wall_s"]:.1f} s, CPU '
               f'{r["cpu_s"]:.1f} s, peak {r["peak_rss_mib"]} MiB; {_outcome_line(r)}'
               for r in results)]
    write_results(f'detection_single_{_tag(sensors)}', {'draws': results}, lines)


def twins(count: int, sensors: str, jobs: int) -> None:
    """Check each record's stated detection limits against full diagnoses of its twins."""
    with tempfile.TemporaryDirectory() as folder:
        seeds = [('ab'[i % 2], FIRST_TWIN_SEED + i) for i in range(count)]
        bases = run_tasks([(plant, seed, 'none', None, sensors, folder, HIDDEN_DURATION)
                           for plant, seed in seeds], jobs)
        tasks, stated = [], {}
        for base in bases:
            if base['causes']:
                continue  # a record that named a cause states no limit for it
            for effect, limit in base['limits'].items():
                ladder = base['ladders'][effect]
                if limit is None or limit not in ladder:
                    continue
                i = ladder.index(limit)
                stated[(base['plant'], base['seed'], effect)] = limit
                if i + TWIN_STEPS < len(ladder):
                    tasks.append((base['plant'], base['seed'], effect, ladder[i + TWIN_STEPS],
                                  sensors, folder, DURATION))
                if i - TWIN_STEPS >= 0:
                    tasks.append((base['plant'], base['seed'], effect, ladder[i - TWIN_STEPS],
                                  sensors, folder, DURATION))
        results = run_tasks(tasks, jobs)
    lines = [f'bench/detection.py --twins {count} --sensors {sensors}: {describe_machine()}',
             f'{TWIN_STEPS} ladder steps either side of each stated limit; a twin agrees when '
             'the stronger is named (first) and the weaker not']
    agree = 0
    for row in sorted(results, key=lambda r: (r['effect'], r['plant'], r['seed'], r['size'])):
        limit = stated[(row['plant'], row['seed'], row['effect'])]
        stronger = row['size'] > limit if row['effect'] != 'relief_valve' else row['size'] < limit
        named = bool(row['causes']) and row['causes'][0] == row['effect']
        agree += named == stronger
        lines.append(f'  {row["effect"]:<18} plant {row["plant"]} seed {row["seed"]}: limit '
                     f'{limit:.3g}, twin at {row["size"]:.3g} '
                     f'({"stronger" if stronger else "weaker"}) '
                     f'{"named" if named else "not named"}'
                     f'{"" if named == stronger else "  <- disagrees"}')
    lines.insert(2, f'agreement: {agree} of {len(results)} twins')
    write_results(f'detection_twins_{sensors}', {'bases': bases, 'twins': results}, lines)


def stated_limits(count: int, plants: str, sensors: str, jobs: int,
                  offsets: Sequence[int] = (0, 2),
                  effects: Sequence[str] | None = None) -> None:
    """Check each record's stated limits at the limit itself: whether they are named there.

    ``count`` effect-free draws of :data:`HIDDEN_DURATION` of the plants named (``'b'``,
    ``'c'``, ...), taking turns; each effect with a stated limit is put into the draw's twin
    at ``offsets`` ladder steps stronger than the limit (0: at it), and diagnosed in full.
    Per effect and offset, the share of twins named: a stated limit holds when at least
    80 % are named at offset 0.
    """
    with tempfile.TemporaryDirectory() as folder:
        seeds = [(plants[i % len(plants)], FIRST_LIMIT_CHECK_SEED + i) for i in range(count)]
        bases = run_tasks([(plant, seed, 'none', None, sensors, folder, DURATION)
                           for plant, seed in seeds], jobs)
        tasks = []
        for base in bases:
            if base['causes'] or base['verdict'] == 'structure':
                continue  # a record that named a cause states no limit for it
            for effect, limit in base['limits'].items():
                ladder = base['ladders'][effect]
                module = plant_c if base['plant'].startswith('c') else PLANTS[base['plant']]
                if limit is None or limit not in ladder or effect not in module.EFFECTS \
                        or (effects and effect not in effects):
                    continue  # no limit, an effect this plant cannot hide, or not asked
                i = ladder.index(limit)
                tasks += [(base['plant'], base['seed'], effect, ladder[i + k], sensors, folder,
                           HIDDEN_DURATION) for k in offsets if i + k < len(ladder)]
        results = run_tasks(tasks, jobs)
    ladders = {(b['plant'], b['seed'], e): (b['ladders'][e], b['ladders'][e].index(limit))
               for b in bases for e, limit in b['limits'].items()
               if limit is not None and limit in b['ladders'][e]}
    lines = [f'bench/detection.py --stated-limits {count} --plants {plants} --sensors '
             f'{sensors}: {describe_machine()}',
             "each effect put into an effect-free record's twin at the record's stated limit "
             '(offset 0) and ladder steps stronger; share named (first) per offset']
    table: dict[str, dict[int, list[bool]]] = {}
    for row in results:
        ladder, i = ladders[(row['plant'], row['seed'], row['effect'])]
        offset = ladder.index(row['size']) - i
        named = bool(row['causes']) and row['causes'][0] == row['effect']
        table.setdefault(row['effect'], {}).setdefault(offset, []).append(named)
    for effect, by_offset in sorted(table.items()):
        lines.append(f'  {effect}: ' + ', '.join(
            f'{offset:+d}: {sum(v)}/{len(v)} ({sum(v) / len(v):.0%})'
            for offset, v in sorted(by_offset.items())))
    suffix = '' if list(offsets) == [0, 2] else '_' + '_'.join(f'{k:+d}' for k in offsets)
    write_results(f'detection_stated_limits_{plants}_{sensors}{suffix}',
                  {'bases': bases, 'twins': results,
                   'table': {e: {str(k): v for k, v in t.items()} for e, t in table.items()}},
                  lines)


def _twin_size(effect: str, limit: float, factor: float) -> float:
    """Return the size ``factor`` times as strong as a stated limit.

    A crack pressure's effect grows as it falls: ``factor`` divides it.
    """
    return limit / factor if effect == 'relief_valve' else limit * factor


def file_limits(count: int, sensors: str, jobs: int, first_seed: int,
                factors: Sequence[float], duration: float = DURATION,
                effects: Sequence[str] | None = None) -> None:
    """Measure the false alarms and check the stated limits per parameters file (--files).

    ``count`` effect-free draws of ``duration`` [s] from ``first_seed``, the plants a and b
    taking turns, each drawing its joint type; each effect a plant can hide whose limit the
    record states is put into the draw's twin (the same seed and length) at ``factors`` times
    the limit (:func:`_twin_size`) and diagnosed in full. Per file (joint type): the false
    alarms, each effect's stated limits (median and range), and the share of twins that named
    it (first) per factor; a stated limit holds in a record when its twin at factor 1 names it.
    ``effects``: twins of these effects only (a larger draw for one limit), default all.
    """
    with tempfile.TemporaryDirectory() as folder:
        bases = run_tasks([('ab'[i % 2], first_seed + i, 'none', None, sensors, folder,
                            duration) for i in range(count)], jobs)
        tasks = []
        for base in bases:
            if base['causes'] or base['verdict'] == 'structure':
                continue  # a record that named a cause states no limit for it
            for effect, limit in base['limits'].items():
                if limit is None or effect not in PLANTS[base['plant']].EFFECTS \
                        or (effects and effect not in effects):
                    continue
                tasks += [(base['plant'], base['seed'], effect, _twin_size(effect, limit, f),
                           sensors, folder, duration) for f in factors]
        twins = run_tasks(tasks, jobs)
    stated = {(b['plant'], b['seed'], e): v for b in bases for e, v in b['limits'].items()}
    for row in twins:
        limit = stated[(row['plant'], row['seed'], row['effect'])]
        row['factor'] = (limit / row['size'] if row['effect'] == 'relief_valve'
                         else row['size'] / limit)
    used = [u for r in bases + twins for u in r['stroke_used']]
    lines = [f'bench/detection.py --file-limits {count} --first-seed {first_seed} --files '
             f'{"bench" if RIG["folder"] is None else "shipped"} --sensors {sensors} '
             f'--factors {" ".join(f"{f:g}" for f in factors)} --duration {duration:g}: '
             f'{describe_machine()}',
             f'{len(bases)} effect-free draws of {duration:g} s (plants a and b taking turns) '
             f'and {len(twins)} twins; position over the stroke: {min(used):.2f} to '
             f'{max(used):.2f} of it; wall per diagnosis median '
             f'{float(np.median([r["wall_s"] for r in bases + twins])):.1f} s']
    table: dict[str, Any] = {}
    for joint in JOINT_NAMES:
        mine = [b for b in bases if b['joint'] == joint]
        quiet = [b for b in mine if not b['causes'] and b['verdict'] != 'structure']
        alarms = [b for b in mine if b['causes']]
        lines.append(f'{joint} ({rig_file(joint, RIG["folder"]).name}): false alarms '
                     f'{len(alarms)} of {len(mine)} effect-free draws'
                     + ''.join(f'; {b["plant"]} {b["seed"]} named {", ".join(b["causes"])}'
                               for b in alarms)
                     + f'; structure verdicts {sum(b["verdict"] == "structure" for b in mine)}')
        rows: dict[str, Any] = {'draws': len(mine), 'false_alarms': len(alarms)}
        for effect in (e for e in LIMIT_SIZES if not effects or e in effects):
            values = [b['limits'].get(effect) for b in quiet
                      if effect in PLANTS[b['plant']].EFFECTS]
            found = [v for v in values if v is not None]
            mytwins = [t for t in twins if t['joint'] == joint and t['effect'] == effect]
            shares = {}
            for f in factors:
                at = [t for t in mytwins if abs(t['factor'] - f) < 1e-6 * f]
                named = sum(bool(t['causes']) and t['causes'][0] == effect for t in at)
                shares[f'{f:g}'] = [named, len(at)]
            wrong = [t for t in mytwins if set(t['causes']) - {effect}]
            rows[effect] = {'limits': found, 'none_stated': len(values) - len(found),
                            'named': shares, 'another_cause': len(wrong)}
            spread = (f'median {float(np.median(found)):.3g}, {min(found):.3g} to '
                      f'{max(found):.3g}' if found else 'none stated')
            lines.append(f'  {effect}: stated {spread} ({len(found)} of {len(values)} records); '
                         + ', '.join(f'x{f}: named {n}/{k}' for f, (n, k) in shares.items())
                         + (f'; another cause named in {len(wrong)}: '
                            + ', '.join(f'{t["plant"]} {t["seed"]} {t["causes"]}'
                                        for t in wrong) if wrong else ''))
        table[joint] = rows
    write_results(f'detection_file_limits_{_tag(sensors)}_{first_seed}',
                  {'bases': bases, 'twins': twins, 'table': table}, lines)


def main() -> None:
    """Parse the arguments and run the ensemble, the limits or the twins."""
    parser = argparse.ArgumentParser(description=(__doc__ or '').splitlines()[0])
    mode = parser.add_mutually_exclusive_group(required=True)
    mode.add_argument('--null', type=int, metavar='N', help='effect-free draws')
    mode.add_argument('--limits', action='store_true', help='detection limit of each effect')
    mode.add_argument('--holdout', type=int, metavar='N',
                      help="effect-free draws of seeds apart from --null's, to check a rule "
                      'chosen on those')
    mode.add_argument('--twins', type=int, metavar='N',
                      help='effect-free draws whose stated limits are checked on their twins')
    mode.add_argument('--hidden', action='store_true',
                      help="the hidden-effect test's 21 draws, each outcome listed")
    mode.add_argument('--stated-limits', type=int, metavar='N',
                      help='effect-free draws whose stated limits are checked at the limit '
                      'itself, by twins (--plants)')
    mode.add_argument('--single', nargs='+', metavar='PLANT/SEED[/EFFECT]',
                      help='draws diagnosed one at a time on every core (a, b, c, c:paper)')
    parser.add_argument('--progress', action='store_true',
                        help="with --single: the diagnosis's progress lines")
    parser.add_argument('--plants', default='b',
                        help='with --stated-limits: the plants taking turns (a, b, c)')
    parser.add_argument('--offsets', type=int, nargs='+', default=[0, 2],
                        help='with --stated-limits: ladder steps stronger than the limit')
    parser.add_argument('--effects', nargs='+',
                        help='with --stated-limits or --file-limits: only these effects '
                        '(default all)')
    mode.add_argument('--low-relief', type=int, metavar='N',
                      help='draws of the second plant with a relief valve cracking at 20-30 %% '
                      'of its setting')
    mode.add_argument('--third', type=int, metavar='N',
                      help='draws of the third plant (one-way pump, direction valves, '
                      'accumulator, braking load), the effects taking turns')
    parser.add_argument('--circuit', choices=('switched', 'paper'), default='switched',
                        help="with --third: the rig's own circuit in its parameters file, or "
                        "the paper's")
    mode.add_argument('--file-limits', type=int, metavar='N',
                      help="effect-free draws: per parameters file, the false alarms, the "
                      "records' stated limits and their twins at --factors times them")
    parser.add_argument('--first-seed', type=int,
                        help=f'with --file-limits: the first seed (default {FIRST_FILE_LIMIT_SEED}'
                        f"; the fresh draw: {FIRST_FRESH_SEED}; the delay's own: "
                        f"{FIRST_DELAY_FRESH_SEED}; entrained air's: {FIRST_AIR_FRESH_SEED}, "
                        f'and at three steps {FIRST_AIR_CHECK_SEED})')
    parser.add_argument('--factors', type=float, nargs='+', default=[1.0, 2.0],
                        help='with --file-limits: sizes of the twins, as multiples of the limit')
    parser.add_argument('--duration', type=float, default=DURATION,
                        help='with --file-limits: length of each draw [s]')
    parser.add_argument('--files', choices=tuple(FILES), default='bench',
                        help="the parameters files the plants a and b draw around: the bench's "
                        '(test/bench_rig) or the shipped hip and knee (exo_has_sim/config)')
    parser.add_argument('--draws', type=int, default=10, help='draws per effect and size')
    parser.add_argument('--sensors', choices=('full', 'position'), default='full')
    parser.add_argument('--constant-load', action='store_true',
                        help="diagnose with --constant-load (the user's word that the load "
                        'does not vary)')
    parser.add_argument('--workers', '--jobs', dest='jobs', type=int,
                        default=os.cpu_count() or 1,
                        help='processes that write the draws, and worker processes that '
                        'diagnose them (default: one per CPU)')
    parser.add_argument('--scheduler', metavar='ADDRESS',
                        help='diagnose on the Dask cluster of this scheduler instead '
                        '(exo-has diagnose --scheduler)')
    args = parser.parse_args()
    WHERE.update(workers=args.jobs, scheduler=args.scheduler)
    RIG['folder'] = FILES[args.files]
    if args.constant_load:
        os.environ[CONSTANT_LOAD] = '1'  # the diagnoses of the forked processes read it
    if args.null is not None:
        null_ensemble(args.null, args.sensors, args.jobs)
    elif args.holdout is not None:
        null_ensemble(args.holdout, args.sensors, args.jobs, FIRST_HOLDOUT_SEED, 'holdout')
    elif args.twins is not None:
        twins(args.twins, args.sensors, args.jobs)
    elif args.single is not None:
        single(args.single, args.sensors, args.progress)
    elif args.hidden:
        hidden_draws(args.sensors, args.jobs)
    elif args.low_relief is not None:
        low_relief(args.low_relief, args.sensors, args.jobs)
    elif args.third is not None:
        third_plant(args.third, args.circuit, args.sensors, args.jobs)
    elif args.file_limits is not None:
        file_limits(args.file_limits, args.sensors, args.jobs,
                    args.first_seed or FIRST_FILE_LIMIT_SEED, args.factors, args.duration,
                    args.effects)
    elif args.stated_limits is not None:
        stated_limits(args.stated_limits, args.plants, args.sensors, args.jobs, args.offsets,
                      args.effects)
    else:
        detection_limits(args.draws, args.sensors, args.jobs)


if __name__ == '__main__':
    main()
