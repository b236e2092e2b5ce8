"""Tests of exo_has_common.realtime: SCHED_FIFO for a node's loop thread."""

from __future__ import annotations

import ctypes
import errno
import os
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from exo_has_common import realtime
from exo_has_common.realtime import (
    M_MMAP_MAX,
    M_TRIM_THRESHOLD,
    MAX_PRIORITY,
    MCL_CURRENT,
    MCL_FUTURE,
    lock_memory,
    parse_cpus,
    set_cpus,
    set_realtime_priority,
)


def _policy_of_a_thread_set_to(priority: int) -> tuple[str | None, int, int]:
    """Set a fresh thread's class; return the message, its policy and its priority."""
    result: list[tuple[str | None, int, int]] = []

    def run() -> None:
        message = set_realtime_priority(priority)
        result.append((message, os.sched_getscheduler(0), os.sched_getparam(0).sched_priority))

    thread = threading.Thread(target=run)
    thread.start()
    thread.join()
    return result[0]


def test_priority_zero_leaves_the_thread_under_the_default_scheduler() -> None:
    message, policy, _priority = _policy_of_a_thread_set_to(0)
    assert message is None
    assert policy == os.SCHED_OTHER


def test_a_priority_puts_only_the_calling_thread_under_sched_fifo_where_permitted() -> None:
    message, policy, priority = _policy_of_a_thread_set_to(10)
    if message is not None:
        # Without the privilege (or, as root, without a real-time budget in its control
        # group) the thread runs on, and the message says why.
        assert 'no permission' in message or 'although running as root' in message
        assert policy == os.SCHED_OTHER
        return
    assert (policy, priority) == (os.SCHED_FIFO, 10)
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the test's own thread is untouched



def _refused(monkeypatch: pytest.MonkeyPatch, tmp_path: Path, euid: int, cgroup: str,
             capabilities: str = '000001ffffffffff', budget: str | None = '0') -> str:
    """Return the message of a refused SCHED_FIFO for a process as described."""

    def refuse(*_args: object) -> None:
        raise PermissionError(1, 'Operation not permitted')

    monkeypatch.setattr(os, 'sched_setscheduler', refuse)
    monkeypatch.setattr(os, 'geteuid', lambda: euid)
    (tmp_path / 'cgroup').write_text(cgroup)
    (tmp_path / 'status').write_text(f'Name:\tpython\nCapEff:\t{capabilities}\n')
    mount = tmp_path / 'fs'
    group = mount / 'user.slice' / 'user-0.slice'
    group.mkdir(parents=True)
    if budget is not None:
        (group / 'cpu.rt_runtime_us').write_text(f'{budget}\n')
    monkeypatch.setattr(realtime, 'CGROUP_FILE', tmp_path / 'cgroup')
    monkeypatch.setattr(realtime, 'CGROUP_MOUNT', mount)
    monkeypatch.setattr(realtime, 'STATUS_FILE', tmp_path / 'status')
    message = set_realtime_priority(40)
    assert message is not None
    assert message.endswith('running under the default scheduler')
    return message


def test_a_refusal_without_root_asks_for_root_or_a_limit(monkeypatch, tmp_path) -> None:
    message = _refused(monkeypatch, tmp_path, euid=1000, cgroup='0::/user.slice/user-0.slice\n')
    assert 'needs root, CAP_SYS_NICE or an rtprio limit' in message
    assert 'control group' not in message


def test_a_refusal_as_root_names_the_control_group_without_a_budget_and_the_fix(
        monkeypatch, tmp_path) -> None:
    message = _refused(monkeypatch, tmp_path, euid=0, cgroup='0::/user.slice/user-0.slice\n')
    assert 'needs root' not in message
    assert 'although running as root' in message
    assert 'control group /user.slice/user-0.slice' in message
    assert 'cpu.rt_runtime_us is 0' in message
    assert f'echo $$ > {tmp_path / "fs" / "cgroup.procs"}' in message
    assert 'CPUAccounting' in message


def test_a_refusal_as_root_reads_the_cpu_hierarchy_of_cgroup_v1(monkeypatch, tmp_path) -> None:
    (tmp_path / 'fs' / 'cpu,cpuacct' / 'user.slice' / 'user-0.slice').mkdir(parents=True)
    (tmp_path / 'fs' / 'cpu,cpuacct' / 'user.slice' / 'user-0.slice' / 'cpu.rt_runtime_us') \
        .write_text('0\n')
    message = _refused(monkeypatch, tmp_path, euid=0, budget=None,
                       cgroup='4:memory:/other\n3:cpu,cpuacct:/user.slice/user-0.slice\n'
                              '0::/user.slice/user-0.slice/session-3.scope\n')
    assert 'control group /user.slice/user-0.slice,' in message
    assert 'cpu.rt_runtime_us is 0' in message
    assert f'echo $$ > {tmp_path / "fs" / "cpu,cpuacct" / "cgroup.procs"}' in message


