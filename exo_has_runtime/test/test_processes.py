"""Tests of exo_has_runtime.processes: modules run as processes for tests."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from exo_has_runtime.processes import NodeProcess, Processes, alive

pytestmark = pytest.mark.process  # every test here starts processes


def test_a_process_started_with_stdin_reads_the_lines_sent_to_it(tmp_path) -> None:
    # json.tool echoes what it reads once its input closes: proof the line got through.
    with NodeProcess('json.tool', log_path=tmp_path / 'echo.log', stdin=True) as process:
        process.send('{"answer": 42}')
        assert process.process.stdin is not None
        process.process.stdin.close()
        assert process.wait() == 0
        assert '"answer": 42' in process.output


def test_sending_without_a_pipe_or_after_the_end_names_the_problem(tmp_path) -> None:
    with NodeProcess('json.tool', log_path=tmp_path / 'none.log') as process:
        with pytest.raises(RuntimeError, match='without a pipe'):
            process.send('{}')
        process.wait()
    with NodeProcess('json.tool', log_path=tmp_path / 'ended.log', stdin=True) as process:
        assert process.process.stdin is not None
        process.process.stdin.close()
        process.wait()
        with pytest.raises(RuntimeError, match='has ended'):
            process.send('{}')


def test_a_temporary_log_is_read_after_the_end_and_removed_with_its_process() -> None:
    import gc

    process = NodeProcess('json.tool', ['--help'])
    assert process.wait() == 0
    process.stop()
    assert 'usage' in process.output
    log = process.log_path
    del process
    gc.collect()
    assert not log.exists()


def test_a_log_the_caller_named_is_kept(tmp_path) -> None:
    with NodeProcess('json.tool', ['--help'], log_path=tmp_path / 'kept.log') as process:
        process.wait()
    del process
    assert (tmp_path / 'kept.log').read_text().startswith('usage')


#: Ignores SIGTERM, starts a child in its process group, says the child's pid, then waits.
STUBBORN = """
import signal, subprocess, time
signal.signal(signal.SIGTERM, signal.SIG_IGN)
print(subprocess.Popen(['sleep', '60']).pid, flush=True)
time.sleep(60)
"""


def test_processes_that_ignore_sigterm_are_killed_with_their_group_after_the_grace() -> None:
    with Processes(grace=0.2) as processes:
        process = processes.start([sys.executable, '-c', STUBBORN], stdout=subprocess.PIPE,
                                  text=True)
        assert process.stdout is not None
        child = int(process.stdout.readline())
    assert process.returncode == -signal.SIGKILL
    # The child, in the group and ignoring SIGTERM as well (inherited), got the SIGKILL too:
    # gone once reaped by whoever adopted it, a zombie until then, dying a moment before.
    deadline = time.monotonic() + 5.0
    while alive(child) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not alive(child)


def test_a_run_that_fails_its_check_or_overruns_its_timeout_says_so() -> None:
    with Processes() as processes:
        assert processes.run(['echo', 'hi'], stdout=subprocess.PIPE, text=True).stdout == 'hi\n'
        with pytest.raises(subprocess.CalledProcessError):
            processes.run(['false'], check=True)
        with pytest.raises(subprocess.TimeoutExpired):
            processes.run(['sleep', '60'], timeout=0.2)
        sleeping = processes.started[-1]
    assert sleeping.returncode == -signal.SIGTERM  # ended on leaving the with
