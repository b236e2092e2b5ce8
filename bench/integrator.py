"""Benchmark: the open-loop integrator's work and precision on the diagnosis's own calls.

``exo-has diagnose`` spends most of its time in :func:`exo_has_sim.integrator.open_loop`,
called through :func:`exo_has_sim.simulate.integrate_packed` on blocks of candidate x window
joints. ``capture`` runs a diagnosis and pickles the arguments of its first calls;
``measure`` replays them through this tree's ``open_loop`` and a baseline's (an
``integrator.py`` of another commit, loaded as a module of its own against this tree's model:
``git show COMMIT:exo_has_sim/exo_has_sim/integrator.py > FILE``), each at the diagnosis's
tolerances (``HAS_ATOL``, ``HAS_RTOL``) times a factor, on one thread, taking turns call by
call so that the machine's drift hits both. Per method and factor: steps per sample, CPU
seconds (``time.process_time``, the least of the repeats) and the largest position and p_A
error over all calls and samples against this tree at tolerance x ``--reference`` (checked
against the baseline's at that tolerance on ``--check`` calls). Then, for each factor of
this tree whose worst errors are no larger than the baseline's at x1, the CPU ratio
baseline / this tree over the calls: median and worst.

Usage: ``.venv/bin/python bench/integrator.py capture RECORD OUT.pkl [--calls N] [-- ARGS]``
(ARGS: more arguments of ``exo-has diagnose``), then ``.venv/bin/python bench/integrator.py
measure CALLS.pkl [...] --baseline FILE [--factors 1 0.5] [--repeats 3] [--out FILE]``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import pickle
import platform
import statistics
import sys
import time
from pathlib import Path
from types import ModuleType

import numpy as np

from exo_has_sim import integrator, model, simulate
from exo_has_sim.diagnosis.has_plant import HAS_ATOL, HAS_RTOL

#: Largest integration step of the diagnosis's calls [s] (integrate_packed's default).
MAX_STEP = integrator.DEFAULT_STEP


class _EnoughError(Exception):
    """Raised to end a captured diagnosis once it has made the calls wanted."""


def capture(record: str, out: Path, calls: int, extra: list[str]) -> None:
    """Run ``exo-has diagnose`` on a record and pickle the arguments of its first calls."""
    caught = []
    original = simulate.integrate_packed

    def wrapped(packed, delay, y0, n_cmd, f_load, period, **kwargs):
        caught.append((packed.copy(), delay.copy(), y0.copy(), n_cmd.copy(), f_load.copy(),
                       period, kwargs))
        if len(caught) >= calls:
            raise _EnoughError
        return original(packed, delay, y0, n_cmd, f_load, period, **kwargs)

    simulate.integrate_packed = wrapped
    from exo_has_sim.diagnosis import has_plant
    has_plant.simulate.integrate_packed = wrapped  # the plant calls it through the module
    from exo_has_sim.diagnosis.cli import main
    try:
        main([record, *extra])
    except _EnoughError:
        pass
    finally:
        simulate.integrate_packed = original
    out.write_bytes(pickle.dumps(caught))
    print(f'{len(caught)} calls written to {out}')


def load_baseline(path: Path) -> ModuleType:
    """Load an integrator.py of another commit as a module of its own."""
    spec = importlib.util.spec_from_file_location('baseline_integrator', path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # compiled.py finds a function's sources through it
    spec.loader.exec_module(module)
    return module


def run(module: ModuleType, call: tuple, factor: float) -> tuple[np.ndarray, int, float]:
    """Integrate one captured call with ``module.open_loop``; return states, steps, CPU s."""
    packed, delay, y0, n_cmd, f_load, period, _ = call
    out = np.empty((n_cmd.shape[0] + 1, packed.shape[0], model.N_STATE))
    start = time.process_time()
    taken = module.open_loop(y0, packed, n_cmd, f_load, period, delay, HAS_ATOL * factor,
                             HAS_RTOL * factor, MAX_STEP, out)
    return out, taken, time.process_time() - start


def errors(states: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """Largest position [m] and p_A [Pa] differences over all samples and joints."""
    return (float(np.max(np.abs(states[:, :, model.X] - reference[:, :, model.X]))),
            float(np.max(np.abs(states[:, :, model.PA] - reference[:, :, model.PA]))))


def prepared(call: tuple) -> tuple:
    """Return the call with its arrays contiguous, as integrate_packed hands them on."""
    packed, delay, y0, n_cmd, f_load, period, kwargs = call
    return (np.ascontiguousarray(packed), np.ascontiguousarray(delay, dtype=float),
            np.ascontiguousarray(y0, dtype=float), np.ascontiguousarray(n_cmd),
            np.ascontiguousarray(f_load), period, kwargs)


def measure(paths: list[Path], baseline: ModuleType, factors: list[float], repeats: int,
            reference_factor: float, check: int) -> dict[str, object]:
    """Replay every captured call (see the module docstring); return the rows and ratios."""
    calls = [prepared(c) for path in paths for c in pickle.loads(path.read_bytes())]
    cases = [('baseline', baseline, 1.0)] + [('this tree', integrator, f) for f in factors]
    for _, module, _ in cases:  # compile (or load) both before any timing
        run(module, calls[0], 1.0)
    per_case = {i: [] for i in range(len(cases))}
    checks = []
    for number, call in enumerate(calls):
        reference = run(integrator, call, reference_factor)[0]
        if number < check:
            second = run(baseline, call, reference_factor)[0]
            checks.append(errors(second, reference))
        samples = call[3].shape[0] * call[0].shape[0]
        best = {}
        for _ in range(repeats):
            for i, (_, module, factor) in enumerate(cases):
                states, taken, cpu = run(module, call, factor)
                best[i] = min(best.get(i, (np.inf,)), (cpu, taken, states), key=lambda r: r[0])
        for i in best:
            cpu, taken, states = best[i]
            per_case[i].append({'cpu_s': cpu, 'steps_per_sample': taken / samples,
                                'errors': errors(states, reference)})
        print(f'call {number + 1}/{len(calls)}: {call[0].shape[0]} joints', flush=True)
    rows = []
    for i, (name, _, factor) in enumerate(cases):
        entries = per_case[i]
        rows.append({'method': name, 'factor': factor,
                     'steps_per_sample': statistics.mean(e['steps_per_sample'] for e in entries),
                     'cpu_s_per_call': statistics.mean(e['cpu_s'] for e in entries),
                     'max_position_error_m': max(e['errors'][0] for e in entries),
                     'max_pressure_error_pa': max(e['errors'][1] for e in entries)})
    ratios = []
    base = rows[0]
    for i in range(1, len(cases)):
        if (rows[i]['max_position_error_m'] <= base['max_position_error_m']
                and rows[i]['max_pressure_error_pa'] <= base['max_pressure_error_pa']):
            each = [b['cpu_s'] / e['cpu_s'] for b, e in zip(per_case[0], per_case[i], strict=True)]
            total = (sum(b['cpu_s'] for b in per_case[0]) / sum(e['cpu_s'] for e in per_case[i]))
            ratios.append({'factor': cases[i][2], 'median': statistics.median(each),
                           'worst': min(each), 'total': total})
    return {'calls': len(calls), 'repeats': repeats, 'reference_factor': reference_factor,
            'reference_check': {'calls': len(checks),
                                'max_position_error_m': max((c[0] for c in checks), default=None),
                                'max_pressure_error_pa': max((c[1] for c in checks),
                                                             default=None)},
            'rows': rows, 'equal_accuracy_ratios': ratios}


def report(result: dict[str, object]) -> None:
    """Print the table and the ratios."""
    check = result['reference_check']
    print(f'{result["calls"]} calls; reference: this tree at tolerance x'
          f'{result["reference_factor"]:g}', end='')
    if check['calls']:
        print(f", off the baseline's at the same tolerance by at most "
              f'{check["max_position_error_m"] * 1e6:.2f} um and '
              f'{check["max_pressure_error_pa"] / 1e3:.2f} kPa on {check["calls"]} calls')
    else:
        print()
    print('| method | tolerance | steps/sample | CPU per call | max position error '
          '| max p_A error |\n|---|---|---|---|---|---|')
    for row in result['rows']:
        print(f'| {row["method"]} | x{row["factor"]:g} | {row["steps_per_sample"]:.2f} '
              f'| {row["cpu_s_per_call"] * 1e3:.1f} ms '
              f'| {row["max_position_error_m"] * 1e6:.1f} um '
              f'| {row["max_pressure_error_pa"] / 1e3:.1f} kPa |')
    for ratio in result['equal_accuracy_ratios']:
        print(f'at equal or better accuracy, x{ratio["factor"]:g}: baseline CPU / this tree\'s '
              f'median {ratio["median"]:.2f}, worst {ratio["worst"]:.2f}, '
              f'all calls {ratio["total"]:.2f}')


def main() -> int:
    """Capture or measure (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest='command', required=True)
    grab = commands.add_parser('capture', help='pickle the integrator calls of a diagnosis')
    grab.add_argument('record')
    grab.add_argument('out', type=Path)
    grab.add_argument('--calls', type=int, default=40)
    grab.add_argument('extra', nargs='*', help='more arguments of exo-has diagnose')
    replay = commands.add_parser('measure', help='replay captured calls')
    replay.add_argument('calls', type=Path, nargs='+')
    replay.add_argument('--baseline', type=Path, required=True,
                        help='an integrator.py of another commit')
    replay.add_argument('--factors', type=float, nargs='+', default=[1.0])
    replay.add_argument('--repeats', type=int, default=3)
    replay.add_argument('--reference', type=float, default=1e-3,
                        help='tolerance factor of the reference (1e-3)')
    replay.add_argument('--check', type=int, default=4,
                        help='calls on which the baseline checks the reference (4)')
    replay.add_argument('--out', type=Path)
    args = parser.parse_args()
    if args.command == 'capture':
        capture(args.record, args.out, args.calls, args.extra)
        return 0
    result = measure(args.calls, load_baseline(args.baseline), args.factors, args.repeats,
                     args.reference, args.check)
    report(result)
    if args.out:
        result['machine'] = {'platform': platform.platform(), 'cpus': os.cpu_count(),
                             'python': platform.python_version(), 'argv': sys.argv[1:]}
        args.out.write_text(json.dumps(result, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
