"""A stop that signals ask for: a flag a signal handler may set, and the handlers that set it.

Free of ROS. ``threading.Event.set`` takes a lock; a signal handler runs in the main thread
between two bytecodes, possibly while that thread waits on the same Event (``Event.wait`` holds
its lock between checks) or inside another handler's ``set``: the handler then waits on the lock
forever, and the process never ends. It happened to the robot loop's process at 1 kHz
(py-spy: the main thread in ``on_signal`` -> ``Event.set`` -> ``Condition.__enter__``, inside
``Event.wait``), its drives still enabled. Setting an attribute cannot block.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Sequence
from types import FrameType


class StopRequest:
    """A stop that a signal handler may ask for: a plain flag, no lock."""

    def __init__(self) -> None:
        self._requested = False

    def set(self) -> None:
        """Ask for the stop (safe in a signal handler, any number of times)."""
        self._requested = True

    def is_set(self) -> bool:
        """Whether the stop was asked for."""
        return self._requested

    def wait(self, timeout: float) -> bool:
        """Sleep up to ``timeout`` [s], less if the stop is asked for; return whether it was.

        A signal ends the sleep early (its handler runs, then the sleep goes on for what is
        left: Python retries an interrupted sleep); the flag is looked at in slices of at most
        :data:`WAIT_SLICE`, so that a stop is seen within that.
        """
        deadline = time.monotonic() + timeout
        while not self._requested:
            left = deadline - time.monotonic()
            if left <= 0.0:
                break
            time.sleep(min(left, WAIT_SLICE))
        return self._requested

    def __call__(self, number: int, frame: FrameType | None) -> None:
        """Set the stop: the signal handler."""
        self._requested = True


#: Longest sleep of :meth:`StopRequest.wait` before it looks at the flag again [s].
WAIT_SLICE = 0.05


def stop_on_signals(numbers: Sequence[int] = (signal.SIGINT, signal.SIGTERM)) -> StopRequest:
    """Have the signals ``numbers`` ask for a stop, from now on; return the request."""
    request = StopRequest()
    for number in numbers:
        signal.signal(number, request)
    return request
