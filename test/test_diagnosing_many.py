"""Many records diagnosed at once: local worker processes, a Dask cluster, resumed, interrupted.

The records are short draws of the first truth plant (``truth_plant.py``): 6 s with 80 N of
Coulomb friction, 4 s of two seeds without an effect, and the friction draw's CSV log cut
short mid-row; and a bag of the nodes' topics with the friction draw on one hip and an
effect-free one on the other. Each is diagnosed as the hidden-effect tests do (the bench's
parameters file, the load mass), in full (no time budget, whose searches would depend on the
machine's speed).
"""

from __future__ import annotations

import csv
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import truth_plant
from rigs import rig_file

from exo_has_runtime.processes import Processes, alive, children
from exo_has_sim.diagnosis.batch import (
    ERROR_STATUS,
    INTERRUPTED_STATUS,
    UNFINISHED_STATUS,
    ProgressBar,
    run_batch,
)
from exo_has_sim.diagnosis.cli import main
from exo_has_sim.diagnosis.records import Options, find_records

pytestmark = pytest.mark.slow  # worker processes and a Dask cluster: long, no node timed

#: How each record is diagnosed (the hidden-effect tests' way).
OPTIONS = ['--joint', 'hip', '--params', str(rig_file('hip')), '--load-mass', '50']


@pytest.fixture(scope='module')
def records(tmp_path_factory) -> dict[str, Path]:
    """Write the records: friction, two effect-free, and a CSV log cut short mid-row."""
    folder = tmp_path_factory.mktemp('records')
    paths = {}
    for name, seed, effect, size, duration in (('friction', 4242, 'coulomb_friction', 80.0, 6.0),
                                               ('quiet', 4242, 'none', None, 4.0),
                                               ('still', 4243, 'none', None, 4.0)):
        draw = truth_plant.draw(seed, 'hip', effect=effect, size=size, excitation='sine_sum',
                                duration=duration)
        paths[name] = folder / f'{name}.csv'
        truth_plant.write_csv(draw, paths[name])
    # Cut in the middle of a row, after its third field.
    lines = paths['friction'].read_text().splitlines(keepends=True)
    cut = len(lines) * 6 // 10
    paths['torn'] = folder / 'torn.csv'
    paths['torn'].write_text(''.join(lines[:cut]) + ','.join(lines[cut].split(',')[:3]))
    return paths


def summary_rows(folder: Path) -> dict[str, dict[str, str]]:
    """Return summary.csv's rows by the input's file name."""
    return {Path(row['input']).name: row for row in csv.DictReader((folder / 'summary.csv')
                                                                     .open())}


def documents(folder: Path) -> dict[str, dict]:
    """Return the records' JSON documents by the input's file name."""
    docs = (json.loads(path.read_text()) for path in (folder / 'records').glob('*.json'))
    return {Path(doc['record']['input']).name: doc for doc in docs}


@pytest.fixture(scope='module')
def local_run(records, tmp_path_factory) -> tuple[int, Path, float]:
    """Diagnose friction, quiet and torn on two local workers: exit status, summary, seconds."""
    out = tmp_path_factory.mktemp('local') / 'summary'
    started = time.monotonic()
    code = main([str(records[name]) for name in ('friction', 'quiet', 'torn')]
                + [*OPTIONS, '--workers', '2', '--summary', str(out)])
    return code, out, time.monotonic() - started


def test_local_workers_diagnose_each_record_and_list_the_truncated_csv_with_its_error(
        local_run, records):
    code, out, _ = local_run
    assert code == ERROR_STATUS  # the torn log could not be read; the others were diagnosed
    rows = summary_rows(out)
    assert rows['friction.csv']['verdict'] == 'effect'
    assert rows['friction.csv']['cause'] == 'coulomb_friction'
    assert 70.0 < float(rows['friction.csv']['size']) < 90.0
    assert rows['friction.csv']['unit'] == 'N'
    assert rows['quiet.csv']['verdict'] == 'none'
    assert rows['torn.csv']['verdict'] == 'error'
    assert 'has 3 fields, the header 8' in rows['torn.csv']['error']
    text = (out / 'summary.md').read_text()
    assert '3 records: 1 effect, 1 none, 1 error.' in text
    assert f'- `{records["torn"]} (hip)`: ' in text  # the error in full, under the table
    docs = documents(out)
    assert docs['friction.csv']['causes'] == ['coulomb_friction']  # --json's document
    assert f'{socket.gethostname()}:{os.getpid()}' not in {
        doc['record']['worker'] for doc in docs.values()}  # diagnosed in worker processes


