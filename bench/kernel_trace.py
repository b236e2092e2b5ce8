"""What a CPU did, from the kernel's own trace: when a thread ran, when the CPU was not there.

:class:`CpuTrace` records scheduler and interrupt events of some CPUs through tracefs
(``/sys/kernel/tracing``; root) for the length of a ``with``, on the monotonic clock
(``time.monotonic``'s). Two readings come of it:

- :func:`switch_ins`: the times a thread was switched in. A periodic loop's thread runs at least
  once a period; a longer interval between two runs is a gap in the loop.
- :func:`absences`: the spans in which a CPU recorded no event at all. With a timer armed on it
  every millisecond (the witness, :mod:`witness`, wakes every 1 ms) and the tick, a CPU that
  runs produces an event at least every millisecond, whatever it runs (while the witness waits
  to run, its timer is not armed: then the tick's period is the bound); a longer span without
  one is a span the CPU did not run: on a virtual machine, the host ran
  something else on the physical core under the vCPU (the guest counts it as *steal*), or the
  guest kept interrupts off that long. Either way no thread on that CPU, at any priority,
  could have run in it.

A gap of the loop that an absence fills (all but a period of it) is the platform's; one it does
not is the loop's own, or of what shares its CPU.
"""

from __future__ import annotations

import bisect
import gzip
import itertools
import os
import re
from dataclasses import dataclass
from pathlib import Path

#: Where tracefs is mounted; EXO_HAS_TRACEFS for another mount point (or none: a test's).
TRACEFS = Path(os.environ.get('EXO_HAS_TRACEFS', '/sys/kernel/tracing'))
#: Enough events to see both what runs and that the CPU runs at all.
EVENTS = ('sched/sched_switch', 'sched/sched_waking', 'irq_vectors/local_timer_entry',
          'irq/softirq_entry', 'irq/irq_handler_entry', 'irq_vectors/reschedule_entry',
          'irq_vectors/call_function_single_entry')
#: A line of the ``trace`` file: task-pid, [cpu], flags, time [s], event, its fields.
LINE = re.compile(r'^\s*.+?-(\d+)\s+\[(\d+)\]\s+\S+\s+([\d.]+): (\w+): (.*)$')


@dataclass(frozen=True)
class Event:
    """One traced event: time [s] on the monotonic clock, CPU, name, fields as printed."""

    t: float
    cpu: int
    name: str
    fields: str


class CpuTrace:
    """Trace the scheduler and interrupt events of ``cpus`` while the context is open.

    Parameters
    ----------
    cpus : frozenset of int
        CPUs whose events are kept.
    buffer_mb : int
        Ring buffer per CPU [MB]; at about 25,000 events a second on a busy CPU, 100 MB holds
        about 60 s. :attr:`lost` says whether it overflowed.

    Raises
    ------
    PermissionError
        Without root, or where tracefs is not mounted (``mount -t tracefs nodev
        /sys/kernel/tracing``).

    """

    def __init__(self, cpus: frozenset[int], buffer_mb: int = 100) -> None:
        if not (TRACEFS / 'trace').exists():
            msg = f'no tracefs at {TRACEFS}: mount -t tracefs nodev {TRACEFS} (as root)'
            raise PermissionError(msg)
        self.cpus = cpus
        self.buffer_mb = buffer_mb
        self.events: list[Event] = []
        self.lost = False

    def _write(self, name: str, value: str) -> None:
        (TRACEFS / name).write_text(value)

    def __enter__(self) -> CpuTrace:
        self._write('tracing_on', '0')
        self._write('trace', '')
        self._write('current_tracer', 'nop')
        self._write('trace_clock', 'mono')
        self._write('buffer_size_kb', str(self.buffer_mb * 1024))
        self._write('tracing_cpumask', f'{sum(1 << cpu for cpu in self.cpus):x}')
        self._write('set_event', '')
        for event in EVENTS:
            self._write(f'events/{event}/enable', '1')
        self._write('tracing_on', '1')
        return self

    def __exit__(self, *exc: object) -> None:
        self._write('tracing_on', '0')
        text = (TRACEFS / 'trace').read_text()
        self._write('set_event', '')
        self._write('trace', '')
        self._write('buffer_size_kb', '1408')  # the kernel's default, the memory given back
        header = re.search(r'entries-in-buffer/entries-written: (\d+)/(\d+)', text)
        self.lost = header is not None and header.group(1) != header.group(2)
        for line in text.splitlines():
            found = LINE.match(line)
            if found is not None:
                self.events.append(Event(float(found.group(3)), int(found.group(2)),
                                         found.group(4), found.group(5)))


def switch_ins(events: list[Event], tid: int) -> list[float]:
    """Return the times [s] the thread ``tid`` was switched in."""
    mark = f'next_pid={tid} '
    return [e.t for e in events if e.name == 'sched_switch' and mark in e.fields]


