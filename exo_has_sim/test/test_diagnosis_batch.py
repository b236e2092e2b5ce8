"""Many records: finding them, naming them, their summary, the batch's exit status.

Nothing here diagnoses a record in full nor starts a process (``--workers 0``: in this
process); test/test_diagnosing_many.py runs whole batches on worker processes and on a Dask
cluster.
"""

import csv
import json
import math

import pytest

from exo_has_sim.diagnosis.batch import (
    DESCRIBED_STATUS,
    ERROR_STATUS,
    INTERRUPTED_STATUS,
    STRUCTURE_STATUS,
    UNFINISHED_STATUS,
    BatchOutcome,
)
from exo_has_sim.diagnosis.cli import main
from exo_has_sim.diagnosis.records import Options, Record, find_records, record_id
from exo_has_sim.diagnosis.summary import SummaryFolder, SummaryRow

#: Enough of a CSV log's header and rows to be read, too few to be diagnosed.
SHORT_LOG = 'time,motor_speed_command,position\n' + ''.join(
    f'{0.005 * k},0.0,0.05\n' for k in range(20))


def write_bag(path, joints):
    """Write a bag that records the HAS states of ``joints`` (no messages: its topics)."""
    from exo_has_common.bag import BagWriter

    with BagWriter(path) as writer:
        for joint in joints:
            writer.add_topic(f'/{joint}/has_state', 'exo_has_msgs/msg/HasState')
            writer.add_topic(f'/{joint}/has_command', 'exo_has_msgs/msg/HasCommand')
    return path


def test_the_records_of_folders_and_bags_are_found_each_once_with_every_joint_of_a_bag(tmp_path):
    (tmp_path / 'day' / 'bench').mkdir(parents=True)
    (tmp_path / 'day' / '.cache').mkdir()
    (tmp_path / 'day' / 'summary').mkdir()
    for name in ('day/a.csv', 'day/bench/b.CSV', 'day/.cache/hidden.csv',
                 'day/summary/summary.csv', 'day/notes.txt'):
        (tmp_path / name).write_text(SHORT_LOG)
    bag = write_bag(tmp_path / 'day' / 'bench' / 'session', ['right_knee', 'left_hip'])
    day = tmp_path / 'day'
    found = find_records([day, day / 'a.csv'], 'all', leave_out=[day / 'summary'])
    assert [(r.source.relative_to(tmp_path).as_posix(), r.joint) for r in found] == [
        ('day/a.csv', None), ('day/bench/b.CSV', None),
        ('day/bench/session', 'left_hip'), ('day/bench/session', 'right_knee')]
    assert find_records([bag], 'left_hip') == [Record(bag, 'left_hip')]
    # Without --joint, the diagnosis asks for one (the bag records two); a path that is not
    # there is a record too: its diagnosis names the problem.
    assert find_records([bag, tmp_path / 'gone.csv']) == [Record(bag),
                                                          Record(tmp_path / 'gone.csv')]
    # A CSV log has no joints: with --joint all it takes a hip's parameter set.
    assert find_records([day / 'a.csv'], 'knee') == [Record(day / 'a.csv', 'knee')]


def test_a_records_id_is_stable_and_changes_with_its_data_options_and_parameters_file(
        tmp_path):
    log = tmp_path / 'session 1.csv'
    log.write_text(SHORT_LOG)
    params = tmp_path / 'rig.yaml'
    params.write_text('a: 1\n')
    record = Record(log, 'hip', Options(params=params, load_mass=50.0))
    first = record_id(record)
    assert first == record_id(Record(log, 'hip', Options(params=params, load_mass=50.0)))
    assert first.startswith('session_1-hip-') and len(first) == len('session_1-hip-') + 16
    assert record_id(Record(log, 'knee', record.options)) != first
    assert record_id(Record(log, 'hip', Options(params=params, load_mass=40.0))) != first
    params.write_text('a: 2\n')
    assert record_id(record) != first
    params.write_text('a: 1\n')
    log.write_text(SHORT_LOG + '0.1,0.0,0.05\n')
    assert record_id(record) != first


