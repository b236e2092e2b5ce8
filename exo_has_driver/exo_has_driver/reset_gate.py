"""The driver's reset gate: a reset waits while another node's (the watchdog's) stop holds.

Free of ROS. The watchdog and the driver answer the same reset request; the controllers
resume on the driver's RESET event, so the driver must not release while the watchdog's stop
is latched: :class:`ResetGate` passes a reset on only once the newest event of another node
says no stop is latched there.
"""

from __future__ import annotations

#: How long a reset waits for another node's (the watchdog's) release [s].
RESET_WAIT = 1.0


class ResetGate:
    """Holds a reset back while another node's (the watchdog's) stop is latched.

    The newest event from another node tells whether its stop is latched. A reset is passed on
    at once when it is not; otherwise it waits up to ``wait`` [s] for an event that says it
    was released (the watchdog answers the same reset), and is refused after that.
    """

    def __init__(self, wait: float = RESET_WAIT) -> None:
        self.wait = wait
        #: Text of the newest latched event of another node; None when none holds a stop.
        self.latched_by: str | None = None
        self._deadline: float | None = None

    def on_event(self, latched: bool, text: str) -> bool:
        """Take another node's event; return whether a waiting reset may go on now."""
        self.latched_by = text if latched else None
        if latched or self._deadline is None:
            return False
        self._deadline = None
        return True

    def on_reset(self, now: float) -> bool:
        """Take a reset request at ``now`` [s]; return whether it may go on now."""
        if self.latched_by is None:
            return True
        self._deadline = now + self.wait
        return False

    def expired(self, now: float) -> str | None:
        """Return the refusal text once a waiting reset ran out of time, else None."""
        if self._deadline is None or now <= self._deadline:
            return None
        self._deadline = None
        return f'reset refused: a stop latched by another node holds: {self.latched_by}'
