"""``exo-has diagnose``: what the simulation gets wrong on measured data, and why.

Reads a CSV log or a bag, compares the project's HAS model (or a generic mass) with it over
held-out windows, names the physical effect that explains the difference (or none), and shows
how much better the extended model predicts. Several records (several inputs, folders of them,
``--joint all``) make a batch (:mod:`~exo_has_sim.diagnosis.batch`): diagnosed on local
worker processes or a Dask cluster into ``--summary DIR``, resumably. Installed without ROS,
the same command is ``exo-has-diagnose``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

from exo_has_common.errors import ExoHasError
from exo_has_sim.diagnosis.batch import (
    ERROR_STATUS,
    INTERRUPTED_STATUS,
    STRUCTURE_STATUS,
    ProgressBar,
    run_batch,
)
from exo_has_sim.diagnosis.compare import DEFAULT_HORIZON
from exo_has_sim.diagnosis.diagnose import DEFAULT_BURN_IN
from exo_has_sim.diagnosis.records import (
    ALL_JOINTS,
    Options,
    Record,
    diagnosis_of,
    find_records,
    is_bag,
)
from exo_has_sim.diagnosis.report import summary, write_json, write_report
from exo_has_sim.diagnosis.summary import counts

EPILOG = """CSV: a header row, one row per sample, SI units: time [s], motor_speed_command
[rad/s] (--plant has) or force [N] (--plant mass), position [m]; optionally reference [m],
pressure_a, pressure_b [Pa], motor_speed [rad/s], load_force [N]. Exit status 0 when the
diagnosis was made and the model's structure describes the data (whatever effect it names, or
none), 3 when the structure does not describe them (the verdict names the evidence and what
structure would; a model that cannot follow the record is such a verdict), 1 when the input
cannot be read. Several records (a batch, --summary DIR): 0 when every record was diagnosed
and described, 3 when a record's structure verdict is the worst, 1 when a record could not be
diagnosed (its error is in the summary), 4 when a record was not finished (its worker died:
the same command does it), 130 when interrupted (Ctrl-C: the summary holds what finished); 2
for bad arguments."""

__all__ = ['STRUCTURE_STATUS', 'main']


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='exo-has diagnose',
                                     description=(__doc__ or '').splitlines()[0], epilog=EPILOG)
    parser.add_argument('inputs', type=Path, nargs='+', metavar='INPUT',
                        help='CSV log, rosbag2 directory (MCAP), or a folder of them (searched '
                        'at any depth); several records make a batch (--summary)')
    parser.add_argument('--plant', choices=('has', 'mass'), default='has',
                        help='model: the HAS (default) or a generic mass driven by a force')
    parser.add_argument('--joint', help='joint to read from a bag (left_hip, ...; all: every '
                        'joint it records, a batch); for a CSV, hip or knee picks the '
                        'parameter set (default hip)')
    parser.add_argument('--load-mass', type=float, metavar='KG',
                        help="mass moved by the cylinder [kg] (the paper's rig: 50)")
    parser.add_argument('--params', type=Path, metavar='FILE',
                        help="HAS parameters file instead of the joint type's")
    parser.add_argument('--report', type=Path, metavar='DIR',
                        help='write a Markdown report with plots into this folder')
    parser.add_argument('--json', type=Path, metavar='FILE', help='write the result as JSON')
    parser.add_argument('--horizon', type=float, default=DEFAULT_HORIZON, metavar='S',
                        help=f'scored prediction horizon per window [s] ({DEFAULT_HORIZON})')
    parser.add_argument('--burn-in', type=float, default=DEFAULT_BURN_IN, metavar='S',
                        help=f'unscored simulation before each horizon [s] ({DEFAULT_BURN_IN})')
    parser.add_argument('--constant-load', action='store_true',
                        help='the load is constant (a fixed mass on a bench): lets a record '
                        'without pressure_a or load_force name the effects that act through '
                        'the pressure')
    parser.add_argument('--motor-speed-input', action='store_true',
                        help='drive the pump by the measured motor_speed instead of the command '
                        "through the motor's speed loop: judges the hydraulics apart from a "
                        'motor at its torque limit')
    parser.add_argument('--max-causes', type=int, default=2, help='most effects to name (2)')
    parser.add_argument('--time-budget', type=float, metavar='S',
                        help='wall-clock seconds for the diagnosis: the searches that refine '
                        'the verdict (other structures, further selection steps, rival '
                        'effects, detection limits) start only within it, and the summary '
                        'says what was not tried (default: no budget)')
    parser.add_argument('-q', '--quiet', action='store_true',
                        help='no progress lines on stderr')
    batch = parser.add_argument_group(
        'several records', 'a batch: each record diagnosed into --summary DIR as it ends; run '
        'again, the same command skips the records done')
    batch.add_argument('--summary', type=Path, metavar='DIR',
                       help="write summary.md, summary.csv and each record's JSON here")
    batch.add_argument('--workers', type=int, metavar='N',
                       help='local worker processes (default: one per core; 0: in this '
                       'process)')
    batch.add_argument('--scheduler', metavar='ADDRESS',
                       help='run the records on the Dask cluster of this scheduler '
                       '(tcp://host:8786); its workers read the inputs at the same paths')
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the arguments, diagnose, print the summary, write the requested files."""
    parser = _parser()
    args = parser.parse_args(argv)
    options = Options(plant=args.plant, load_mass=args.load_mass, params=args.params,
                      horizon=args.horizon, burn_in=args.burn_in,
                      constant_load=args.constant_load, motor_speed_input=args.motor_speed_input,
                      max_causes=args.max_causes, time_budget=args.time_budget)
    if len(args.inputs) > 1 or args.joint == ALL_JOINTS or args.summary is not None \
            or args.workers is not None or args.scheduler is not None \
            or (args.inputs[0].is_dir() and not is_bag(args.inputs[0])):
        return _batch(parser, args, options)

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    try:
        result = diagnosis_of(Record(args.inputs[0], args.joint, options),
                              None if args.quiet else progress)
        print(summary(result))
        if args.json:
            write_json(result, args.json)
            print(f'wrote {args.json}')
        if args.report:
            print(f'wrote {write_report(result, args.report)}')
    except (ExoHasError, OSError) as exc:
        print(f'exo-has diagnose: {exc}', file=sys.stderr)
        return ERROR_STATUS
    return 0 if result.described else STRUCTURE_STATUS


