"""Gaps in a recording: where a topic that came steadily stopped coming for a while.

A recorder on the operator's laptop loses what a partition of the link keeps from it; the bag
must say where. A topic's usual interval is learnt as it is recorded (an exponential average
of the intervals, gaps left out); once ``settle`` messages have set it, an interval over
``factor`` times the usual one, and over ``floor_s``, is a gap. Sporadic topics (safety
events) never settle on an interval short enough to show one; a 1 Hz topic shows gaps over
10 s. The recorder logs each gap as it ends, and ``exo-has bag info`` lists them from the
bag's own times, which a recovered bag has as well.
"""

from __future__ import annotations

from dataclasses import dataclass, field

#: How much longer than usual an interval must be to be a gap.
DEFAULT_FACTOR = 10.0

#: Shortest gap [s]: scheduling hiccups of a few periods are not gaps.
DEFAULT_FLOOR_S = 0.1

#: Messages of a topic before its usual interval is trusted.
DEFAULT_SETTLE = 50

#: Weight of the newest interval in the usual interval.
SMOOTHING = 0.05


@dataclass(frozen=True)
class Gap:
    """A stretch of time without a topic's messages.

    Attributes
    ----------
    topic : str
        The topic.
    start_ns, end_ns : int
        Times of the last message before and the first message after [ns].
    usual_interval_s : float
        The topic's usual interval before the gap [s].

    """

    topic: str
    start_ns: int
    end_ns: int
    usual_interval_s: float

    @property
    def seconds(self) -> float:
        """Length of the gap [s]."""
        return (self.end_ns - self.start_ns) * 1e-9

    @property
    def missing(self) -> int:
        """Messages the gap is likely to have cost, at the usual interval."""
        return max(0, round(self.seconds / self.usual_interval_s) - 1)

    def describe(self) -> str:
        """One line: topic, length, when and how many messages it likely cost."""
        return (f'{self.topic}: {self.seconds:.3f} s without a message from {self.start_ns} ns '
                f'(about {self.missing} missing at {1.0 / self.usual_interval_s:.4g} Hz)')


@dataclass
class _Topic:
    last_ns: int
    count: int = 1
    interval_s: float | None = None


@dataclass
class GapFinder:
    """Finds gaps in the messages of each topic, taken in order of time."""

    factor: float = DEFAULT_FACTOR
    floor_s: float = DEFAULT_FLOOR_S
    settle: int = DEFAULT_SETTLE
    gaps: list[Gap] = field(default_factory=list)
    _topics: dict[str, _Topic] = field(default_factory=dict)

    def take(self, topic: str, t_ns: int) -> Gap | None:
        """Take a message's time [ns]; return the gap it ends, if any (also kept in ``gaps``)."""
        state = self._topics.get(topic)
        if state is None:
            self._topics[topic] = _Topic(t_ns)
            return None
        previous_ns, state.last_ns = state.last_ns, t_ns
        interval = (t_ns - previous_ns) * 1e-9
        state.count += 1
        usual = state.interval_s
        if usual is not None and state.count > self.settle \
                and interval > max(self.floor_s, self.factor * usual):
            gap = Gap(topic, previous_ns, t_ns, usual)
            self.gaps.append(gap)
            return gap
        if interval >= 0.0:
            state.interval_s = interval if usual is None \
                else usual + SMOOTHING * (interval - usual)
        return None