def absences(events: list[Event], cpu: int, heartbeat_priority: int,
             longer_than: float = 1.5e-3) -> list[tuple[float, float]]:
    """Return the spans [s] in which ``cpu`` recorded no event although one was due.

    An event is due every ``longer_than`` [s] while the heartbeat (the witness, waking every
    millisecond under SCHED_FIFO ``heartbeat_priority``) can run; while it waits to run (the
    scheduler ran something else: the fair server's reservation for ordinary tasks, since
    Linux 6.12), its timer is not armed and only the tick is due, every :func:`kernel_tick`.
    """
    waiting = f'prio={99 - heartbeat_priority} '
    tick = kernel_tick()
    mine = [e for e in events if e.cpu == cpu]
    spans = []
    blocked = False  # the heartbeat woken and not yet run
    for before, after in itertools.pairwise(mine):
        if before.name == 'sched_waking' and waiting in before.fields:
            blocked = True
        elif before.name == 'sched_switch' and f'next_prio={99 - heartbeat_priority}' \
                in before.fields:
            blocked = False
        if after.t - before.t > (tick + 0.5e-3 if blocked else longer_than):
            spans.append((before.t, after.t))
    return spans


def kernel_tick() -> float:
    """Return the kernel's tick period [s] (CONFIG_HZ), from its configuration; 10 ms if unknown.

    10 ms is the longest tick Linux builds with (HZ=100): with it, no span is taken for an
    absence that the tick alone would leave quiet.
    """
    text = ''
    config = Path('/proc/config.gz')
    if config.exists():
        text = gzip.decompress(config.read_bytes()).decode(errors='replace')
    else:
        booted = Path(f'/boot/config-{os.uname().release}')
        text = booted.read_text(errors='replace') if booted.exists() else ''
    found = re.search(r'^CONFIG_HZ=(\d+)$', text, re.MULTILINE)
    return 1.0 / int(found.group(1)) if found else 0.01


def gaps_explained(run_times: list[float], absent: list[tuple[float, float]], period: float,
                   slack: float = 1e-3) -> list[tuple[float, float]]:
    """Return each gap between runs longer than ``period + slack`` [s], with its absence.

    Returns
    -------
    list of (gap, absent)
        The gap [s] and the time [s] of it in which the CPU was absent. The gap is the
        platform's where ``gap - absent`` is within ``period + slack``.

    """
    starts = [a for a, _ in absent]
    found = []
    for a, b in itertools.pairwise(run_times):
        if b - a <= period + slack:
            continue
        first = max(0, bisect.bisect_left(starts, a) - 1)
        last = bisect.bisect_right(starts, b)
        lost = sum(max(0.0, min(y, b) - max(x, a)) for x, y in absent[first:last])
        found.append((b - a, lost))
    return found



#: Slack [s] over a period before an interval between a loop thread's runs is a gap.
GAP_SLACK = 1e-3
#: The figures of :func:`trace_figures`: key, label, format.
TRACE_FIGURES = (('loop_gaps', 'trace: gaps of the loop (over a period + 1 ms)', '.0f'),
                 ('loop_gaps_platform', "... of them filled by the CPU's absence", '.0f'),
                 ('loop_gap_max_ms', 'trace: longest gap of the loop [ms]', '.1f'),
                 ('loop_gap_own_max_ms', 'trace: longest gap net of absence [ms]', '.1f'),
                 ('absent_spans', 'trace: CPU absent over 1.5 ms, spans', '.0f'),
                 ('absent_ms', 'trace: CPU absent, total [ms]', '.0f'),
                 ('absent_longest_ms', 'trace: CPU absent, longest [ms]', '.1f'))


def trace_figures(trace: CpuTrace, tid: int | None, period: float, heartbeat_priority: int,
                  window: tuple[float, float] | None = None) -> dict[str, float]:
    """Return a one-CPU trace's figures: the CPU's absences; the loop's gaps, which they fill.

    ``tid``: the loop's thread (None: the absences only). A gap is the platform's where the
    absence in it leaves no more than a period and :data:`GAP_SLACK`; ``loop_gap_own_max_ms``
    is the longest gap net of its absence among the others (0: none). ``heartbeat_priority``:
    the witness's (:func:`absences`). ``window``: the span [s], on the monotonic clock, to
    judge (None: the whole trace).
    """
    (cpu,) = trace.cpus
    events = trace.events if window is None else \
        [e for e in trace.events if window[0] <= e.t <= window[1]]
    absent = absences(events, cpu, heartbeat_priority)
    figures = {'trace_lost': float(trace.lost), 'absent_spans': float(len(absent)),
               'absent_ms': 1e3 * sum(b - a for a, b in absent),
               'absent_longest_ms': 1e3 * max((b - a for a, b in absent), default=0.0)}
    if tid is None:
        return figures
    gaps = gaps_explained(switch_ins(events, tid), absent, period, GAP_SLACK)
    own = [gap - lost for gap, lost in gaps if gap - lost > period + GAP_SLACK]
    return {**figures, 'loop_gaps': float(len(gaps)),
            'loop_gap_max_ms': 1e3 * max((gap for gap, _ in gaps), default=0.0),
            'loop_gaps_platform': float(len(gaps) - len(own)),
            'loop_gap_own_max_ms': 1e3 * max(own, default=0.0)}


def only_other_thread(pid: int) -> int:
    """Return the one thread of process ``pid`` besides its main thread (a loop's I/O thread).

    Raises
    ------
    RuntimeError
        If the process has none or several.

    """
    tids = sorted(int(task.name) for task in Path(f'/proc/{pid}/task').iterdir())
    others = [tid for tid in tids if tid != pid]
    if len(others) != 1:
        msg = f'expected process {pid} to run one thread beside its main thread, got {others}'
        raise RuntimeError(msg)
    return others[0]
