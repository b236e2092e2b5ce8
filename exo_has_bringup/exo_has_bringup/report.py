"""A session report: Markdown with PNG plots of a recorded exoskeleton session.

Reference against actual joint angles, cylinder positions, chamber pressures, the loads on
the rods, motor speeds
(command and actual), the tracking error, the safety events and tracking-error statistics per
joint and trial.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib as mpl

mpl.use('Agg')  # files only: no display on a robot PC or in CI
import matplotlib.pyplot as plt
import numpy as np

from exo_has_bringup.analysis import (
    SessionData,
    Tracking,
    joint_angles,
    joint_parameters,
    linkages,
    rates,
    tracking,
)
from exo_has_common.joints import JOINT_NAMES
from exo_has_sim.parameters import HasParameters

SEVERITIES = ('info', 'warn', 'error', 'fatal')
#: SafetyEvent's phases, by number.
PHASES = {0: 'start', 1: 'change', 2: 'clear'}


def segments_of(motions: Sequence[str], durations: Sequence[float]) -> list[tuple[str, float,
                                                                                   float]]:
    """Named windows ``(name, start, end)`` [s from the first reference] of the trials."""
    windows, start = [], 0.0
    for number, (motion, duration) in enumerate(zip(motions, durations, strict=True), 1):
        windows.append((f'{number} {motion}', start, start + float(duration)))
        start += float(duration)
    return windows


def _figure(title: str) -> tuple[plt.Figure, np.ndarray]:
    fig, axes = plt.subplots(4, 1, sharex=True, figsize=(10, 9), constrained_layout=True)
    fig.suptitle(title)
    return fig, axes


def _save(fig: plt.Figure, folder: Path, name: str) -> str:
    fig.savefig(folder / name, dpi=90)
    plt.close(fig)
    return name


def plot_session(data: SessionData, folder: Path,
                 params: Mapping[str, HasParameters] | None = None) -> dict[str, str]:
    """Write the plots; return their file names by subject (``params``: see tracking)."""
    links = linkages(params)
    t0 = data.start
    plots = {}
    fig, axes = _figure('Joint angles: reference (dashed) and actual')
    for index, (ax, joint) in enumerate(zip(axes, JOINT_NAMES, strict=True)):
        ax.plot(data.reference_t - t0, np.degrees(data.reference[:, index]), '--', lw=1,
                label='reference')
        if joint in data.states:
            t, angle = joint_angles(data, joint, links[joint])
            ax.plot(t - t0, np.degrees(angle), lw=1, label='actual')
        ax.set_ylabel(f'{joint} [deg]')
    axes[0].legend(loc='upper right')
    axes[-1].set_xlabel('time from the first reference [s]')
    plots['angles'] = _save(fig, folder, 'joint_angles.png')

    fig, axes = _figure('Tracking error, actual minus reference')
    for index, (ax, joint) in enumerate(zip(axes, JOINT_NAMES, strict=True)):
        if joint in data.states:
            t, angle = joint_angles(data, joint, links[joint])
            ref = np.interp(t, data.reference_t, data.reference[:, index])
            ax.plot(t - t0, np.degrees(angle - ref), lw=1)
        ax.axhspan(-1.5, 2.5, color='tab:green', alpha=0.12,
                   label="paper's squat band -1.5/+2.5 deg")
        ax.set_ylabel(f'{joint} [deg]')
    axes[0].legend(loc='upper right')
    axes[-1].set_xlabel('time from the first reference [s]')
    plots['error'] = _save(fig, folder, 'tracking_error.png')

    for key, title, field, scale, unit in (
            ('position', 'Cylinder positions', 'position', 1e3, 'mm'),
            ('pressure', 'Rodless chamber pressures', 'pressure_a', 1e-6, 'MPa'),
            ('load', 'External loads on the rods (positive pushing the cylinder in)',
             'load_force', 1.0, 'N')):
        fig, axes = _figure(title)
        for ax, joint in zip(axes, JOINT_NAMES, strict=True):
            if joint in data.states:
                series = data.states[joint]
                ax.plot(series['t'] - t0, series[field] * scale, lw=1)
            ax.set_ylabel(f'{joint} [{unit}]')
        axes[-1].set_xlabel('time from the first reference [s]')
        plots[key] = _save(fig, folder, f'{key}.png')

    fig, axes = _figure('Motor speeds: command (dashed) and actual')
    for ax, joint in zip(axes, JOINT_NAMES, strict=True):
        if joint in data.commands:
            series = data.commands[joint]
            ax.plot(series['t'] - t0, series['motor_speed'], '--', lw=1, label='command')
        if joint in data.states:
            series = data.states[joint]
            ax.plot(series['t'] - t0, series['motor_speed'], lw=1, label='actual')
        ax.set_ylabel(f'{joint} [rad/s]')
    axes[0].legend(loc='upper right')
    axes[-1].set_xlabel('time from the first reference [s]')
    plots['speed'] = _save(fig, folder, 'motor_speed.png')
    return plots


def tracking_table(rows: Sequence[Tracking]) -> list[str]:
    """Markdown table of tracking statistics."""
    lines = ['| joint | trial | samples | rms [deg] | min [deg] | max [deg] | cylinder rms [mm] '
             '| motor at its limit [%] |', '|---|---|---|---|---|---|---|---|']
    lines += [f'| {r.joint} | {r.segment} | {r.samples} | {r.rms:.2f} | {r.minimum:+.2f} | '
              f'{r.maximum:+.2f} | {r.cylinder_rms * 1e3:.2f} | {100 * r.saturated:.1f} |'
              for r in rows]
    return lines


def write_report(data: SessionData, folder: Path, motions: Sequence[str],
                 durations: Sequence[float], bag: Path | None = None,
                 notes: Sequence[str] = (),
                 files: Mapping[str, str | Path] | None = None) -> Path:
    """Write ``report.md`` and its plots into folder; return the report's path.

    ``files``: the plants' parameters files by joint type, where they are not the shipped
    ones (the joint angles and the motor limits are theirs).
    """
    folder.mkdir(parents=True, exist_ok=True)
    params = joint_parameters(files)
    plots = plot_session(data, folder, params)
    rows = tracking(data, segments_of(motions, durations), params)
    lines = ['# exo_has session report', '']
    if bag is not None:
        lines += [f'Bag: `{bag}` (rosbag2, MCAP); replay it with `exo-has replay {bag}`.', '']
    trials = ', '.join(f'{m} {d:g} s' for m, d in zip(motions, durations, strict=True))
    lines += [f'Trials: {trials} (each from standing to standing).', '']
    lines += list(notes)
    lines += ['## Tracking', '', *tracking_table(rows), '',
              "The paper's hip tracked within -1.5/+2.5 deg while squatting on the exoskeleton "
              '(Sun et al. 2021, section 5.3).', '',
              f'![joint angles]({plots["angles"]})', '', f'![tracking error]({plots["error"]})',
              '', '## Hydraulics', '', f'![cylinder positions]({plots["position"]})', '',
              f'![pressures]({plots["pressure"]})', '', f'![loads]({plots["load"]})', '',
              f'![motor speeds]({plots["speed"]})', '',
              '## Safety events', '']
    if data.events:
        lines += ['| t [s] | joint | kind | severity | phase | value | limit | latched | text |',
                  '|---|---|---|---|---|---|---|---|---|']
        lines += [f'| {e.t - data.start:.3f} | {e.joint or "-"} | {e.kind} | '
                  f'{SEVERITIES[min(e.severity, 3)]} | {PHASES.get(e.phase, e.phase)} | '
                  f'{e.value:.4g} | {e.limit:.4g} | {"yes" if e.latched else "no"} | {e.text} |'
                  for e in data.events]
    else:
        lines.append('None.')
    lines += ['', '## Messages', '', '| topic | messages | rate [Hz] |', '|---|---|---|']
    topic_rates = rates(data)
    lines += [f'| `{topic}` | {count} | '
              f'{topic_rates[topic]:.1f} |' if topic in topic_rates else
              f'| `{topic}` | {count} | - |' for topic, count in sorted(data.counts.items())]
    path = folder / 'report.md'
    path.write_text('\n'.join(lines) + '\n', encoding='utf-8')
    return path
