"""Acceptance of ``exo-has diagnose`` on command and position alone (issue 12).

The paper's rig logged the motor speed command and the position only (section 4.2), with the
load unmeasured. Then an effect that acts through the rodless pressure (friction, a quadratic
leakage, a cracked relief valve, entrained air) cannot be told from a load that varies, and
the diagnosis must say so rather than guess; what stays identifiable is the flow path from
the command to the pump. Draws of the two truth plants of this folder (as
``test_hidden_effects.py`` makes them, 20 s each), written with the columns ``time``,
``motor_speed_command``, ``position`` and ``reference`` only, diagnosed by the command.

The stated rate, over these draws: no alarm on the draws without an effect (the rate itself
is measured by bench/detection.py --null 40 --sensors position: on 2026-11-27 1 alarm in 40,
a 3.1 rad/s dead zone on the second plant's gait with four effects beside it, and 1 structure
verdict, a 47 % position fit; on 2026-11-26 2 in 40, and 0 of 40 on seeds apart); no cause
named other than the hidden effect unless the hidden effect is reported indistinguishable
from it (an effect that the signals cannot identify is still checked as a
rival of what is named: the second plant's entrained air, 6006, was once named as a 10.9
rad/s dead zone with the air beside it); every effect acting through the pressure reported
unidentifiable, never named; every pump dead zone of the first plant named, within
25 % of its size (here 5002; the second plant's, 11.8 rad/s on a knee's gait, came out
11.5 % high: bench/README.md, "Position only"). Transport delays are not asserted: without the
motor speed, a delay of a few milliseconds and a slower speed loop predict the position
alike, and none of the three delays of these draws is named (5010's 11 ms delay is fitted
and refused, the baseline re-fitted from the delay's values predicting as well). No
detection limit is stated without a pressure signal (none was measured there): asserted.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import second_truth_plant as sp
import truth_plant as tp
from diagnosis_runs import Queued
from rigs import rig_file

from exo_has_sim.diagnosis.cli import main
from exo_has_sim.diagnosis.effects import EFFECTS

pytestmark = pytest.mark.slow  # every test here runs long diagnoses

#: Columns of a record as the paper's rig logged it.
KEPT = ('time', 'motor_speed_command', 'position', 'reference')
#: (plant, seed, effect): seeds of test_hidden_effects.py: effect-free draws, effects through
#: the pressure (a 95 N friction in a squat makes lost motion at each reversal, as a dead zone
#: does: it was once named as a 3.6 rad/s one, with the friction beside it; a relief valve
#: cracked 10 MPa low slows the extension as a circuit that feeds the rod side would, and had
#: the structure's verdict), and a dead zone of the first plant (its other, 5009, named at
#: -0.0 % in bench/detection.py --hidden, is left to the bench: its diagnosis, rival checks
#: included, takes 2.4 min there). The walking knee (5007), whose dead zone false alarm was the
#: reason each window has a load of its own, is left to ``--null 40 --sensors position`` too.
#: A 28 N friction on a walking hip (5001) makes the flow gains differ by 1.40 by direction,
#: which the model with a friction explains as well as another circuit: no structure verdict.
#: The dead zone goes first: named, it takes about as long as the others together (2 min), and
#: one process does it while the other does the rest.
DRAWS = ((tp, 5002, 'pump_deadzone'), (tp, 5008, 'coulomb_friction'), (tp, 5005, 'relief_valve'),
         (tp, 5001, 'coulomb_friction'), (sp, 6000, 'none'), (tp, 5000, 'none'))
SIZE_TOLERANCE = 0.25


def run_draw(task):
    """Simulate one draw, keep the position-only columns, diagnose; return the JSON."""
    plant_name, seed, effect, folder = task
    plant = {tp.__name__: tp, sp.__name__: sp}[plant_name]
    draw = plant.draw(seed, effect=effect, duration=20.0)
    path = folder / f'position_only_{seed}.csv'
    table = np.column_stack([draw.columns[name] for name in KEPT])
    np.savetxt(path, table, fmt='%.17g', delimiter=',', header=','.join(KEPT), comments='')
    out = folder / f'position_only_{seed}.json'
    code = main([str(path), '--joint', draw.joint_type, '--params', str(rig_file(draw.joint_type)),
                 '--load-mass', '50', '--json', str(out), '-q'])
    assert code == 0
    return {'seed': seed, 'effect': effect, 'size': draw.size,
            'doc': json.loads(out.read_text())}


def queue_diagnoses(pool, folder):
    """Queue the draws in its pool (conftest.py)."""
    tasks = [(plant.__name__, seed, effect, folder) for plant, seed, effect in DRAWS]
    return Queued(folder, draws=pool.map_async(run_draw, tasks, chunksize=1))


@pytest.fixture(scope='module')
def results(diagnoses):
    rows = diagnoses['draws'].get()
    for row in rows:
        print(f'{row["seed"]} {row["effect"]:<18} named {row["doc"]["causes"]} '
              f'{row["doc"]["sizes"]}')
    return rows


def test_no_other_cause_is_named_unless_the_hidden_one_is_reported_beside_it(results):
    wrong = [(r['seed'], r['effect'], r['doc']['causes']) for r in results
             if set(r['doc']['causes']) - {r['effect']}
             and r['effect'] not in r['doc']['indistinguishable']]
    assert wrong == []
    assert all(not r['doc']['causes'] for r in results if r['effect'] == 'none')


def test_every_effect_through_the_pressure_is_reported_unidentifiable_not_named(results):
    through = sorted(e for e, effect in EFFECTS.items() if effect.through_pressure)
    for row in results:
        assert sorted(row['doc']['unidentifiable']) == through
        assert not set(row['doc']['causes']) & set(through)
        assert not set(row['doc']['detection_limits']) & set(through)
        assert all(limit['limit'] is None for limit in row['doc']['detection_limits'].values())
        # The effects that stay identifiable are still tried, the transport delay among them.
        tried = {r['effect'] for r in row['doc']['ranking']}
        assert 'transport_delay' in tried and not tried & set(through), row['seed']


def test_a_flow_gain_by_direction_that_an_effect_unseen_explains_gives_no_structure_verdict(
        results):
    # 5001: a 28 N seal friction on a walking hip, under its load, slows the extension
    # through the leakage at the pressure it adds: the flow gains differ by about 1.4, and a
    # closed circuit predicted the position with 0.31 of the paper circuit's error; the
    # paper's circuit with a friction, which these signals cannot identify, does as well.
    row = next(r for r in results if r['seed'] == 5001)
    assert row['doc']['verdict'] == 'none'
    gain = next(f for f in row['doc']['structure']['findings'] if f['check'] == 'direction_gain')
    assert not gain['passed'] and not gain['gating']  # reported, saying why it cannot decide
    assert 'record pressure_a' in gain['text']


def test_every_dead_zone_is_named_within_25_percent(results):
    for row in (r for r in results if r['effect'] == 'pump_deadzone'):
        assert row['doc']['causes'] == ['pump_deadzone'], row['seed']
        error = row['doc']['sizes']['pump_deadzone'] / row['size'] - 1.0
        assert abs(error) <= SIZE_TOLERANCE, (row['seed'], error)
