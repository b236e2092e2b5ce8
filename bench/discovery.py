"""Benchmark: how long a process joining the domain takes to find a publisher, by profile.

A node publishes on one topic; then ``--joins`` processes join the domain one after another,
each a fresh interpreter that creates a node with a subscription and waits until it sees the
publisher (``count_publishers``): the time from its node's creation to that. Both run on the
LOCALHOST profile of :mod:`exo_has_runtime.dds`, as shipped (participants announce themselves
every 0.5 s) or with Fast DDS's default of every 3 s; the two take turns, each with a
publisher of its own on a domain of its own. A join whose first exchange with the publisher
fails waits for the next periodic announcement.

Run (in ``./run shell``): ``python bench/discovery.py [--joins 24]``.
"""

from __future__ import annotations

import argparse
import os
import random
import statistics
import subprocess
import sys

from common import on_this_machine, write_results

from exo_has_runtime.dds import (
    ANNOUNCEMENT_PERIOD,
    FAST_DDS_ANNOUNCEMENT_PERIOD,
    localhost_profile,
    write_profile,
)
from exo_has_runtime.processes import Processes

#: The announcement periods compared [s], by name (None: Fast DDS's 3 s).
PERIODS: dict[str, float | None] = {"Fast DDS's default": None, 'shipped': ANNOUNCEMENT_PERIOD}
#: A join slower than this [s] missed its first exchange.
SLOW = 1.0
TOPIC = 'discovery_bench'

PUBLISHER = f"""
import rclpy
from rclpy.executors import ExternalShutdownException
from std_msgs.msg import Float64
rclpy.init()
node = rclpy.create_node('discovery_publisher')
node.create_publisher(Float64, {TOPIC!r}, 10)
print('ready', flush=True)
try:
    rclpy.spin(node)
except (KeyboardInterrupt, ExternalShutdownException):
    pass
"""

JOINER = f"""
import time
import rclpy
from std_msgs.msg import Float64
rclpy.init()
node = rclpy.create_node('discovery_joiner')
start = time.monotonic()
node.create_subscription(Float64, {TOPIC!r}, lambda message: None, 10)
while node.count_publishers({TOPIC!r}) == 0 and time.monotonic() - start < 30.0:
    time.sleep(0.002)
print(time.monotonic() - start)
"""


def environment(period: float | None, domain: int) -> dict[str, str]:
    """Return the environment of a process on the LOCALHOST profile with this period [s]."""
    profile = write_profile(localhost_profile(announcement_period=period))
    return {**os.environ, 'ROS_DOMAIN_ID': str(domain),
            'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SYSTEM_DEFAULT',
            'FASTRTPS_DEFAULT_PROFILES_FILE': str(profile)}


def join_times(joins: int) -> dict[str, list[float]]:
    """Time ``joins`` joins per profile, taking turns; seconds to the publisher, by profile."""
    domains = random.SystemRandom().sample(range(100, 200), len(PERIODS))
    envs = {name: environment(period, domain)
            for (name, period), domain in zip(PERIODS.items(), domains, strict=True)}
    times: dict[str, list[float]] = {name: [] for name in PERIODS}
    with Processes() as processes:
        for env in envs.values():
            publisher = processes.start([sys.executable, '-c', PUBLISHER], env=env,
                                        stdout=subprocess.PIPE, text=True)
            assert publisher.stdout is not None
            if publisher.stdout.readline().strip() != 'ready':
                msg = 'the publisher did not start'
                raise RuntimeError(msg)
        for _ in range(joins):
            for name, env in envs.items():
                done = processes.run([sys.executable, '-c', JOINER], env=env, timeout=60.0,
                                     check=True, stdout=subprocess.PIPE, text=True)
                times[name].append(float(done.stdout.strip()))
    return times


def main() -> None:
    """Parse the arguments, time the joins, write the results."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--joins', type=int, default=24, help='joins per profile')
    args = parser.parse_args()
    on_this_machine()
    times = join_times(args.joins)
    lines = [f'{args.joins} joins per profile, taking turns (bench/discovery.py)', '',
             '| announcements | median [s] | 90th percentile [s] | longest [s] | '
             f'joins over {SLOW:g} s |', '|---|---|---|---|---|']
    for name, found in times.items():
        deciles = statistics.quantiles(found, n=10)
        every = PERIODS[name] or FAST_DDS_ANNOUNCEMENT_PERIOD
        lines.append(f'| every {every:g} s ({name}) | {statistics.median(found):.3f} | '
                     f'{deciles[-1]:.3f} | {max(found):.3f} | '
                     f'{sum(t > SLOW for t in found)} of {len(found)} |')
    write_results('discovery', {'joins': args.joins, 'periods_s': PERIODS, 'times_s': times},
                  lines)


if __name__ == '__main__':
    main()
