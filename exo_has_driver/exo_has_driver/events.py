"""Safety events and the stop latch they set, shared by the watchdog and the hardware driver.

Free of ROS. :class:`SafetyKind` and :class:`Severity` number events as
exo_has_msgs/msg/SafetyEvent does (a test checks they agree); an :class:`Event` is one such
message's content. A :class:`Condition` is a fault that holds now (a stale state, an open
safety valve, a lost heartbeat). A :class:`StopLatch` is the one stop latch of exo_has: a FATAL
event latches it, and only an explicit reset releases it, which it refuses while a condition
still holds. The watchdog (:mod:`exo_has_driver.safety`) and the CANopen master's supervision
(:mod:`exo_has_driver.hardware.supervision`) each hold one; what holds, and when a reset is
complete (the master first takes its drives out of fault), is theirs to say. A
:class:`Clearing` is the one rule for when a reported condition is over: absent for
:data:`CLEAR_TIME`.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Sequence
from dataclasses import dataclass
from enum import IntEnum
from typing import Generic, TypeVar

#: [s] How long a reported condition must stay absent to be reported cleared (and be reported
#: again should it return): fifty periods at 200 Hz. One that comes and goes faster (a second
#: plant's states beside the real one's, a slave's TPDOs lost now and then) stays one condition.
CLEAR_TIME = 0.25
#: A condition's key, as its reporter names it.
Key = TypeVar('Key', bound=Hashable)


class SafetyKind(IntEnum):
    """What an event is about, numbered as SafetyEvent's ``KIND_*`` (their units there)."""

    SAFETY_VALVE_OPEN = 1
    OVER_PRESSURE = 2
    STROKE_END = 3
    TRACKING_ERROR = 4
    STALE_STATE = 5
    STALE_COMMAND = 6
    INVALID_COMMAND = 7
    DRIVE_FAULT = 8
    HEARTBEAT_LOST = 9
    BUS_OFF = 10
    SENSOR_FAULT = 11
    E_STOP = 12
    RESET = 13
    SECOND_SOURCE = 14
    STALE_REFERENCE = 15

    @property
    def label(self) -> str:
        """Readable name, for texts and diagnostics (``'safety valve open'``)."""
        return 'emergency stop' if self is SafetyKind.E_STOP \
            else self.name.lower().replace('_', ' ').replace('over pressure', 'over-pressure')


class Severity(IntEnum):
    """How bad an event is, numbered as SafetyEvent's ``SEVERITY_*``; FATAL latches a stop."""

    INFO = 0
    WARN = 1
    ERROR = 2
    FATAL = 3


class Phase(IntEnum):
    """Where a condition is in its life, numbered as SafetyEvent's ``PHASE_*``.

    A condition is reported when it starts, when what it is changes while it lasts (a stroke
    end reached at the other end, a second source whose publishers change), and when it has
    cleared: not once per sample that shows it.
    """

    START = 0
    CHANGE = 1
    CLEAR = 2


@dataclass(frozen=True)
class Event:
    """A safety event, as exo_has_msgs/msg/SafetyEvent carries it (the stamp aside).

    Attributes
    ----------
    joint : str
        Joint concerned, empty for a system-wide event.
    kind : SafetyKind
        What it is about.
    severity : Severity
        How bad it is.
    value : float
        Measured value, in the unit SafetyEvent lists for the kind; NaN where there is none.
    limit : float
        Limit the value crossed, same unit; NaN where there is none.
    latched : bool
        Whether the source holds a latched stop after this event.
    text : str
        Human-readable description.
    phase : Phase
        Whether the condition starts, changes or has cleared (RESET and refusals: START).

    """

    joint: str
    kind: SafetyKind
    severity: Severity
    value: float
    limit: float
    latched: bool
    text: str
    phase: Phase = Phase.START


@dataclass(frozen=True)
class Condition:
    """A fault that holds now: what latches a stop, and what forbids releasing it.

    Attributes
    ----------
    key : Hashable
        Identifies the condition, so that it is reported once while it lasts.
    joint : str
        Joint concerned, empty for a system-wide one.
    kind : SafetyKind
        What it is about.
    value : float
        Measured value (SafetyEvent's unit for the kind), NaN where there is none.
    limit : float
        Limit crossed, same unit, NaN where there is none.
    text : str
        Human-readable description.

    """

    key: Hashable
    joint: str
    kind: SafetyKind
    value: float
    limit: float
    text: str


