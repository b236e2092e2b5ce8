"""Benchmark: demo sessions back to back, and the safety events, rates and tracking of each.

Runs ``exo-has demo`` (:func:`exo_has_bringup.demo.run`, walking 10 s at 0.85 strides/s then
squatting 8 s at 0.5 Hz at 200 Hz on the four plant nodes, with its report) ``--sessions``
times for each design, the designs taking turns so that they share the machine's moods, then
reads each bag: every safety event of severity ERROR or FATAL (none is expected: the demo has no
fault), the rate of each joint's HAS state and command topics, the tracking peaks (walking,
and the hips' squat band) and the share of walking commands at the motor's speed limit.

Designs (``--designs``): ``searched``, the shipped files (issue 26's design search) under loads
that follow the gait for 25 kg; ``old_gait``, the design before the search (the truth plants'
bench, ``test/bench_rig``) under the same loads; ``old_constant``, that design as the demo ran
it before issue 26 (constant loads: the peak extensor moment of 50 kg on the hips and 25 kg on
the knees at the standing lever).

The printout and ``bench/results/demo_series.{json,txt}`` hold one line per session and a
table per design (``demo_series_can.*`` with ``--hardware can``: the hardware driver on
simulated CAN devices in place of the plant nodes, the searched design only).

Run (in ``./run shell``): ``python bench/demo_series.py [--sessions 10] [--designs ...]
[--hardware can]``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import statistics
import tempfile
from pathlib import Path
from typing import Any

from common import describe_machine, on_this_machine, write_results

from exo_has_bringup.analysis import joint_parameters, rates, read_session, tracking
from exo_has_bringup.demo import run
from exo_has_bringup.plan import SessionConfig
from exo_has_bringup.report import segments_of
from exo_has_common.joints import JOINT_NAMES, joint_type_of

ERROR = 2  # SafetyEvent severity: ERROR and FATAL count


#: The design before issue 26's search: the truth plants' bench keeps its files.
OLD_FILES = Path(__file__).resolve().parent.parent / 'test' / 'bench_rig'
DESIGNS = ('searched', 'old_gait', 'old_constant')
#: Constant loads of the demo before issue 26 [kg], by joint type.
OLD_CONSTANT_MASS = {'hip': 50.0, 'knee': 25.0}


def design_config(design: str, hardware: str) -> tuple[SessionConfig, dict[str, Path] | None]:
    """Return a design's session, and its parameters files by joint type (None: shipped)."""
    config = dataclasses.replace(SessionConfig(), hardware=hardware)
    if design == 'searched':
        return config, None
    files = {kind: OLD_FILES / f'{kind}.yaml' for kind in ('hip', 'knee')}
    config = dataclasses.replace(config, params={k: str(f) for k, f in files.items()})
    if design == 'old_gait':
        return config, files
    arguments = {joint: ('-p', 'load_model:=constant',
                         '-p', f'load_mass:={OLD_CONSTANT_MASS[joint_type_of(joint)]}')
                 for joint in JOINT_NAMES}
    return dataclasses.replace(config, plant_arguments=arguments), files


def session_figures(config: SessionConfig, folder: Path,
                    files: dict[str, Path] | None) -> dict[str, object]:
    """Run one demo session into folder; its events, rates and tracking figures."""
    run(config, folder)
    data = read_session(folder / 'bag')
    rows = tracking(data, segments_of(config.motions, config.durations),
                    joint_parameters(files))
    rate = rates(data)
    return {
        'events': [e.text for e in data.events if e.severity >= ERROR],
        'state_rate_hz': {joint: round(rate.get(f'/{joint}/has_state', 0.0), 2)
                          for joint in JOINT_NAMES},
        'command_rate_hz': {joint: round(rate.get(f'/{joint}/has_command', 0.0), 2)
                            for joint in JOINT_NAMES},
        'tracking_peak_deg': {f'{r.joint} {r.segment}': round(r.peak, 2) for r in rows},
        'squat_band_deg': {r.joint: [round(r.minimum, 2), round(r.maximum, 2)] for r in rows
                           if r.segment.endswith('squat')},
        'walk_saturated': {r.joint: round(r.saturated, 4) for r in rows
                           if r.segment.endswith('walk')},
    }


def summary(design: str, results: list[dict[str, Any]]) -> list[str]:
    """Return a design's table row: medians and worst cases over its sessions."""
    def over(kind: str, segment: str) -> list[float]:
        return [max(v for k, v in r['tracking_peak_deg'].items()
                    if kind in k and k.endswith(segment)) for r in results]

    hip_walk, knee_walk = over('hip', 'walk'), over('knee', 'walk')
    hip_squat = [r['squat_band_deg'][j] for r in results for j in r['squat_band_deg']
                 if j.endswith('hip')]
    saturated = [max(r['walk_saturated'].values()) for r in results]
    events = sum(len(r['events']) for r in results)
    return [f'| {design} | {len(results)} | {statistics.median(hip_walk):.2f} / '
            f'{max(hip_walk):.2f} | {statistics.median(knee_walk):.2f} / {max(knee_walk):.2f} | '
            f'{min(b[0] for b in hip_squat):+.2f} / {max(b[1] for b in hip_squat):+.2f} | '
            f'{100 * statistics.median(saturated):.1f} / {100 * max(saturated):.1f} | '
            f'{events} |']


def main() -> None:
    """Run the sessions and write bench/results/demo_series.{json,txt}."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--sessions', type=int, default=10)
    parser.add_argument('--designs', nargs='+', choices=DESIGNS, default=list(DESIGNS))
    parser.add_argument('--hardware', choices=('plants', 'can'), default='plants')
    args = parser.parse_args()
    designs = ['searched'] if args.hardware == 'can' else args.designs
    on_this_machine()
    results: dict[str, list[dict[str, Any]]] = {design: [] for design in designs}
    with tempfile.TemporaryDirectory() as scratch:
        for k in range(args.sessions):
            for design in designs:
                config, files = design_config(design, args.hardware)
                figures = session_figures(config, Path(scratch) / f'{design}_{k}', files)
                results[design].append(figures)
                print(design, json.dumps(figures), flush=True)
    lines = [f'bench/demo_series.py --sessions {args.sessions} --designs {" ".join(designs)} '
             f'--hardware {args.hardware}: {describe_machine()}', '',
             '| design | sessions | hip walk peak, median / max [deg] | knee walk peak [deg] '
             '| hip squat error, min / max [deg] | walk commands at the motor limit, '
             'median / max [%] | ERROR/FATAL events |', '|---|---|---|---|---|---|---|']
    for design in designs:
        lines += summary(design, results[design])
    lines.append('')
    for design in designs:
        for k, r in enumerate(results[design]):
            states, commands = r['state_rate_hz'], r['command_rate_hz']
            lines.append(f'{design} session {k + 1}: {len(r["events"])} ERROR/FATAL events '
                         f'{r["events"]}; state rates {min(states.values())}-'
                         f'{max(states.values())} Hz, command rates {min(commands.values())}-'
                         f'{max(commands.values())} Hz; tracking peaks {r["tracking_peak_deg"]}')
    name = 'demo_series' if args.hardware == 'plants' else f'demo_series_{args.hardware}'
    write_results(name, {'hardware': args.hardware, 'sessions': results}, lines)


if __name__ == '__main__':
    main()
