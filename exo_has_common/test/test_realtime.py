"""Tests of exo_has_common.realtime: SCHED_FIFO for a node's loop thread."""

from __future__ import annotations

import os
import threading

import pytest

from exo_has_common.realtime import MAX_PRIORITY, parse_cpus, set_cpus, set_realtime_priority


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
        # Without the privilege the thread runs on, and the message says why.
        assert 'no permission' in message
        assert policy == os.SCHED_OTHER
        return
    assert (policy, priority) == (os.SCHED_FIFO, 10)
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the test's own thread is untouched


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
