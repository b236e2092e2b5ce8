"""bench/suite_time.py charges each test module with its CPU, its child processes' too.

A small suite of its own, run by pytest with the bench's plugin: one module spins in the test
process, another in a child it waits for; the records must put each one's CPU where it was
spent, and the summary must take a run's floor as its wall where one process ran it, and as
its CPU over the cores where workers did.
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

BENCH = Path(__file__).resolve().parents[1] / 'bench'
#: CPU seconds each spinning test takes.
SPIN_S = 0.3

SPIN = f"""
import time


def spin():
    end = time.process_time() + {SPIN_S}
    while time.process_time() < end:
        pass


def test_one():
    spin()


def test_two():
    pass
"""

CHILD = f"""
import subprocess
import sys


def test_a_child_spins():
    subprocess.run([sys.executable, '-c', 'import time\\nend = time.process_time() + {SPIN_S}\\n'
                    'while time.process_time() < end: pass'], check=True)
"""


@pytest.fixture
def suite_time(monkeypatch: pytest.MonkeyPatch) -> ModuleType:
    monkeypatch.syspath_prepend(str(BENCH))
    return importlib.import_module('suite_time')


def test_each_module_is_charged_with_its_own_and_its_childrens_cpu(
        tmp_path: Path, suite_time: ModuleType) -> None:
    folder = tmp_path / 'suite'
    folder.mkdir()
    (folder / 'test_spin.py').write_text(SPIN)
    (folder / 'test_child.py').write_text(CHILD)
    records = tmp_path / 'records.jsonl'
    env = {k: v for k, v in os.environ.items() if k != 'PYTEST_ADDOPTS'}
    env.update(SUITE_TIME_OUT=str(records),
               PYTHONPATH=os.pathsep.join(p for p in (str(BENCH), env.get('PYTHONPATH')) if p))
    done = subprocess.run([sys.executable, '-m', 'pytest', '-p', 'suite_time_plugin', '-q',
                           '-p', 'no:cacheprovider', '-p', 'no:xdist', str(folder)],
                          cwd=folder, env=env, capture_output=True, text=True, timeout=60,
                          check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    summary = suite_time.summarise(suite_time.read_records(records))
    (run,) = summary['runs']
    modules = {m['module']: m for m in run['modules']}
    assert set(modules) == {'test_spin.py', 'test_child.py'}
    assert modules['test_spin.py']['tests'] == 2
    assert modules['test_spin.py']['self'] >= 0.9 * SPIN_S
    assert modules['test_spin.py']['children'] < 0.5 * SPIN_S
    assert modules['test_child.py']['children'] >= 0.9 * SPIN_S
    assert run['cpu'] >= 1.8 * SPIN_S
    assert run['exit'] == 0 and summary['tests'] == 3
    assert not run['parallel'] and summary['floor'] == run['wall'] >= 2 * SPIN_S
    assert any('test_spin.py' in line for line in suite_time.report(summary, 5))


def test_a_run_on_workers_has_its_cpu_over_the_cores_as_its_floor(
        suite_time: ModuleType) -> None:
    records = [
        {'kind': 'module', 'part': 'not process', 'module': 'a.py', 'worker': 'gw0',
         'self': 100.0, 'children': 300.0, 'wall': 250.0, 'tests': 4},
        {'kind': 'module', 'part': 'not process', 'module': 'b.py', 'worker': 'gw1',
         'self': 200.0, 'children': 0.0, 'wall': 240.0, 'tests': 9},
        {'kind': 'run', 'part': 'not process', 'wall': 310.0, 'busy_cores': 1.9,
         'steal_cores': 0.0, 'cores': 2, 'workers': 2, 'exit': 0},
        {'kind': 'module', 'part': 'process', 'module': 'c.py', 'worker': '',
         'self': 5.0, 'children': 40.0, 'wall': 120.0, 'tests': 3},
        {'kind': 'run', 'part': 'process', 'wall': 121.0, 'busy_cores': 0.4,
         'steal_cores': 0.0, 'cores': 2, 'workers': 0, 'exit': 0},
    ]
    summary = suite_time.summarise(records)
    first, second = summary['runs']
    assert first['parallel'] and first['floor'] == pytest.approx(300.0)  # 600 CPU-s over 2 cores
    assert [m['module'] for m in first['modules']] == ['a.py', 'b.py']
    assert not second['parallel'] and second['floor'] == 121.0
    assert summary['floor'] == pytest.approx(421.0)
    assert summary['wall'] == pytest.approx(431.0) and summary['tests'] == 16


def test_a_file_that_is_not_the_plugins_is_refused_naming_the_line(
        tmp_path: Path, suite_time: ModuleType) -> None:
    path = tmp_path / 'records.jsonl'
    path.write_text('{"kind": "module", "part": "", "module": "a.py", "worker": "", "self": 1, '
                    '"children": 0, "wall": 1, "tests": 1}\nnot json\n')
    with pytest.raises(ValueError, match=r'records\.jsonl:2: not a record of suite_time_plugin'):
        suite_time.read_records(path)
    for line in ('[1, 2]', '{"kind": "run", "part": ""}', '{"kind": "other"}'):
        path.write_text(line + '\n')
        with pytest.raises(ValueError, match=r'records\.jsonl:1: not a record'):
            suite_time.read_records(path)
