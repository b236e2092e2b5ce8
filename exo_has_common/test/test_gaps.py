"""Gaps in a recording: found in a steady topic, not in jitter or sporadic topics."""

import numpy as np
import pytest

from exo_has_common.bags.gaps import GapFinder

PERIOD_NS = 5_000_000  # 200 Hz


def test_jitter_and_a_few_late_samples_are_not_gaps():
    rng = np.random.default_rng(3)
    times = np.cumsum(PERIOD_NS + rng.integers(-2_000_000, 2_000_000, 2000))
    times[1000:] += 40_000_000  # one 45 ms hold-up: under the 0.1 s floor
    finder = GapFinder()
    assert [finder.take('/s', int(t)) for t in times].count(None) == len(times)


def test_a_gap_is_reported_once_when_the_topic_comes_back_and_the_usual_interval_is_kept():
    finder = GapFinder()
    times = [i * PERIOD_NS for i in range(100)] + [
        99 * PERIOD_NS + 500_000_000 + i * PERIOD_NS for i in range(100)]
    found = [gap for t in times if (gap := finder.take('/s', t)) is not None]
    assert len(found) == 1 and finder.gaps == found
    assert found[0].seconds == pytest.approx(0.5)
    assert found[0].usual_interval_s == pytest.approx(0.005)
    assert found[0].missing == 99


def test_nothing_is_judged_before_the_usual_interval_is_settled():
    finder = GapFinder(settle=50)
    times = [i * PERIOD_NS for i in range(10)] + [10 * PERIOD_NS + 1_000_000_000]
    assert all(finder.take('/s', t) is None for t in times)
