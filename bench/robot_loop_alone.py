"""Benchmark: the robot loop's own timing, without a session: devices, loop, a constant reference.

Runs the simulated CAN devices and the robot loop (``robot_main --activate``) on a udp_multicast
bus of their own for ``--seconds``, a process sending a constant reference to the loop's socket
at 50 Hz (``exo_has_bringup/test/robot_reference_sender.py``), and ``--busy`` processes that
spin, the i-th pinned to core i. The loop and the devices may be kept to CPUs of their own
(``--loop-cpus``, ``--devices-cpus``) and given SCHED_FIFO priorities. Prints the loop's closing
summary (periods, missed, lateness p99 / p99.9 / max, longest gap, cycle compute max). What else
runs on the machine is up to the caller: bench/README.md, "The robot side against the old
chain", ran it beside an ``exo-has demo`` on another domain (``taskset -c 0 exo-has demo``),
to see what a ROS session's traffic does to the loop.

Run (in ``./run shell``, as root for SCHED_FIFO): ``python bench/robot_loop_alone.py --rate 200
--seconds 15 --devices-priority 19 --loop-priority 20 --busy 2 --loop-cpus 1 --devices-cpus 1``.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from exo_has_bringup.robot_exchange import bridge_end
from exo_has_driver.hardware.bus import random_multicast_group

SENDER = Path(__file__).resolve().parents[1] / 'exo_has_bringup' / 'test' / \
    'robot_reference_sender.py'
REFERENCE = ('left_hip=0.2', 'left_knee=0.3', 'right_hip=0.2', 'right_knee=0.3')  # rad


def pinned(cpus: str, command: list[str]) -> list[str]:
    """Return ``command`` kept to ``cpus`` (as taskset takes them), or as it is."""
    return ['taskset', '-c', cpus, *command] if cpus else command


def run(args: argparse.Namespace) -> str:
    """Run the devices, the loop, the sender and the busy processes; return the loop's summary."""
    cores = os.cpu_count() or 1
    busy = [subprocess.Popen(['taskset', '-c', str(i % cores), sys.executable, '-c',
                              'while True: pass']) for i in range(args.busy)]
    group = random_multicast_group()
    started: list[subprocess.Popen[str]] = []
    with tempfile.TemporaryDirectory(prefix='exo-alone-') as directory:
        bridge = bridge_end(Path(directory))
        try:
            devices = subprocess.Popen(pinned(args.devices_cpus, [
                sys.executable, '-m', 'exo_has_driver.devices.main', '--interface',
                'udp_multicast', '--channel', group,
                '--realtime-priority', f'{args.devices_priority}']), stdout=subprocess.PIPE,
                text=True)
            started.append(devices)
            assert devices.stdout is not None
            devices.stdout.readline()  # can devices ready
            loop = subprocess.Popen(pinned(args.loop_cpus, [
                sys.executable, '-m', 'exo_has_bringup.robot_main', '--interface',
                'udp_multicast', '--channel', group, '--rate', f'{args.rate}',
                '--bitrate', f'{args.bitrate}', '--socket-dir', directory,
                '--realtime-priority', f'{args.loop_priority}', '--activate']),
                stdout=subprocess.PIPE, text=True)
            started.append(loop)
            assert loop.stdout is not None
            loop.stdout.readline()  # robot loop ready
            sender = subprocess.Popen([sys.executable, str(SENDER), directory, '50', *REFERENCE],
                                      stdout=subprocess.PIPE, text=True)
            started.append(sender)
            deadline = time.monotonic() + args.seconds
            while time.monotonic() < deadline:
                bridge.receive()  # what the loop sends, taken as a bridge would
                time.sleep(0.005)
            sender.kill()
            loop.send_signal(signal.SIGTERM)
            output = loop.communicate(timeout=30.0)[0]
        finally:
            for process in [*started, *busy]:
                if process.poll() is None:
                    process.kill()
                process.wait()
            bridge.close()
    lines = [line for line in output.splitlines() if line.startswith('robot loop stopped')]
    return lines[-1] if lines else output


def main() -> None:
    """Parse the arguments, run once, print the loop's summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--rate', type=float, default=200.0, help='loop rate [Hz]')
    parser.add_argument('--seconds', type=float, default=15.0, help='how long it runs [s]')
    parser.add_argument('--devices-priority', type=int, default=19)
    parser.add_argument('--loop-priority', type=int, default=20)
    parser.add_argument('--busy', type=int, default=2, help='spinning processes, one a core')
    parser.add_argument('--loop-cpus', default='', help='CPUs of the loop (taskset -c)')
    parser.add_argument('--devices-cpus', default='', help='CPUs of the devices (taskset -c)')
    parser.add_argument('--bitrate', type=int, default=5_000_000,
                        help='bit rate [bit/s] the master judges its bus load at')
    args = parser.parse_args()
    print(f'bench/robot_loop_alone.py {" ".join(sys.argv[1:])}: {run(args)}', flush=True)


if __name__ == '__main__':
    main()
