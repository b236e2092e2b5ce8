"""``exo-has diagnose``: what the simulation gets wrong on measured data, and why.

Reads a CSV log or a bag, compares the project's HAS model (or a generic mass) with it over
held-out windows, names the physical effect that explains the difference (or none), and shows
how much better the extended model predicts.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from pathlib import Path

from exo_has_common.errors import ExoHasError
from exo_has_sim.diagnosis.budget import TimeBudget
from exo_has_sim.diagnosis.compare import DEFAULT_HORIZON
from exo_has_sim.diagnosis.diagnose import DEFAULT_BURN_IN, diagnose
from exo_has_sim.diagnosis.loading import load_plant
from exo_has_sim.diagnosis.report import summary, write_json, write_report

EPILOG = """CSV: a header row, one row per sample, SI units: time [s], motor_speed_command
[rad/s] (--plant has) or force [N] (--plant mass), position [m]; optionally reference [m],
pressure_a, pressure_b [Pa], motor_speed [rad/s], load_force [N]. Exit status 0 when the
diagnosis was made and the model's structure describes the data (whatever effect it names, or
none), 3 when the structure does not describe them (the verdict names the evidence and what
structure would; a model that cannot follow the record is such a verdict), 1 when the input
cannot be read."""


#: Exit status of a diagnosis whose verdict is that the model's structure does not describe
#: the data.
STRUCTURE_STATUS = 3


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog='exo-has diagnose',
                                     description=(__doc__ or '').splitlines()[0], epilog=EPILOG)
    parser.add_argument('input', type=Path, help='CSV log, or rosbag2 directory (MCAP)')
    parser.add_argument('--plant', choices=('has', 'mass'), default='has',
                        help='model: the HAS (default) or a generic mass driven by a force')
    parser.add_argument('--joint', help='joint to read from a bag (left_hip, ...); for a CSV, '
                        'hip or knee picks the parameter set (default hip)')
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
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the arguments, diagnose, print the summary, write the requested files."""
    args = _parser().parse_args(argv)

    def progress(line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    try:
        budget = TimeBudget(math.inf if args.time_budget is None else args.time_budget)
        plant = load_plant(args.input, args.plant, args.joint, args.load_mass, args.params,
                           args.constant_load, args.motor_speed_input)
        result = diagnose(plant, args.horizon, args.burn_in, max_causes=args.max_causes,
                          progress=None if args.quiet else progress, budget=budget)
        print(summary(result))
        if args.json:
            write_json(result, args.json)
            print(f'wrote {args.json}')
        if args.report:
            print(f'wrote {write_report(result, args.report)}')
    except (ExoHasError, OSError) as exc:
        print(f'exo-has diagnose: {exc}', file=sys.stderr)
        return 1
    return 0 if result.described else STRUCTURE_STATUS
