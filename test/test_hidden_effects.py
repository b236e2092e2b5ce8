"""Acceptance of ``exo-has diagnose`` (issues 5 and 12): hidden effects in data of two plants.

The data come from two truth plants in this folder, each written without the project's model
and run in closed loop at 200 Hz for 20 s: ``truth_plant.py`` (the paper's structure, compact
valve, PD controller; 14 draws) and ``second_truth_plant.py`` (written apart from both: rod
side to a tank through a line, a second-order motor loop, a PI controller, quantised sensors;
7 draws). Every draw takes from its seed the plant's hard-to-know parameters (+-30 %; the
second plant also its motor lag, flow gain and dead volume, +-20-30 %), the excitation, the
load, the sensor noise and the effect's size; the effect itself is set in turn to each of the
seven choices (none and the six effects), twice on the first plant and once on the second,
since free draws of one in seven would leave an effect out. Each draw is written as a
CSV log and diagnosed by the command (``main``) with the joint type's parameters file, as a
user would, with the JSON document as the result.

Acceptance: over the 21 draws, the named cause is the hidden effect (exactly, ``none`` for the
none draws) in at least 90 %; every size named is within 25 % of the truth, on each plant; every
real effect shows a positive validated gain in the ranking; no none draw raises an alarm (the
calibrated rate is measured by bench/detection.py on 40 draws). Two effects at once (Coulomb
friction with a transport delay) are both named, or the delay reported as indistinguishable
from a second-order motor loop. A table of every draw is printed (``pytest -s``).
"""

from __future__ import annotations

import time

import pytest
import second_truth_plant as sp
import truth_plant as tp
from diagnosis_runs import Queued, diagnose_csv

#: (plant, draws, first seed): the effects take turns over each plant's draws.
PLANTS = ((tp, 14, 5000), (sp, 7, 6000))
SIZE_TOLERANCE = 0.25
FIRST_SEED = PLANTS[0][2]
#: Two effects at once, on one draw of the first plant.
TWO_EFFECTS = {'coulomb_friction': 80.0, 'transport_delay': 0.008}


def run_draw(task):
    """Simulate one draw of a plant, write its CSV, diagnose it; return the table row."""
    plant_name, seed, effect, folder = task
    plant = {tp.__name__: tp, sp.__name__: sp}[plant_name]
    draw = plant.draw(seed, effect=effect, duration=20.0)
    path = folder / f'draw_{seed}.csv'
    plant.write_csv(draw, path)
    started = time.perf_counter()
    doc = diagnose_csv(path, draw.joint_type, 50.0, folder / f'draw_{seed}.json')
    return {'plant': plant_name, 'draw': draw, 'doc': doc,
            'wall': time.perf_counter() - started}


def run_two_effects(folder):
    """Simulate a draw of the first plant with two effects at once, diagnose it.

    Return the effects simulated and the JSON document.
    """
    base = tp.draw(FIRST_SEED + 100, 'hip', effect='none', excitation='sine_sum')
    run = tp.simulate(tp.plant_parameters(base), TWO_EFFECTS,
                      reference=base.clean['reference'], load_force=base.clean['load_force'],
                      noise=base.noise, seed=base.seed)
    path = folder / 'two.csv'
    header = ','.join(tp.COLUMNS)
    rows = zip(*(run.noisy[name] for name in tp.COLUMNS), strict=True)
    path.write_text(header + '\n' + '\n'.join(','.join(f'{v:.17g}' for v in row)
                                              for row in rows) + '\n')
    return run.effects, diagnose_csv(path, 'hip', base.load_mass, folder / 'two.json')


def queue_diagnoses(pool, folder):
    """Queue the record with two effects and the draws in its pool (conftest.py).

    Each test takes its own result, and fails on its own where that raised.
    """
    # The second plant's draws first: they take the longest (up to 50 s each), and the
    # processes then end on short ones together.
    tasks = [(plant.__name__, first_seed + i, tp.EFFECT_CHOICES[i % len(tp.EFFECT_CHOICES)],
              folder) for plant, draws, first_seed in reversed(PLANTS) for i in range(draws)]
    return Queued(folder, two=pool.apply_async(run_two_effects, (folder,)),
                  draws=pool.map_async(run_draw, tasks, chunksize=1))


@pytest.fixture(scope='module')
def results(diagnoses):
    rows = diagnoses['draws'].get()
    print_table(rows)
    return rows


def size_error(row):
    draw, doc = row['draw'], row['doc']
    if draw.effect == 'none' or draw.effect not in doc['sizes']:
        return None
    return doc['sizes'][draw.effect] / draw.size - 1.0


def hit(row):
    expected = [] if row['draw'].effect == 'none' else [row['draw'].effect]
    return row['doc']['causes'] == expected


