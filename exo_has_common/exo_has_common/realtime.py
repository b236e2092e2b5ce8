"""A real-time scheduling class for the thread that runs a node's periodic loop.

On a shared Linux machine a 200 Hz loop under the default (CFS) scheduler waits behind other
processes now and then: on the project's 2-vCPU machine about 0.1 % of a plant's periods pass
with no tick, and its ticks run up to 15 to 30 ms late (``bench/system.py``). Under
``SCHED_FIFO`` the loop's thread preempts every ordinary thread as soon as its timer expires,
as ros2_control runs its control loop on a robot PC. Only the calling thread is raised: the
DDS threads a node created before stay ordinary, so a busy one cannot hold the loop off at its
own priority. Needs root or ``CAP_SYS_NICE`` (or an ``rtprio`` limit in
``/etc/security/limits.conf``); without, the loop runs as before and the caller is told why.
ROS-free.
"""

from __future__ import annotations

import os

#: Highest priority accepted: above it run the kernel's own threads (threaded interrupts at 50).
MAX_PRIORITY = 49


def set_realtime_priority(priority: int, thread_id: int = 0) -> str | None:
    """Put a thread under ``SCHED_FIFO`` at ``priority``; 0 leaves it as it is.

    Parameters
    ----------
    priority : int
        ``SCHED_FIFO`` priority, 1 to :data:`MAX_PRIORITY`; 0 does nothing.
    thread_id : int
        Native thread ID (``threading.get_native_id()``); 0 is the calling thread.

    Returns
    -------
    str or None
        Why the class could not be set (no permission, no such scheduler), or None.

    Raises
    ------
    ValueError
        For a priority outside 0 to :data:`MAX_PRIORITY`.

    """
    if isinstance(priority, bool) or not isinstance(priority, int) \
            or not 0 <= priority <= MAX_PRIORITY:
        msg = f'a real-time priority must be an integer within 0 and {MAX_PRIORITY}, ' \
              f'got {priority!r}'
        raise ValueError(msg)
    if priority == 0:
        return None
    if not hasattr(os, 'sched_setscheduler'):
        return 'this platform has no SCHED_FIFO: running under the default scheduler'
    try:
        os.sched_setscheduler(thread_id, os.SCHED_FIFO, os.sched_param(priority))
    except PermissionError:
        return (f'no permission for SCHED_FIFO priority {priority} (needs root, CAP_SYS_NICE or '
                'an rtprio limit): running under the default scheduler')
    except OSError as exc:
        return f'cannot set SCHED_FIFO priority {priority} ({exc}): running under the default ' \
               'scheduler'
    return None
