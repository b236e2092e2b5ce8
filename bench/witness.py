"""A witness of the platform: cyclictest above every thread of ours, and the vCPUs' steal time.

A periodic real-time loop can be late for reasons of its own (its computing, a lock, its
interpreter) or because nothing on its CPU ran at all: a kernel section that does not preempt,
or, on a virtual machine, the hypervisor running something else on the physical core under the
vCPU (the time the guest's ``/proc/stat`` counts as *steal*). The witness tells the two apart
in the same run: rt-tests' ``cyclictest`` (a small C program, the Linux real-time community's
latency gauge; Debian package ``rt-tests``), with its memory locked, wakes every ``interval``
on each of the loop's CPUs under SCHED_FIFO at a priority above every thread of ours. Only the
kernel and what is under the kernel can make it late, so a stall the loop saw that the witness
saw too at the same moment is the platform's, not the loop's. Its cost on its CPU is about
10 us a wake-up (0.1 s of CPU in 10 s at 1 kHz, measured here with ``/usr/bin/time``).

cyclictest's own habit of asking the kernel for no idle latency (``/dev/cpu_dma_latency`` 0)
is turned off (``--latency`` at the kernel's default, 2e9 us): on a guest whose idle driver is
haltpoll it would keep the vCPUs polling, and change what it measures.
"""

from __future__ import annotations

import bisect
import re
import shutil
import signal
import subprocess
import threading
import time
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

from exo_has_runtime.processes import Processes

#: A sample line of ``cyclictest -v``: thread index, cycle, latency [us].
SAMPLE = re.compile(r'^\s*(\d+):\s*(\d+):\s*(\d+)\s*$')
#: PM QoS value that asks nothing of the idle states [us] (the kernel's default).
NO_LATENCY_TARGET = 2_000_000_000
#: USER_HZ: the unit of /proc/stat's times.
TICK = 100.0
#: A wake-up later than this [ms] is a stall of the platform.
STALL_MS = 1.0
#: The witness's figures in the benchmarks' reports: key, label, format.
WITNESS_FIGURES = (('witness_max_ms', 'witness: latest wake-up [ms]', '.1f'),
                   ('witness_p99_ms', 'witness: lateness p99 [ms]', '.2f'),
                   ('witness_stalls', f'witness: wake-ups over {STALL_MS:g} ms late', '.0f'),
                   ('steal_ms', 'witness: steal time of its CPUs [ms]', '.0f'))


def steal_seconds(cpus: frozenset[int]) -> dict[int, float]:
    """Return each CPU's steal time since boot [s], from ``/proc/stat``."""
    steal = {}
    for line in Path('/proc/stat').read_text().splitlines():
        name, *values = line.split()
        if name.startswith('cpu') and name[3:].isdigit() and int(name[3:]) in cpus:
            steal[int(name[3:])] = int(values[7]) / TICK
    return steal


@dataclass
class Stalls:
    """The witness's late wake-ups over a span: what any thread on those CPUs could get."""

    wakeups: int = 0
    max_ms: float = 0.0
    p99_ms: float = 0.0
    #: Wall-clock time [s] and lateness [ms] of every wake-up later than the threshold.
    late: list[tuple[float, float]] = field(default_factory=list)


