"""What the benchmarks share: spinners, CPU time, the machine, CPU shares, the results."""

from __future__ import annotations

import json
import os
import platform
import random
import re
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from exo_has_runtime.processes import Processes, stat_fields

if TYPE_CHECKING:  # the scripts choose the backend before they import the session
    from exo_has_bringup.runner import Session

TICK = os.sysconf('SC_CLK_TCK')
#: A process that spins: the load of the benchmarks' ``--busy``.
SPIN = (sys.executable, '-c', 'while True: pass')


def pinned(cpus: str, command: Sequence[str]) -> list[str]:
    """Return ``command`` kept to ``cpus`` (as taskset takes them), or as it is."""
    return ['taskset', '-c', cpus, *command] if cpus else list(command)


def start_busy(processes: Processes, count: int) -> list[subprocess.Popen[Any]]:
    """Start ``count`` processes that spin, the i-th pinned to core i modulo the cores.

    Every core of the machine, whatever this process's own CPUs are.
    """
    cores = os.cpu_count() or 1
    return [processes.start(pinned(str(index % cores), SPIN)) for index in range(count)]


def on_this_machine() -> None:
    """Run this benchmark and what it starts on a ROS domain of its own, on this machine only.

    A random domain (100 to 200) and LOCALHOST discovery, unless the environment says
    otherwise, with the DDS transport every exo_has process takes (exo_has_runtime.dds); call
    before the first participant exists: the processes it starts inherit all three.
    """
    from exo_has_runtime.dds import configure_transport

    os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(100, 200)))
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    configure_transport()


#: The robot loop's closing line (exo_has_bringup.robot_main), its figures by name.
LOOP_SUMMARY = re.compile(
    r'robot loop stopped: (?P<periods>\d+) periods, (?P<missed>\d+) missed, (?P<late>\d+) late '
    r'by over half a period, lateness p99 (?P<p99>[\d.]+) ms p99\.9 (?P<p999>[\d.]+) ms max '
    r'(?P<max>[\d.]+) ms; longest gap between bus commands (?P<gap>[\d.]+) ms; cycle compute '
    r'max (?P<compute>[\d.]+) ms; datagrams dropped (?P<dropped>\d+), refused (?P<refused>\d+)')


def raise_softirq_threads(cpus: frozenset[int], priority: int) -> dict[int, int]:
    """Put each CPU's ``ksoftirqd`` under SCHED_FIFO ``priority``; return their old policies.

    With a busy process on the loop's CPU, the kernel's softirq thread there (SCHED_OTHER)
    waits its turn behind it, and the network work deferred to it (the simulated bus's UDP)
    piles up until an interrupt's exit or the loop's own send runs it: the loop ran ~3.5 ms
    late for stretches. Under SCHED_FIFO one level under the loop it runs at once; PREEMPT_RT
    runs softirqs in such threads by design.
    """
    names = {f'ksoftirqd/{cpu}' for cpu in cpus}
    saved = {}
    for comm in Path('/proc').glob('[0-9]*/comm'):
        try:
            name = comm.read_text().strip()
        except OSError:
            continue
        if name in names:
            pid = int(comm.parent.name)
            saved[pid] = os.sched_getscheduler(pid)
            os.sched_setscheduler(pid, os.SCHED_FIFO, os.sched_param(priority))
    return saved


def restore_threads(saved: dict[int, int]) -> None:
    """Give the threads of :func:`raise_softirq_threads` their policies back (priority 0)."""
    for pid, policy in saved.items():
        os.sched_setscheduler(pid, policy, os.sched_param(0))


#: Where each benchmark writes ``<name>.json`` and ``<name>.txt``.
RESULTS = Path(__file__).resolve().parent / 'results'


def machine_ticks() -> tuple[int, int, int]:
    """Return the machine's busy, stolen and total CPU clock ticks since boot (``/proc/stat``).

    Busy is user, nice, system, irq and softirq time; total adds idle, iowait and steal (guest
    time is already counted in user and nice).
    """
    with open('/proc/stat', encoding='ascii') as handle:
        user, nice, system, idle, iowait, irq, softirq, steal = \
            (int(v) for v in handle.readline().split()[1:9])
    busy = user + nice + system + irq + softirq
    return busy, steal, busy + idle + iowait + steal


def cpu_seconds(pid: int) -> float:
    """User plus system CPU time of a process [s]."""
    fields = stat_fields(pid)
    return (int(fields[11]) + int(fields[12])) / TICK


def describe_machine() -> dict[str, object]:
    """Describe the machine the figures come from."""
    return {'cpus': os.cpu_count(), 'machine': platform.machine(),
            'python': platform.python_version(), 'kernel': platform.release()}


def trial_cpu_shares(session: Session, duration: float) -> dict[str, float]:
    """Wait out a started session's trials; each process's CPU share over their middle 60 %.

    Returns when the trials of ``duration`` seconds are over (and half a second more); the
    shares are in percent of one core, by process name.
    """
    assert session.started_at is not None
    time.sleep(max(0.0, session.started_at - time.monotonic()) + duration * 0.2)
    before = {name: cpu_seconds(p.process.pid) for name, p in session.processes.items()}
    t0 = time.monotonic()
    time.sleep(duration * 0.6)
    span = time.monotonic() - t0
    after = {name: cpu_seconds(p.process.pid) for name, p in session.processes.items()}
    time.sleep(max(0.0, session.started_at + duration + 0.5 - time.monotonic()))
    return {name: 100.0 * (after[name] - before[name]) / span for name in before}


def write_results(name: str, data: dict[str, object], lines: list[str]) -> None:
    """Write a benchmark's data (with the machine) and printout under results/, and print it."""
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f'{name}.json').write_text(
        json.dumps({'machine': describe_machine(), **data}, indent=1) + '\n')
    (RESULTS / f'{name}.txt').write_text('\n'.join(lines) + '\n')
    print('\n'.join(lines))