def test_a_refusal_as_root_with_an_unreadable_budget_still_names_the_group(
        monkeypatch, tmp_path) -> None:
    message = _refused(monkeypatch, tmp_path, euid=0, budget=None,
                       cgroup='0::/system.slice/exo.service\n')
    assert 'control group /system.slice/exo.service' in message
    assert 'CONFIG_RT_GROUP_SCHED' in message


def test_a_refusal_as_root_in_the_root_group_points_at_the_system_budget(
        monkeypatch, tmp_path) -> None:
    message = _refused(monkeypatch, tmp_path, euid=0, cgroup='0::/\n')
    assert 'root control group' in message
    assert 'sched_rt_runtime_us' in message


def test_a_refusal_as_root_without_cap_sys_nice_says_so(monkeypatch, tmp_path) -> None:
    message = _refused(monkeypatch, tmp_path, euid=0, capabilities='00000000a80425fb',
                       cgroup='0::/docker/abc\n')
    assert 'root without CAP_SYS_NICE' in message
    assert 'control group' not in message


@pytest.mark.parametrize('priority', [-1, MAX_PRIORITY + 1, 2.5, True])
def test_a_priority_out_of_range_is_refused_with_the_range(priority) -> None:
    with pytest.raises(ValueError, match=f'within 0 and {MAX_PRIORITY}'):
        set_realtime_priority(priority)


@pytest.mark.parametrize(('text', 'cpus'), [('0', {0}), ('0,1', {0, 1}), ('0-1', {0, 1}),
                                            (' 1 , 0 ', {0, 1})])
def test_a_cpu_list_is_read_as_taskset_writes_it(text, cpus) -> None:
    assert parse_cpus(text) == cpus


@pytest.mark.parametrize(('text', 'wording'), [('', 'expected numbers and ranges'),
                                               ('1-0', 'expected numbers and ranges'),
                                               ('a', 'expected numbers and ranges'),
                                               ('4096', 'which this machine does not have')])
def test_a_bad_cpu_list_is_refused_naming_it(text, wording) -> None:
    with pytest.raises(ValueError, match=wording):
        parse_cpus(text)


def test_cpus_keep_the_calling_thread_and_those_it_starts_afterwards() -> None:
    def affinity_of_a_new_thread() -> set[int]:
        seen: list[set[int]] = []
        thread = threading.Thread(target=lambda: seen.append(os.sched_getaffinity(0)))
        thread.start()
        thread.join()
        return seen[0]

    before = os.sched_getaffinity(0)
    try:
        assert set_cpus(frozenset({0})) is None
        assert os.sched_getaffinity(0) == {0}
        assert affinity_of_a_new_thread() == {0}
    finally:
        os.sched_setaffinity(0, before)
    assert set_cpus(frozenset()) is None  # none asked: left as it is
    assert os.sched_getaffinity(0) == before


class _CLibrary:
    """A stand-in for the C library: records the calls, fails mlockall with ``error``."""

    def __init__(self, error: int = 0) -> None:
        self.error = error
        self.calls: list[tuple[str, int, int]] = []

    def mlockall(self, flags: int) -> int:
        self.calls.append(('mlockall', flags, 0))
        if self.error:
            ctypes.set_errno(self.error)
            return -1
        return 0

    def mallopt(self, parameter: int, value: int) -> int:
        self.calls.append(('mallopt', parameter, value))
        return 1


def test_locking_memory_locks_present_and_future_pages_and_keeps_the_heap() -> None:
    libc = _CLibrary()
    assert lock_memory(libc) is None
    assert libc.calls == [('mlockall', MCL_CURRENT | MCL_FUTURE, 0),
                          ('mallopt', M_TRIM_THRESHOLD, -1), ('mallopt', M_MMAP_MAX, 0)]


@pytest.mark.parametrize(('error', 'wording'), [(errno.EPERM, 'no permission'),
                                                (errno.ENOMEM, 'memlock limit'),
                                                (errno.EINVAL, os.strerror(errno.EINVAL))])
def test_memory_that_cannot_be_locked_is_reported_with_the_reason(error, wording) -> None:
    libc = _CLibrary(error)
    message = lock_memory(libc)
    assert message is not None
    assert wording in message
    assert 'memory not locked' in message
    assert [call[0] for call in libc.calls] == ['mlockall']  # the heap left as it was


@pytest.mark.process
def test_a_process_that_locks_its_memory_has_it_locked_where_permitted() -> None:
    script = ('from exo_has_common.realtime import lock_memory\n'
              'print(lock_memory())\n'
              "print(next(line.split()[1] for line in open('/proc/self/status') "
              "if line.startswith('VmLck:')))\n")
    message, locked_kb = subprocess.run([sys.executable, '-c', script], capture_output=True,
                                        text=True, check=True, timeout=60).stdout.splitlines()
    if message != 'None':
        assert 'cannot lock memory' in message  # no CAP_IPC_LOCK and a small memlock limit
        return
    assert int(locked_kb) > 1024  # the interpreter's own pages at least