class Witness:
    """cyclictest on ``cpus`` under SCHED_FIFO ``priority`` while the context is open.

    Parameters
    ----------
    cpus : frozenset of int
        CPUs to watch, one cyclictest thread on each.
    priority : int
        SCHED_FIFO priority, above every thread of the system under test.
    interval : float
        Wake-up period [s]; a stall shorter than it may fall between two wake-ups.
    threshold : float
        Lateness [s] above which a wake-up is kept with its time (the rest only counted).

    Raises
    ------
    FileNotFoundError
        If cyclictest is not installed (Debian: ``apt-get install rt-tests``).

    """

    def __init__(self, cpus: frozenset[int], priority: int, interval: float = 1e-3,
                 threshold: float = STALL_MS * 1e-3) -> None:
        if shutil.which('cyclictest') is None:
            msg = 'the witness needs cyclictest: apt-get install rt-tests'
            raise FileNotFoundError(msg)
        self.cpus = cpus
        self.priority = priority
        self.interval = interval
        self.threshold = threshold
        self._processes = Processes()
        self._process: subprocess.Popen[str] | None = None
        self._reader: threading.Thread | None = None
        # Per thread: wall-clock time of its first sample [s]; then every sample's time is
        # that plus cycle * interval (cyclictest sleeps to absolute times on that grid), plus
        # the grid points it skipped, uncounted, after each wake-up later than an interval.
        self._origin: dict[int, float] = {}
        self._skipped: dict[int, int] = {}
        self._times: list[float] = []  # of every sample, in arrival order per thread
        self._lateness: list[float] = []  # [ms], alongside
        self._lock = threading.Lock()
        self.steal: dict[int, float] = {}

    def __enter__(self) -> Witness:
        cpus = ','.join(str(cpu) for cpu in sorted(self.cpus))
        self._steal_before = steal_seconds(self.cpus)
        with ExitStack() as stack:  # cyclictest ends if a step after its start fails
            stack.enter_context(self._processes)
            # stdbuf: line-buffered, so that a sample's arrival dates its thread's first cycle.
            self._process = self._processes.start(
                ['stdbuf', '-oL', 'cyclictest', '--mlockall', '--quiet', '--verbose',
                 f'--priority={self.priority}', f'--affinity={cpus}',
                 f'--threads={len(self.cpus)}', '--distance=0',
                 f'--interval={round(self.interval * 1e6)}',
                 f'--latency={NO_LATENCY_TARGET}'],
                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
            self._reader = threading.Thread(target=self._read, name='witness', daemon=True)
            self._reader.start()
            stack.pop_all()
        return self

    def __exit__(self, *exc: object) -> None:
        assert self._process is not None and self._reader is not None
        self._processes.end(self._process, first=signal.SIGINT)  # cyclictest's own stop
        self._reader.join(timeout=5.0)
        after = steal_seconds(self.cpus)
        self.steal = {cpu: after[cpu] - self._steal_before.get(cpu, after[cpu])
                      for cpu in after}

    def _read(self) -> None:
        assert self._process is not None and self._process.stdout is not None
        for line in self._process.stdout:
            found = SAMPLE.match(line)
            if found is None:
                continue
            thread, cycle, latency_us = (int(value) for value in found.groups())
            now = time.time()
            origin = self._origin.setdefault(thread, now - cycle * self.interval)
            skipped = self._skipped.get(thread, 0)
            with self._lock:
                self._times.append(origin + (cycle + skipped) * self.interval)
                self._lateness.append(latency_us * 1e-3)
            self._skipped[thread] = skipped + int(latency_us * 1e-6 // self.interval)

    def stalls(self, start: float, end: float) -> Stalls:
        """Return the wake-ups between wall-clock times ``start`` and ``end`` [s]."""
        with self._lock:
            order = sorted(range(len(self._times)), key=self._times.__getitem__)
            times = [self._times[i] for i in order]
            lateness = [self._lateness[i] for i in order]
        first, last = bisect.bisect_left(times, start), bisect.bisect_right(times, end)
        span = lateness[first:last]
        late = [(times[i], lateness[i]) for i in range(first, last)
                if lateness[i] > self.threshold * 1e3]
        p99 = sorted(span)[min(len(span) - 1, int(0.99 * len(span)))] if span else 0.0
        return Stalls(wakeups=len(span), max_ms=max(span, default=0.0), p99_ms=p99, late=late)

    def figures(self, start: float, end: float) -> dict[str, float]:
        """Return :data:`WITNESS_FIGURES` between wall-clock times ``start`` and ``end`` [s]."""
        stalls = self.stalls(start, end)
        return {'witness_max_ms': stalls.max_ms, 'witness_p99_ms': stalls.p99_ms,
                'witness_stalls': float(len(stalls.late)),
                'steal_ms': 1e3 * sum(self.steal.values())}
