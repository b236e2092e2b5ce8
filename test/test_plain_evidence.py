"""The plainest evidence comes first, and a "none" says what it could not judge.

Records of the first truth plant (test/truth_plant.py: a 14 mm bore, 130 mm stroke cylinder
simulated apart from the project's model), diagnosed by the command as a user runs it.
"""

import json

import pytest
import truth_plant as tp
from rigs import rig_file

from exo_has_sim.diagnosis.cli import STRUCTURE_STATUS, main
from exo_has_sim.diagnosis.evidence import stroke_reach
from exo_has_sim.diagnosis.loading import load_plant


@pytest.fixture(scope='module')
def hip_record(tmp_path_factory):
    folder = tmp_path_factory.mktemp('plain')
    draw = tp.draw(5, 'hip', effect='none', excitation='sine_sum', duration=10.0)
    path = folder / 'hip.csv'
    tp.write_csv(draw, path)
    return draw, path


def file_with_stroke(path, stroke):
    """Write the bench's hip file with another stroke [m]; return its path."""
    text = rig_file('hip').read_text().replace('stroke: 0.13', f'stroke: {stroke!r}')
    assert f'stroke: {stroke!r}' in text
    path.write_text(text)
    return path


def test_a_record_past_the_files_stroke_gets_the_structure_verdict_citing_the_stroke_first(
        hip_record, tmp_path, capsys):
    draw, path = hip_record
    reach = float(draw.columns['position'].max())
    stroke = 0.07  # the record reaches 80 mm: a file of another, shorter cylinder
    assert reach > stroke * 1.05
    params = file_with_stroke(tmp_path / 'short.yaml', stroke)
    out = tmp_path / 'short.json'
    code = main([str(path), '--params', str(params), '--load-mass', '50', '--json', str(out)])
    assert code == STRUCTURE_STATUS
    lines = capsys.readouterr().out.splitlines()
    assert lines[0] == 'verdict: structure'
    assert lines[2].startswith('  the stroke: the record moves from')
    assert f'a stroke of {stroke * 1e3:.1f} mm' in lines[2]
    assert 'the file does not describe this cylinder' in lines[2]
    doc = json.loads(out.read_text())
    first = doc['structure']['findings'][0]
    assert first['check'] == 'stroke' and not first['passed'] and first['gating']
    assert first['value'] == pytest.approx(reach - stroke, abs=1e-3)
    # No other circuit changes a cylinder's stroke: none is fitted in vain.
    assert doc['structure']['alternatives'] == []


def test_a_record_within_the_stroke_passes_the_stroke_finding(hip_record):
    _, path = hip_record
    finding = stroke_reach(load_plant(path, 'has', 'hip', 50.0, rig_file('hip'), False, False))
    assert finding.check == 'stroke' and finding.passed and finding.gating
    assert finding.value == 0.0
    assert 'a stroke of 130.0 mm' in finding.text


def test_a_spent_time_budget_skips_the_refining_searches_and_says_which(hip_record, tmp_path,
                                                                        capsys):
    _, path = hip_record
    out = tmp_path / 'budget.json'
    code = main([str(path), '--params', str(rig_file('hip')), '--load-mass', '50', '--json',
                 str(out), '--time-budget', '0.001'])
    assert code == 0
    doc = json.loads(out.read_text())
    assert doc['untried'] == ['the named causes against their rival effects',
                              'the detection limits of the effects left out']
    assert doc['detection_limits'] == {}
    assert len(doc['steps']) == 1  # the first step of the selection always runs
    captured = capsys.readouterr()
    assert 'the time budget ended the search; not tried: the named causes' in captured.out
    assert 'the time budget of 0.001 s ended the search' in captured.err


def test_a_time_budget_must_be_positive(hip_record, capsys):
    _, path = hip_record
    assert main([str(path), '--time-budget', '0']) == 1
    assert 'a time budget must be positive seconds, got 0.0' in capsys.readouterr().err
