"""Conversions between the SI units of the HAS messages and the raw units on the CAN bus.

Drive side (:class:`DriveUnits`): the pump speed [rad/s] of ``HasCommand.motor_speed`` and
``HasState.motor_speed`` against the drive's velocity unit (COPLEY: 0.1 encoder counts/s) through
the encoder resolution and the gear ratio, and the drive's current unit (COPLEY: 0.01 A).

Sensor side (:func:`decode_sensors`): the sensor board's micrometres, kilopascals and
micrometres per second to metres, pascals and metres per second, with the no-reading sentinel
(the most negative value of the type) as NaN, and the board's status bits and the sensors' valid
ranges (``config/canopen/README.md``) checked into a :class:`SensorFault`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from exo_has_driver import can_dictionary as cd
from exo_has_driver.errors import HardwareConfigError

I32_MIN = -0x80000000
I32_MAX = 0x7FFFFFFF
U32_MAX = 0xFFFFFFFF


@dataclass(frozen=True)
class DriveUnits:
    """Unit conversions of one motor drive.

    Parameters
    ----------
    encoder_counts : int
        Encoder counts per motor revolution.
    gear_ratio : float
        Motor revolutions per pump revolution.
    velocity_unit : float
        Encoder counts/s per drive velocity unit (COPLEY: 0.1).
    current_unit : float
        Amperes per drive current unit (COPLEY: 0.01).

    Raises
    ------
    HardwareConfigError
        Naming the first value that is not positive and finite.

    """

    encoder_counts: int = cd.ENCODER_COUNTS
    gear_ratio: float = cd.GEAR_RATIO
    velocity_unit: float = cd.VELOCITY_UNIT
    current_unit: float = cd.CURRENT_UNIT

    def __post_init__(self) -> None:
        if isinstance(self.encoder_counts, bool) or not isinstance(self.encoder_counts, int) \
                or self.encoder_counts < 1:
            msg = f'encoder_counts = {self.encoder_counts!r} must be a positive integer'
            raise HardwareConfigError(msg)
        for name in ('gear_ratio', 'velocity_unit', 'current_unit'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                msg = f'{name} = {value!r} must be positive and finite'
                raise HardwareConfigError(msg)

    @property
    def velocity_per_rad_s(self) -> float:
        """Drive velocity units per rad/s of the pump."""
        return self.gear_ratio * self.encoder_counts / (2.0 * math.pi) / self.velocity_unit

    def velocity_to_drive(self, speed: float) -> int:
        """Return the drive velocity [units] of a pump speed [rad/s], rounded and clamped to I32.

        Raises
        ------
        HardwareConfigError
            For a NaN speed (an infinite one clamps).

        """
        if math.isnan(speed):
            msg = 'a NaN speed has no drive velocity'
            raise HardwareConfigError(msg)
        units = speed * self.velocity_per_rad_s
        if units >= I32_MAX:
            return I32_MAX
        if units <= I32_MIN:
            return I32_MIN
        return round(units)

    def velocity_from_drive(self, units: int) -> float:
        """Return the pump speed [rad/s] of a drive velocity [units]."""
        return units / self.velocity_per_rad_s

    def acceleration_to_drive(self, acceleration: float) -> int:
        """Return a profile ramp [drive velocity units/s] of a pump acceleration [rad/s^2].

        Raises
        ------
        HardwareConfigError
            For an acceleration that is not positive and finite or does not fit UNSIGNED32.

        """
        units = round(acceleration * self.velocity_per_rad_s) \
            if math.isfinite(acceleration) else -1
        if not (math.isfinite(acceleration) and acceleration > 0.0 and 0 < units <= U32_MAX):
            msg = (f'acceleration {acceleration!r} rad/s^2 must be positive and at most '
                   f'{U32_MAX / self.velocity_per_rad_s:.6g} rad/s^2 (UNSIGNED32 drive units)')
            raise HardwareConfigError(msg)
        return units

    def current_from_drive(self, units: int) -> float:
        """Return the motor current [A] of a drive current [units]."""
        return units * self.current_unit


@dataclass(frozen=True, slots=True)
class SensorFault:
    """The first fault found in one sensor board sample.

    Attributes
    ----------
    channel : str
        ``'position'``, ``'pressure_a'``, ``'pressure_b'`` or ``'velocity'``.
    value : float
        The channel's value in SI units, NaN for no reading.
    limit : float
        The bound of the valid range it crossed, NaN for no reading or a status bit.
    text : str
        What is wrong, with the units.

    """

    channel: str
    value: float
    limit: float
    text: str


@dataclass(frozen=True, slots=True)
class SensorValues:
    """One sensor board sample in SI units; NaN where the channel had no reading."""

    position: float  # m, from the retracted end
    pressure_a: float  # Pa, gauge
    pressure_b: float  # Pa, gauge
    velocity: float  # m/s
    fault: SensorFault | None


_STATUS_BITS = (('position', cd.SENSOR_FAULT_POSITION),
                ('pressure_a', cd.SENSOR_FAULT_PRESSURE_A),
                ('pressure_b', cd.SENSOR_FAULT_PRESSURE_B),
                ('velocity', cd.SENSOR_FAULT_VELOCITY))


def decode_sensors(position_um: int, pressure_a_kpa: int, pressure_b_kpa: int,
                   velocity_um_s: int, status: int, stroke: float) -> SensorValues:
    """Convert one sensor board sample to SI units and check it.

    Parameters
    ----------
    position_um, pressure_a_kpa, pressure_b_kpa, velocity_um_s : int
        Raw values of the board's TPDOs (um, kPa, kPa, um/s).
    status : int
        The board's status bits (``SENSOR_FAULT_*``).
    stroke : float
        Cylinder stroke [m], for the position's valid range.

    Returns
    -------
    SensorValues
        With the first fault found: a channel without reading, a status bit, a position more
        than ``SENSOR_POSITION_TOLERANCE`` beyond a stroke end, or a pressure outside
        [``SENSOR_PRESSURE_MIN``, ``SENSOR_PRESSURE_MAX``]; None when the sample is sound.

    """
    nan = math.nan
    position = nan if position_um == cd.NO_READING_I32 else position_um * cd.POSITION_UNIT
    pressure_a = nan if pressure_a_kpa == cd.NO_READING_I16 \
        else pressure_a_kpa * cd.PRESSURE_UNIT
    pressure_b = nan if pressure_b_kpa == cd.NO_READING_I16 \
        else pressure_b_kpa * cd.PRESSURE_UNIT
    velocity = nan if velocity_um_s == cd.NO_READING_I32 \
        else velocity_um_s * cd.VELOCITY_SENSOR_UNIT
    values = {'position': position, 'pressure_a': pressure_a, 'pressure_b': pressure_b,
              'velocity': velocity}
    fault = _fault(values, status, stroke)
    return SensorValues(position, pressure_a, pressure_b, velocity, fault)


def _fault(values: dict[str, float], status: int, stroke: float) -> SensorFault | None:
    nan = math.nan
    for channel, bit in _STATUS_BITS:
        value = values[channel]
        if math.isnan(value):
            return SensorFault(channel, nan, nan, f'{channel}: no reading (sentinel value)')
        if status & bit:
            return SensorFault(channel, value, nan,
                               f'{channel}: the board flags a fault (status 0x{status:04X})')
    position = values['position']
    low = -cd.SENSOR_POSITION_TOLERANCE
    high = stroke + cd.SENSOR_POSITION_TOLERANCE
    if not low <= position <= high:
        bound = low if position < low else high
        return SensorFault('position', position, bound,
                           f'position {position * 1e3:.2f} mm outside [{low * 1e3:.1f}, '
                           f'{high * 1e3:.1f}] mm (stroke {stroke * 1e3:.1f} mm)')
    for channel in ('pressure_a', 'pressure_b'):
        pressure = values[channel]
        if not cd.SENSOR_PRESSURE_MIN <= pressure <= cd.SENSOR_PRESSURE_MAX:
            bound = cd.SENSOR_PRESSURE_MIN if pressure < cd.SENSOR_PRESSURE_MIN \
                else cd.SENSOR_PRESSURE_MAX
            return SensorFault(channel, pressure, bound,
                               f'{channel} {pressure * 1e-6:.3f} MPa outside '
                               f'[{cd.SENSOR_PRESSURE_MIN * 1e-6:g}, '
                               f'{cd.SENSOR_PRESSURE_MAX * 1e-6:g}] MPa')
    return None
