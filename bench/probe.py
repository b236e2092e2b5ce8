"""A node that does nothing but tick at a rate: the machine's own timing floor.

``bench/system.py`` runs it next to a session: its missed periods and lateness are what any
200 Hz node on this machine sees at that moment with no work of its own, the reference for the
plants' figures. Prints :meth:`exo_has_common.timing.PeriodMonitor.summary` at the end.

Run (in ``./run shell``): ``python bench/probe.py --rate 200 --duration 20``.
"""

from __future__ import annotations

import argparse
import threading

import rclpy
from rclpy.node import Node

from exo_has_common.timing import PeriodMonitor
from exo_has_runtime.execution import spin


def main() -> None:
    """Tick for ``--duration`` seconds, then print the timing summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rate', type=float, default=200.0, help='tick rate [Hz]')
    parser.add_argument('--duration', type=float, default=20.0, help='run time [s]')
    args = parser.parse_args()
    rclpy.init()
    node = Node('timing_probe')
    done = threading.Event()
    period_ns = round(1e9 / args.rate)
    monitor = PeriodMonitor(period_ns)
    clock = node.get_clock()
    end_ns = clock.now().nanoseconds + round(args.duration * 1e9)

    def tick() -> None:
        now = clock.now().nanoseconds
        monitor.tick(now)
        if now >= end_ns:
            done.set()

    node.create_timer(period_ns * 1e-9, tick)
    try:
        spin(node, stop=done)  # on the executor the nodes use (EXO_HAS_EXECUTOR)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    print(f'probe: {monitor.summary()}', flush=True)


if __name__ == '__main__':
    main()
