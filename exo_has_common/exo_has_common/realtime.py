"""A real-time scheduling class for the thread that runs a node's periodic loop.

On a shared Linux machine a 200 Hz loop under the default (CFS) scheduler waits behind other
processes now and then: on the project's 2-vCPU machine about 0.1 % of a plant's periods pass
with no tick, and its ticks run up to 15 to 30 ms late (``bench/system.py``). Under
``SCHED_FIFO`` the loop's thread preempts every ordinary thread as soon as its timer expires,
as ros2_control runs its control loop on a robot PC. Only the calling thread is raised: the
DDS threads a node created before stay ordinary, so a busy one cannot hold the loop off at its
own priority. Needs root or ``CAP_SYS_NICE`` (or an ``rtprio`` limit in
``/etc/security/limits.conf``); without, the loop runs as before and the caller is told why.
Root can be refused too: with ``CONFIG_RT_GROUP_SCHED`` a control group other than the root one
has no real-time budget unless given one (its ``cpu.rt_runtime_us`` is 0), and the kernel
answers EPERM to everyone in it. A root shell of a 16-core Linux 6.18 machine was, until it
was moved to the root group; the message then names the group and the fix, not root.

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
from pathlib import Path

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
        if os.geteuid() == 0 and _has_capability(CAP_SYS_NICE):
            return (f'SCHED_FIFO priority {priority} refused although running as root: '
                    f'{_real_time_budget()}: running under the default scheduler')
        if os.geteuid() == 0:
            return (f'no permission for SCHED_FIFO priority {priority}: root without '
                    'CAP_SYS_NICE (a container drops it; docker run --cap-add SYS_NICE): '
                    'running under the default scheduler')
        return (f'no permission for SCHED_FIFO priority {priority} (needs root, CAP_SYS_NICE or '
                'an rtprio limit): running under the default scheduler')
    except OSError as exc:
        return f'cannot set SCHED_FIFO priority {priority} ({exc}): running under the default ' \
               'scheduler'
    return None


#: Where the kernel lists the process's control groups, and where their hierarchies are
#: mounted (tests point both elsewhere).
CGROUP_FILE = Path('/proc/self/cgroup')
CGROUP_MOUNT = Path('/sys/fs/cgroup')
#: Where the kernel lists the process's capabilities (``CapEff``).
STATUS_FILE = Path('/proc/self/status')
#: The capability that lets a process set real-time classes (capability(7)).
CAP_SYS_NICE = 23


def _has_capability(capability: int) -> bool:
    """Whether the process holds ``capability`` (True where it cannot be read: root's case)."""
    try:
        for line in STATUS_FILE.read_text().splitlines():
            if line.startswith('CapEff:'):
                return bool(int(line.split()[1], 16) >> capability & 1)
    except (OSError, ValueError, IndexError):
        pass
    return True


def _cpu_cgroup() -> tuple[str, Path] | None:
    """Return the process's group in the hierarchy with the cpu controller, and its root.

    A cgroup v1 ``cpu`` line (``4:cpu,cpuacct:/user.slice``) if there is one, where the
    real-time budget lives, else the unified v2 line (``0::/user.slice/...``).
    """
    try:
        lines = CGROUP_FILE.read_text().splitlines()
    except OSError:
        return None
    unified = None
    for line in lines:
        _, controllers, group = [*line.split(':', 2), '', ''][:3]
        if 'cpu' in controllers.split(','):
            root = next((CGROUP_MOUNT / name for name in (controllers, 'cpu', 'cpu,cpuacct')
                         if (CGROUP_MOUNT / name).is_dir()), CGROUP_MOUNT / 'cpu')
            return group or '/', root
        if not controllers and unified is None:
            unified = group or '/'
    return (unified, CGROUP_MOUNT) if unified is not None else None


def _real_time_budget() -> str:
    """Say why a root process with CAP_SYS_NICE is refused SCHED_FIFO, and the fix."""
    found = _cpu_cgroup()
    if found is None:
        return ('the likely cause is a control group with no real-time budget '
                '(cpu.rt_runtime_us 0, CONFIG_RT_GROUP_SCHED); start it in the root control '
                'group or give its group a budget')
    group, root = found
    if group == '/':
        return ('the process is in the root control group; see whether its real-time budget '
                'is 0 (/proc/sys/kernel/sched_rt_runtime_us, cpu.rt_runtime_us)')
    folder = root / group.lstrip('/')
    try:
        budget = (folder / 'cpu.rt_runtime_us').read_text().strip()
    except OSError:
        budget = ''
    if budget in ('', '0'):
        why = ('which has no real-time budget (its cpu.rt_runtime_us is '
               f'{budget or "unreadable"}; with CONFIG_RT_GROUP_SCHED a child group gets none '
               'unless given one)')
    else:
        why = f'whose real-time budget may be short (its cpu.rt_runtime_us is {budget})'
    return (f'the process is in control group {group}, {why}. Start it from the root group '
            f'(echo $$ > {root / "cgroup.procs"} in its shell, as root), give the group a '
            f'budget (echo 950000 > {folder / "cpu.rt_runtime_us"}, its parents first), or '
            'start it outside the systemd slice that put it there (a unit with '
            'CPUAccounting=no)')


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
