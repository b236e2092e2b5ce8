"""The library of physical effects a diagnosis can add to a model, with their parameters.

Each effect is an extension of the plant with parameters of its own; the first parameter is the
effect's size, which a diagnosis reports. For the HAS the extensions are those of
:class:`exo_has_sim.parameters.Effects` (the model of issue 3 carries them, off by default); for
the mass plant, Coulomb friction, a delay of the force and a force dead zone.

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

from dataclasses import dataclass

import numpy as np

from exo_has_sim.diagnosis.plants import Parameter
from exo_has_sim.errors import DiagnosisError
from exo_has_sim.parameters import HasParameters

#: Starting conductance of a cracked safety valve [m^3/(s Pa)] (0.12 L/min per MPa).
RELIEF_CRACK_CONDUCTANCE = 2.0e-12


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
        Plants it applies to.
    grows_with_size : bool
        Whether a larger size is a stronger effect (not so for a crack pressure).
    through_pressure : bool
        Whether it acts on the HAS's motion only through the rodless pressure: a force
        (friction) that the pressure balances, or a flow law of the pressure (a leakage, a
        valve, the oil's stiffness). Without a pressure or a load-force signal an unmeasured
        load that varies can make any pressure, so such an effect is not identifiable from
        the command and the position alone (:attr:`HasPlant.unidentifiable`).

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
           'seal friction F_c tanh(v / 1 mm/s) opposing the motion (HAS); F_c sign(v) with '
           'stiction (mass plant)',
           'a step in the force (pressure) residual with the sign of the velocity, largest '
           'at direction reversals', 'coulomb_friction', 'N', ('has', 'mass'),
           through_pressure=True),
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


def _geometric(low: float, high: float, count: int = 6) -> tuple[float, ...]:
    return tuple(float(v) for v in np.geomspace(low, high, count))


def has_effect_parameters(effect: str, params: HasParameters) -> tuple[Parameter, ...]:
    """Parameters of an effect in the HAS model (the size first), with search bounds.

    The size's grid spans what a fault of a small EHA plausibly is (screening only; the fit
    searches the wider bounds).

    Raises
    ------
    DiagnosisError
        For an unknown effect.

    """
    relief = params.relief_pressure
    thrust = params.peak_thrust
    top = params.motor_speed_max
    table = {
        'coulomb_friction': (Parameter('coulomb_friction', 'N', 0.02 * thrust, 0.5, thrust,
                                       'seal Coulomb friction F_c',
                                       grid=_geometric(0.005 * thrust, 0.15 * thrust)),),
        'pump_deadzone': (Parameter('pump_deadzone', 'rad/s', 0.02 * top, 0.05, 0.25 * top,
                                    'pump dead zone n_dz',
                                    grid=_geometric(0.005 * top, 0.15 * top)),),
        'transport_delay': (Parameter('transport_delay', 's', 0.005, 1e-5, 0.1,
                                      'command transport delay',
                                      grid=_geometric(0.001, 0.04)),),
        'quadratic_leakage': (Parameter('quadratic_leakage', 'm^3/(s Pa^2)', 5e-21, 1e-24,
                                        1e-17, 'quadratic pump leakage L_n2',
                                        grid=_geometric(3e-22, 1e-19, 7)),),
        'relief_valve': (Parameter('relief_crack_pressure', 'Pa', 0.6 * relief,
                                   0.05 * relief, 0.995 * relief,
                                   'crack pressure of the safety valve',
                                   grid=tuple(float(f) * relief for f in
                                              np.linspace(0.3, 0.9, 7))),
                         Parameter('relief_crack_conductance', 'm^3/(s Pa)',
                                   RELIEF_CRACK_CONDUCTANCE, 1e-14, 1e-9,
                                   'conductance of the cracked safety valve')),
        'entrained_air': (Parameter('entrained_air', '-', 0.02, 1e-4, 0.5,
                                    'free-air volume fraction at atmospheric pressure',
                                    grid=_geometric(0.003, 0.3, 7)),),
    }
    if effect not in table:
        msg = f'no effect {effect!r} for the HAS; known: {", ".join(table)}'
        raise DiagnosisError(msg)
    return table[effect]


def mass_effect_parameters(effect: str, force_max: float) -> tuple[Parameter, ...]:
    """Parameters of an effect in the mass plant, bounds scaled by the largest force [N].

    Raises
    ------
    DiagnosisError
        For an effect the mass plant does not have.

    """
    top = max(force_max, 1e-6)
    table = {
        'coulomb_friction': (Parameter('coulomb_friction', 'N', 0.05 * top, 1e-4 * top, top,
                                       'Coulomb friction F_c',
                                       grid=_geometric(0.005 * top, 0.3 * top)),),
        'transport_delay': (Parameter('transport_delay', 's', 0.005, 1e-5, 0.1,
                                      'delay of the force', grid=_geometric(0.001, 0.04)),),
        'pump_deadzone': (Parameter('pump_deadzone', 'N', 0.05 * top, 1e-4 * top, top,
                                    'force dead zone', grid=_geometric(0.005 * top, 0.3 * top)),),
    }
    if effect not in table:
        msg = f'no effect {effect!r} for the mass plant; known: {", ".join(table)}'
        raise DiagnosisError(msg)
    return table[effect]
