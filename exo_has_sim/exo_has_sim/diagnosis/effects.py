"""The library of physical effects a diagnosis can add to a model, with their parameters.

Each effect is an extension of the plant with parameters of its own; the first parameter is the
effect's size, which a diagnosis reports. For the HAS the extensions are those of
:class:`exo_has_sim.parameters.Effects` (the model of issue 3 carries them, off by default) and
a braking load (the model's brake, :attr:`exo_has_sim.parameters.HasParameters.brake_force`);
for the mass plant, Coulomb friction, a delay of the force and a force dead zone. A size's grid
(what screening tries) and bounds come from the parameter set and, where the record shows it,
from the record itself (:class:`RecordRange`): a relief valve can only show cracking below the
pressures the record reaches, and no force can resist the motion beyond what the record's
pressures push with.

The relief valve. A safety valve that cracks below its setting passes
``G_crack (min(p, p_relief) - p_crack)`` once the pressure exceeds the crack pressure. Both the
crack pressure and the conductance of the cracked valve are unknown on a real HAS (a weeping
valve is as much a fault of the seat as of the spring), and the pressure range of a record
above the crack pressure determines both: the flow's threshold and its slope. The effect
therefore fits both, the crack pressure being its size; :data:`RELIEF_CRACK_CONDUCTANCE` is
only the fit's starting value (a weeping valve passing the pump's full flow 13 MPa above
cracking).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from exo_has_sim.diagnosis.plants import Parameter
from exo_has_sim.errors import DiagnosisError
from exo_has_sim.parameters import HasParameters

#: Starting conductance of a cracked safety valve [m^3/(s Pa)] (0.12 L/min per MPa).
RELIEF_CRACK_CONDUCTANCE = 2.0e-12
#: Largest seal friction a cylinder can have per metre of sealed circumference (the piston's
#: and the rod's) [N/m]: a generous bound, several times what common seal sets give at their
#: working pressure. Seal friction grows with the seals' length, not with the bore's area as
#: the thrust does: 276 N for the project's 14/8 mm cylinder, 980 N for a 50/28 mm one. The
#: Coulomb friction's search ends there and a braking load's begins.
SEAL_FRICTION_PER_METRE = 4000.0


def seal_friction_limit(params: HasParameters) -> float:
    """Return the largest seal friction [N] of the cylinder (:data:`SEAL_FRICTION_PER_METRE`)."""
    return SEAL_FRICTION_PER_METRE * math.pi * (params.bore_diameter + params.rod_diameter)


@dataclass(frozen=True)
class Effect:
    """One physical effect of the library.

    Attributes
    ----------
    id : str
        Identifier, as in the JSON output and ``exo_has_sim.parameters.Effects``.
    title : str
        Short name.
    physics : str
        How it extends the model.
    signature : str
        What it does to the residuals of a model without it.
    size : str
        Name of the parameter that is the effect's size.
    unit : str
        SI unit of the size.
    plants : tuple[str, ...]
        Kinds of plant it applies to (``'has'``, ``'mass'``): the one statement of which
        effects a plant has (:func:`effects_of`).
    grows_with_size : bool
        Whether a larger size is a stronger effect (not so for a crack pressure).
    through_pressure : bool
        Whether it acts on the HAS's motion only through the rodless pressure: a force
        (friction) that the pressure balances, or a flow law of the pressure (a leakage, a
        valve, the oil's stiffness). Without a pressure or a load-force signal an unmeasured
        load that varies can make any pressure, so such an effect is not identifiable from
        the command and the position alone
        (:attr:`~exo_has_sim.diagnosis.has_plant.HasPlant.unidentifiable`).

    """

    id: str
    title: str
    physics: str
    signature: str
    size: str
    unit: str
    plants: tuple[str, ...]
    grows_with_size: bool = True
    through_pressure: bool = False


EFFECTS: dict[str, Effect] = {e.id: e for e in (
    Effect('coulomb_friction', 'Coulomb friction',
           'seal friction F_c tanh(v / 1 mm/s) opposing the motion (HAS), up to what seals '
           'can give (4 N per mm of sealed circumference); F_c sign(v) with stiction (mass '
           'plant)',
           'a step in the force (pressure) residual with the sign of the velocity, largest '
           'at direction reversals', 'coulomb_friction', 'N', ('has', 'mass'),
           through_pressure=True),
    Effect('braking_load', 'braking load',
           'a load resisting the motion both ways, F_b tanh(v / v_b) (v_b the parameter '
           "set's brake_velocity): a brake, a throttled load cylinder; beyond what seal "
           'friction can be (from 4 N per mm of sealed circumference up to the force the '
           "record's pressures push with), so it is not called friction",
           'a force step with the sign of the velocity, as friction gives, but larger than any '
           'seal', 'brake_force', 'N', ('has',), through_pressure=True),
    Effect('pump_deadzone', 'pump dead zone',
           'no flow while |n| < n_dz (the flow matching valve has not switched), '
           'n - n_dz sign(n) beyond it (HAS); a force dead zone on the input (mass plant)',
           'a velocity residual against the sign of the command, largest for small commands',
           'pump_deadzone', 'rad/s (HAS), N (mass plant)', ('has', 'mass')),
    Effect('transport_delay', 'transport delay',
           'the drive acts on the command (the mass on the force) a delay after it was sent',
           "a residual correlated with the input's rate; the cross-correlation of residual "
           'and input peaks at a positive lag', 'transport_delay', 's', ('has', 'mass')),
    Effect('quadratic_leakage', 'quadratic leakage',
           'an extra pump leakage L_n2 p|p| (turbulent gaps)',
           'a velocity residual growing with the square of the pressure', 'quadratic_leakage',
           'm^3/(s Pa^2)', ('has',), through_pressure=True),
    Effect('relief_valve', 'relief valve cracking below its setting',
           'the safety valve passes G_crack (min(p, p_relief) - p_crack) above p_crack',
           'a velocity residual that appears only above a pressure threshold',
           'relief_crack_pressure', 'Pa', ('has',), grows_with_size=False,
           through_pressure=True),
    Effect('entrained_air', 'entrained air',
           'free air in the oil (volume fraction alpha at atmospheric pressure) compressed '
           'adiabatically: a bulk modulus that falls at low pressure',
           'a pressure residual at low pressure where the pressure changes fast (too stiff a '
           'model there)', 'entrained_air', '-', ('has',), through_pressure=True),
)}


def effects_of(kind: str) -> tuple[str, ...]:
    """Return the ids of the effects that apply to a kind of plant, in :data:`EFFECTS`'s order.

    The plants take their effects from here, and their parameter tables
    (:func:`has_effect_table`, :func:`mass_effect_table`) have a row for each, in this order.
    """
    return tuple(effect.id for effect in EFFECTS.values() if kind in effect.plants)


def effect_title(effect: str) -> str:
    """Human name of an effect id (or the id itself)."""
    return EFFECTS[effect].title if effect in EFFECTS else effect


def _geometric(low: float, high: float, count: int = 6) -> tuple[float, ...]:
    return tuple(float(v) for v in np.geomspace(low, high, count))


@dataclass(frozen=True)
class RecordRange:
    """What a record shows of the HAS's pressures and forces (None: not measured).

    Attributes
    ----------
    pressure : float or None
        The rodless pressure the record reaches [Pa] (its 99th percentile).
    force : float or None
        The hydraulic force the record's pressures push with [N] (99th percentile of
        ``|A_A p_A - A_B p_B|``).

    """

    pressure: float | None = None
    force: float | None = None


def has_effect_table(params: HasParameters,
                     record: RecordRange = RecordRange()) -> dict[str, tuple[Parameter, ...]]:
    """Parameters of each HAS effect (the size first), with search bounds, by effect id.

    A row for each of ``effects_of('has')``, in its order. The size's grid spans what a fault
    of a small EHA plausibly is and what the record can show (screening only; the fit
    searches the wider bounds): a crack pressure from a tenth of the pressure the record
    reaches to just below it (the setting's 30-90 % without a pressure signal), a friction
    up to what a seal can give (:func:`seal_friction_limit`) and a braking load from there
    up to the force the record's pressures push with.
    """
    relief = params.relief_pressure
    thrust = params.peak_thrust
    top = params.motor_speed_max
    seal = seal_friction_limit(params)
    reached = relief if record.pressure is None else min(max(record.pressure, 0.05 * relief),
                                                          relief)
    cracks = np.linspace(0.3, 0.9, 7) * relief if record.pressure is None \
        else np.linspace(0.1, 0.95, 7) * reached
    pushed = max(thrust if record.force is None else record.force, 2.0 * seal)
    return {
        'coulomb_friction': (Parameter('coulomb_friction', 'N', min(0.02 * thrust, 0.5 * seal),
                                       0.5, seal, 'seal Coulomb friction F_c',
                                       grid=_geometric(0.005 * thrust,
                                                       min(0.15 * thrust, seal))),),
        'braking_load': (Parameter('brake_force', 'N', 2.0 * seal, seal, 2.0 * pushed,
                                   'force of a load resisting the motion both ways',
                                   grid=_geometric(seal, pushed, 5)),),
        'pump_deadzone': (Parameter('pump_deadzone', 'rad/s', 0.02 * top, 0.05, 0.25 * top,
                                    'pump dead zone n_dz',
                                    grid=_geometric(0.005 * top, 0.15 * top)),),
        # Eleven points, not six: a delay's fit has a basin at every few samples, and from
        # the coarser grid's 2.1 ms a 6.4 ms delay's fit stopped at 2.5 ms.
        'transport_delay': (Parameter('transport_delay', 's', 0.005, 1e-5, 0.1,
                                      'command transport delay',
                                      grid=_geometric(0.001, 0.04, 11)),),
        'quadratic_leakage': (Parameter('quadratic_leakage', 'm^3/(s Pa^2)', 5e-21, 1e-24,
                                        1e-17, 'quadratic pump leakage L_n2',
                                        grid=_geometric(3e-22, 1e-19, 7)),),
        'relief_valve': (Parameter('relief_crack_pressure', 'Pa', float(cracks[3]),
                                   0.02 * relief, 0.995 * relief,
                                   'crack pressure of the safety valve',
                                   grid=tuple(float(c) for c in cracks)),
                         Parameter('relief_crack_conductance', 'm^3/(s Pa)',
                                   RELIEF_CRACK_CONDUCTANCE, 1e-14, 1e-9,
                                   'conductance of the cracked safety valve')),
        'entrained_air': (Parameter('entrained_air', '-', 0.02, 1e-4, 0.5,
                                    'free-air volume fraction at atmospheric pressure',
                                    grid=_geometric(0.003, 0.3, 7)),),
    }


def has_effect_parameters(effect: str, params: HasParameters,
                          record: RecordRange = RecordRange()) -> tuple[Parameter, ...]:
    """Parameters of an effect in the HAS model (the size first) (:func:`has_effect_table`).

    Raises
    ------
    DiagnosisError
        For an unknown effect.

    """
    table = has_effect_table(params, record)
    if effect not in table:
        msg = f'no effect {effect!r} for the HAS; known: {", ".join(table)}'
        raise DiagnosisError(msg)
    return table[effect]


def mass_effect_table(force_max: float) -> dict[str, tuple[Parameter, ...]]:
    """Parameters of each mass-plant effect, bounds scaled by the largest force [N], by id.

    A row for each of ``effects_of('mass')``, in its order.
    """
    top = max(force_max, 1e-6)
    return {
        'coulomb_friction': (Parameter('coulomb_friction', 'N', 0.05 * top, 1e-4 * top, top,
                                       'Coulomb friction F_c',
                                       grid=_geometric(0.005 * top, 0.3 * top)),),
        'pump_deadzone': (Parameter('pump_deadzone', 'N', 0.05 * top, 1e-4 * top, top,
                                    'force dead zone', grid=_geometric(0.005 * top, 0.3 * top)),),
        'transport_delay': (Parameter('transport_delay', 's', 0.005, 1e-5, 0.1,
                                      'delay of the force', grid=_geometric(0.001, 0.04)),),
    }


def mass_effect_parameters(effect: str, force_max: float) -> tuple[Parameter, ...]:
    """Parameters of an effect in the mass plant (:func:`mass_effect_table`).

    Raises
    ------
    DiagnosisError
        For an effect the mass plant does not have.

    """
    table = mass_effect_table(force_max)
    if effect not in table:
        msg = f'no effect {effect!r} for the mass plant; known: {", ".join(table)}'
        raise DiagnosisError(msg)
    return table[effect]
