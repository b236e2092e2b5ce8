"""Settings of the CANopen master and the samples it hands its caller: pure and thread-free.

:class:`JointConfig` and :class:`MasterConfig` check themselves on construction, the bus load
of the SYNC cycle included (:func:`frame_bits`, :func:`bits_per_sync`, :data:`MAX_BUS_LOAD`);
:class:`JointSample` is one joint's state at a SYNC, its valve mode from
:func:`infer_valve_mode`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from exo_has_driver import can_dictionary as cd
from exo_has_driver.errors import HardwareConfigError
from exo_has_driver.hardware import cia402
from exo_has_driver.hardware.units import DriveUnits
from exo_has_sim.parameters import HasParameters
from exo_has_sim.valve import ValveMode

#: Default SYNC periods without a TPDO from a slave after which the bus counts as silent.
DEFAULT_MISSING_SYNCS = 10
#: Default profile acceleration and deceleration of the pump [rad/s^2]: full speed (418.9 rad/s)
#: in 28 ms, against the motor's 5 ms time constant (the EDS default is about the same).
DEFAULT_ACCELERATION = 15000.0
#: Default quick stop deceleration [rad/s^2]: full speed to standstill in 14 ms.
DEFAULT_QUICK_STOP_DECELERATION = 30000.0
#: Default age of the newest command after which the drive is sent zero speed [s].
DEFAULT_COMMAND_TIMEOUT = 0.25
#: Share of the bit rate the cyclic frames and heartbeats may take: the rest is for SDO, EMCY,
#: retransmissions, and the TPDOs must be in before the next SYNC.
MAX_BUS_LOAD = 0.8

_DEFAULT_UNITS = DriveUnits()


@dataclass(frozen=True)
class JointConfig:
    """One joint on the bus: node IDs and what the checks and the valve inference need.

    Attributes
    ----------
    name : str
        Joint name (``left_hip``...).
    drive_id, sensor_id : int
        CANopen node IDs of the drive and the sensor board.
    stroke : float
        Cylinder stroke [m].
    relief_pressure : float
        Safety valve setting [Pa].
    drop_pressure : float
        Pressure under which the compact valve falls to free mode [Pa].
    stopped_speed : float
        Motor speed under which the motor counts as stopped [rad/s].
    motor_speed_max : float
        Largest pump speed commanded [rad/s]; faster commands are clamped to it.

    """

    name: str
    drive_id: int
    sensor_id: int
    stroke: float
    relief_pressure: float
    drop_pressure: float
    stopped_speed: float
    motor_speed_max: float = math.inf

    @classmethod
    def from_parameters(cls, name: str, params: HasParameters, drive_id: int | None = None,
                        sensor_id: int | None = None) -> JointConfig:
        """Build a joint from its HAS parameter set; node IDs default to can_dictionary's.

        Raises
        ------
        HardwareConfigError
            For a joint that has no default node ID.

        """
        try:
            drive = cd.DRIVE_NODE_IDS[name] if drive_id is None else drive_id
            sensor = cd.SENSOR_NODE_IDS[name] if sensor_id is None else sensor_id
        except KeyError:
            msg = (f'joint {name!r} has no default node ID: known are '
                   f'{", ".join(cd.DRIVE_NODE_IDS)}')
            raise HardwareConfigError(msg) from None
        return cls(name, drive, sensor, params.stroke, params.relief_pressure,
                   params.valve_drop_pressure, params.valve_release_speed,
                   params.motor_speed_max)


@dataclass(frozen=True)
class MasterConfig:
    """Settings of the master; times in seconds, accelerations in rad/s^2 of the pump.

    ``bitrate`` [bit/s] is the bus's: the SYNC cycle's frames (see :func:`bits_per_sync`) and
    the heartbeats must fit in :data:`MAX_BUS_LOAD` of it.

    Raises
    ------
    HardwareConfigError
        Naming the first setting out of range, a node ID used twice, or a bus load the bit
        rate cannot carry.

    """

    joints: tuple[JointConfig, ...]
    units: DriveUnits = _DEFAULT_UNITS
    period: float = cd.SYNC_PERIOD
    heartbeat_period: float = cd.HEARTBEAT_PERIOD
    heartbeat_timeout: float = cd.HEARTBEAT_TIMEOUT
    missing_syncs: int = DEFAULT_MISSING_SYNCS
    acceleration: float = DEFAULT_ACCELERATION
    quick_stop_deceleration: float = DEFAULT_QUICK_STOP_DECELERATION
    command_timeout: float = DEFAULT_COMMAND_TIMEOUT
    sdo_timeout: float = 0.5
    boot_timeout: float = 2.0
    enable_timeout: float = 2.0
    master_id: int = cd.MASTER_NODE_ID
    bitrate: int = 1_000_000

    def __post_init__(self) -> None:
        if not self.joints:
            msg = 'the master needs at least one joint'
            raise HardwareConfigError(msg)
        for name in ('period', 'heartbeat_period', 'heartbeat_timeout', 'acceleration',
                     'quick_stop_deceleration', 'command_timeout', 'sdo_timeout',
                     'boot_timeout', 'enable_timeout'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                msg = f'{name} = {value!r} must be positive and finite'
                raise HardwareConfigError(msg)
        # The object dictionary holds the heartbeat times in whole milliseconds (16 bits).
        for name in ('heartbeat_period', 'heartbeat_timeout'):
            ms = round(getattr(self, name) * 1e3)
            if not 1 <= ms <= 0xFFFF:
                msg = f'{name} = {getattr(self, name)!r} s must be 1 ms to 65.535 s'
                raise HardwareConfigError(msg)
        if self.heartbeat_timeout <= self.heartbeat_period:
            msg = (f'heartbeat_timeout {self.heartbeat_timeout} s must exceed heartbeat_period '
                   f'{self.heartbeat_period} s')
            raise HardwareConfigError(msg)
        if isinstance(self.missing_syncs, bool) or not isinstance(self.missing_syncs, int) \
                or self.missing_syncs < 1:
            msg = f'missing_syncs = {self.missing_syncs!r} must be an integer of at least 1'
            raise HardwareConfigError(msg)
        ids = [self.master_id]
        for joint in self.joints:
            ids += [joint.drive_id, joint.sensor_id]
        for node in ids:
            if isinstance(node, bool) or not isinstance(node, int) or not 1 <= node <= 127:
                msg = f'node ID {node!r} must be an integer of 1 to 127'
                raise HardwareConfigError(msg)
        if len(set(ids)) != len(ids):
            msg = f'node IDs must differ (master and every drive and sensor board): {ids}'
            raise HardwareConfigError(msg)
        names = [joint.name for joint in self.joints]
        if len(set(names)) != len(names):
            msg = f'joint names must differ: {names}'
            raise HardwareConfigError(msg)
        self.units.acceleration_to_drive(self.acceleration)
        self.units.acceleration_to_drive(self.quick_stop_deceleration)
        if isinstance(self.bitrate, bool) or not isinstance(self.bitrate, int) \
                or self.bitrate <= 0:
            msg = f'bitrate = {self.bitrate!r} must be a positive integer [bit/s]'
            raise HardwareConfigError(msg)
        per_sync = bits_per_sync(len(self.joints))
        load = per_sync / self.period \
            + (2 * len(self.joints) + 1) * frame_bits(1) / self.heartbeat_period
        if load > MAX_BUS_LOAD * self.bitrate:
            msg = (f'the bus cannot carry a SYNC every {self.period * 1e3:g} ms: '
                   f'{len(self.joints)} joints take about {per_sync} bit per SYNC, '
                   f'{load * 1e-3:.0f} kbit/s with the heartbeats, over '
                   f'{MAX_BUS_LOAD:.0%} of {self.bitrate * 1e-3:g} kbit/s; lower the rate')
            raise HardwareConfigError(msg)


def frame_bits(data_bytes: int) -> int:
    """Bits a base-format CAN frame takes on the bus at worst, stuff bits and gap included.

    44 bits of frame and 3 of interframe space, 8 per data byte, and one stuff bit per four
    of the 34 + 8 n bits that are stuffed (the worst case).
    """
    stuffed = 34 + 8 * data_bytes
    return 47 + 8 * data_bytes + (stuffed - 1) // 4


def bits_per_sync(joints: int) -> int:
    """Bits of one SYNC cycle at worst: per joint an RPDO and three TPDOs, and the SYNC."""
    per_joint = frame_bits(cd.DRIVE_RPDO1.size) + frame_bits(cd.DRIVE_TPDO1.size) \
        + frame_bits(cd.SENSOR_TPDO1.size) + frame_bits(cd.SENSOR_TPDO2.size)
    return joints * per_joint + frame_bits(0)


@dataclass(frozen=True, slots=True)
class JointSample:
    """One joint's state at a SYNC, in the units of exo_has_msgs/msg/HasState.

    Attributes
    ----------
    joint : str
        Joint name.
    stamp : float
        Receive time of the sensor board's TPDO1 [s since the epoch] (python-can's timestamp).
    position, velocity : float
        Cylinder extension [m] and its velocity [m/s]; NaN without reading.
    pressure_a, pressure_b : float
        Chamber gauge pressures [Pa]; NaN without reading.
    motor_speed : float
        Measured pump speed [rad/s].
    motor_speed_command : float
        Target speed sent with this SYNC [rad/s].
    motor_current : float
        Motor current [A].
    valve_mode : int
        Inferred valve mode (:class:`~exo_has_sim.valve.ValveMode`); see
        :func:`infer_valve_mode`.
    drive_state : str
        CiA 402 state of the drive.
    sensor_fault : bool
        Whether the sensor board sample has a fault.
    counter : int
        The sensor board's sample counter.

    """

    joint: str
    stamp: float
    position: float
    velocity: float
    pressure_a: float
    pressure_b: float
    motor_speed: float
    motor_speed_command: float
    motor_current: float
    valve_mode: int
    drive_state: str
    sensor_fault: bool
    counter: int


def infer_valve_mode(joint: JointConfig, drive_state: str, motor_speed: float,
                     pressure_a: float, pressure_b: float) -> int:
    """Infer the compact valve's mode (a ``ValveMode``), which the hardware does not measure.

    As the plant model defines it (exo_has_sim: relief while the safety valve passes flow, free
    when the motor is stopped and the system pressure has dropped): RELIEF when a chamber
    pressure is at or over the joint's relief setting; FREE when the drive is not in operation
    enabled, or when the motor is stopped (speed under the valve's release speed) and both
    pressures are under the valve's drop pressure; ASSIST otherwise.
    """
    if pressure_a >= joint.relief_pressure or pressure_b >= joint.relief_pressure:
        return ValveMode.RELIEF
    if drive_state != cia402.OPERATION_ENABLED:
        return ValveMode.FREE
    if abs(motor_speed) < joint.stopped_speed and pressure_a < joint.drop_pressure \
            and pressure_b < joint.drop_pressure:
        return ValveMode.FREE
    return ValveMode.ASSIST
