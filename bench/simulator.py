"""Benchmark: the fast HAS simulator, in real time and against solve_ivp at equal accuracy.

1. Four joints (hips and knees, 50 kg on each), 60 s of closed-loop walking at 0.85 strides/s
   under a 1 kHz PD controller: wall time, and its multiple of real time.
2. Accuracy against time on the same kind of run (one hip, 3 s, 1 kHz PD): the fast simulator
   at several tolerances and solve_ivp (LSODA, Radau, BDF) at several rtol, integrating between
   two controller actions as solve_ivp must, each against Radau at rtol 1e-10; then the
   speed-up over the cheapest solve_ivp run at least as accurate as the fast simulator at its
   default tolerance.

Usage: ``.venv/bin/python bench/simulator.py [--repeats N] [--out FILE] [--walk-only]``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from exo_has_sim import linear, model
from exo_has_sim.gait import load_gait_cycle
from exo_has_sim.integrator import DEFAULT_RTOL
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters
from exo_has_sim.reference_solution import simulate_reference_closed_loop
from exo_has_sim.simulate import simulate_closed_loop

LOAD = 50.0 * 9.81


def references(params_list: list, duration: float, period: float,
               stride: float = 0.85) -> tuple[np.ndarray, np.ndarray]:
    """Cylinder position and velocity references of walking, one column per joint."""
    t = np.arange(round(duration / period)) * period
    hip, knee = load_gait_cycle().angles_at(t * stride)
    x_ref = np.column_stack([Linkage.from_parameters(p).position(hip if p.joint_type == 'hip'
                                                                  else knee)
                             for p in params_list])
    return x_ref, np.gradient(x_ref, period, axis=0)


def closed_loop_walk(repeats: int) -> dict[str, float]:
    """Time 60 s of closed-loop walking of four joints at 1 kHz."""
    hip, knee = load_parameters('hip'), load_parameters('knee')
    joints = [hip, knee, hip, knee]
    duration, period = 60.0, 0.001
    x_ref, v_ref = references(joints, duration, period)
    x_ref[:, 2:] = np.roll(x_ref[:, 2:], round(0.5 / 0.85 / period), axis=0)  # right leg
    v_ref[:, 2:] = np.roll(v_ref[:, 2:], round(0.5 / 0.85 / period), axis=0)
    y0 = np.stack([model.initial_state(p, x_ref[0, i], LOAD) for i, p in enumerate(joints)])
    gains = np.array([[35e3, 15.0, 1.0 / linear.velocity_gain(p)] for p in joints])
    loads = np.full(len(x_ref), LOAD)
    simulate_closed_loop(joints, y0, x_ref[:100], v_ref[:100], loads[:100], gains, period)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = simulate_closed_loop(joints, y0, x_ref, v_ref, loads, gains, period)
        times.append(time.perf_counter() - start)
    error = result.position[1:] - x_ref
    wall = statistics.median(times)
    return {'duration_s': duration, 'wall_s': wall, 'real_time_factor': duration / wall,
            'tracking_rms_mm': float(np.sqrt(np.mean(error ** 2)) * 1e3)}


def accuracy_against_time(repeats: int) -> dict[str, object]:
    """Error and wall time of each solver on 3 s of 1 kHz closed-loop walking of one hip."""
    params = load_parameters('hip')
    period, duration = 0.001, 3.0
    x_ref, v_ref = references([params], duration, period)
    y0 = model.initial_state(params, x_ref[0, 0], LOAD)
    loads = np.full(len(x_ref), LOAD)
    gains = np.array([[35e3, 15.0, 1.0 / linear.velocity_gain(params)]])
    truth = simulate_reference_closed_loop(params, y0, x_ref[:, 0], v_ref[:, 0], loads, gains,
                                           period, rtol=1e-10)[:, model.X]

    def measure(run, times_run: int) -> tuple[float, float]:
        position = run()
        times = []
        for _ in range(times_run):
            start = time.perf_counter()
            run()
            times.append(time.perf_counter() - start)
        return float(np.max(np.abs(position - truth))), statistics.median(times)

    rows = []
    for rtol in (1e-2, 1e-3, 1e-4):
        error, wall = measure(lambda r=rtol: simulate_closed_loop(
            [params], y0[None, :], x_ref, v_ref, loads, gains, period, rtol=r).position[:, 0],
            repeats)
        rows.append({'solver': 'fast ROS2', 'rtol': rtol, 'max_error_mm': error * 1e3,
                     'wall_s': wall})
    for method in ('LSODA', 'Radau', 'BDF'):
        for rtol in (1e-3, 1e-5):
            error, wall = measure(lambda m=method, r=rtol: simulate_reference_closed_loop(
                params, y0, x_ref[:, 0], v_ref[:, 0], loads, gains, period, rtol=r,
                method=m)[:, model.X], 1)
            rows.append({'solver': f'solve_ivp {method}', 'rtol': rtol,
                         'max_error_mm': error * 1e3, 'wall_s': wall})
            print(f'  {method} rtol {rtol:g}: error {error * 1e3:.4f} mm, {wall:.2f} s',
                  flush=True)
    fast = next(r for r in rows if r['solver'] == 'fast ROS2' and r['rtol'] == DEFAULT_RTOL)
    matching = [r for r in rows if r['solver'].startswith('solve_ivp')
                and r['max_error_mm'] <= fast['max_error_mm']]
    cheapest = min(matching, key=lambda r: r['wall_s']) if matching else None
    return {'duration_s': duration, 'rows': rows, 'fast_default': fast,
            'cheapest_equal_accuracy': cheapest,
            'speedup': cheapest['wall_s'] / fast['wall_s'] if cheapest else None}


def main() -> int:
    """Run both parts, print the results, optionally write JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=5, help='timed runs per case (5)')
    parser.add_argument('--out', type=Path, help='write the results as JSON here')
    parser.add_argument('--walk-only', action='store_true',
                        help='time the closed-loop walk only (to time two versions side by side)')
    args = parser.parse_args()
    walk = closed_loop_walk(args.repeats)
    print(f'4 joints, {walk["duration_s"]:.0f} s closed-loop walking at 1 kHz: '
          f'{walk["wall_s"]:.3f} s wall (median of {args.repeats}), '
          f'{walk["real_time_factor"]:.0f}x real time, tracking rms '
          f'{walk["tracking_rms_mm"]:.2f} mm', flush=True)
    if args.walk_only:
        return 0
    accuracy = accuracy_against_time(max(1, args.repeats // 2))
    for row in accuracy['rows']:
        print(f'{row["solver"]:<18} rtol {row["rtol"]:<7g} max error '
              f'{row["max_error_mm"]:8.4f} mm wall {row["wall_s"]:8.4f} s')
    cheapest = accuracy['cheapest_equal_accuracy']
    if cheapest:
        print(f'speed-up over the cheapest solve_ivp run at least as accurate '
              f'({cheapest["solver"]}, rtol {cheapest["rtol"]:g}): {accuracy["speedup"]:.0f}x')
    if args.out:
        args.out.write_text(json.dumps({
            'machine': {'platform': platform.platform(), 'cpus': os.cpu_count(),
                        'python': platform.python_version()},
            'closed_loop_walk': walk, 'accuracy_against_time': accuracy}, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
