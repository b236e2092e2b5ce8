"""A real-time scheduling class for the thread that runs a node's periodic loop.

On a shared Linux machine a 200 Hz loop under the default (CFS) scheduler waits behind other
processes now and then: on the project's 2-vCPU machine about 0.1 % of a plant's periods pass
with no tick, and its ticks run up to 15 to 30 ms late (``bench/system.py``). Under
``SCHED_FIFO`` the loop's thread preempts every ordinary thread as soon as its timer expires,
as ros2_control runs its control loop on a robot PC. Only the calling thread is raised: the
DDS threads a node created before stay ordinary, so a busy one cannot hold the loop off at its
own priority. Needs root or ``CAP_SYS_NICE`` (or an ``rtprio`` limit in
``/etc/security/limits.conf``); without, the loop runs as before and the caller is told why.

A CPU of its own (:func:`set_cpus`, as ``taskset`` or an isolated core gives one): SCHED_FIFO
does not keep the kernel's network work off the loop's CPU. A process sending over the loopback
or a NIC leaves packets for the NET_RX softirq of the CPU it runs on, and a thread there runs
that backlog when it next sends (its own frames and everyone's DDS traffic alike), or is held
up while an interrupt's exit runs it. With a ROS session beside it on the same two cores the
robot loop ran ~4 ms late for stretches of a hundred periods; kept to its own CPU, with the
session on the other, 0.1 ms (bench/README.md, "The robot side against the old chain").

Memory of its own (:func:`lock_memory`): a page the loop touches for the first time, or one the
kernel swapped out or (on a virtual machine) handed back to the host, is a fault taken inside
the cycle. Locking every page, present and future, and keeping the C heap from returning
memory, moves those faults to start-up, as ros2_control's controller manager does by default
(its ``lock_memory`` parameter) and as the Linux real-time community's guides ask.
ROS-free.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno
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


#: mlockall(2) flags: the pages mapped now, and those mapped from now on.
MCL_CURRENT, MCL_FUTURE = 1, 2
#: mallopt(3) parameters: the heap's trim threshold, the most blocks served by mmap.
M_TRIM_THRESHOLD, M_MMAP_MAX = -1, -4


def lock_memory(libc: ctypes.CDLL | None = None) -> str | None:
    """Lock the process's memory in RAM, now and from now on; keep the C heap from shrinking.

    ``mlockall(MCL_CURRENT | MCL_FUTURE)``: every page mapped now is faulted in and locked, and
    every page mapped later is faulted in when mapped (a thread's stack, an allocator's arena),
    not when first touched. glibc is told never to trim its heap nor to serve a block with its
    own mapping, so that memory freed in one cycle is reused in the next without a fault.
    Resident memory grows to the mapped size (the libraries' pages too).

    Parameters
    ----------
    libc : ctypes.CDLL, optional
        The C library to call (the process's own by default; tests give a stand-in).

    Returns
    -------
    str or None
        Why the memory could not be locked (no permission, the ``memlock`` limit, no
        mlockall on this platform), or None.

    """
    if libc is None:
        name = ctypes.util.find_library('c')
        if name is None or not hasattr(os, 'sched_setscheduler'):
            return 'this platform has no mlockall: memory not locked'
        libc = ctypes.CDLL(name, use_errno=True)
    if libc.mlockall(MCL_CURRENT | MCL_FUTURE) != 0:
        code = ctypes.get_errno()
        why = {errno.EPERM: 'no permission (needs root or CAP_IPC_LOCK)',
               errno.ENOMEM: 'over the memlock limit (ulimit -l; needs root, CAP_IPC_LOCK or a '
                             'memlock limit in /etc/security/limits.conf)'}.get(
            code, os.strerror(code))
        return f'cannot lock memory: {why}: memory not locked, pages may fault in the loop'
    # mallopt returns 1 on success; a C library without it (not glibc) keeps its own habits.
    if hasattr(libc, 'mallopt'):
        libc.mallopt(M_TRIM_THRESHOLD, -1)
        libc.mallopt(M_MMAP_MAX, 0)
    return None


def parse_cpus(text: str) -> frozenset[int]:
    """Read a CPU list as ``taskset -c`` writes it: ``1``, ``2,3``, ``0-3``.

    Raises
    ------
    ValueError
        For a list that is empty, malformed, or names a CPU this machine does not have; the
        message names the list and the CPUs there are.

    """
    available = sorted(os.sched_getaffinity(0)) if hasattr(os, 'sched_getaffinity') else []
    count = os.cpu_count() or 1
    cpus: set[int] = set()
    try:
        for part in text.split(','):
            first, _, last = part.strip().partition('-')
            low, high = int(first), int(last or first)
            if low < 0 or high < low:
                raise ValueError(part)
            cpus.update(range(low, high + 1))
    except ValueError:
        msg = f'CPU list {text!r}: expected numbers and ranges such as 1 or 2,3 or 0-3'
        raise ValueError(msg) from None
    missing = sorted(cpu for cpu in cpus if cpu >= count)
    if missing:
        msg = (f'CPU list {text!r} names CPU {", ".join(map(str, missing))}, which this machine '
               f'does not have (it has 0 to {count - 1}; this process may run on '
               f'{",".join(map(str, available))})')
        raise ValueError(msg)
    return frozenset(cpus)


def set_cpus(cpus: frozenset[int]) -> str | None:
    """Keep the calling thread, and the threads it starts from now on, to ``cpus``.

    A thread keeps the CPUs of the thread that started it: call this before starting the
    threads that should share them. Threads started before keep theirs.

    Returns
    -------
    str or None
        Why the affinity could not be set, or None.

    """
    if not cpus:
        return None
    if not hasattr(os, 'sched_setaffinity'):
        return 'this platform sets no CPU affinity: running on every CPU'
    try:
        os.sched_setaffinity(0, cpus)
    except OSError as exc:
        return f'cannot keep to CPUs {sorted(cpus)} ({exc}): running on every CPU'
    return None
