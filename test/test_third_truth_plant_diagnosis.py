"""Acceptance of ``exo-has diagnose`` (issue 25) on a rig of another circuit, simulated apart.

The data come from ``third_truth_plant.py``, written apart from the project's model and from
the other two truth plants: a one-way gear pump, direction valves, an accumulator on the
low-pressure side, a 50/28 mm cylinder and a hydraulic load cylinder that brakes both ways, its
motor torque-limited, logged as the real rig of the issue was (command, motor speed, position,
both pressures; the load not measured). Each draw takes its nuisance parameters, brake, mass,
excitation, noise and hidden effect from its seed, and is diagnosed by the command as a user
would, with a parameters file written from the rig's datasheet (``third_rig.py``).

- Described with the paper's circuit (the project's model, the rig's own values): every record
  logged with its pressures gets the verdict that the model's structure does not describe the
  data, naming the flow gain that differs by direction by about A_A/A_B, with exit status 3;
  from the position alone the flow gain is named too, and decides only where no effect that
  the position cannot identify explains it; no effect is named.
- Described with its own circuit (``circuit: switched``, the brake declared with its
  uncertainty): the structure describes every record, nothing is named that is not there,
  the sizes named are within 25 %, a seal's friction is reported as not identifiable beside
  the brake whose force is fitted, and where an effect is missed the record's own detection
  limit does not claim it would have been named, and a limit is stated only for the effect
  whose margin was measured on this plant (the relief valve). The draws are four of the
  first seven of ``bench/detection.py --third 14`` (results/detection_third_switched_full.txt),
  whose brakes are held where the torque-limited motor keeps up (``third_rig.HELD_BRAKES``).
"""

from __future__ import annotations

import json
import math
import os

import pytest
import third_rig
import third_truth_plant as rig
from diagnosis_runs import Queued

from exo_has_sim.diagnosis.cli import STRUCTURE_STATUS, main

pytestmark = pytest.mark.slow  # every test here runs long diagnoses

LOGGED = third_rig.LOGGED
POSITION_ONLY = ('time', 'motor_speed_command', 'position', 'reference')
#: Draws described with the paper's circuit: seed, effect, columns.
PAPER_CIRCUIT_DRAWS = ((9103, 'none', POSITION_ONLY), (9102, 'quadratic_leakage', LOGGED),
                       (9100, 'none', LOGGED))
#: Draws described with the rig's own circuit, seeds of bench/detection.py --third (where
#: the effects take turns, none first): no effect, a seal's friction beside the brake, a
#: quadratic leakage and a relief valve, the one effect whose limit is stated on this circuit
#: (the bench's other three draws of its first seven, a dead zone, a delay and entrained air,
#: are missed there with no limit stated, and took 2 of this test's 4 minutes).
RIGHT_CIRCUIT_DRAWS = ((95005, 'relief_valve', LOGGED), (95004, 'quadratic_leakage', LOGGED),
                       (95000, 'none', LOGGED), (95001, 'coulomb_friction', LOGGED))
#: The effects whose detection limit is stated where the pump feeds either chamber
#: (exo_has_sim.diagnosis.limits.LIMIT_MARGIN['either']).
STATED_ON_THIS_CIRCUIT = {'relief_valve'}
SIZE_TOLERANCE = 0.25


FIRST = {'paper': PAPER_CIRCUIT_DRAWS[0][0], 'switched': RIGHT_CIRCUIT_DRAWS[0][0]}


def diagnose_draw(task):
    """Simulate one draw, write what the rig logs, diagnose it; return the code and the JSON."""
    seed, effect, columns, circuit, folder = task
    draw = rig.draw(seed, effect=effect, duration=20.0, brake_force=third_rig.held_brake(seed))
    path = os.path.join(folder, f'{circuit}_{seed}.csv')
    rig.write_csv(draw, path, columns=columns)
    params = third_rig.write_rig_file(os.path.join(folder, f'{circuit}.yaml'), circuit)
    out = os.path.join(folder, f'{circuit}_{seed}.json')
    # The first record of each circuit also gets its report: a structure verdict's report once
    # failed on the extended model's residual tests, which that verdict has none of.
    report = ('--report', os.path.join(folder, f'{circuit}_{seed}')) if seed == FIRST[circuit] \
        else ()
    code = main([path, '--params', str(params), '--json', out, '-q', *report])
    with open(out, encoding='utf-8') as handle:
        return draw, code, json.load(handle)


def queue_diagnoses(pool, folder):
    """Queue the draws of both descriptions in its pool (conftest.py)."""
    tasks = [(seed, effect, columns, 'paper', str(folder))
             for seed, effect, columns in PAPER_CIRCUIT_DRAWS]
    tasks += [(seed, effect, columns, 'switched', str(folder))
              for seed, effect, columns in RIGHT_CIRCUIT_DRAWS]
    return Queued(folder, draws=pool.map_async(diagnose_draw, tasks, chunksize=1))


@pytest.fixture(scope='module')
def diagnoses_folder(diagnoses):
    return diagnoses.folder


@pytest.fixture(scope='module')
def done(diagnoses):
    return diagnoses['draws'].get()


