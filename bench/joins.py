"""Benchmark: what processes joining the domain do to a running plant, by DDS transport.

A plant node (left hip, 200 Hz) and the PD controller run; then ``--joiners`` gait publishers
join the domain one after another, each staying a few seconds, each a third-party participant
on rmw_fastrtps_cpp's own LOCALHOST settings (shared memory and UDP), as a ``ros2 topic echo``
would be. The plant and the controller run either as exo_has ships them (``udp``: UDP only,
:mod:`exo_has_runtime.dds`) or on rmw_fastrtps_cpp's LOCALHOST settings (``rmw``: shared memory
too), taking turns. Each run reports the plant's missed periods and its worst tick lateness
(from its own :class:`~exo_has_common.timing.PeriodMonitor`); a shared-memory port check shows
as a lateness of about 333 ms.

Run (in ``./run shell``): ``python bench/joins.py [--repeats 5] [--joiners 6]``.
"""

from __future__ import annotations

import argparse
import re
import statistics
import tempfile
import time
from pathlib import Path

from common import on_this_machine, write_results

from exo_has_runtime.dds import RMW_LOCALHOST_ENVIRONMENT
from exo_has_runtime.processes import NodeProcess

#: Joiners per run, and how long each stays after its first trial starts [s].
JOINERS = 6
JOINER_STAY = 2.5
#: Time the plant and the controller run alone first [s].
SETTLE = 2.0


def plant_timing_while_joined(folder: Path, node_env: dict[str, str], joiners: int = JOINERS,
                              stay: float = JOINER_STAY) -> dict[str, float]:
    """Run a plant and a controller while third-party joiners come and go; the plant's timing.

    ``node_env``: the plant's and the controller's extra environment ({}: as exo_has ships).
    Returns the plant's ticks, missed periods and worst lateness [s], from its closing summary.
    """
    with NodeProcess('exo_has_sim.plant_node', (
            '--ros-args', '-p', 'joint:=left_hip', '-p', 'rate:=200.0'), env=node_env,
            log_path=folder / 'plant.log') as plant, \
            NodeProcess('exo_has_control.pd_controller', (
                '--ros-args', '-p', "joints:=['left_hip']"), env=node_env,
                log_path=folder / 'controller.log') as controller:
        plant.wait_for_output(r'left_hip plant ready', 60.0)
        controller.wait_for_output(r'controller ready', 60.0)
        time.sleep(SETTLE)
        for index in range(joiners):
            with NodeProcess('exo_has_control.gait_publisher', (
                    '--ros-args', '-r', f'__node:=joiner_{index}', '-p', "motions:=['stand']",
                    '-p', f'durations:=[{stay}]'), env=RMW_LOCALHOST_ENVIRONMENT,
                    log_path=folder / f'joiner_{index}.log') as joiner:
                joiner.wait_for_output(r'trial 1/1', 30.0)
                time.sleep(stay)
        plant.stop()
        summary = plant.output
    found = re.search(r'plant: (\d+) periods, (\d+) missed.* max ([\d.]+) ms', summary)
    if not found:
        msg = f'the plant printed no timing summary:\n{summary}'
        raise RuntimeError(msg)
    return {'ticks': float(found.group(1)), 'missed': float(found.group(2)),
            'max_lateness_s': float(found.group(3)) * 1e-3}


#: The nodes' environments compared: as shipped, and rmw_fastrtps_cpp's LOCALHOST as it stands.
TRANSPORTS = {'udp': {}, 'rmw': RMW_LOCALHOST_ENVIRONMENT}
#: A tick this late was held up by something other than scheduling [s].
STALL_S = 0.1


def main() -> None:
    """Run the plant under both transports, taking turns, and write bench/results/joins.*."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=5)
    parser.add_argument('--joiners', type=int, default=JOINERS)
    args = parser.parse_args()
    on_this_machine()
    runs: list[dict[str, object]] = []
    for repeat in range(args.repeats):
        for transport, env in TRANSPORTS.items():
            with tempfile.TemporaryDirectory(prefix='joins-') as folder:
                timing = plant_timing_while_joined(Path(folder), env, args.joiners)
            runs.append({'transport': transport, 'repeat': repeat, **timing})
            print(f'{transport} run {repeat + 1}: {timing}', flush=True)
    lines = [f'bench/joins.py --repeats {args.repeats} --joiners {args.joiners} '
             f'(each joiner stays {JOINER_STAY:g} s after its trial starts)']
    for transport in TRANSPORTS:
        mine = [r for r in runs if r['transport'] == transport]
        lateness = [float(r['max_lateness_s']) * 1e3 for r in mine]
        missed = [float(r['missed']) for r in mine]
        stalled = sum(value >= STALL_S * 1e3 for value in lateness)
        lines.append(
            f'{transport}: worst tick lateness median {statistics.median(lateness):.1f} ms '
            f'(runs: {", ".join(f"{v:.1f}" for v in lateness)}); runs with a stall over '
            f'{STALL_S * 1e3:.0f} ms: {stalled} of {len(mine)}; missed periods median '
            f'{statistics.median(missed):g} (runs: {", ".join(f"{v:g}" for v in missed)})')
    write_results('joins', {'runs': runs, 'joiners': args.joiners, 'stay_s': JOINER_STAY},
                  lines)


if __name__ == '__main__':
    main()
