"""Benchmark: ``exo-has diagnose`` on 30 s, 2 min and 10 min of 200 Hz HAS data.

The data are made by the project's own HAS model (hip, 50 kg) in closed loop under the PD
controller (P = 35 (rad/s)/mm, D = 15 (rad/s)/(m/s), velocity feed-forward), following a sum of
eight sines 0.2-5 Hz (the paper's Fig. 13 excitation) against a load swinging between 2 and
12 MPa, with 60 N of Coulomb friction and sensor noise (position 10 um, pressure 30 kPa, motor
speed 1 rad/s, load 3 N), written as a CSV log. Each run is the whole command, CSV reading
included, in a fresh Python process (numba's compiled code cached on disk beforehand), timed
by wall clock, with the process's peak resident memory (``ru_maxrss``). ``--sensors position``
writes the command, the position and the reference only (the paper's logging): friction then
cannot be identified, and each window takes a load of its own.

Usage: ``.venv/bin/python bench/diagnose.py [--repeats N] [--durations S ...]
[--sensors full|position] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from exo_has_runtime.processes import Processes
from exo_has_sim import model
from exo_has_sim.diagnosis.data import check_columns, write_csv
from exo_has_sim.parameters import load_parameters
from exo_has_sim.simulate import simulate_closed_loop

PERIOD = 0.005
#: Columns kept with ``--sensors position``.
POSITION_ONLY = ('time', 'motor_speed_command', 'position', 'reference')
CHILD = """
import json, resource, sys, time
start = time.perf_counter()
from exo_has_sim.diagnosis.cli import main
code = main([sys.argv[1], '--joint', 'hip', '-q', '--json', sys.argv[2]])
elapsed = time.perf_counter() - start
print(json.dumps({'code': code, 'wall': elapsed,
                  'peak_rss_mb': resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def make_log(duration: float, path: Path, seed: int = 0, sensors: str = 'full') -> None:
    """Write a CSV log of ``duration`` seconds (see the module docstring)."""
    rng = np.random.default_rng(seed)
    hip = load_parameters('hip')
    truth = hip.replace(bulk_modulus=0.9e9, pump_leakage=1.7e-13, damping=1300.0) \
        .with_effects(coulomb_friction=60.0)
    t = np.arange(round(duration / PERIOD)) * PERIOD
    freqs = np.geomspace(0.2, 5.0, 8)
    phases = rng.uniform(0.0, 2.0 * math.pi, 8)
    ramp = np.clip(t, 0.0, 1.0) ** 2
    amplitude = np.minimum(8e-3, 15e-3 / (2.0 * math.pi * freqs))
    x_ref = hip.stroke / 2.0 + ramp * (np.sin(np.outer(t, 2 * math.pi * freqs) + phases)
                                       @ amplitude)
    load = hip.area_a * (2e6 + 10e6 * 0.5 * (1.0 - np.cos(2.0 * math.pi * 0.15 * t)))
    y0 = model.initial_state(truth, x_ref[0], load[0])
    gains = np.array([[35e3, 15.0, hip.flow_area / hip.pump_displacement]])
    run = simulate_closed_loop([truth], y0[None], x_ref[:, None],
                               np.gradient(x_ref, PERIOD)[:, None], load, gains, PERIOD,
                               rtol=1e-4)
    n = len(t)
    columns = {'time': t, 'motor_speed_command': run.commands[:, 0],
               'position': run.position[:-1, 0] + rng.normal(0.0, 1e-5, n),
               'reference': x_ref,
               'pressure_a': run.pressure[:-1, 0] + rng.normal(0.0, 3e4, n),
               'motor_speed': run.states[:-1, 0, model.N] + rng.normal(0.0, 1.0, n),
               'load_force': load + rng.normal(0.0, 3.0, n)}
    if sensors == 'position':
        columns = {name: columns[name] for name in POSITION_ONLY}
    write_csv(check_columns(columns, 'has', 'bench'), path)


def run_child(log: Path, result: Path) -> dict[str, float]:
    """Run the command on a log in a fresh process; return its wall time and peak RSS."""
    with Processes() as processes:
        out = processes.run([sys.executable, '-c', CHILD, str(log), str(result)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            check=True)
    measured: dict[str, float] = json.loads(out.stdout.strip().splitlines()[-1])
    if measured['code'] != 0:
        msg = f'exo-has diagnose failed: {out.stderr}'
        raise RuntimeError(msg)
    return measured


def main() -> None:
    """Run the benchmark and print (and optionally write) its numbers."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--durations', type=float, nargs='+', default=[30.0, 120.0, 600.0])
    parser.add_argument('--sensors', choices=('full', 'position'), default='full')
    parser.add_argument('--out', type=Path)
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        make_log(30.0, work / 'warm.csv', sensors=args.sensors)
        run_child(work / 'warm.csv', work / 'warm.json')  # fills numba's disk cache
        for duration in args.durations:
            log = work / f'log_{duration:g}.csv'
            started = time.perf_counter()
            make_log(duration, log, sensors=args.sensors)
            made = time.perf_counter() - started
            runs = [run_child(log, work / 'result.json') for _ in range(args.repeats)]
            doc = json.loads((work / 'result.json').read_text())
            wall = statistics.median(r['wall'] for r in runs)
            row = {'duration_s': duration, 'samples': round(duration / PERIOD),
                   'wall_s': wall, 'wall_all_s': [r['wall'] for r in runs],
                   'seconds_per_minute_of_data': wall / (duration / 60.0),
                   'peak_rss_mb': max(r['peak_rss_mb'] for r in runs),
                   'diagnosis_s': doc['elapsed'], 'cause': doc['cause'],
                   'coulomb_friction_n': doc['sizes'].get('coulomb_friction'),
                   'fit_baseline': doc['fit_baseline'], 'fit_extended': doc['fit_extended'],
                   'log_made_s': made, 'csv_mb': log.stat().st_size / 1e6}
            rows.append(row)
            friction = row['coulomb_friction_n']
            named = '' if friction is None else f', F_c {friction:.1f} N (truth 60)'
            print(f"{duration:6.0f} s of data ({row['samples']} samples, "
                  f"{row['csv_mb']:.1f} MB CSV): {wall:6.1f} s wall (median of "
                  f"{args.repeats}), {row['seconds_per_minute_of_data']:5.2f} s per minute of "
                  f"data, peak RSS {row['peak_rss_mb']:.0f} MB; cause {row['cause']}{named}, "
                  f"fit {row['fit_baseline']:.2f} -> {row['fit_extended']:.2f} %", flush=True)
    result = {'command': 'exo-has diagnose LOG --joint hip -q --json FILE',
              'sensors': args.sensors,
              'machine': {'platform': platform.platform(), 'python': platform.python_version(),
                          'cpus': os.cpu_count()},
              'date': time.strftime('%Y-%m-%d'), 'repeats': args.repeats, 'rows': rows}
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + '\n', encoding='utf-8')


if __name__ == '__main__':
    main()