def test_a_rerun_skips_what_is_done(local_run, records, capsys):
    _, out, _ = local_run
    before = {path.name: path.stat().st_mtime_ns for path in (out / 'records').iterdir()}
    started = time.monotonic()
    code = main([str(records[name]) for name in ('friction', 'quiet', 'torn')]
                + [*OPTIONS, '--summary', str(out)])
    assert time.monotonic() - started < 5.0
    assert code == ERROR_STATUS
    assert '3 records: 3 done before, none to diagnose' in capsys.readouterr().err
    assert {path.name: path.stat().st_mtime_ns for path in (out / 'records').iterdir()} == before


def write_session_bag(path: Path, draws: dict[str, truth_plant.Draw]) -> Path:
    """Write draws as a bag of the nodes' topics: a joint's states, its commands 1 ms later."""
    from rclpy.serialization import serialize_message

    from exo_has_common.bag import BagWriter
    from exo_has_msgs.msg import HasCommand, HasState

    t0 = 1_700_000_000_000_000_000
    with BagWriter(path) as writer:
        for joint in draws:
            writer.add_topic(f'/{joint}/has_state', 'exo_has_msgs/msg/HasState')
            writer.add_topic(f'/{joint}/has_command', 'exo_has_msgs/msg/HasCommand')
        for joint, draw in draws.items():
            c = draw.columns
            for k, t in enumerate(c['time']):
                stamp = t0 + round(t * 1e9)
                state = HasState(joint=joint, position=c['position'][k],
                                 pressure_a=c['pressure_a'][k], pressure_b=c['pressure_b'][k],
                                 motor_speed=c['motor_speed'][k],
                                 motor_speed_command=c['motor_speed_command'][k],
                                 load_force=c['load_force'][k])
                state.header.stamp.sec, state.header.stamp.nanosec = divmod(stamp, 10 ** 9)
                writer.write(f'/{joint}/has_state', stamp, serialize_message(state))
                command = HasCommand(joint=joint, motor_speed=c['motor_speed_command'][k],
                                     enable=True)
                answer = stamp + 1_000_000
                command.header.stamp.sec, command.header.stamp.nanosec = divmod(answer, 10 ** 9)
                writer.write(f'/{joint}/has_command', answer, serialize_message(command))
    return path


def test_joint_all_diagnoses_every_joint_a_bag_records_each_a_row_of_the_summary(tmp_path):
    draws = {'left_hip': truth_plant.draw(4242, 'hip', effect='coulomb_friction', size=80.0,
                                          excitation='sine_sum', duration=6.0),
             'right_hip': truth_plant.draw(4242, 'hip', excitation='sine_sum', duration=4.0)}
    bag = write_session_bag(tmp_path / 'session', draws)  # as the friction and quiet CSV logs
    out = tmp_path / 'summary'
    code = main([str(bag), '--joint', 'all', '--params', str(rig_file('hip')), '--load-mass',
                 '50', '--workers', '2', '--summary', str(out)])
    assert code == 0
    rows = list(csv.DictReader((out / 'summary.csv').open()))
    assert sorted((row['joint'], row['verdict'], row['cause']) for row in rows) == [
        ('left_hip', 'effect', 'coulomb_friction'), ('right_hip', 'none', '')]
    friction = next(row for row in rows if row['joint'] == 'left_hip')
    assert 70.0 < float(friction['size']) < 90.0
    assert '2 records: 1 effect, 1 none.' in (out / 'summary.md').read_text()


def free_port() -> int:
    """Return a TCP port free on the loopback now (the scheduler binds it a moment later)."""
    with socket.socket() as probe:
        probe.bind(('127.0.0.1', 0))
        return int(probe.getsockname()[1])


def test_a_dask_scheduler_with_two_worker_processes_gives_the_same_verdicts_and_sizes(
        local_run, records, tmp_path):
    from dask.distributed import Client

    _, local, _ = local_run
    address = f'tcp://127.0.0.1:{free_port()}'
    # The workers import exo_has_sim as this process does (its environment), one thread each.
    environment = {**os.environ, 'EXO_HAS_THREADS': '1', 'OPENBLAS_NUM_THREADS': '1'}
    log = (tmp_path / 'dask.log').open('wb')
    with Processes() as processes:
        processes.start([sys.executable, '-m', 'dask', 'scheduler', '--host', '127.0.0.1',
                         '--port', address.rpartition(':')[2], '--no-dashboard'],
                        stdout=log, stderr=subprocess.STDOUT, cwd=tmp_path)
        for name in ('first', 'second'):
            processes.start([sys.executable, '-m', 'dask', 'worker', address, '--name', name,
                             '--nthreads', '1', '--no-dashboard'], stdout=log,
                            stderr=subprocess.STDOUT, cwd=tmp_path, env=environment)
        with Client(address, timeout=30, set_as_default=False) as client:
            client.wait_for_workers(2, timeout=60)
        out = tmp_path / 'summary'
        code = main([str(records[name]) for name in ('friction', 'quiet', 'torn')]
                    + [*OPTIONS, '--scheduler', address, '--summary', str(out)])
    log.close()
    assert code == ERROR_STATUS, (tmp_path / 'dask.log').read_text()[-3000:]
    on_dask, at_home = documents(out), documents(local)
    assert sorted(on_dask) == sorted(at_home) == ['friction.csv', 'quiet.csv', 'torn.csv']
    for name, doc in on_dask.items():
        assert doc['verdict'] == at_home[name]['verdict']
        assert doc.get('causes') == at_home[name].get('causes')
        assert doc.get('sizes', {}) == pytest.approx(at_home[name].get('sizes', {}), rel=1e-9)
        assert doc.get('error') == at_home[name].get('error')
    # The same ids: the same records and options, wherever they ran.
    assert sorted(p.name for p in (out / 'records').iterdir()) == sorted(
        p.name for p in (local / 'records').iterdir())


