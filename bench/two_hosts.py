"""Benchmark: two hosts (robot PC and operator laptop) on a link: discovery and partitions.

Root only: the hosts are network namespaces joined by a veth pair
(:mod:`exo_has_bringup.hosts`).

1. Discovery settings. A publisher on the robot host (``exo_has_runtime.topic_tool``,
   reliable, 100 Hz) and, started after it, a subscriber on the operator host: the time from
   the subscriber's start to its first message, which includes the start of its Python and
   rclpy (the ``loopback`` row, both on one host, gives that floor). Compared: the ROS 2 Jazzy
   settings a user of two machines may choose, each on a link that carries multicast and on
   one that drops it (iptables on the link, as many Wi-Fi networks and managed switches do).
2. Partitions. Two-host walking sessions (:class:`exo_has_bringup.runner.Session` with
   ``hosts=2``): the link goes down at 4 s for 2 s, comes back, and the operator resets 1 s
   later. From the robot's own bag: the time from the cut to the STALE_REFERENCE hold event,
   and to every joint standing (its cylinder slower than 2 mm/s for 0.1 s on); from the
   operator's bag, the time from the link's return to its first state.

Run (in ``./run shell``, as root): ``python bench/two_hosts.py [--repeats 3]``; results in
``bench/results/two_hosts.{json,txt}``.
"""

from __future__ import annotations

import argparse
import os
import random
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

os.environ.setdefault('ROS_DOMAIN_ID', str(random.SystemRandom().randint(100, 200)))

from common import describe_machine, write_results

from exo_has_bringup.analysis import read_session
from exo_has_bringup.hosts import ADDRESSES, LINK_INTERFACE, OPERATOR, ROBOT, VirtualHosts
from exo_has_bringup.plan import SessionConfig
from exo_has_bringup.runner import Session
from exo_has_common.joints import JOINT_NAMES
from exo_has_msgs.msg import SafetyEvent
from exo_has_runtime.processes import NodeProcess, Processes

