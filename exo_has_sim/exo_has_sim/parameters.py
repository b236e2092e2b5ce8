"""HAS parameter sets (hip, knee) with the provenance of every value.

The sets live in ``config/<joint type>.yaml``, in the ROS 2 parameters-file format so that a plant
node can take them with ``--params-file``: values under ``/**: ros__parameters: has:`` and, beside
them, the provenance of each value under ``provenance:`` (a node ignores what it does not
declare). Every value is SI (REP 103). Loading checks that every value is present, finite and
within a plausible range for its unit, so that a value written in mm, r/min, bar or mL fails with
a message naming it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from exo_has_common.errors import CommandLineError
from exo_has_common.joints import JOINT_TYPES
from exo_has_common.params_yaml import read_yaml_file
from exo_has_sim.errors import ParameterError


def _config_dir() -> Path:
    """Return the folder of the joint types' parameter files.

    Beside the package in the source tree (where colcon's ``--symlink-install`` leaves it
    too); else where setup.py's ``data_files`` put it under the prefix the package was
    installed into, ``<prefix>/lib/pythonX.Y/site-packages/exo_has_sim`` (pip, and colcon
    without symlinks): ``<prefix>/share/exo_has_sim/config``.
    """
    package = Path(__file__).resolve().parent
    source = package.parent / 'config'
    if source.is_dir() or len(package.parents) < 4:
        return source
    installed = package.parents[3] / 'share' / 'exo_has_sim' / 'config'
    return installed if installed.is_dir() else source


#: The joint types' parameter files (``hip.yaml``, ``knee.yaml``).
CONFIG_DIR = _config_dir()
#: Hydraulic circuits a parameter set can describe (:attr:`HasParameters.circuit`).
CIRCUITS = ('paper', 'two_chamber', 'closed', 'switched')
#: Values a parameters file may leave out, and what they then are: the paper's HAS (its
#: circuit, no torque limit modelled, no brake). A file of another rig states its own.
OPTIONAL_VALUES: dict[str, Any] = {
    'motor_damping_ratio': 0.0, 'circuit': 'paper', 'rod_dead_volume': 8.0e-6,
    'charge_pressure': 0.0, 'charge_stiffness': 0.0, 'return_conductance': 1.0e-10,
    'motor_inertia': 0.0,
    'brake_force': 0.0, 'brake_velocity': 0.005}
#: Largest relative standard uncertainty a parameters file may state (500 %).
MAX_UNCERTAINTY = 5.0


@dataclass(frozen=True)
class Effects:
    """Effects of real hardware that the paper's model leaves out; all off by default.

    An effect is on when its size is non-zero. Friction is Coulomb plus a Stribeck peak,
    smoothed with tanh(v / friction_smoothing_velocity).

    Attributes
    ----------
    coulomb_friction : float
        Seal Coulomb friction force [N].
    stribeck_friction : float
        Static friction peak above the Coulomb level [N] (needs coulomb_friction on).
    stribeck_velocity : float
        Velocity scale of the Stribeck decay [m/s].
    friction_smoothing_velocity : float
        Velocity below which friction is smoothed to zero [m/s].
    pump_deadzone : float
        Motor speed below which the flow matching valve has not switched and the pump delivers
        no flow to the cylinder [rad/s].
    transport_delay : float
        Delay of the motor-speed command before the drive acts on it [s].
    quadratic_leakage : float
        Pressure-squared pump leakage coefficient [m^3/(s Pa^2)].
    relief_crack_pressure : float
        Pressure at which the safety valve starts to open below its setting [Pa].
    relief_crack_conductance : float
        Flow conductance of the valve between cracking and its setting [m^3/(s Pa)].
    entrained_air : float
        Volume fraction of free air in the oil at atmospheric pressure [-].

    """

    coulomb_friction: float = 0.0
    stribeck_friction: float = 0.0
    stribeck_velocity: float = 0.005
    friction_smoothing_velocity: float = 0.001
    pump_deadzone: float = 0.0
    transport_delay: float = 0.0
    quadratic_leakage: float = 0.0
    relief_crack_pressure: float = 0.0
    relief_crack_conductance: float = 0.0
    entrained_air: float = 0.0

    @property
    def enabled(self) -> list[str]:
        """Names of the effects that are on."""
        names = []
        if self.coulomb_friction:
            names.append('coulomb_friction')
        if self.pump_deadzone:
            names.append('pump_deadzone')
        if self.transport_delay:
            names.append('transport_delay')
        if self.quadratic_leakage:
            names.append('quadratic_leakage')
        if self.relief_crack_pressure:
            names.append('relief_valve')
        if self.entrained_air:
            names.append('entrained_air')
        return names


@dataclass(frozen=True)
class HasParameters:
    """Physical parameters of one HAS and its joint linkage, SI units.

    The names follow Sun et al. (2021): D_p pump_displacement, L_n pump_leakage, L_c
    cylinder_leakage, E_y bulk_modulus, A_A and A_B from the bore and rod diameters, V_A
    dead_volume, M_a piston_mass, M_L load_mass, B damping.

    The motor's speed loop is first order with ``motor_time_constant`` (the paper's), or, when
    ``motor_damping_ratio`` is positive, second order with that damping ratio and the same
    low-frequency lag: natural frequency ``2 zeta / motor_time_constant``. With a positive
    ``motor_inertia`` (a first-order loop), the motor's torque is limited to
    ``motor_torque_peak``: the loop's acceleration then stops where the torque, inertia and
    the pump's load ``D_p dp / eta`` included, would exceed it (a drive's current limit).

    ``circuit`` says how the pump meets the cylinder (:data:`CIRCUITS`, and
    :mod:`exo_has_sim.model` for the flows): ``'paper'``, the paper's (the pump between the
    tank and the rodless chamber, the rod side open to the tank: section 3.3's p_B = 0);
    ``'two_chamber'``, the same pump with the rod side a chamber of its own, returning to the
    tank through a line of ``return_conductance`` (the paper's Eq. 5 kept); ``'closed'``, the
    pump between the two chambers (its Eqs. 2-7 as written), a flow matching valve joining the
    lower-pressure chamber to the charge pressure; ``'switched'``, a one-way pump whose flow
    direction valves send to A or B while the other chamber drains to an accumulator at
    ``charge_pressure`` (at mid stroke; an accumulator's falls by ``charge_stiffness`` [Pa/m]
    as the cylinder extends and takes up the rod's volume of its oil, ``kappa (p + p_atm)
    (A_A - A_B) / V_gas``). ``brake_force`` is a load known to resist the motion both ways (a
    brake or throttled load cylinder on a test rig): ``F_b tanh(v / brake_velocity)``.
    A parameters file may leave the values of :data:`OPTIONAL_VALUES` out.
    """

    joint_type: str
    pump_displacement: float
    motor_speed_max: float
    motor_time_constant: float
    motor_torque_nominal: float
    motor_torque_peak: float
    pump_mechanical_efficiency: float
    pump_leakage: float
    cylinder_leakage: float
    bulk_modulus: float
    bore_diameter: float
    rod_diameter: float
    stroke: float
    dead_volume: float
    piston_mass: float
    load_mass: float
    damping: float
    max_working_pressure: float
    relief_pressure: float
    relief_conductance: float
    free_conductance: float
    valve_engage_speed: float
    valve_release_speed: float
    valve_hold_pressure: float
    valve_drop_pressure: float
    valve_time_constant: float
    cavitation_pressure: float
    end_stop_stiffness: float
    end_stop_damping: float
    control_rate: float
    peak_thrust: float
    no_load_speed: float
    walking_stroke: float
    link_ac: float
    link_co: float
    link_bd: float
    link_od: float
    angle_offset: float
    cylinder_length_min: float
    motor_damping_ratio: float = 0.0
    circuit: str = 'paper'
    rod_dead_volume: float = 8.0e-6
    charge_pressure: float = 0.0
    charge_stiffness: float = 0.0
    return_conductance: float = 1.0e-10
    motor_inertia: float = 0.0
    brake_force: float = 0.0
    brake_velocity: float = 0.005
    effects: Effects = field(default_factory=Effects)
    provenance: Mapping[str, str] = field(default_factory=dict, compare=False)
    uncertainty: Mapping[str, float] = field(default_factory=dict, compare=False)

    @property
    def area_a(self) -> float:
        """Rodless (piston) area A_A [m^2]."""
        return math.pi / 4.0 * self.bore_diameter ** 2

    @property
    def area_b(self) -> float:
        """Rod-side annulus area A_B [m^2]."""
        return math.pi / 4.0 * (self.bore_diameter ** 2 - self.rod_diameter ** 2)

    @property
    def flow_area(self) -> float:
        """Area whose motion the rodless chamber's flow balance counts [m^2]: A_A (Eq. 4).

        The rodless chamber fills and empties at ``A_A v`` whatever the rod side does: in the
        paper's circuit the rod side returns to the tank and the flow matching valve makes up
        the pump's inlet from it (2.2, 2.3.3). The paper's Eq. 10 divides by the average
        ``(A_A + A_B) / 2`` instead, having added the rod side's balance as if it fed the pump
        (:func:`exo_has_sim.linear.averaged_flow_area` gives its Eqs. 12-14 as printed). Data
        can hardly tell the two apart: scaling every flow alike changes no prediction but
        through the prior on the pump displacement and the compact valve's free-mode flow.
        What the area does change is the size of a flow law that a diagnosis names (a
        quadratic leakage, entrained air), which comes out in proportion to it
        (bench/README.md, "The flow area").
        """
        return self.area_a

    @property
    def moving_mass(self) -> float:
        """M = M_a + M_L [kg]."""
        return self.piston_mass + self.load_mass

    def with_effects(self, **sizes: float) -> HasParameters:
        """Return a copy with the given effects set (names of :class:`Effects`)."""
        return replace(self, effects=replace(self.effects, **sizes))

    def replace(self, **values: Any) -> HasParameters:
        """Return a copy with some values replaced, checked as on loading."""
        changed = replace(self, **values)
        check_parameters(changed)
        return changed


# Plausible range of every value, in its SI unit: a value outside names a likely unit mistake.
_RANGES: dict[str, tuple[float, float, str]] = {
    'pump_displacement': (1e-9, 1e-5, 'm^3/rad (0.4 mL/r is 6.37e-8)'),
    'motor_speed_max': (10.0, 2000.0, 'rad/s (4000 r/min is 418.9)'),
    'motor_time_constant': (1e-4, 0.5, 's'),
    'motor_damping_ratio': (0.0, 5.0, '- (0: a first-order speed loop)'),
    'rod_dead_volume': (1e-8, 1e-3, 'm^3'),
    'charge_pressure': (0.0, 1e7, 'Pa (gauge)'),
    'charge_stiffness': (0.0, 1e10, 'Pa/m'),
    'return_conductance': (1e-13, 1e-7, 'm^3/(s Pa)'),
    'motor_inertia': (0.0, 1.0, 'kg m^2 (0: no torque limit modelled)'),
    'brake_force': (0.0, 1e6, 'N'),
    'brake_velocity': (1e-5, 1.0, 'm/s'),
    'motor_torque_nominal': (0.01, 100.0, 'N m'),
    'motor_torque_peak': (0.01, 100.0, 'N m'),
    'pump_mechanical_efficiency': (0.1, 1.0, '-'),
    'pump_leakage': (0.0, 1e-10, 'm^3/(s Pa)'),
    'cylinder_leakage': (0.0, 1e-10, 'm^3/(s Pa)'),
    'bulk_modulus': (1e7, 3e9, 'Pa'),
    'bore_diameter': (0.004, 0.2, 'm'),
    'rod_diameter': (0.002, 0.15, 'm'),
    'stroke': (0.01, 1.0, 'm'),
    'dead_volume': (1e-8, 1e-3, 'm^3'),
    'piston_mass': (0.0, 100.0, 'kg'),
    'load_mass': (0.0, 1000.0, 'kg'),
    'damping': (0.0, 1e6, 'N s/m'),
    'max_working_pressure': (1e6, 1e8, 'Pa'),
    'relief_pressure': (1e6, 1e8, 'Pa'),
    'relief_conductance': (1e-13, 1e-7, 'm^3/(s Pa)'),
    'free_conductance': (1e-13, 1e-7, 'm^3/(s Pa)'),
    'valve_engage_speed': (0.0, 200.0, 'rad/s'),
    'valve_release_speed': (0.0, 200.0, 'rad/s'),
    'valve_hold_pressure': (0.0, 10.0e6, 'Pa'),
    'valve_drop_pressure': (0.0, 10.0e6, 'Pa'),
    'valve_time_constant': (1e-4, 1.0, 's'),
    'cavitation_pressure': (-1.0e5, 0.0, 'Pa (gauge)'),
    'end_stop_stiffness': (1e4, 1e10, 'N/m'),
    'end_stop_damping': (0.0, 1e7, 'N s/m'),
    'control_rate': (1.0, 10000.0, 'Hz'),
    'peak_thrust': (1.0, 1e6, 'N'),
    'no_load_speed': (1e-3, 10.0, 'm/s'),
    'walking_stroke': (1e-3, 1.0, 'm'),
    'link_ac': (0.0, 2.0, 'm'),
    'link_co': (0.0, 2.0, 'm'),
    'link_bd': (0.0, 2.0, 'm'),
    'link_od': (0.0, 2.0, 'm'),
    'angle_offset': (-2 * math.pi, 2 * math.pi, 'rad'),
    'cylinder_length_min': (0.01, 2.0, 'm'),
}
#: Values that are names, not numbers.
_TEXT_VALUES = ('joint_type', 'circuit')
_EFFECT_RANGES: dict[str, tuple[float, float, str]] = {
    'coulomb_friction': (0.0, 5e3, 'N'),
    'stribeck_friction': (0.0, 5e3, 'N'),
    'stribeck_velocity': (1e-5, 1.0, 'm/s'),
    'friction_smoothing_velocity': (1e-6, 0.1, 'm/s'),
    'pump_deadzone': (0.0, 200.0, 'rad/s'),
    'transport_delay': (0.0, 0.5, 's'),
    'quadratic_leakage': (0.0, 1e-16, 'm^3/(s Pa^2)'),
    'relief_crack_pressure': (0.0, 1e8, 'Pa'),
    'relief_crack_conductance': (0.0, 1e-7, 'm^3/(s Pa)'),
    'entrained_air': (0.0, 0.2, '-'),
}


def _check_value(where: str, name: str, value: object,
                 ranges: Mapping[str, tuple[float, float, str]], prefix: str = '') -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        msg = f'{where}: {prefix}{name} must be a number, got {value!r}'
        raise ParameterError(msg)
    number = float(value)
    low, high, unit = ranges[name]
    name = prefix + name
    if not math.isfinite(number) or not low <= number <= high:
        msg = (f'{where}: {name} = {value!r} is outside [{low:g}, {high:g}] {unit}; '
               'check the unit (SI throughout)')
        raise ParameterError(msg)
    return number


def check_parameters(params: HasParameters, where: str = 'parameters') -> None:
    """Check every value's range and the relations between values.

    Raises
    ------
    ParameterError
        Naming the first value out of range or the relation violated.

    """
    for name in _RANGES:
        _check_value(where, name, getattr(params, name), _RANGES)
    for name in _EFFECT_RANGES:
        _check_value(where, name, getattr(params.effects, name), _EFFECT_RANGES, 'effects.')
    if params.joint_type not in JOINT_TYPES:
        msg = f'{where}: joint_type {params.joint_type!r} is not one of {JOINT_TYPES}'
        raise ParameterError(msg)
    if params.circuit not in CIRCUITS:
        msg = f'{where}: circuit {params.circuit!r} is not one of {", ".join(CIRCUITS)}'
        raise ParameterError(msg)
    if params.rod_diameter >= params.bore_diameter:
        msg = f'{where}: rod_diameter must be smaller than bore_diameter'
        raise ParameterError(msg)
    if params.relief_pressure < params.max_working_pressure:
        msg = f'{where}: relief_pressure must not be below max_working_pressure'
        raise ParameterError(msg)
    if params.valve_release_speed >= params.valve_engage_speed:
        msg = f'{where}: valve_release_speed must be below valve_engage_speed'
        raise ParameterError(msg)
    if params.valve_drop_pressure >= params.valve_hold_pressure:
        msg = f'{where}: valve_drop_pressure must be below valve_hold_pressure'
        raise ParameterError(msg)
    crack = params.effects.relief_crack_pressure
    if crack and not 0.0 < crack < params.relief_pressure:
        msg = f'{where}: effects.relief_crack_pressure must lie below relief_pressure'
        raise ParameterError(msg)


def parameters_from_mapping(values: Mapping[str, Any], provenance: Mapping[str, str],
                            where: str,
                            uncertainty: Mapping[str, Any] | None = None) -> HasParameters:
    """Build and check a parameter set from the ``has`` mapping of a parameters file.

    ``uncertainty`` holds the relative standard uncertainty of values known only roughly
    (0.3: +-30 %), as the file's ``uncertainty:`` section states it; a diagnosis takes it as
    the spread of its prior on that value.
    """
    names = [f.name for f in fields(HasParameters)
             if f.name not in ('effects', 'provenance', 'uncertainty')]
    values = {**OPTIONAL_VALUES, **values}
    missing = [name for name in names if name not in values]
    unknown = sorted(set(values) - {*names, 'effects'})
    if missing:
        msg = f'{where}: missing {", ".join(missing)}'
        raise ParameterError(msg)
    if unknown:
        msg = f'{where}: unknown parameter {", ".join(unknown)}'
        raise ParameterError(msg)
    effect_values = values.get('effects') or {}
    if not isinstance(effect_values, Mapping):
        msg = f'{where}: effects must be a mapping'
        raise ParameterError(msg)
    unknown_effects = sorted(set(effect_values) - {f.name for f in fields(Effects)})
    if unknown_effects:
        msg = f'{where}: unknown effect {", ".join(unknown_effects)}'
        raise ParameterError(msg)
    for name, value in effect_values.items():
        _check_value(where, name, value, _EFFECT_RANGES, 'effects.')
    effects = Effects(**{k: float(v) for k, v in effect_values.items()})
    numbers = {name: values[name] for name in names if name not in _TEXT_VALUES}
    for name, value in numbers.items():
        _check_value(where, name, value, _RANGES)
    spreads = dict(uncertainty or {})
    for name, value in spreads.items():
        if name not in numbers:
            msg = f'{where}: uncertainty of an unknown parameter {name!r}'
            raise ParameterError(msg)
        if isinstance(value, bool) or not isinstance(value, (int, float)) \
                or not 0.0 < float(value) <= MAX_UNCERTAINTY:
            msg = (f'{where}: uncertainty.{name} must be a relative standard uncertainty in '
                   f'(0, {MAX_UNCERTAINTY:g}] (0.3 for +-30 %), got {value!r}')
            raise ParameterError(msg)
    params = HasParameters(joint_type=str(values['joint_type']), circuit=str(values['circuit']),
                           effects=effects,
                           provenance=dict(provenance),
                           uncertainty={k: float(v) for k, v in spreads.items()},
                           **{k: float(v) for k, v in numbers.items()})
    check_parameters(params, where)
    return params


def load_parameters(source: str | Path) -> HasParameters:
    """Load a parameter set: ``'hip'``, ``'knee'`` or the path of a parameters file.

    Raises
    ------
    ParameterError
        If the file cannot be read, has not the expected layout, or a value is missing, unknown
        or implausible.

    """
    path = CONFIG_DIR / f'{source}.yaml' if source in JOINT_TYPES else Path(source)
    try:
        document: Any = read_yaml_file(path)
    except CommandLineError as exc:
        raise ParameterError(str(exc)) from exc
    try:
        section = document['/**']['ros__parameters']
        values = section['has']
    except (KeyError, TypeError) as exc:
        msg = f'{path}: expected /**: ros__parameters: has: {{...}} (a ROS 2 parameters file)'
        raise ParameterError(msg) from exc
    uncertainty = section.get('uncertainty') or {}
    if not isinstance(uncertainty, Mapping):
        msg = f'{path}: uncertainty must be a mapping of parameter names to relative spreads'
        raise ParameterError(msg)
    return parameters_from_mapping(values, section.get('provenance') or {}, str(path),
                                   uncertainty)