class Clearing(Generic[Key]):
    """The reported conditions that stopped holding, and since when: :data:`CLEAR_TIME`'s rule.

    A reporter (the watchdog's :class:`~exo_has_driver.joint_watch.JointWatch`, the CANopen
    master's :class:`~exo_has_driver.hardware.supervision.Supervision`) marks a condition it
    reported :meth:`absent` while it does not hold and :meth:`holds` when it does again (or is
    forgotten); :meth:`due` names those absent for :data:`CLEAR_TIME`, to be reported cleared.
    """

    def __init__(self) -> None:
        self._since: dict[Key, float] = {}

    def holds(self, key: Key) -> None:
        """Stop timing ``key``: it holds again, or is forgotten without a clear."""
        self._since.pop(key, None)

    def absent(self, key: Key, t: float) -> None:
        """Note that ``key`` does not hold at t [s]; its absence counts from the first such t."""
        self._since.setdefault(key, t)

    def due(self, t: float) -> set[Key]:
        """Return the keys absent for :data:`CLEAR_TIME` at t [s], and stop timing them."""
        done = {key for key, since in self._since.items() if t - since >= CLEAR_TIME}
        for key in done:
            del self._since[key]
        return done


class StopLatch:
    """A stop that FATAL events latch and only an explicit, accepted reset releases.

    It also remembers which conditions it has reported (:meth:`report_once`), so that a
    condition that lasts is reported once, when it arises.
    """

    def __init__(self) -> None:
        self._latched = False
        self._cause: Event | None = None
        self._reported: set[Hashable] = set()

    @property
    def latched(self) -> bool:
        """Whether a stop is latched."""
        return self._latched

    @property
    def cause(self) -> Event | None:
        """The first FATAL event since the last release, None when not latched."""
        return self._cause

    def event(self, joint: str, kind: SafetyKind, severity: Severity, value: float,
              limit: float, text: str, phase: Phase = Phase.START) -> Event:
        """Return an event; a FATAL one latches the stop (the first is kept as its cause)."""
        if severity >= Severity.FATAL:
            self._latched = True
        made = Event(joint, SafetyKind(kind), Severity(severity), float(value), float(limit),
                     self._latched, text, Phase(phase))
        if severity >= Severity.FATAL and self._cause is None:
            self._cause = made
        return made

    def report_once(self, condition: Condition,
                    severity: Severity = Severity.FATAL) -> list[Event]:
        """Return the condition's event when it was not reported yet; nothing while it lasts."""
        if condition.key in self._reported:
            return []
        self._reported.add(condition.key)
        return [self.event(condition.joint, condition.kind, severity, condition.value,
                           condition.limit, condition.text)]

    def is_reported(self, key: Hashable) -> bool:
        """Whether a condition is reported and not forgotten since."""
        return key in self._reported

    def forget(self, keys: Sequence[Hashable] | set[Hashable]) -> None:
        """Forget conditions that no longer hold: they are reported again should they return."""
        self._reported.difference_update(keys)

    @property
    def reported(self) -> frozenset[Hashable]:
        """The keys of the conditions reported and not forgotten."""
        return frozenset(self._reported)

    def refusal(self, holding: Sequence[Condition]) -> Event | None:
        """Return the WARN event that refuses a reset while conditions hold, or None.

        The event carries the first condition's joint, kind, value and limit, and its text
        lists every condition. It leaves the latch as it is.
        """
        if not holding:
            return None
        first = holding[0]
        texts = '; '.join(condition.text for condition in holding)
        return Event(first.joint, first.kind, Severity.WARN, float(first.value),
                     float(first.limit), self._latched, f'reset refused: {texts}')

    def release(self) -> Event:
        """Release the stop (the caller checked nothing holds); return the RESET event.

        Not latched: an INFO event saying so. Released: INFO, not latched, naming the cause;
        the reported conditions are forgotten, as a fresh start.
        """
        if not self._latched:
            return Event('', SafetyKind.RESET, Severity.INFO, math.nan, math.nan, False,
                         'reset: no stop was latched')
        cause = self._cause
        self._latched = False
        self._cause = None
        self._reported.clear()
        because = f' (latched by {cause.text})' if cause is not None else ''
        return Event('', SafetyKind.RESET, Severity.INFO, math.nan, math.nan, False,
                     f'reset: stop released{because}')
