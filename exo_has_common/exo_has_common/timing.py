"""Timing of a periodic loop: missed periods and release jitter, measured on the loop's clock.

A loop with period T is released at t0 + k T. A tick that comes after the next release
(late by a full period or more) leaves at least one period without a tick: those periods are
*missed*, the count rclcpp's timers keep of the calls they skip (a deadline miss, the deadline
being the next release). A tick late by less than a period still ran in its period, but late;
:class:`PeriodMonitor` also keeps the distribution of that lateness (the release jitter) in
bins of :data:`BIN_NS`, so its percentiles cost constant memory however long the loop runs.
ROS-free.
"""

from __future__ import annotations

#: Width of a lateness bin [ns]: 0.1 ms.
BIN_NS = 100_000
#: Lateness bins kept [1]: 0 to 100 ms; later ticks count in the last bin.
BINS = 1000


class PeriodMonitor:
    """Count the ticks, missed periods and lateness of a loop released every ``period_ns``.

    Parameters
    ----------
    period_ns : int
        Period of the loop [ns].

    Raises
    ------
    ValueError
        For a period that is not positive.

    """

    def __init__(self, period_ns: int) -> None:
        if period_ns <= 0:
            msg = f'a loop period must be positive, got {period_ns} ns'
            raise ValueError(msg)
        self.period_ns = period_ns
        self.ticks = 0
        self.missed = 0
        self.late = 0  # ticks later than half a period after their release
        self.max_lateness_ns = 0
        self._histogram = [0] * BINS
        self._release_ns: int | None = None

    def tick(self, now_ns: int) -> None:
        """Count a tick that ran at ``now_ns`` (the loop's clock) [ns].

        The first tick sets the release grid; a tick earlier than its release moves the grid
        back to it, since a timer never runs early: the first tick may have been late, and the
        grid would hide that much of every later tick's lateness. A clock that jumps back by
        more than a period (a restarted simulation) starts a new grid.
        """
        release = self._release_ns
        if release is None or now_ns < release - self.period_ns:
            self._release_ns = now_ns + self.period_ns
            return
        release = min(release, now_ns)
        lateness = max(0, now_ns - release)
        skipped = lateness // self.period_ns
        self.ticks += 1
        self.missed += skipped
        # Lateness within the tick's own period: a tick after a skipped release belongs to
        # the latest release before it.
        lateness -= skipped * self.period_ns
        if lateness * 2 > self.period_ns:
            self.late += 1
        self.max_lateness_ns = max(self.max_lateness_ns, lateness + skipped * self.period_ns)
        self._histogram[min(lateness // BIN_NS, BINS - 1)] += 1
        self._release_ns = release + (skipped + 1) * self.period_ns

    def lateness_percentile(self, percent: float) -> float:
        """Lateness [s] that ``percent`` of the ticks did not exceed, to the bin's upper edge.

        Raises
        ------
        ValueError
            For a percentage outside 0 to 100.

        """
        if not 0.0 <= percent <= 100.0:
            msg = f'a percentile must be within 0 and 100, got {percent!r}'
            raise ValueError(msg)
        wanted = percent / 100.0 * self.ticks
        seen = 0
        for index, count in enumerate(self._histogram):
            seen += count
            if count and seen >= wanted:
                return (index + 1) * BIN_NS * 1e-9
        return 0.0

    def summary(self) -> str:
        """One line for a log, parsed by ``bench/system.py``."""
        return (f'{self.ticks} periods, {self.missed} missed, {self.late} late by over half a '
                f'period, lateness p99 {self.lateness_percentile(99.0) * 1e3:.1f} ms '
                f'p99.9 {self.lateness_percentile(99.9) * 1e3:.1f} ms '
                f'max {self.max_lateness_ns * 1e-6:.1f} ms')
