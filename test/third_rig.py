"""The third truth plant's rig as its user describes it: a parameters file from its datasheet.

``exo-has diagnose --params FILE`` takes a rig of the user's own; this writes the file a user of
the rig in ``third_truth_plant.py`` would write from its datasheet (``datasheet()``: the
geometry, the pump, the motor and its torque limit, the accumulator, the valves, the brake),
in the layout of ``exo_has_sim/config/hip.yaml``, whose values it replaces (the linkage's,
which a rig has not, stay as they are). Two circuits: the rig's own (``'switched'``, the brake
declared) and the paper's, as a user who kept the project's model would describe the rig.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import third_truth_plant as rig

from exo_has_sim.parameters import CONFIG_DIR

ATMOSPHERE = 101325.0  # Pa
#: What the rig logs (as the real rig of issue 25 did): command, motor speed, position and
#: both pressures; the load is not measured.
LOGGED = ('time', 'motor_speed_command', 'position', 'reference', 'pressure_a', 'pressure_b',
          'motor_speed')
#: Brakes [N] under which the rig's torque-limited motor holds its commands: above about
#: 4.5 kN it cannot retract against the brake and stalls for half the record or more
#: (third_truth_plant.py draws brakes of 1 to 7 kN).
HELD_BRAKES = (1.0e3, 4.0e3)


def held_brake(seed: int) -> float:
    """Return a brake [N] within :data:`HELD_BRAKES`, drawn from the seed (its own stream)."""
    low, high = HELD_BRAKES
    return float(low + (high - low) * np.random.default_rng([seed, 25]).random())


def rig_values(circuit: str) -> dict[str, float | str]:
    """Return the parameters file's values of the rig, SI, for the circuit named."""
    ds = rig.datasheet()
    area_a = math.pi / 4.0 * ds['bore_diameter'] ** 2
    area_b = math.pi / 4.0 * (ds['bore_diameter'] ** 2 - ds['rod_diameter'] ** 2)
    own = circuit != 'paper'
    # The accumulator's gas spring: extending takes the rod's volume of oil from it.
    gas = ds['accumulator_volume'] * (1.0 - ds['accumulator_fill'])
    stiffness = ds['polytropic_index'] * (ds['charge_pressure'] + ATMOSPHERE) \
        * (area_a - area_b) / gas
    return {
        'circuit': circuit,
        'bore_diameter': ds['bore_diameter'], 'rod_diameter': ds['rod_diameter'],
        'stroke': ds['stroke'], 'pump_displacement': ds['pump_displacement'],
        'motor_speed_max': ds['motor_speed_max'], 'motor_torque_peak': ds['motor_torque_peak'],
        'motor_torque_nominal': 0.5 * ds['motor_torque_peak'],
        'pump_mechanical_efficiency': ds['pump_mechanical_efficiency'],
        'motor_time_constant': ds['motor_time_constant'], 'motor_inertia': ds['motor_inertia'],
        'pump_leakage': ds['pump_leakage'], 'cylinder_leakage': ds['cylinder_leakage'],
        'bulk_modulus': ds['bulk_modulus'], 'dead_volume': ds['dead_volume_a'],
        'rod_dead_volume': ds['dead_volume_b'], 'piston_mass': ds['piston_mass'],
        'load_mass': ds['load_mass'],
        # The brake's throttle adds to the cylinder's own viscous damping.
        'damping': ds['damping'] + (ds['brake_damping'] if own else 0.0),
        'max_working_pressure': ds['relief_pressure'], 'relief_pressure': ds['relief_pressure'],
        'relief_conductance': ds['relief_gain'], 'valve_time_constant': ds['valve_time_constant'],
        'valve_release_speed': 2.0, 'valve_engage_speed': 3.0,  # the valves' deadband
        'peak_thrust': area_a * ds['relief_pressure'],
        'no_load_speed': ds['pump_displacement'] * ds['motor_speed_max'] / area_a,
        'charge_pressure': ds['charge_pressure'] if own else 0.0,
        'charge_stiffness': stiffness if own else 0.0,
        'return_conductance': ds['valve_rated_flow'] / ds['valve_pressure_drop'],
        'brake_force': ds['brake_force'] if own else 0.0,
        'brake_velocity': ds['brake_velocity'],
        'cavitation_pressure': ds['cavitation_pressure'],
    }


#: What the rig's user knows only roughly, as relative standard uncertainties: the motor's
#: loop, the pump's flow gain and the dead volume (as the project's files), the accumulator's
#: charge (it drifts with temperature) and the brake's setting (a relief valve's, on another
#: cylinder).
UNCERTAINTY = {'motor_time_constant': 0.3, 'pump_displacement': 0.15, 'dead_volume': 0.3,
               'charge_pressure': 0.3, 'brake_force': 0.5}


def write_rig_file(path: str | Path, circuit: str = 'switched') -> Path:
    """Write the rig's parameters file for ``circuit`` (``'switched'`` or ``'paper'``)."""
    values = rig_values(circuit)
    out, section = [], ''
    for line in (CONFIG_DIR / 'hip.yaml').read_text().splitlines():
        stripped = line.strip()
        if line.startswith('    ') and not line.startswith('     '):
            section = stripped.rstrip(':')
        key = stripped.split(':')[0]
        if section == 'has' and line.startswith('      ') and key in values:
            value = values[key]
            line = f'      {key}: {value}' if isinstance(value, str) else \
                f'      {key}: {float(value)!r}'
        elif section == 'uncertainty' and line.startswith('      '):
            continue
        out.append(line)
        if stripped == 'uncertainty:':
            spreads = {k: v for k, v in UNCERTAINTY.items()
                       if circuit != 'paper' or k not in ('charge_pressure', 'brake_force')}
            out.extend(f'      {k}: {v}' for k, v in spreads.items())
    path = Path(path)
    path.write_text('\n'.join(out) + '\n', encoding='utf-8')
    return path


#: The thrust [N] the rig's motor holds at its peak torque, standing.
THRUST = math.pi / 4.0 * rig.datasheet()['bore_diameter'] ** 2 \
    * rig.datasheet()['motor_torque_peak'] * rig.datasheet()['pump_mechanical_efficiency'] \
    / rig.datasheet()['pump_displacement']
#: Records like those of the real rig that stopped the diagnosis: seed, brake as a share of
#: :data:`THRUST`, excursion (the share of its usual stroke the rod moves over), the
#: accumulator's charge pressure [Pa], and whether the rig's pressures are logged (else the
#: position only).
RIG_LIKE = ((9140, 0.30, 0.10, 5.0e5, True), (9141, 0.45, 0.25, 5.5e5, True),
            (9142, 0.55, 0.15, 6.0e5, False), (9143, 0.40, 0.05, 5.2e5, True),
            (9144, 0.50, 0.35, 5.8e5, False), (9145, 0.35, 0.20, 5.4e5, True))
#: The columns of a record without the pressures and the motor speed.
POSITION_ONLY = ('time', 'motor_speed_command', 'position', 'reference')


def write_rig_like(folder: str | Path, seed: int, share: float, excursion: float,
                   charge: float, logged: bool, duration: float = 20.0) -> tuple[Path, object]:
    """Simulate a record of :data:`RIG_LIKE` and write it as a CSV; return its path and draw."""
    draw = rig.draw(seed, effect='none', duration=duration, brake_force=share * THRUST,
                    excursion=excursion, charge_pressure=charge)
    path = Path(folder) / f'{seed}.csv'
    rig.write_csv(draw, path, columns=LOGGED if logged else POSITION_ONLY)
    return path, draw