#: Discovery settings compared: name -> environment of the robot's and the operator's nodes.
SETTINGS: dict[str, tuple[dict[str, str], dict[str, str]]] = {
    'SUBNET (multicast)': ({'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'},
                           {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET'}),
    'SUBNET + ROS_STATIC_PEERS': (
        {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET', 'ROS_STATIC_PEERS': ADDRESSES[OPERATOR]},
        {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'SUBNET', 'ROS_STATIC_PEERS': ADDRESSES[ROBOT]}),
    'LOCALHOST + ROS_STATIC_PEERS': (
        {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_STATIC_PEERS': ADDRESSES[OPERATOR]},
        {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST', 'ROS_STATIC_PEERS': ADDRESSES[ROBOT]}),
}
TOPIC = '/bench_discovery=std_msgs/msg/String'
#: Longest wait for a first message [s]; a setting that finds nothing is reported as such.
DISCOVERY_TIMEOUT = 15.0


def first_message(hosts: VirtualHosts | None, robot_env: dict[str, str],
                  operator_env: dict[str, str]) -> float | None:
    """Seconds from a subscriber's start to its first message, or None within the timeout."""
    netns = {name: hosts.hosts[name].netns if hosts else None for name in (ROBOT, OPERATOR)}
    with NodeProcess('exo_has_runtime.topic_tool', (
            'publish', f'{TOPIC}={{"data": "x"}}', '--no-wait', '--period', '0.01',
            '--duration', '60', '--name', 'talker'), env=robot_env, netns=netns[ROBOT]) as talker:
        talker.wait_for_output('READY', timeout_s=30.0)
        prefix = ['nsenter', f'--net={netns[OPERATOR]}'] if netns[OPERATOR] else []
        start = time.monotonic()
        with Processes() as processes:
            listener = processes.start(
                [*prefix, sys.executable, '-u', '-m', 'exo_has_runtime.topic_tool', 'record',
                 TOPIC.rsplit('=', 1)[0] + '=std_msgs/msg/String', '--count', '1',
                 '--duration', f'{DISCOVERY_TIMEOUT:g}', '--name', 'listener'],
                stdout=subprocess.PIPE, text=True, env={**os.environ, **operator_env},
                cwd=tempfile.gettempdir())
            assert listener.stdout is not None
            found = None
            for line in listener.stdout:
                if line.startswith('{'):
                    found = time.monotonic() - start
                    break
            processes.end(listener, first=signal.SIGKILL)
        return found


def discovery(repeats: int) -> dict[str, dict[str, list[float | None]]]:
    """First-message times of each setting, with and without multicast on the link."""
    results: dict[str, dict[str, list[float | None]]] = {}
    local = {'ROS_AUTOMATIC_DISCOVERY_RANGE': 'LOCALHOST'}
    results['loopback (one host)'] = {'multicast carried': [
        first_message(None, local, local) for _ in range(repeats)]}
    with VirtualHosts() as hosts:
        for multicast in (True, False):
            for name in hosts.hosts:
                hosts.inside(name, 'iptables', '-F', 'INPUT')
                if not multicast:
                    hosts.inside(name, 'iptables', '-A', 'INPUT', '-i', LINK_INTERFACE, '-d',
                                 '224.0.0.0/4', '-j', 'DROP')
            label = 'multicast carried' if multicast else 'multicast dropped'
            for _ in range(repeats):
                for setting, (robot_env, operator_env) in SETTINGS.items():
                    found = first_message(hosts, robot_env, operator_env)
                    results.setdefault(setting, {}).setdefault(label, []).append(found)
                    print(f'{setting}, {label}: {found}', flush=True)
    return results


def partition(folder: Path, walk: float = 12.0, cut_at: float = 4.0,
              cut_s: float = 2.0) -> dict[str, float]:
    """One two-host session with a partition; the safety reaction's times [s]."""
    session = Session(SessionConfig(('walk',), (walk,), 200.0, hosts=2), folder)
    session.start(show=lambda line: None)
    marks = {}
    try:
        assert session.hosts is not None and session.started_at is not None
        for at, name, act in ((cut_at, 'cut', session.hosts.cut),
                              (cut_at + cut_s, 'restore', session.hosts.restore),
                              (cut_at + cut_s + 1.0, 'reset', session.reset)):
            time.sleep(max(0.0, session.started_at + at - time.monotonic()))
            marks[name] = time.time()
            act()
        time.sleep(max(0.0, session.started_at + walk + 1.0 - time.monotonic()))
    finally:
        session.stop()
    assert session.bag is not None and session.robot_bag is not None
    robot, operator = read_session(session.robot_bag), read_session(session.bag)
    hold = next(e for e in robot.events if e.kind == SafetyEvent.KIND_STALE_REFERENCE)
    fatal = sum(1 for e in robot.events if e.severity == SafetyEvent.SEVERITY_FATAL)
    standing = []
    for joint in JOINT_NAMES:
        t, v = robot.states[joint]['t'], np.abs(robot.states[joint]['velocity'])
        after = (t >= marks['cut']) & (t < marks['reset'])
        slow = v[after] < 2e-3
        # The first instant from which the cylinder stays slow for 0.1 s (20 states).
        runs = np.convolve(slow, np.ones(20, dtype=int), mode='valid') == 20
        standing.append(float(t[after][np.argmax(runs)]) if runs.any() else float('nan'))
    back = min(float(s['t'][s['t'] > marks['restore']][0]) for s in operator.states.values())
    return {'cut_to_hold_s': hold.t - marks['cut'],
            'cut_to_standing_s': max(standing) - marks['cut'],
            'restore_to_operator_state_s': back - marks['restore'], 'fatal_events': fatal}


def main() -> None:
    """Run both parts and write bench/results/two_hosts.{json,txt}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=3)
    args = parser.parse_args()
    found = discovery(args.repeats)
    partitions = []
    with tempfile.TemporaryDirectory() as scratch:
        for repeat in range(args.repeats):
            partitions.append(partition(Path(scratch) / f'run_{repeat}'))
            print(partitions[-1], flush=True)
    lines = [f'bench/two_hosts.py --repeats {args.repeats}: {describe_machine()}',
             'Discovery: subscriber start to first message [s], median (runs; none: nothing '
             f'within {DISCOVERY_TIMEOUT:g} s)']
    for setting, by_link in found.items():
        for label, times in by_link.items():
            got = [t for t in times if t is not None]
            median = f'{statistics.median(got):.2f}' if len(got) == len(times) else 'none'
            lines.append(f'  {setting}, {label}: {median} '
                         f'({", ".join("none" if t is None else f"{t:.2f}" for t in times)})')
    lines.append('Partition of 2 s in walking, medians of '
                 f'{args.repeats} (each run in brackets):')
    for key in ('cut_to_hold_s', 'cut_to_standing_s', 'restore_to_operator_state_s',
                'fatal_events'):
        values = [p[key] for p in partitions]
        lines.append(f'  {key}: {statistics.median(values):.3f} '
                     f'({", ".join(f"{v:.3f}" for v in values)})')
    write_results('two_hosts', {'discovery_s': found, 'partitions': partitions}, lines)


if __name__ == '__main__':
    main()
