"""tools/at_idle_priority: the lowest CPU priority, as bench/stalls.py --background runs a load."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

TOOL = Path(__file__).resolve().parents[1] / 'tools' / 'at_idle_priority'
AUTOGROUP = Path('/proc/self/autogroup')
#: Prints the policy of the process it runs in and its autogroup file as read (empty if none).
REPORT = (f'import os, pathlib; group = pathlib.Path("{AUTOGROUP}"); '
          'print(os.sched_getscheduler(0)); '
          'print(group.read_text().strip() if group.exists() else "")')


def report(*prefix: str) -> tuple[int, str]:
    """Run REPORT under ``prefix``; return the policy and the autogroup line it printed."""
    out = subprocess.run([*prefix, str(TOOL), sys.executable, '-c', REPORT], check=True,
                         capture_output=True, text=True, timeout=30).stdout.split('\n')
    return int(out[0]), group_line(out[1])


def own_autogroup() -> str:
    """Return this process's autogroup line, or none where it has none (:func:`group_line`)."""
    return group_line(AUTOGROUP.read_text().strip() if AUTOGROUP.exists() else '')


def group_line(read: str) -> str:
    """Return an autogroup file's line as read, or none for an empty or missing file.

    The kernel may have no autogroups, and it prints an empty line for a task that a cgroup of
    its own shares the CPU for (as in a container).
    """
    return read or 'none'


def test_a_command_in_a_session_of_its_own_runs_at_idle_priority_in_a_group_of_nice_19() -> None:
    policy, group = report('setsid', '--wait')
    assert policy == os.SCHED_IDLE
    if group == 'none':
        pytest.skip('this kernel shares the CPU without autogroups')
    assert group.endswith(' nice 19'), group
    assert group.split()[0] != own_autogroup().split()[0]


def test_a_command_left_in_its_callers_session_leaves_the_callers_group_as_it_was() -> None:
    before = own_autogroup()
    policy, group = report()
    assert policy == os.SCHED_IDLE
    assert group == before == own_autogroup()
