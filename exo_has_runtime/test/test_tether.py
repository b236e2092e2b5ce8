"""A tethered child ends when the process that started it dies, even by SIGKILL."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from exo_has_runtime.processes import alive
from exo_has_runtime.tether import EXEC_EXIT, ORPHANED_EXIT

pytestmark = pytest.mark.process  # every test here starts processes

# The child writes each file under another name and renames it: the test, which waits for the
# file to exist, never reads one created but not yet written (CI once read '' for 'SIGTERM').
CHILD = """
import pathlib, signal, sys, time
def publish(path, text):
    partial = path.with_name(path.name + '.partial')
    partial.write_text(text)
    partial.replace(path)
out = pathlib.Path(sys.argv[1])
signal.signal(signal.SIGTERM, lambda *_: (publish(out, 'SIGTERM'), sys.exit(0)))
publish(out.with_suffix('.started'), ' '.join(sys.argv[2:]))
time.sleep(60)
"""

PARENT = """
import os, subprocess, sys, time
subprocess.Popen([sys.executable, '-m', 'exo_has_runtime.tether', str(os.getpid()),
                  'tethered_child', *sys.argv[1:]])
time.sleep(60)
"""


def test_a_tethered_child_gets_sigterm_when_its_parent_is_killed(tmp_path):
    (tmp_path / 'tethered_child.py').write_text(textwrap.dedent(CHILD))
    env = {**os.environ, 'PYTHONPATH': f'{tmp_path}{os.pathsep}{os.environ.get("PYTHONPATH", "")}'}
    out = tmp_path / 'ended.txt'
    parent = subprocess.Popen([sys.executable, '-c', PARENT, str(out), 'a', 'b'], env=env)
    try:
        deadline = time.monotonic() + 20.0
        while not out.with_suffix('.started').exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        # The module ran with its own arguments, as python -m would run it.
        assert out.with_suffix('.started').read_text() == 'a b'
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 5.0
        while not out.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert out.read_text() == 'SIGTERM'
    finally:
        if parent.poll() is None:
            parent.kill()


EXEC_PARENT = """
import os, subprocess, sys, time
child = subprocess.Popen([sys.executable, '-m', 'exo_has_runtime.tether', str(os.getpid()),
                          '--exec', 'sleep', '60'])
print(child.pid, flush=True)
time.sleep(60)
"""


def test_a_tethered_program_gets_sigterm_when_its_parent_is_killed():
    parent = subprocess.Popen([sys.executable, '-c', EXEC_PARENT], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert parent.stdout is not None
        pid = int(parent.stdout.readline())
        deadline = time.monotonic() + 20.0
        while b'sleep' not in Path(f'/proc/{pid}/cmdline').read_bytes():  # the exec done
            assert time.monotonic() < deadline
            time.sleep(0.05)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        deadline = time.monotonic() + 5.0
        while alive(pid) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not alive(pid)
    finally:
        if parent.poll() is None:
            parent.kill()


def test_a_program_that_cannot_run_is_named():
    result = subprocess.run([sys.executable, '-m', 'exo_has_runtime.tether', str(os.getpid()),
                             '--exec', 'no-such-program-here'],
                            capture_output=True, text=True, timeout=30, check=False)
    assert result.returncode == EXEC_EXIT
    assert 'cannot run no-such-program-here' in result.stderr


def test_a_child_whose_parent_is_already_gone_does_not_run(tmp_path):
    result = subprocess.run(
        [sys.executable, '-m', 'exo_has_runtime.tether', '1', 'this_module_never_runs'],
        capture_output=True, text=True, timeout=30, check=False)
    assert result.returncode == ORPHANED_EXIT
    assert 'parent 1 ended before this process started' in result.stderr


def test_a_malformed_command_line_names_the_usage():
    result = subprocess.run([sys.executable, '-m', 'exo_has_runtime.tether', 'x'],
                            capture_output=True, text=True, timeout=30, check=False)
    assert result.returncode == 1 and 'usage:' in result.stderr
