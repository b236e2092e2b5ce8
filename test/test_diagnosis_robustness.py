"""``exo-has diagnose`` on data and parameter files it was not made for: no traceback, ever.

Issue 12: a user's parameters file of another geometry on closed-loop data once ended a
diagnosis in ``OverflowError: math range error`` (a Gauss-Newton step mapped through exp()
unclipped). The data here come from the second truth plant (``second_truth_plant.py``), not
from the project's model.
"""

from __future__ import annotations

import json
import re

import pytest
import second_truth_plant as plant_b
from rigs import rig_file

from exo_has_sim.diagnosis.cli import STRUCTURE_STATUS, main


def params_file(tmp_path, name, **values):
    """Write the bench's hip file with some values replaced; return its path."""
    text = rig_file('hip').read_text()
    for key, value in values.items():
        text, count = re.subn(rf'^(      {key}): .*$', rf'\g<1>: {value}', text, count=1,
                              flags=re.MULTILINE)
        assert count == 1, key
    path = tmp_path / f'{name}.yaml'
    path.write_text(text)
    return path


@pytest.fixture(scope='module')
def log(tmp_path_factory):
    draw = plant_b.draw(12001, 'hip', effect='coulomb_friction', size=60.0,
                        excitation='sine_sum', duration=12.0)
    path = tmp_path_factory.mktemp('robust') / 'log.csv'
    plant_b.write_csv(draw, path)
    return path


@pytest.mark.slow
def test_a_parameters_file_of_another_geometry_gives_a_verdict_not_a_traceback(tmp_path, log,
                                                                             capsys):
    # A bigger bore, a thinner rod, a shorter stroke, a third of the dead volume, twice the
    # motor lag: far from the plant that made the data.
    other = params_file(tmp_path, 'other', bore_diameter=0.016, rod_diameter=0.006,
                        stroke=0.12, dead_volume=2.7e-06, motor_time_constant=0.01,
                        piston_mass=0.5)
    out = tmp_path / 'other.json'
    code = main([str(log), '--joint', 'hip', '--params', str(other), '--load-mass', '50',
                 '--json', str(out), '-q'])
    captured = capsys.readouterr()
    assert 'Traceback' not in captured.err
    assert code in (0, STRUCTURE_STATUS), captured.err  # an effect, none, or the structure's
    doc = json.loads(out.read_text())
    assert set(doc['causes']) <= {'coulomb_friction', 'pump_deadzone', 'transport_delay',
                                  'quadratic_leakage', 'relief_valve', 'entrained_air'}
    assert isinstance(doc['indistinguishable'], list)


def test_a_bad_uncertainty_in_the_parameters_file_fails_in_one_line_naming_it(tmp_path, log,
                                                                            capsys):
    bad = params_file(tmp_path, 'bad', dead_volume='8.0e-06')
    bad.write_text(bad.read_text().replace('      motor_time_constant: 0.3\n',
                                           '      motor_time_constant: 30\n', 1))
    code = main([str(log), '--joint', 'hip', '--params', str(bad), '-q'])
    err = capsys.readouterr().err
    assert code == 1
    assert 'uncertainty.motor_time_constant must be a relative standard uncertainty' in err
    assert 'Traceback' not in err and len(err.strip().splitlines()) == 1
