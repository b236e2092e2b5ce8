"""``exo-has diagnose`` on real measurements: the EMPS benchmark, and its command-line errors."""

import json

import numpy as np
import pytest
from numpy.testing import assert_allclose

from exo_has_runtime.cli import subcommands
from exo_has_sim.diagnosis.cli import main
from exo_has_sim.diagnosis.data import write_csv
from exo_has_sim.diagnosis.emps import DATA_FILE, REFERENCE, load_emps


@pytest.fixture(scope='module')
def emps_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp('emps') / 'emps.csv'
    write_csv(load_emps(), path)
    return path


def test_the_shipped_emps_record_is_the_benchmark_s_estimation_set():
    m = load_emps()
    assert m.samples == 24841 and m.plant == 'mass'
    assert_allclose(m.period, 1e-3, rtol=1e-4)
    with np.load(DATA_FILE) as data:
        assert_allclose(data['gtau'][0], 35.15065188, rtol=1e-9)
        assert_allclose(m.input, data['gtau'][0] * data['vir'], rtol=0)
    assert (DATA_FILE.parent / 'README.md').is_file()


def test_emps_names_coulomb_friction_with_fc_within_20_percent(emps_csv, tmp_path, capsys):
    out = tmp_path / 'emps.json'
    report = tmp_path / 'report'
    code = main([str(emps_csv), '--plant', 'mass', '--load-mass', '95', '--json', str(out),
                 '--report', str(report)])
    assert code == 0
    doc = json.loads(out.read_text())
    assert doc['cause'] == 'coulomb_friction'
    assert doc['causes'] == ['coulomb_friction']
    fc = doc['parameters']['coulomb_friction']['value']
    assert_allclose(fc, REFERENCE['coulomb_friction'], rtol=0.2)
    low, high = doc['parameters']['coulomb_friction']['ci95']
    assert low < fc < high
    assert_allclose(doc['parameters']['mass']['value'], REFERENCE['mass'], rtol=0.1)
    assert_allclose(doc['parameters']['viscous_friction']['value'],
                    REFERENCE['viscous_friction'], rtol=0.1)
    assert doc['fit_extended'] > doc['fit_baseline'] + 1.0
    assert {row['effect'] for row in doc['ranking']} == {'coulomb_friction', 'transport_delay',
                                                          'pump_deadzone'}
    assert doc['ranking'][0]['effect'] == 'coulomb_friction'
    assert all(set(row) >= {'effect', 'fit', 'score'} for row in doc['ranking'])
    assert doc['transfer_function']['fit'] is not None
    for name in ('report.md', 'predictions.png', 'ranking.png', 'residual_tests.png',
                 'signatures.png'):
        assert (report / name).is_file()
    text = (report / 'report.md').read_text()
    assert 'Cause: Coulomb friction' in text and 'signatures.png' in text
    captured = capsys.readouterr()
    assert 'cause: coulomb_friction' in captured.out
    assert 'step 1' in captured.err  # progress, one line per effect


def test_the_command_is_registered_with_exo_has():
    assert 'diagnose' in subcommands()


def test_bad_input_fails_with_a_message_naming_the_problem(tmp_path, capsys):
    assert main([str(tmp_path / 'missing.csv'), '-q']) == 1
    assert 'cannot read' in capsys.readouterr().err
    log = tmp_path / 'log.csv'
    log.write_text('time,position\n' + '\n'.join(f'{k * 0.005},0.05' for k in range(300)))
    assert main([str(log), '-q']) == 1
    assert 'missing column motor_speed_command' in capsys.readouterr().err
    assert main([str(log), '--plant', 'mass', '-q']) == 1
    assert 'missing column force' in capsys.readouterr().err
    assert main([str(log), '--load-mass', '-3', '-q']) == 1
    assert 'positive mass' in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(log), '--plant', 'spring'])