@pytest.fixture(scope='module')
def paper_circuit(done):
    return done[:len(PAPER_CIRCUIT_DRAWS)]


@pytest.fixture(scope='module')
def right_circuit(done):
    return done[len(PAPER_CIRCUIT_DRAWS):]


def logged(doc):
    """Whether the record had the rig's pressures (else its position only)."""
    return 'pressure_a' in doc['data']['outputs']


def test_with_the_papers_circuit_every_logged_record_gets_the_structure_verdict_and_no_effect(
        paper_circuit, diagnoses_folder):
    report = diagnoses_folder / f'paper_{FIRST["paper"]}' / 'report.md'
    assert 'structure' in report.read_text()
    for draw, code, doc in paper_circuit:
        assert doc['causes'] == [], draw.seed
        if logged(doc):
            assert code == STRUCTURE_STATUS and doc['verdict'] == 'structure', draw.seed


def test_the_flow_gain_that_differs_by_direction_by_the_area_ratio_is_named_in_every_record(
        paper_circuit):
    ds = rig.datasheet()
    areas = ds['bore_diameter'] ** 2 / (ds['bore_diameter'] ** 2 - ds['rod_diameter'] ** 2)
    for draw, _, doc in paper_circuit:
        gain = next(f for f in doc['structure']['findings'] if f['check'] == 'direction_gain')
        assert not gain['passed'], draw.seed
        # Closer to A_A/A_B (1.46) than to 1: an effect that costs the loaded side flow (a
        # leakage at the rod side's pressure) takes some off it (1.24-1.49 over 14 draws,
        # bench/detection.py --third 14 --circuit paper).
        assert abs(math.log(gain['value'] / areas)) < abs(math.log(gain['value'])), draw.seed
        assert 'A_A/A_B' in gain['text']
        # From the position alone it decides only where no effect the position cannot see
        # predicts the record nearly as well as another circuit (bench/detection.py --third 8
        # --circuit paper --sensors position: in none of 8); else it says what would.
        if logged(doc):
            assert gain['gating'], draw.seed
        elif not gain['gating']:
            assert 'record pressure_a' in gain['text'], draw.seed


def test_with_both_pressures_the_rod_side_and_the_brake_are_seen_and_the_rigs_circuit_suggested(
        paper_circuit):
    for draw, _, doc in paper_circuit:
        if 'pressure_b' not in doc['data']['outputs'] and doc['data']['outputs'] != [
                'position']:
            continue
        findings = {f['check']: f for f in doc['structure']['findings']}
        if 'pressure_a' not in doc['fits']['baseline']:
            continue  # position only: the circuit is seen from the flow gain alone
        assert not findings['rod_pressure']['passed'], draw.seed
        assert doc['structure']['suggestion'] is not None, draw.seed
        assert doc['structure']['suggestion'].startswith(('circuit=switched',
                                                          'circuit=closed')), draw.seed
        best = doc['structure']['alternatives'][0]
        brake = draw.parameters['brake_force']
        assert math.isclose(best['parameters']['brake_force'], brake, rel_tol=0.3), draw.seed


def test_with_its_own_circuit_the_structure_describes_every_record(right_circuit):
    for draw, code, doc in right_circuit:
        assert code == 0 and doc['verdict'] != 'structure', (draw.seed, doc['structure'])


def test_with_its_own_circuit_nothing_is_named_that_is_not_there(right_circuit):
    for draw, _, doc in right_circuit:
        assert set(doc['causes']) <= set(draw.effects), (draw.seed, doc['causes'])


def test_the_sizes_named_on_the_rig_are_within_25_percent_of_the_truth(right_circuit):
    named = [(draw, doc) for draw, _, doc in right_circuit if draw.effect in doc['sizes']]
    assert {draw.effect for draw, _ in named} >= {'relief_valve'}
    for draw, doc in named:
        assert abs(doc['sizes'][draw.effect] / draw.size - 1.0) <= SIZE_TOLERANCE, draw.seed


def test_a_seals_friction_is_not_identifiable_beside_the_brake_whose_force_is_fitted(
        right_circuit):
    for draw, _, doc in right_circuit:
        assert 'coulomb_friction' in doc['unidentifiable'], draw.seed
        assert 'brake' in doc['unidentifiable']['coulomb_friction']


def test_a_limit_is_stated_only_where_it_was_measured_and_never_claims_a_missed_effect(
        right_circuit):
    for draw, _, doc in right_circuit:
        stated = {e for e, limit in doc['detection_limits'].items() if limit['limit'] is not None}
        assert stated <= STATED_ON_THIS_CIRCUIT, (draw.seed, stated)
        if draw.effect == 'none' or draw.effect in doc['causes'] \
                or draw.effect in doc['unidentifiable']:
            continue
        limit = doc['detection_limits'][draw.effect]['limit']
        if limit is None:
            continue  # the record states no limit for it: nothing is claimed
        stronger = draw.size >= limit if draw.effect != 'relief_valve' else draw.size <= limit
        assert not stronger, (draw.seed, draw.effect, draw.size, limit)
