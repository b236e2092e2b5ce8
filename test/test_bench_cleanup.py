"""A benchmark that fails at any step leaves no process behind (issue 39, item 5).

``bench/robot_loop_alone.py --busy 2 --trace`` once failed at its start where tracefs was not
mounted, and its two spinning processes took both cores for 77 minutes. Each test here marks
the processes it makes a benchmark start by a variable of their environment, which they
inherit, and looks for them in /proc once the benchmark has failed.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from exo_has_runtime.processes import children, stat_fields

pytestmark = pytest.mark.process

BENCH = Path(__file__).resolve().parents[1] / 'bench'
#: The variable that marks the processes of a test.
MARK = 'EXO_HAS_BENCH_CLEANUP_TEST'


#: The flag of a kernel thread in /proc/PID/stat (``PF_KTHREAD``): it has no environment.
KERNEL_THREAD = 0x00200000


def environment(pid: int) -> list[bytes]:
    """Return a process's environment (none for a kernel thread, or one that has ended).

    Read again while it is empty otherwise: a process that replaces its program (exec, as the
    tether and taskset do) shows none for a moment.
    """
    for _ in range(100):
        fields = stat_fields(pid)
        if fields[0] == 'Z' or int(fields[6]) & KERNEL_THREAD:
            return []
        text = Path(f'/proc/{pid}/environ').read_bytes()
        if text:
            return text.split(b'\0')
        time.sleep(0.001)
    return []


def marked(token: str) -> set[int]:
    """Return the processes, this one aside, with ``MARK=token`` in their environment."""
    entry = f'{MARK}={token}'.encode()
    found = set()
    for process in Path('/proc').glob('[0-9]*'):
        with contextlib.suppress(OSError):  # ended meanwhile
            if entry in environment(int(process.name)):
                found.add(int(process.name))
    return found - {os.getpid()}


@pytest.fixture
def left_behind(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[[], set[int]]]:
    """Give what lists the processes started in the test that remain, by their mark.

    They are marked through this process's environment, which every process it starts
    inherits; children of this process that ended but were not reaped count too. Those left
    at the end are killed, so that a failing test does not leave them in turn.
    """
    token = uuid.uuid4().hex
    monkeypatch.setenv(MARK, token)
    before = set(children(zombies=True))

    def remaining() -> set[int]:
        return marked(token) | (set(children(zombies=True)) - before)

    yield remaining
    for pid in remaining():
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
        with contextlib.suppress(ChildProcessError):
            os.waitpid(pid, 0)


@pytest.mark.parametrize('failure', ['tracefs not mounted', 'interrupted'])
def test_a_bench_that_fails_at_set_up_leaves_no_process(
        failure: str, left_behind: Callable[[], set[int]], monkeypatch: pytest.MonkeyPatch,
        tmp_path: Path) -> None:
    monkeypatch.syspath_prepend(str(BENCH))
    import kernel_trace
    import robot_loop_alone

    # The trace's set-up, the step that failed: where tracefs is not mounted, or on Ctrl-C.
    monkeypatch.setattr(kernel_trace, 'TRACEFS', tmp_path / 'tracing')
    running_then: set[int] = set()

    def trace_set_up(cpus: frozenset[int]) -> kernel_trace.CpuTrace:
        running_then.update(left_behind())
        if failure == 'interrupted':
            raise KeyboardInterrupt
        return kernel_trace.CpuTrace(cpus)

    monkeypatch.setattr(robot_loop_alone, 'CpuTrace', trace_set_up)
    # As --busy 2 --trace --loop-cpus 0, without the witness (cyclictest, not everywhere).
    args = argparse.Namespace(
        busy=2, trace=True, witness_priority=0, loop_cpus='0', devices_cpus='', rate=200.0,
        seconds=1.0, devices_priority=19, loop_priority=20, bitrate=5_000_000)
    with pytest.raises(PermissionError if failure == 'tracefs not mounted'
                       else KeyboardInterrupt):
        robot_loop_alone.run(args, 'locked')
    assert len(running_then) == 2  # the busy processes ran when the set-up failed
    assert left_behind() == set()


def test_the_bench_of_the_incident_leaves_no_process(
        left_behind: Callable[[], set[int]], tmp_path: Path) -> None:
    # The command line that failed, tracefs made unavailable through EXO_HAS_TRACEFS; without
    # cyclictest installed the witness's set-up fails first, after the busy processes too.
    # Output to a file: a process left behind would hold a pipe open, and the wait with it.
    log = tmp_path / 'bench.log'
    with log.open('w') as out:
        code = subprocess.run(
            [sys.executable, str(BENCH / 'robot_loop_alone.py'), '--busy', '2', '--trace',
             '--witness-priority', '21', '--loop-cpus', '0', '--seconds', '1'],
            env={**os.environ, 'EXO_HAS_TRACEFS': str(tmp_path / 'tracing')}, stdout=out,
            stderr=subprocess.STDOUT, timeout=60, check=False).returncode
    assert code == 1
    assert 'no tracefs at' in log.read_text() or 'witness needs cyclictest' in log.read_text()
    assert left_behind() == set()


KILLED = """
import sys, time
sys.path.insert(0, sys.argv[1])
from common import Processes, start_busy
start_busy(Processes(), 2)
print('started', flush=True)
time.sleep(60)
"""


def test_a_bench_killed_by_sigkill_leaves_no_process(
        left_behind: Callable[[], set[int]]) -> None:
    bench = subprocess.Popen([sys.executable, '-c', KILLED, str(BENCH)],
                             stdout=subprocess.PIPE, text=True)
    assert bench.stdout is not None
    assert bench.stdout.readline() == 'started\n'
    assert len(left_behind() - {bench.pid}) == 2
    bench.send_signal(signal.SIGKILL)  # no clean-up of its own can run
    bench.wait()
    deadline = time.monotonic() + 5.0
    while left_behind() and time.monotonic() < deadline:
        time.sleep(0.05)
    assert left_behind() == set()
