"""Benchmark: the robot loop's own timing, without a session: devices, loop, a constant reference.

Runs the simulated CAN devices and the robot loop (``robot_main --activate``) on a udp_multicast
bus of their own for ``--seconds``, a process sending a constant reference to the loop's socket
at 50 Hz (``exo_has_bringup/test/robot_reference_sender.py``), and ``--busy`` processes that
spin, the i-th pinned to core i. The loop and the devices may be kept to CPUs of their own
(``--loop-cpus``, ``--devices-cpus``) and given SCHED_FIFO priorities. The variants
(``--memory locked unlocked``: the loop's ``--lock-memory`` or ``--no-lock-memory``) take
turns ``--repeats`` times, so that they share the machine's moods.

With ``--witness-priority N`` a witness (:mod:`witness`: cyclictest under SCHED_FIFO N, above the
loop, on the loop's CPUs, waking every 1 ms) runs through each run. With ``--trace`` as well
(root; one ``--loop-cpus``), the kernel's trace of that CPU (:mod:`kernel_trace`), from the
loop's activation to the end of the run, says when the loop's thread ran and when the CPU itself
was absent (no event for over 1.5 ms, with the witness's timer due every 1 ms): each gap of the
loop (over a period and 1 ms between two runs of its thread) is the platform's where the
absence fills all but a period and 1 ms of it, else the loop's own. What else runs on the
machine is up to the caller: bench/README.md, "The robot side against the old chain", ran it
beside an ``exo-has demo`` on another domain (``taskset -c 0 exo-has demo``), to see what a ROS
session's traffic does.

Prints per run the loop's closing summary and the witness's figures, then per variant the
medians (and the worst run). Run (in ``./run shell``, as root for SCHED_FIFO and mlockall):
``python bench/robot_loop_alone.py --rate 200 --seconds 60 --repeats 5 --busy 2 --loop-cpus 1
--devices-cpus 1 --softirq-priority 19 --witness-priority 21 --trace --results
robot_loop_memory``.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np
from common import (
    LOOP_SUMMARY,
    pinned,
    raise_softirq_threads,
    restore_threads,
    start_busy,
    write_results,
)
from kernel_trace import TRACE_FIGURES, CpuTrace, only_other_thread, trace_figures
from witness import WITNESS_FIGURES, Witness

from exo_has_bringup.robot_exchange import DatagramExchange, bridge_end
from exo_has_common.realtime import parse_cpus
from exo_has_driver.hardware.bus import random_multicast_group
from exo_has_runtime.processes import Processes

SENDER = Path(__file__).resolve().parents[1] / 'exo_has_bringup' / 'test' / \
    'robot_reference_sender.py'
REFERENCE = ('left_hip=0.2', 'left_knee=0.3', 'right_hip=0.2', 'right_knee=0.3')  # rad


def run(args: argparse.Namespace, memory: str) -> dict[str, Any]:
    """Run the devices, the loop, the sender and the busy processes once; return the figures."""
    cores = os.cpu_count() or 1
    group = random_multicast_group()
    witness_cpus = parse_cpus(args.loop_cpus) if args.loop_cpus else \
        frozenset(range(cores))
    with tempfile.TemporaryDirectory(prefix='exo-alone-') as directory, ExitStack() as stack:
        # Entered first, left last: every process started is ended, whichever step fails.
        processes = stack.enter_context(Processes())
        start_busy(processes, args.busy)
        bridge = bridge_end(Path(directory))
        stack.callback(bridge.close)
        witness = stack.enter_context(Witness(witness_cpus, args.witness_priority)) \
            if args.witness_priority else None
        # From before the loop starts; judged from its activation on.
        trace = stack.enter_context(CpuTrace(witness_cpus)) if args.trace else None
        devices = processes.start(pinned(args.devices_cpus, [
            sys.executable, '-m', 'exo_has_driver.devices.main', '--interface',
            'udp_multicast', '--channel', group,
            '--realtime-priority', f'{args.devices_priority}']), stdout=subprocess.PIPE,
            text=True)
        assert devices.stdout is not None
        devices.stdout.readline()  # can devices ready
        loop = processes.start(pinned(args.loop_cpus, [
            sys.executable, '-m', 'exo_has_bringup.robot_main', '--interface',
            'udp_multicast', '--channel', group, '--rate', f'{args.rate}',
            '--bitrate', f'{args.bitrate}', '--socket-dir', directory,
            '--realtime-priority', f'{args.loop_priority}', '--activate',
            '--lock-memory' if memory == 'locked' else '--no-lock-memory']),
            stdout=subprocess.PIPE, text=True)
        assert loop.stdout is not None
        loop.stdout.readline()  # robot loop ready: configured and activated
        ready = time.monotonic()
        sender = processes.start([sys.executable, str(SENDER), directory, '50', *REFERENCE],
                                 stdout=subprocess.PIPE, text=True)
        begin = time.time()
        deadline = time.monotonic() + args.seconds
        # What the loop sends is taken, as a bridge would, to the end of the run.
        drained = threading.Event()
        drainer = threading.Thread(target=drain, args=(bridge, drained), daemon=True)
        drainer.start()
        stack.callback(drainer.join)
        stack.callback(drained.set)
        time.sleep(1.0)
        resident_mb = resident(loop.pid)
        tid = only_other_thread(loop.pid)  # the loop's I/O thread
        time.sleep(max(0.0, deadline - time.monotonic()))
        end = time.time()
        running = (ready, time.monotonic())
        processes.end(sender, first=signal.SIGKILL)
        loop.send_signal(signal.SIGTERM)
        output = loop.communicate(timeout=30.0)[0]
    found = LOOP_SUMMARY.search(output)
    if found is None:
        msg = f'the robot loop printed no summary: {output[-2000:]}'
        raise RuntimeError(msg)
    figures: dict[str, Any] = {'memory': memory, 'resident_mb': resident_mb,
                               'summary': found.group(0),
                               **{key: float(value) for key, value in found.groupdict().items()}}
    if witness is not None:
        figures.update(witness.figures(begin, end))
    if trace is not None:
        figures.update(trace_figures(trace, tid, 1.0 / args.rate, args.witness_priority,
                                     running))
    return figures


def drain(bridge: DatagramExchange, done: threading.Event) -> None:
    """Take what the loop sends, as a bridge would, until ``done`` is set."""
    while not done.is_set():
        if bridge.wait(0.1):
            bridge.receive()


def resident(pid: int) -> float:
    """Resident memory of a process [MB] (VmRSS), NaN if it is gone."""
    try:
        status = Path(f'/proc/{pid}/status').read_text()
    except OSError:
        return float('nan')
    kilobytes = next((line.split()[1] for line in status.splitlines()
                      if line.startswith('VmRSS:')), 'nan')
    return float(kilobytes) / 1024.0


#: Figures summarised per variant: key, label, format; each as median (worst).
FIGURES = (('p99', 'lateness p99 [ms]', '.1f'), ('max', 'lateness max [ms]', '.1f'),
           ('gap', 'longest gap between bus commands [ms]', '.1f'),
           ('compute', 'cycle compute max [ms]', '.2f'),
           ('late', 'cycles late by over half a period', '.0f'),
           ('missed', 'missed periods', '.0f'),
           *TRACE_FIGURES,
           *WITNESS_FIGURES,
           ('resident_mb', "the loop's resident memory [MB]", '.0f'))


def report(runs: list[dict[str, Any]], args: argparse.Namespace) -> list[str]:
    """Each run's summary, then per variant the median (and the worst run) of each figure."""
    lines = [f'bench/robot_loop_alone.py {" ".join(sys.argv[1:])}']
    lines += [f'{r["memory"]:8s} {r["summary"]}; witness max {r.get("witness_max_ms", 0):.1f} '
              f'ms; gaps {r.get("loop_gaps", "-")}, the platform\'s '
              f'{r.get("loop_gaps_platform", "-")}' for r in runs]
    lines.append(f'{"figure":48s}' + ''.join(f' | {m:>16s}' for m in args.memory))
    for key, label, form in FIGURES:
        cells = []
        for memory in args.memory:
            values = [r[key] for r in runs if r['memory'] == memory and key in r]
            cells.append(f'{np.median(values):{form}} ({max(values):{form}})' if values
                         else '-')
        if any(cell != '-' for cell in cells):
            lines.append(f'{label:48s}' + ''.join(f' | {cell:>16s}' for cell in cells))
    return lines