def ranking_row(row):
    return next(r for r in row['doc']['ranking'] if r['effect'] == row['draw'].effect)


def print_table(rows):
    print(f'\n{"plant":<18} {"seed":>5} {"effect":<18} {"joint":<5} {"excitation":<9} '
          f'{"named":<30} '
          f'{"size":>10} {"error":>7} {"fit":>15} {"wall":>6}')
    for row in rows:
        draw, doc = row['draw'], row['doc']
        error = size_error(row)
        print(f'{row["plant"]:<18} {draw.seed:>5} {draw.effect:<18} {draw.joint_type:<5} '
              f'{draw.excitation:<9} '
              f'{",".join(doc["causes"]) or "none":<30} {draw.size:>10.4g} '
              f'{"" if error is None else f"{error:+.1%}":>7} '
              f'{doc["fit_baseline"]:6.2f}->{doc["fit_extended"]:6.2f} {row["wall"]:5.1f}s')
    hits = sum(hit(row) for row in rows)
    print(f'named correctly: {hits}/{len(rows)}; wall {sum(r["wall"] for r in rows):.0f} s')


@pytest.mark.slow
def test_the_hidden_effect_is_named_in_at_least_90_percent_of_the_draws(results):
    assert sp.EFFECT_CHOICES == tp.EFFECT_CHOICES
    for plant in (tp, sp):
        drawn = {row['draw'].effect for row in results if row['plant'] == plant.__name__}
        assert drawn == set(tp.EFFECT_CHOICES), plant.__name__
    assert sum(hit(row) for row in results) >= 0.9 * len(results)


@pytest.mark.slow
@pytest.mark.parametrize('plant, share', [(tp, 0.9), (sp, 0.5)],
                         ids=['first plant', 'second plant'])
def test_every_size_named_is_within_25_percent_of_the_truth(results, plant, share):
    # The second plant's structure differs from the model's (rod side through a line, a
    # second-order motor loop, a PI controller): its small quadratic leakage (6004) comes out
    # 20 % low (44 % low while the model took the paper's averaged flow area). Of its six
    # effects, its 7.8 ms delay lies under its record's detection limit beside the motor's
    # second-order loop, and its relief valve ties with a quadratic leakage, reported beside
    # it: four are named.
    rows = [row for row in results if row['plant'] == plant.__name__]
    named = [e for e in (size_error(row) for row in rows) if e is not None]
    assert len(named) >= share * sum(row['draw'].effect != 'none' for row in rows)
    assert max(abs(e) for e in named) <= SIZE_TOLERANCE, named


@pytest.mark.slow
def test_every_real_effect_shows_a_positive_validated_gain(results):
    for row in results:
        if row['draw'].effect == 'none':
            continue
        doc = row['doc']
        # The diagnosis's own measure of gain: the validated cost over all outputs.
        assert ranking_row(row)['cost_ratio'] < 1.0, row['draw'].seed
        if row['plant'] == tp.__name__ and not doc['baseline_structure']:
            assert ranking_row(row)['fit'] > doc['fit_baseline'], row['draw'].seed
        if hit(row):
            assert doc['fit_extended'] > doc['fit_baseline']
            low, high = doc['parameters'][_size_name(row['draw'].effect)]['ci95']
            assert low <= doc['sizes'][row['draw'].effect] <= high


@pytest.mark.slow
def test_no_false_alarm_on_the_draws_without_an_effect(results):
    nones = [row for row in results if row['draw'].effect == 'none']
    assert len(nones) == sum(draws // len(tp.EFFECT_CHOICES) for _, draws, _ in PLANTS)
    for row in nones:
        assert row['doc']['verdict'] == 'none', row['draw'].seed
        assert row['doc']['cause'] == 'none' and row['doc']['causes'] == [], row['draw'].seed
        assert row['doc']['fit_extended'] == row['doc']['fit_baseline']


def _size_name(effect):
    return 'relief_crack_pressure' if effect == 'relief_valve' else effect


@pytest.mark.slow
def test_two_effects_at_once_are_both_found_named_or_reported_beside_their_rival(diagnoses):
    effects, doc = diagnoses['two'].get()
    # The delay ties with a second-order motor loop in these data (issue 12): a verdict may
    # take the loop and report the delay beside it as indistinguishable, but never drop it.
    assert doc['causes'][0] == 'coulomb_friction'
    if doc['causes'] == ['coulomb_friction']:
        assert doc['baseline_structure'] == ['second_order_motor']
        assert 'transport_delay' in doc['indistinguishable']
    else:
        assert doc['causes'] == ['coulomb_friction', 'transport_delay']
    for effect in doc['causes']:
        assert abs(doc['sizes'][effect] / effects[effect] - 1.0) <= SIZE_TOLERANCE, effect
    assert doc['fit_extended'] > doc['fit_baseline']