def test_the_summary_lists_each_records_verdict_cause_size_fits_seconds_and_error(tmp_path):
    found = {'verdict': 'effect', 'cause': 'coulomb_friction',
             'sizes': {'coulomb_friction': 80.26},
             'steps': [[{'effect': 'coulomb_friction', 'unit': 'N'}]],
             'fits': {'nominal': {'position': 93.28}}, 'fit_baseline': 99.12,
             'fit_extended': 99.76, 'record': {'seconds': 4.21}}
    folder = SummaryFolder(tmp_path / 'out')
    rows = [SummaryRow.of(Record(tmp_path / 'a.csv', 'hip'), 'a-1', found),
            SummaryRow.of(Record(tmp_path / 'b|c.csv'), 'b-2',
                          {'verdict': 'error', 'error': 'b.csv: row 3 has 2 fields',
                           'record': {'seconds': 0.01}}, done_before=True),
            SummaryRow.unfinished(Record(tmp_path / 'd.csv'), 'd-3', 'its worker died')]
    markdown, table = folder.write_summary(rows)
    text = markdown.read_text()
    assert '3 records: 1 effect, 1 error, 1 unfinished (1 done by an earlier run).' in text
    assert ('| effect | coulomb_friction | 80.26 N | 93.28 / 99.12 / 99.76 | 4.2 | '
            '[a-1](records/a-1.json) |') in text
    assert 'b\\|c.csv' in text  # a | in a path does not split the table's cells
    assert '## Could not be diagnosed' in text and 'b.csv: row 3 has 2 fields' in text
    assert '## Not finished' in text and 'its worker died' in text
    lines = list(csv.DictReader(table.open()))
    assert [line['verdict'] for line in lines] == ['effect', 'error', 'unfinished']
    assert float(lines[0]['size']) == 80.26 and lines[0]['unit'] == 'N'
    assert lines[0]['fit_extended'] == '99.76' and lines[0]['seconds'] == '4.2'
    assert lines[2]['json'] == '' and lines[2]['error'] == 'its worker died'


def test_a_records_json_is_written_whole_and_one_not_written_by_the_batch_is_done_again(
        tmp_path):
    folder = SummaryFolder(tmp_path)
    path = folder.write('a-1', {'verdict': 'none', 'value': math.pi})
    assert json.loads(path.read_text())['value'] == math.pi
    assert folder.done('a-1') == {'verdict': 'none', 'value': math.pi}
    assert [p.name for p in path.parent.iterdir()] == ['a-1.json']  # no temporary left
    path.write_text('{"verdict": "no')  # cut short: the record is done again
    assert folder.done('a-1') is None
    assert folder.done('b-2') is None


@pytest.mark.parametrize(('verdicts', 'interrupted', 'status'), [
    (['effect', 'none'], False, DESCRIBED_STATUS),
    (['none', 'structure'], False, STRUCTURE_STATUS),
    (['structure', 'error'], False, ERROR_STATUS),
    (['error', 'unfinished'], False, UNFINISHED_STATUS),
    (['none'], True, INTERRUPTED_STATUS),
])
def test_the_batchs_exit_status_tells_the_worst_that_happened(tmp_path, verdicts, interrupted,
                                                                status):
    rows = [SummaryRow(Record(tmp_path / f'{k}.csv'), str(k), verdict)
            for k, verdict in enumerate(verdicts)]
    assert BatchOutcome(rows, interrupted, (tmp_path, tmp_path)).status == status


def test_a_batch_lists_the_records_it_cannot_read_and_a_rerun_skips_what_is_done(tmp_path,
                                                                                capsys):
    short = tmp_path / 'short.csv'
    short.write_text(SHORT_LOG)
    torn = tmp_path / 'torn.csv'
    torn.write_text(SHORT_LOG + '0.1,1.0')  # cut mid-row
    out = tmp_path / 'out'
    args = [str(short), str(torn), str(tmp_path / 'gone.csv'), '--summary', str(out),
            '--workers', '0']
    assert main(args) == ERROR_STATUS
    captured = capsys.readouterr()
    assert '3 records: 0 done before, 3 to diagnose in this process' in captured.err
    assert 'short.csv: error (0.0 s): ' in captured.err  # a line per record, not a terminal
    assert '3 records: 3 error' in captured.out
    rows = {line['input']: line for line in csv.DictReader((out / 'summary.csv').open())}
    assert 'needs at least 200' in rows[str(short)]['error']
    assert 'has 2 fields, the header 3' in rows[str(torn)]['error']
    assert 'No such file' in rows[str(tmp_path / 'gone.csv')]['error']
    assert len(list((out / 'records').glob('*.json'))) == 3
    assert main(args) == ERROR_STATUS
    captured = capsys.readouterr()
    assert '3 records: 3 done before, none to diagnose' in captured.err
    assert '(3 done by an earlier run)' in captured.out


def test_several_records_need_a_summary_folder_and_a_batch_takes_no_json_or_report(tmp_path,
                                                                                    capsys):
    log = tmp_path / 'a.csv'
    log.write_text(SHORT_LOG)
    for args, says in (([log, log], 'need --summary DIR'),
                       ([tmp_path], 'need --summary DIR'),
                       ([log, '--joint', 'all'], 'need --summary DIR'),
                       ([log, log, '--summary', tmp_path / 'out', '--json', tmp_path / 'a.json'],
                        '--json and --report are for one record'),
                       ([log, '--summary', tmp_path / 'out', '--workers', '-1'],
                        '--workers must be 0 or more')):
        with pytest.raises(SystemExit) as exit_:
            main([str(arg) for arg in args])
        assert exit_.value.code == 2
        assert says in capsys.readouterr().err


def test_an_empty_folder_holds_no_records_and_says_so(tmp_path, capsys):
    assert main([str(tmp_path), '--summary', str(tmp_path / 'out')]) == ERROR_STATUS
    assert f'no CSV log nor bag in {tmp_path}' in capsys.readouterr().err