def _batch(parser: argparse.ArgumentParser, args: argparse.Namespace, options: Options) -> int:
    """Diagnose several records into the summary folder; the batch's exit status."""
    if args.summary is None:
        parser.error('several records (several inputs, a folder, --joint all, --workers or '
                     "--scheduler) need --summary DIR, where each record's JSON and the "
                     'summary go')
    if args.json is not None or args.report is not None:
        parser.error("--json and --report are for one record; a batch writes each record's "
                     'JSON into --summary DIR')
    if args.workers is not None and args.workers < 0:
        parser.error(f'--workers must be 0 or more, got {args.workers}')
    try:
        records = find_records(args.inputs, args.joint, options, leave_out=[args.summary])
        if not records:
            print('exo-has diagnose: no CSV log nor bag in ' + ', '.join(map(str, args.inputs)),
                  file=sys.stderr)
            return ERROR_STATUS
        outcome = run_batch(records, args.summary, args.workers, args.scheduler,
                            None if args.quiet else ProgressBar())
    except (ExoHasError, OSError) as exc:
        print(f'exo-has diagnose: {exc}', file=sys.stderr)
        return ERROR_STATUS
    except KeyboardInterrupt:  # before any record started (finding them, hashing them)
        print('exo-has diagnose: interrupted before any record was diagnosed', file=sys.stderr)
        return INTERRUPTED_STATUS
    print(counts(outcome.rows) + ('; interrupted' if outcome.interrupted else ''))
    print(f'wrote {outcome.summary[0]} and {outcome.summary[1]}')
    return outcome.status
