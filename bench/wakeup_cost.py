"""Benchmark: what one thread wake-up costs on this machine, and an idle rclpy timer with it.

Every message between two nodes wakes at least two threads of the receiving process (a DDS
receive thread, then the executor's), and every timer tick one or two. Where a wake-up is
cheap, messaging costs little; this measures what it costs here, apart from any ROS code:

- ``pipe``: two processes bounce one byte over a pair of pipes, both pinned to one CPU, then to
  two CPUs (each wake-up a cross-CPU one, as between two nodes on different cores): wall time
  and CPU time (both sides) per round trip, two wake-ups each.
- ``sleep``: a Python loop sleeping one period at a time at 200 Hz and 1 kHz: CPU per wake-up.
- ``rclpy timer``: a node with one empty 200 Hz timer, on each executor: CPU per tick.

Run (in ``./run shell``): ``python bench/wakeup_cost.py`` (printout and
``bench/results/wakeup_cost.{json,txt}``).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

from common import describe_machine, write_results

from exo_has_runtime.processes import Processes

ROUND_TRIPS = 20_000
REPEATS = 3


def bounce(cpus: tuple[int, int]) -> dict[str, float]:
    """Bounce a byte between this process and a child; per round trip: wall and CPU [us]."""
    from_parent, to_child = os.pipe()  # (read end, write end)
    from_child, to_parent = os.pipe()
    pid = os.fork()
    if pid == 0:  # the child echoes until the parent closes its end
        os.sched_setaffinity(0, {cpus[1]})
        os.close(to_child)
        os.close(from_child)
        while os.read(from_parent, 1):
            os.write(to_parent, b'x')
        os._exit(0)
    os.close(from_parent)
    os.close(to_parent)
    os.sched_setaffinity(0, {cpus[0]})
    for _ in range(1000):  # warm up
        os.write(to_child, b'x')
        os.read(from_child, 1)
    before = os.times()
    start = time.perf_counter()
    for _ in range(ROUND_TRIPS):
        os.write(to_child, b'x')
        os.read(from_child, 1)
    wall = time.perf_counter() - start
    os.close(to_child)
    os.waitpid(pid, 0)
    after = os.times()
    os.close(from_child)
    os.sched_setaffinity(0, set(range(os.cpu_count() or 1)))
    # The child's CPU is counted once it is reaped (children_user, children_system).
    cpu = sum(after[:4]) - sum(before[:4])
    return {'wall_us': 1e6 * wall / ROUND_TRIPS, 'cpu_us': 1e6 * cpu / ROUND_TRIPS}


def sleep_loop(rate: float, duration: float = 5.0) -> float:
    """CPU per wake-up of a loop that sleeps one period at a time [us]."""
    period, wakeups = 1.0 / rate, 0
    cpu, end = time.process_time(), time.monotonic() + duration
    while time.monotonic() < end:
        time.sleep(period)
        wakeups += 1
    return 1e6 * (time.process_time() - cpu) / wakeups


def idle_timer(executor: str) -> float:
    """CPU per tick of an rclpy node with one empty 200 Hz timer [us] (in a child process)."""
    with Processes() as processes:
        out = processes.run([sys.executable, str(Path(__file__).resolve()), '_timer'],
                            env={**os.environ, 'EXO_HAS_EXECUTOR': executor},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            check=True, timeout=120)
    return float(json.loads(out.stdout.strip().splitlines()[-1])['cpu_us_per_tick'])


def timer_side() -> None:
    """Spin an idle 200 Hz timer node for 3 s of warm-up and 10 s measured; print the cost."""
    import threading

    import rclpy
    from rclpy.node import Node

    from exo_has_runtime.execution import spin

    rclpy.init()
    node = Node('wakeup_cost_timer')
    ticks = [0]
    node.create_timer(0.005, lambda: ticks.__setitem__(0, ticks[0] + 1))
    stop, result = threading.Event(), {}

    def measure() -> None:
        time.sleep(3.0)
        cpu, count = time.process_time(), ticks[0]
        time.sleep(10.0)
        result['cpu_us_per_tick'] = 1e6 * (time.process_time() - cpu) / (ticks[0] - count)
        stop.set()
    threading.Thread(target=measure, daemon=True).start()
    spin(node, stop=stop)
    node.destroy_node()
    rclpy.try_shutdown()
    print(json.dumps(result), flush=True)


def main() -> None:
    """Measure each case three times, taking turns, and write the medians."""
    if sys.argv[1:] == ['_timer']:
        timer_side()
        return
    if (os.cpu_count() or 1) < 2:
        sys.exit('bench/wakeup_cost.py: needs two CPUs')
    cases = {
        'pipe, one CPU': lambda: bounce((0, 0)),
        'pipe, two CPUs': lambda: bounce((0, 1)),
        'sleep 200 Hz': lambda: {'cpu_us': sleep_loop(200.0)},
        'sleep 1 kHz': lambda: {'cpu_us': sleep_loop(1000.0)},
        'rclpy timer 200 Hz, events': lambda: {'cpu_us': idle_timer('events')},
        'rclpy timer 200 Hz, single': lambda: {'cpu_us': idle_timer('single')},
    }
    runs: dict[str, list[dict[str, float]]] = {name: [] for name in cases}
    for _ in range(REPEATS):
        for name, case in cases.items():
            runs[name].append(case())
    medians = {name: {key: round(statistics.median(r[key] for r in results), 1)
                      for key in results[0]} for name, results in runs.items()}
    lines = [f'bench/wakeup_cost.py: {describe_machine()}; medians of {REPEATS}, in us']
    lines += [f'{name}: ' + ', '.join(f'{key} {value}' for key, value in median.items())
              for name, median in medians.items()]
    write_results('wakeup_cost', {'medians': medians, 'runs': runs}, lines)


if __name__ == '__main__':
    main()