def worker_processes(parent: int) -> list[int]:
    """Return the pids of a process's children that are multiprocessing's spawned workers."""
    return [pid for pid, command in children(parent, zombies=True).items()
            if 'spawn_main' in command]


class KillAWorker(ProgressBar):
    """Progress that, half a second after the first record ends, kills a busy worker (SIGKILL)."""

    def __init__(self) -> None:
        super().__init__()
        self.killed: list[int] = []

    def update(self, row) -> None:
        """Show that a record ended; after the first, kill a worker a moment later."""
        super().update(row)
        if self.finished == 1:
            threading.Timer(0.5, self.kill).start()

    def kill(self) -> None:
        """Kill one of the two workers, both busy by now."""
        pid = max(worker_processes(os.getpid()))
        os.kill(pid, signal.SIGKILL)
        self.killed.append(pid)


def test_a_worker_killed_mid_batch_costs_only_its_record_which_the_rerun_does(records,
                                                                              tmp_path):
    batch = find_records([records['friction'], records['quiet'], records['still']], 'hip',
                         Options(params=rig_file('hip'), load_mass=50.0))
    progress = KillAWorker()
    outcome = run_batch(batch, tmp_path, 2, progress=progress)
    assert len(progress.killed) == 1
    assert outcome.status == UNFINISHED_STATUS
    lost = [row for row in outcome.rows if row.verdict == 'unfinished']
    assert len(lost) == 1, [(row.record.name, row.verdict, row.error) for row in outcome.rows]
    assert f'its worker process (pid {progress.killed[0]}) ended while diagnosing it' \
        in lost[0].error
    assert {row.verdict for row in outcome.rows if row is not lost[0]} <= {'effect', 'none'}
    assert 'Not finished' in (tmp_path / 'summary.md').read_text()
    again = run_batch(batch, tmp_path, 2)
    assert again.status == 0
    assert [row.done_before for row in again.rows] == [row is not lost[0]
                                                       for row in outcome.rows]


def test_ctrl_c_leaves_a_summary_of_what_finished(records, tmp_path):
    out = tmp_path / 'summary'
    # As a terminal's foreground job takes Ctrl-C, neither ignored nor blocked. A test run in
    # the background of a non-interactive shell (nohup, a CI runner's script) starts with
    # SIGINT ignored, and a child inherits that and its starter's signal mask: two such
    # clean-clone runs failed here (the batch went on, exit 0 for 130); foreground runs did not.
    command = [sys.executable, '-c', 'import signal, sys; '
               'signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT}); '
               'signal.signal(signal.SIGINT, signal.default_int_handler); '
               'from exo_has_sim.diagnosis.cli import main; '
               'sys.exit(main())', str(records['quiet']), str(records['friction']), *OPTIONS,
               '--workers', '1', '--summary', str(out)]
    with Processes() as processes:
        process = processes.start(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True, cwd=tmp_path)
        deadline = time.monotonic() + 60.0
        while not list((out / 'records').glob('quiet-*.json')) and process.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.05)
        workers = worker_processes(process.pid)
        process.send_signal(signal.SIGINT)
        stdout, stderr = process.communicate(timeout=30)
    assert process.returncode == INTERRUPTED_STATUS, stderr
    assert 'Traceback' not in stderr
    rows = summary_rows(out)
    assert rows['quiet.csv']['verdict'] == 'none'
    assert rows['friction.csv']['verdict'] == 'unfinished'
    assert rows['friction.csv']['error'] == 'the batch was interrupted first'
    assert 'interrupted' in (out / 'summary.md').read_text() and 'interrupted' in stdout
    assert len(workers) == 1 and not alive(workers[0])  # the batch ended its worker