def main() -> None:
    """Parse the arguments, run the variants in turn, print and write the figures."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rate', type=float, default=200.0, help='loop rate [Hz]')
    parser.add_argument('--seconds', type=float, default=15.0, help='how long each run is [s]')
    parser.add_argument('--repeats', type=int, default=1, help='runs of each variant')
    parser.add_argument('--memory', nargs='+', choices=('locked', 'unlocked'),
                        default=['locked'], help="the loop's memory: locked (mlockall, its "
                        'default) or not; each in turn')
    parser.add_argument('--devices-priority', type=int, default=19)
    parser.add_argument('--loop-priority', type=int, default=20)
    parser.add_argument('--witness-priority', type=int, default=0, metavar='N',
                        help="run the witness (cyclictest) at SCHED_FIFO N on the loop's CPUs "
                             '(0: none)')
    parser.add_argument('--trace', action='store_true',
                        help="trace the loop's CPU (tracefs, root; one --loop-cpus and the "
                             "witness needed): which gaps the CPU's absence fills")
    parser.add_argument('--busy', type=int, default=2, help='spinning processes, one a core')
    parser.add_argument('--loop-cpus', default='', help='CPUs of the loop (taskset -c)')
    parser.add_argument('--devices-cpus', default='', help='CPUs of the devices (taskset -c)')
    parser.add_argument('--softirq-priority', type=int, default=0, metavar='N',
                        help="SCHED_FIFO priority of the --loop-cpus' ksoftirqd for the run "
                             '(0: left as they are)')
    parser.add_argument('--bitrate', type=int, default=5_000_000,
                        help='bit rate [bit/s] the master judges its bus load at')
    parser.add_argument('--results', default='', metavar='NAME',
                        help='write bench/results/NAME.{json,txt} (default: print only)')
    args = parser.parse_args()
    if args.trace and not (args.witness_priority and args.loop_cpus
                           and len(parse_cpus(args.loop_cpus)) == 1):
        parser.error('--trace needs the witness (--witness-priority) and one --loop-cpus')
    runs = []
    softirq = raise_softirq_threads(parse_cpus(args.loop_cpus), args.softirq_priority) \
        if args.softirq_priority and args.loop_cpus else {}
    try:
        for _ in range(args.repeats):
            for memory in args.memory:
                runs.append(run(args, memory))
                print(f'{memory}: {runs[-1]}', flush=True)
    finally:
        restore_threads(softirq)
    lines = report(runs, args)
    if args.results:
        write_results(args.results, {'command': f'bench/robot_loop_alone.py '
                                                f'{" ".join(sys.argv[1:])}',
                                     'arguments': vars(args), 'runs': runs}, lines)
    else:
        print('\n'.join(lines))


if __name__ == '__main__':
    main()
