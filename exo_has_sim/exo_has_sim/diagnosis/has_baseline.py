"""What the HAS plant fits: its baseline's parameters, and a candidate's parameter set.

The baseline (:attr:`~exo_has_sim.diagnosis.has_plant.HasPlant.baseline`) re-estimates what
section 4.2 of the paper calls hard to know, and the parameters a set states only roughly, each
with a prior from the set; a candidate (values by name, an effect's size among them) becomes a
:class:`exo_has_sim.parameters.HasParameters` and a transport delay
(:func:`candidate_parameters`).
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Any

from exo_has_sim.diagnosis.effects import RELIEF_CRACK_CONDUCTANCE
from exo_has_sim.diagnosis.plants import Candidate, Parameter
from exo_has_sim.parameters import Effects, HasParameters

#: What a candidate may set of :class:`exo_has_sim.parameters.HasParameters`: the HAS
#: baseline's re-estimated parameters and the damping ratio of its second-order motor loop.
NUISANCE = ('bulk_modulus', 'pump_leakage', 'damping', 'motor_time_constant',
            'pump_displacement', 'dead_volume', 'motor_damping_ratio', 'charge_pressure',
            'charge_stiffness', 'return_conductance', 'brake_force')
#: Relative standard uncertainty of a nuisance parameter whose parameter set states none
#: (None: no prior). The motor's speed loop and the dead volume are assumed values in the
#: project's sets (their provenance says so); the displacement is stated (paper 2.3.1: 0.4
#: mL/r), the volumetric efficiency that scales it into the flow gain is not. Bulk modulus,
#: leakage and damping are what the paper (4.2) calls hard to know: the data decide.
DEFAULT_UNCERTAINTY: dict[str, float | None] = {
    'bulk_modulus': None, 'pump_leakage': None, 'damping': None,
    'motor_time_constant': 0.3, 'pump_displacement': 0.15, 'dead_volume': 0.3,
    'return_conductance': None, 'brake_force': None, 'charge_stiffness': None}
#: Unit of the linear search of a charge pressure [Pa] (a charge may be 0 gauge).
CHARGE_SCALE = 1e5
#: Damping ratios a second-order motor loop is screened at: under- to overdamped.
SECOND_ORDER_GRID = (0.4, 0.7, 1.0, 1.5)


def model_air_fraction(fraction: float) -> float:
    """Convert a free-air volume fraction at atmospheric pressure to the model's parameter.

    :func:`exo_has_sim.model.effective_bulk_modulus` takes the air's share of the mixture at
    pressure p as ``a (p_atm / p_abs)^(1/1.4)``, exact for little air. A fraction alpha of the
    volume at atmospheric pressure is ``alpha / (1 - alpha)`` of the oil's volume, and the air's
    share at pressure p is ``alpha r / (1 - alpha + alpha r)`` with r that power ratio (at most
    0.18 above 1 MPa), so ``a = alpha / (1 - alpha)`` to first order in ``alpha r``: without it
    the model's parameter would read 25 % high at alpha = 0.2.
    """
    return fraction / (1.0 - fraction)


def damping_ratio_parameter(start: float, prior: float | None,
                            grid: tuple[float, ...] = ()) -> Parameter:
    """Return the damping ratio [-] of a second-order motor speed loop as a parameter."""
    return Parameter('motor_damping_ratio', '-', start, 0.1, 5.0,
                     'damping ratio of the second-order motor speed loop', prior=prior,
                     grid=grid)


def baseline_parameters(params: HasParameters, speed_input: bool,
                        load_guess: float | None) -> tuple[Parameter, ...]:
    """E_y, L_n, B, motor lag, flow gain, dead volume (and a constant unmeasured load).

    Each but the load carries a prior from the parameter set: centred on its value, as
    wide as the set's stated uncertainty (:data:`DEFAULT_UNCERTAINTY` where it states
    none), so that the baseline takes up what is error of the nominal values and leaves
    the effects what is physics. A circuit with a rod chamber of its own adds its charge
    pressure and return conductance (and an accumulator's stiffness), a brake stated with
    an uncertainty its force. Without the motor's loop (``speed_input``: the measured speed
    drives the pump) its lag and damping ratio are left out; ``load_guess`` [N], where not
    None, starts a constant external load's fit.
    """
    p = params

    def prior(name: str) -> float | None:
        spread = p.uncertainty.get(name, DEFAULT_UNCERTAINTY.get(name))
        return None if spread is None else math.log1p(spread)

    out = [
        Parameter('bulk_modulus', 'Pa', p.bulk_modulus, 5e7, 3e9,
                  'effective bulk modulus E_y of oil, hose and seals',
                  prior=prior('bulk_modulus')),
        Parameter('pump_leakage', 'm^3/(s Pa)', p.pump_leakage, 1e-16, 1e-11,
                  'pump inner leakage coefficient L_n', prior=prior('pump_leakage'),
                  negligible_floor=True),
        Parameter('damping', 'N s/m', p.damping, 10.0, 1e5, 'viscous damping B',
                  prior=prior('damping'), negligible_floor=True),
        Parameter('motor_time_constant', 's', p.motor_time_constant,
                  p.motor_time_constant / 10.0, p.motor_time_constant * 10.0,
                  'time constant of the motor speed loop',
                  prior=prior('motor_time_constant')),
        Parameter('pump_displacement', 'm^3/rad', p.pump_displacement,
                  p.pump_displacement / 2.0, p.pump_displacement * 2.0,
                  'effective pump displacement: the flow gain, volumetric efficiency '
                  'included', prior=prior('pump_displacement')),
        Parameter('dead_volume', 'm^3', p.dead_volume, p.dead_volume / 5.0,
                  p.dead_volume * 5.0, 'oil volume of the rodless side at full retraction',
                  prior=prior('dead_volume')),
    ]
    if p.motor_damping_ratio > 0.0:  # the parameter set's loop is second order already
        out.append(damping_ratio_parameter(p.motor_damping_ratio,
                                           prior('motor_damping_ratio')))
    if speed_input:  # the measured speed drives the pump: no motor loop to fit
        out = [q for q in out if q.name not in ('motor_time_constant',
                                                'motor_damping_ratio')]
    if p.circuit != 'paper':
        spread = p.uncertainty.get('charge_pressure')
        out += [
            Parameter('charge_pressure', 'Pa', p.charge_pressure, -0.05e6,
                      max(10.0 * p.charge_pressure, 2e6), 'pressure of the charge line, '
                      'accumulator or tank the low-pressure chamber returns to',
                      scale=CHARGE_SCALE, prior=None if spread is None else
                      spread * max(p.charge_pressure, CHARGE_SCALE) / CHARGE_SCALE),
            Parameter('return_conductance', 'm^3/(s Pa)', p.return_conductance,
                      p.return_conductance / 100.0, p.return_conductance * 100.0,
                      "conductance of the low-pressure chamber's return path",
                      prior=prior('return_conductance'))]
        if p.charge_stiffness > 0.0:
            out.append(Parameter('charge_stiffness', 'Pa/m', p.charge_stiffness,
                                 p.charge_stiffness / 10.0, p.charge_stiffness * 10.0,
                                 "fall of the accumulator's pressure per metre of "
                                 'extension', prior=prior('charge_stiffness')))
    if p.brake_force > 0.0 and 'brake_force' in p.uncertainty:
        # A brake known only roughly (its file states an uncertainty) is fitted; one
        # stated exactly is held.
        out.append(Parameter('brake_force', 'N', p.brake_force, p.brake_force / 20.0,
                             p.brake_force * 20.0, 'force of the known brake',
                             prior=prior('brake_force')))
    if load_guess is not None:
        # Linear: a rig's load may be nil or pull (a horizontal cylinder, a spring).
        out.append(Parameter('load_force', 'N', load_guess, -p.peak_thrust,
                             2.0 * p.peak_thrust, 'constant external load force pushing '
                             'the cylinder in', scale=0.05 * p.peak_thrust))
    return tuple(out)


def candidate_parameters(params: HasParameters,
                         values: Candidate) -> tuple[HasParameters, float]:
    """Parameter set of a candidate on ``params`` and its transport delay [s].

    The nuisance parameters (:data:`NUISANCE`) and the effects' sizes in ``values`` replace
    those of ``params``; its effects are otherwise off.
    """
    p = params
    sizes = {k: float(values[k]) for k in ('coulomb_friction', 'pump_deadzone',
                                           'quadratic_leakage') if k in values}
    if 'entrained_air' in values:
        sizes['entrained_air'] = model_air_fraction(float(values['entrained_air']))
    if 'relief_crack_pressure' in values:
        sizes['relief_crack_pressure'] = float(values['relief_crack_pressure'])
        sizes['relief_crack_conductance'] = float(
            values.get('relief_crack_conductance', RELIEF_CRACK_CONDUCTANCE))
    nuisance: dict[str, Any] = {name: float(values.get(name, getattr(p, name)))
                                for name in NUISANCE}
    delay = float(values.get('transport_delay', 0.0))
    return replace(p, **nuisance, effects=Effects(**sizes)), delay
