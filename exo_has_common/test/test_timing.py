"""Tests of exo_has_common.timing: missed periods and lateness of a periodic loop."""

from __future__ import annotations

import pytest
from numpy.testing import assert_allclose

from exo_has_common.timing import BIN_NS, PeriodMonitor

MS = 1_000_000  # ns


def _run(monitor: PeriodMonitor, ticks_ms: list[float]) -> PeriodMonitor:
    for t in ticks_ms:
        monitor.tick(round(t * MS))
    return monitor


def test_ticks_on_their_releases_miss_nothing_and_are_not_late() -> None:
    monitor = _run(PeriodMonitor(5 * MS), [5.0 * k for k in range(1, 101)])
    assert (monitor.ticks, monitor.missed, monitor.late) == (99, 0, 0)
    assert monitor.lateness_percentile(100.0) == pytest.approx(BIN_NS * 1e-9)


def test_a_tick_late_by_less_than_a_period_is_late_but_misses_nothing() -> None:
    # Released at 10 ms, runs at 13 ms: late by 3 ms, over half of the 5 ms period.
    monitor = _run(PeriodMonitor(5 * MS), [5.0, 13.0, 15.0, 20.0])
    assert (monitor.ticks, monitor.missed, monitor.late) == (3, 0, 1)
    assert_allclose(monitor.max_lateness_ns, 3 * MS)


def test_a_tick_after_the_next_release_counts_the_periods_left_without_a_tick() -> None:
    # Released at 10 ms, runs at 21 ms: the 10 and 15 ms releases had no tick of their own.
    monitor = _run(PeriodMonitor(5 * MS), [5.0, 21.0, 25.0, 30.0])
    assert (monitor.ticks, monitor.missed) == (3, 2)
    assert monitor.late == 0  # 1 ms after the 20 ms release it belongs to
    assert_allclose(monitor.max_lateness_ns, 11 * MS)
    # The grid is kept: the next ticks are on time.
    assert monitor.lateness_percentile(100.0) == pytest.approx(1.1e-3)


def test_percentiles_come_from_the_lateness_histogram() -> None:
    # The first tick sets the grid; of the 200 counted, 199 are on time and one 2.05 ms late.
    ticks = [5.0 * k for k in range(1, 201)] + [1007.05]
    monitor = _run(PeriodMonitor(5 * MS), ticks)
    assert monitor.lateness_percentile(50.0) == pytest.approx(1e-4)
    assert monitor.lateness_percentile(99.0) == pytest.approx(1e-4)
    assert monitor.lateness_percentile(100.0) == pytest.approx(2.1e-3)


def test_a_clock_that_jumps_back_starts_a_new_grid() -> None:
    monitor = _run(PeriodMonitor(5 * MS), [1000.0, 1005.0, 3.0, 8.0, 13.0])
    assert (monitor.ticks, monitor.missed, monitor.late) == (3, 0, 0)


def test_the_summary_names_the_counts_the_benchmark_parses() -> None:
    monitor = _run(PeriodMonitor(5 * MS), [5.0, 21.0, 25.0])
    assert monitor.summary().startswith('2 periods, 2 missed, 0 late by over half a period')


def test_bad_periods_and_percentiles_are_refused() -> None:
    with pytest.raises(ValueError, match='period must be positive'):
        PeriodMonitor(0)
    with pytest.raises(ValueError, match='within 0 and 100'):
        PeriodMonitor(MS).lateness_percentile(101.0)


def test_a_late_first_tick_does_not_hide_the_lateness_of_later_ones() -> None:
    # Releases every 5 ms from 0; the first tick runs 2 ms late, the third 3 ms late.
    monitor = _run(PeriodMonitor(5 * MS), [2.0, 5.0, 13.0, 15.0])
    assert (monitor.ticks, monitor.missed, monitor.late) == (3, 0, 1)
    assert_allclose(monitor.max_lateness_ns, 3 * MS)
