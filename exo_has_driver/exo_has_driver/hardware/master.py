"""The CANopen master of the HAS joints: start-up, the SYNC cycle, supervision and the stop latch.

One :class:`Master` serves N joints (a CiA 402 drive and a sensor board each) on one python-can
bus, as ``config/canopen/README.md`` specifies.

Start (:meth:`Master.start`, blocking, each wait bounded): the master's heartbeat starts; NMT
reset communication of every slave and wait for each one's boot-up message; SDO configuration
of each (the identity 1018h and device type 1000h checked, the SYNC COB-ID checked, consumed;
the cycle period, heartbeat consumer and producer times written; on the drives first the
abort connection option code 6007h (quick stop) and error behaviour 1029h (no NMT change),
see :data:`ABORT_CONNECTION_OPTION` and :data:`ERROR_BEHAVIOUR`, then modes of operation 3,
quick stop option code 2 and the profile ramps; each PDO's COB-ID (its 11-bit identifier and
valid bit 31; bit 30 is the device's), transmission type and mapping read and, where they
differ from :mod:`exo_has_driver.can_dictionary`, rewritten per CiA 301: PDO invalid, mapping
count 0, entries, count, PDO valid; last the drive's statusword and 603Fh: a drive in fault
with another code than 8130h, the master's heartbeat lost, ends the start naming the code);
NMT start and wait for every heartbeat to report operational; then the I/O thread runs and
the drives are taken through the enable sequence (those in fault with 8130h through one fault
reset first) to operation enabled at zero speed. A device that does not answer raises
:class:`CanOpenTimeoutError` naming the node and the object or step; a bus that fails to
receive, :class:`CanBusError`.

Cycle (the I/O thread, which alone owns the bus and the protocol state): it receives frames until
the next SYNC is due, then checks the slaves, writes every drive's RPDO1 (controlword from
:mod:`.cia402`, target velocity from the newest command, clamped to the joint's
``motor_speed_max``) and sends the SYNC; the master's heartbeat goes out every producer
period. TPDOs are decoded with the structs of ``can_dictionary`` as they come; once a joint's
three TPDOs are in, a :class:`JointSample` is queued, stamped with the receive time of the
sensor board's TPDO1 (``Message.timestamp``: the kernel's on SocketCAN). A failed receive is a
bus fault; after :data:`RECEIVE_FAILURES_MAX` in a row the thread ends (:attr:`Master.running`
false, :attr:`Master.failure` the error). The caller's thread only swaps a command tuple
(:meth:`set_command`), appends a request, or pops the queues (:meth:`take_samples`,
:meth:`take_events`): it never waits on the bus.

Supervision, each a FATAL :class:`~exo_has_driver.Event` that latches the stop:
a drive in fault or an EMCY, a drive that leaves operation enabled by itself while enabled, a
statusword of no CiA 402 state (DRIVE_FAULT, value the error code; a sensor board's EMCY is a
SENSOR_FAULT), a heartbeat older than the consumer time or a slave that reports another NMT
state than operational or boots (HEARTBEAT_LOST), no TPDO from a slave for ``missing_syncs``
SYNC periods, a failed send or receive, a bus-off or error-passive bus (BUS_OFF), a sensor
channel without reading, flagged by the board or out of range (SENSOR_FAULT), an e-stop
request (E_STOP). One function lists the conditions that hold (:meth:`Master._conditions`):
supervision latches them, a reset is refused while they hold. A condition is reported once
while it lasts. While latched every drive is sent quick stop (it brakes on its quick stop ramp
to switch on disabled) and then disable voltage, target 0, and a slave whose heartbeat reports
pre-operational or stopped is sent NMT start, so that these RPDOs reach it.
:meth:`request_reset` works in two phases: refused (a WARN event naming what holds) while a
condition other than a drive in fault holds; else the drives in fault get one rising edge of
the fault reset bit while the stop still holds, and once every drive has left fault (within
:data:`FAULT_RESET_TIME`) the latch is released (a RESET event) and the drives go through the
enable sequence again, at zero speed until the next command; a drive still in fault then
refuses the reset (WARN). A slave that booted while running holds until the driver restarts:
its configuration is lost.

Valve mode: the hardware does not measure it, so it is inferred as the plant model defines it
(exo_has_sim: relief while the safety valve passes flow, free when the motor is stopped and the
system pressure has dropped): RELIEF when a chamber pressure is at or over the joint's relief
setting; FREE when the drive is not in operation enabled, or when the motor is stopped (speed
under the valve's release speed) and both pressures are under the valve's drop pressure;
ASSIST otherwise.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from functools import partial
from typing import TypeVar

import can

from exo_has_driver import can_dictionary as cd
from exo_has_driver.errors import (
    CanBusError,
    CanOpenError,
    CanOpenTimeoutError,
    HardwareConfigError,
)
from exo_has_driver.events import Condition, Event, SafetyKind, Severity, StopLatch
from exo_has_driver.hardware import cia402
from exo_has_driver.hardware.bus import bus_state_fault, error_frame_fault
from exo_has_driver.hardware.sdo import SdoClient, object_name
from exo_has_driver.hardware.units import DriveUnits, SensorFault, decode_sensors
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
#: How long a drive has to leave fault after its fault reset edge [s].
FAULT_RESET_TIME = 0.1
#: How long an error frame's bus fault counts as holding [s].
ERROR_FRAME_HOLD = 1.0
#: Bus state polls: every this many SYNC periods (some interfaces ask the hardware).
BUS_STATE_EVERY = 10
#: Samples kept for the caller: a second of four joints at 200 Hz.
SAMPLE_QUEUE = 800
#: Failed receives in a row after which the I/O thread gives up (after a failure it waits for
#: the next SYNC before it tries again: 0.5 s at 200 Hz).
RECEIVE_FAILURES_MAX = 100
#: Frames handled at most between two SYNCs' catch-up drains (a flooded bus must not hold up
#: the SYNC).
DRAIN_MAX = 256
#: Share of the bit rate the cyclic frames and heartbeats may take: the rest is for SDO, EMCY,
#: retransmissions, and the TPDOs must be in before the next SYNC.
MAX_BUS_LOAD = 0.8
#: Error codes of a drive fault that start-up clears by itself: the master's heartbeat lost
#: (the previous master's, or this one's before it started).
AUTO_RESET_CODES = frozenset({cd.ERROR_HEARTBEAT_LOST})
#: Abort connection option code 6007h written to every drive: on a lost master heartbeat or
#: leaving NMT operational the drive quick stops (brakes on 6085h within 14 ms at full speed,
#: then switch on disabled with 605Ah = 2) rather than coasting (2) or a fault reaction (1,
#: which on a COPLEY disables the motor at once): the HAS then falls to free mode standing.
ABORT_CONNECTION_OPTION = cd.ABORT_CONNECTION_QUICK_STOP
#: Error behaviour 1029h sub 1 written to every drive: a communication error leaves the NMT
#: state alone (not pre-operational, CiA 301's default), so that once the bus is back the
#: master's RPDOs (quick stop, disable voltage) apply at once; 6007h stops the motor meanwhile.
ERROR_BEHAVIOUR = cd.ERROR_BEHAVIOUR_NO_CHANGE

_NMT_STATE_NAMES = {cd.NMT_BOOT_UP: 'boot-up', cd.NMT_STOPPED: 'stopped',
                    cd.NMT_OPERATIONAL: 'operational',
                    cd.NMT_PRE_OPERATIONAL: 'pre-operational'}
_DRIVE_PDOS = ((cd.RPDO1_COMMUNICATION, cd.RPDO1_MAPPING, cd.RPDO1_BASE, cd.DRIVE_RPDO1_MAP),
               (cd.TPDO1_COMMUNICATION, cd.TPDO1_MAPPING, cd.TPDO1_BASE, cd.DRIVE_TPDO1_MAP))
_SENSOR_PDOS = ((cd.TPDO1_COMMUNICATION, cd.TPDO1_MAPPING, cd.TPDO1_BASE, cd.SENSOR_TPDO1_MAP),
                (cd.TPDO2_COMMUNICATION, cd.TPDO2_MAPPING, cd.TPDO2_BASE, cd.SENSOR_TPDO2_MAP))
_DRIVE_TPDO = 1
_SENSOR_TPDO1 = 2
_SENSOR_TPDO2 = 4
_ALL_TPDOS = _DRIVE_TPDO | _SENSOR_TPDO1 | _SENSOR_TPDO2
_NAN = math.nan
_DEFAULT_UNITS = DriveUnits()
# Keys of the conditions that are reported again after they stopped holding for a while.
_CONDITION_KEYS = frozenset({'missing', 'heartbeat', 'sensor', 'bus state', 'send',
                             'error frame', 'receive'})
_T = TypeVar('_T')
_Key = tuple[object, ...]


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
        Inferred valve mode (:class:`~exo_has_sim.valve.ValveMode`); see the module docstring.
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
    """Infer the compact valve's mode (a ``ValveMode``); see the module docstring."""
    if pressure_a >= joint.relief_pressure or pressure_b >= joint.relief_pressure:
        return ValveMode.RELIEF
    if drive_state != cia402.OPERATION_ENABLED:
        return ValveMode.FREE
    if abs(motor_speed) < joint.stopped_speed and pressure_a < joint.drop_pressure \
            and pressure_b < joint.drop_pressure:
        return ValveMode.FREE
    return ValveMode.ASSIST


class _Slave:
    """What the master tracks of one slave."""

    __slots__ = (
        'booted',
        'heartbeat_state',
        'heartbeat_time',
        'joint',
        'label',
        'missing',
        'nmt_start_time',
        'node',
        'rebooted',
        'seen',
    )

    def __init__(self, node: int, joint: str, role: str) -> None:
        self.node = node
        self.joint = joint
        self.label = f'{joint} {role} (node {node})'
        self.heartbeat_time: float | None = None
        self.heartbeat_state: int | None = None
        self.seen = True
        self.missing = 0
        self.booted = False  # a boot-up came since the start's reset communication
        self.rebooted = False  # a boot-up came while running: its configuration is lost
        self.nmt_start_time = -math.inf  # when the latch last sent it NMT start


class _Joint:
    """What the master tracks of one joint; written by the I/O thread only."""

    __slots__ = (
        'config',
        'counter',
        'current',
        'drive',
        'emcy_code',
        'enabled_syncs',
        'fault',
        'fault_reset',
        'fault_reset_until',
        'last_cw',
        'position',
        'pressure_a',
        'pressure_b',
        'received',
        'rpdo',
        'sensor',
        'stamp',
        'state',
        'status',
        'target',
        'velocity',
        'velocity_sensor',
    )

    def __init__(self, config: JointConfig) -> None:
        self.config = config
        self.drive = _Slave(config.drive_id, config.name, 'drive')
        self.sensor = _Slave(config.sensor_id, config.name, 'sensor board')
        self.rpdo = can.Message(arbitration_id=cd.RPDO1_BASE + config.drive_id,
                                data=bytearray(cd.DRIVE_RPDO1.size), is_extended_id=False)
        self.last_cw = cd.CW_DISABLE_VOLTAGE
        self.target = 0
        self.state = cia402.UNKNOWN
        self.fault_reset = False
        self.fault_reset_until = -1.0
        self.emcy_code: int | None = None
        self.enabled_syncs = 0  # SYNCs in a row sent with enable operation
        self.received = 0
        self.stamp = 0.0
        self.velocity = 0
        self.current = 0
        self.position = 0
        self.pressure_a = 0
        self.pressure_b = 0
        self.velocity_sensor = 0
        self.status = 0
        self.counter = 0
        self.fault: SensorFault | None = None


class Master:
    """CANopen master of the HAS joints on one bus; see the module docstring.

    Parameters
    ----------
    bus : can.BusABC
        An open bus; the master does not shut it down (its opener does).
    config : MasterConfig
        Joints, units and timing.
    clock : callable
        Monotonic time [s]; the default is :func:`time.monotonic`.

    """

    def __init__(self, bus: can.BusABC, config: MasterConfig,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.bus = bus
        self.config = config
        self._clock = clock
        self._units = config.units
        self._joints = [_Joint(joint) for joint in config.joints]
        self._indices = {joint.config.name: index for index, joint in enumerate(self._joints)}
        self._slaves = [slave for joint in self._joints for slave in (joint.drive, joint.sensor)]
        now = clock()
        # (speed [rad/s], enable, receive time [s]) per joint; swapped whole by set_command.
        self._commands: list[tuple[float, bool, float]] = [(0.0, True, now)] * len(self._joints)
        self._requests: collections.deque[tuple[str, str]] = collections.deque()
        self._samples: collections.deque[JointSample] = collections.deque(maxlen=SAMPLE_QUEUE)
        self._events: collections.deque[Event] = collections.deque()
        self._sdo_answers: dict[int, bytes] = {}
        self._handlers: dict[int, Callable[[can.Message], None]] = {}
        self._register_handlers()
        self._heartbeat = can.Message(arbitration_id=cd.HEARTBEAT_BASE + config.master_id,
                                      data=bytes((cd.NMT_OPERATIONAL,)), is_extended_id=False)
        self._sync = can.Message(arbitration_id=cd.SYNC_COB_ID, data=b'',
                                 is_extended_id=False)
        self._heartbeat_due: float | None = None
        self._latch_state = StopLatch()
        self._running = False
        self._operational = False
        self._thread: threading.Thread | None = None
        self._stop_thread = threading.Event()
        self._shutting_down = False
        self._sync_count = 0
        self._send_failed: str | None = None
        self._send_failed_sync = -1
        self._frame_fault: str | None = None
        self._frame_fault_time = -math.inf
        self._state_fault: str | None = None
        self._receive_fault: str | None = None
        self._receive_fault_time = -math.inf
        self._receive_failures = 0
        # End of the second phase of a reset: drives sent a fault reset edge must leave fault.
        self._reset_until: float | None = None
        self.failure: BaseException | None = None

    # --- the caller's side -------------------------------------------------------------------
    @property
    def joints(self) -> tuple[str, ...]:
        """The joints, in configuration order."""
        return tuple(joint.config.name for joint in self._joints)

    @property
    def latched(self) -> bool:
        """Whether a stop is latched."""
        return self._latch_state.latched

    @property
    def cause(self) -> Event | None:
        """The event that latched the stop, None when not latched."""
        return self._latch_state.cause

    @property
    def io_thread_id(self) -> int | None:
        """Native ID of the I/O thread (for its scheduling class), None before the start."""
        return None if self._thread is None else self._thread.native_id

    @property
    def running(self) -> bool:
        """Whether the I/O thread runs the SYNC cycle."""
        return self._thread is not None and self._thread.is_alive()

    def drive_states(self) -> dict[str, str]:
        """Each joint's drive state as its newest TPDO reported it."""
        return {joint.config.name: joint.state for joint in self._joints}

    def all_enabled(self) -> bool:
        """Whether every drive reports operation enabled."""
        return all(joint.state == cia402.OPERATION_ENABLED for joint in self._joints)

    def set_command(self, joint: str, motor_speed: float, enable: bool,
                    now: float | None = None) -> None:
        """Take a joint's newest command: pump speed [rad/s], drive enabled.

        A NaN or infinite speed disables the drive (as a stop command would); a speed over the
        joint's ``motor_speed_max`` is clamped to it. Cheap and non-blocking: it is used at
        the next SYNC.

        Raises
        ------
        HardwareConfigError
            For a joint the master does not serve.

        """
        index = self._index(joint)
        t = self._clock() if now is None else now
        if math.isfinite(motor_speed):
            limit = self._joints[index].config.motor_speed_max
            self._commands[index] = (min(max(float(motor_speed), -limit), limit), bool(enable),
                                     t)
        else:
            self._commands[index] = (0.0, False, t)

    def request_stop(self, text: str) -> None:
        """Ask for an emergency stop (E_STOP, latched) at the next SYNC."""
        self._requests.append(('stop', text))

    def request_reset(self) -> None:
        """Ask to release the latched stop at the next SYNC (answered by an event)."""
        self._requests.append(('reset', ''))

    def take_samples(self) -> list[JointSample]:
        """Return the samples completed since the last call, oldest first."""
        return _drain(self._samples)

    def take_events(self) -> list[Event]:
        """Return the events raised since the last call, oldest first."""
        return _drain(self._events)

    # --- start and close ---------------------------------------------------------------------
    def start(self) -> None:
        """Bring every slave up and the drives to operation enabled at zero speed; blocking.

        Raises
        ------
        CanOpenTimeoutError
            If a slave does not boot, answer an SDO, report operational, or a drive does not
            reach operation enabled in time; the node and object or step are named.
        CanOpenError
            On an SDO abort, a wrong identity, a drive in a fault other than the master's
            heartbeat lost (8130h, cleared by a fault reset), or a fault while enabling.
        CanBusError
            If the bus fails to receive.

        """
        if self._thread is not None:
            msg = 'the master was started already'
            raise CanOpenError(msg)
        try:
            self._start_slaves()
        except can.CanError as exc:
            self._send_best_effort_stop()
            msg = f'the CAN bus failed while starting the slaves: {exc}'
            raise CanBusError(msg) from exc
        except BaseException:
            self._send_best_effort_stop()
            raise
        self._thread = threading.Thread(target=self._run, name='can-master', daemon=True)
        self._thread.start()
        deadline = self._clock() + self.config.enable_timeout
        while not self.all_enabled():
            if self._latch_state.latched or not self.running or self._clock() > deadline:
                self.close()
                if self.failure is not None:
                    msg = f'the CAN master failed while enabling the drives: {self.failure}'
                    raise CanOpenError(msg) from self.failure
                if self._latch_state.cause is not None:
                    msg = f'a fault while enabling the drives: {self._latch_state.cause.text}'
                    raise CanOpenError(msg)
                states = ', '.join(f'{joint.config.name} drive (node {joint.drive.node}) in '
                                   f'{joint.state}' for joint in self._joints
                                   if joint.state != cia402.OPERATION_ENABLED)
                msg = (f'drives not in operation enabled within '
                       f'{self.config.enable_timeout:g} s: {states}')
                raise CanOpenTimeoutError(msg)
            time.sleep(self.config.period)

    def close(self, timeout: float = 1.0) -> None:
        """Stop every motor (quick stop, then disable voltage), then end the I/O thread.

        Waits up to ``timeout`` [s] for the drives to reach switch on disabled. The bus stays
        open.
        """
        thread = self._thread
        if thread is None or not thread.is_alive():
            return
        self._shutting_down = True
        deadline = self._clock() + timeout
        while self._clock() < deadline and thread.is_alive():
            if all(joint.state in (cia402.SWITCH_ON_DISABLED, cia402.FAULT, cia402.UNKNOWN)
                   for joint in self._joints):
                break
            time.sleep(self.config.period)
        self._stop_thread.set()
        thread.join(timeout=max(1.0, 10 * self.config.period))

    # --- start-up (caller's thread, before the I/O thread runs) ------------------------------
    def _start_slaves(self) -> None:
        config = self.config
        self._heartbeat_due = self._clock()
        for _ in range(DRAIN_MAX):  # forget frames from before the start (old boot-ups)
            if self.bus.recv(0.0) is None:
                break
        for slave in self._slaves:
            slave.heartbeat_state = None
            slave.booted = False
            self._send_nmt(cd.NMT_RESET_COMMUNICATION, slave.node)
        # Only the boot-up counts: a heartbeat from before the reset does not say it was done.
        self._pump(config.boot_timeout, lambda: all(s.booted for s in self._slaves))
        silent = [s.label for s in self._slaves if not s.booted]
        if silent:
            msg = (f'no boot-up within {config.boot_timeout:g} s of the NMT reset '
                   f'communication from {", ".join(silent)}: powered, on the bus, at that ID?')
            raise CanOpenTimeoutError(msg)
        sdo = SdoClient(self._exchange, timeout=config.sdo_timeout)
        in_fault = []
        for joint in self._joints:
            if self._configure_drive(sdo, joint):
                in_fault.append(joint)
            self._configure_sensor(sdo, joint.sensor.node)
        for slave in self._slaves:
            slave.heartbeat_state = None
            self._send_nmt(cd.NMT_START, slave.node)
        # Wait for a heartbeat sent after the start command, each a producer period apart.
        self._pump(max(config.boot_timeout, 3 * config.heartbeat_period), lambda: all(
            s.heartbeat_state == cd.NMT_OPERATIONAL for s in self._slaves))
        late = [f'{s.label} ({_nmt_name(s.heartbeat_state)})' for s in self._slaves
                if s.heartbeat_state != cd.NMT_OPERATIONAL]
        if late:
            msg = (f'not operational within {config.boot_timeout:g} s of the NMT start: '
                   f'{", ".join(late)}')
            raise CanOpenTimeoutError(msg)
        now = self._clock()
        for slave in self._slaves:
            slave.heartbeat_time = now
            slave.seen = True
            slave.missing = 0
        for joint in in_fault:
            self._arm_fault_reset(joint, now)  # in fault from a lost master heartbeat only
        self._operational = True

    def _configure_common(self, sdo: SdoClient, node: int, product: int,
                          device_type: int) -> None:
        config = self.config
        found = (sdo.read_unsigned(node, cd.IDENTITY, 1), sdo.read_unsigned(node, cd.IDENTITY, 2))
        if found != (cd.VENDOR_ID, product):
            msg = (f'node {node}: identity {object_name(cd.IDENTITY, 1)}/2 is vendor '
                   f'0x{found[0]:08X}, product 0x{found[1]:08X}; expected vendor '
                   f'0x{cd.VENDOR_ID:08X}, product 0x{product:08X}: wrong device at this ID?')
            raise CanOpenError(msg)
        found_type = sdo.read_unsigned(node, cd.DEVICE_TYPE, 0)
        if found_type != device_type:
            msg = (f'node {node}: device type {object_name(cd.DEVICE_TYPE, 0)} is '
                   f'0x{found_type:08X}, expected 0x{device_type:08X}')
            raise CanOpenError(msg)
        sync_cob = sdo.read_unsigned(node, cd.COB_ID_SYNC, 0)
        if sync_cob & cd.COB_ID_MASK != cd.SYNC_COB_ID or sync_cob & cd.SYNC_PRODUCER:
            msg = (f'node {node}: COB-ID SYNC {object_name(cd.COB_ID_SYNC, 0)} is '
                   f'0x{sync_cob:08X}, expected 0x{cd.SYNC_COB_ID:X} consumed (bit 30 clear: '
                   f'only the master produces SYNC)')
            raise CanOpenError(msg)
        sdo.write_unsigned(node, cd.CYCLE_PERIOD, 0, round(config.period * 1e6), 4)
        consumer = (config.master_id << 16) | round(config.heartbeat_timeout * 1e3)
        sdo.write_unsigned(node, cd.CONSUMER_HEARTBEAT_TIME, 1, consumer, 4)
        sdo.write_unsigned(node, cd.PRODUCER_HEARTBEAT_TIME, 0,
                           round(config.heartbeat_period * 1e3), 2)

    def _configure_drive(self, sdo: SdoClient, joint: _Joint) -> bool:
        """Configure a drive; return whether it is in a fault start-up may reset (8130h).

        Raises
        ------
        CanOpenError
            For a drive in any other fault, naming its error code 603Fh.

        """
        node = joint.drive.node
        self._configure_common(sdo, node, cd.DRIVE_PRODUCT_CODE, cd.DRIVE_DEVICE_TYPE)
        units = self._units
        # First what a lost connection does, so that a lost master stops the motor from now on.
        sdo.write_signed(node, cd.ABORT_CONNECTION_OPTION_CODE, 0, ABORT_CONNECTION_OPTION, 2)
        sdo.write_unsigned(node, cd.ERROR_BEHAVIOUR, cd.ERROR_BEHAVIOUR_COMMUNICATION_SUB,
                           ERROR_BEHAVIOUR, 1)
        sdo.write_signed(node, cd.MODES_OF_OPERATION, 0, cd.PROFILE_VELOCITY_MODE, 1)
        sdo.write_signed(node, cd.QUICK_STOP_OPTION_CODE, 0, cd.QUICK_STOP_RAMP_THEN_DISABLE, 2)
        ramp = units.acceleration_to_drive(self.config.acceleration)
        sdo.write_unsigned(node, cd.PROFILE_ACCELERATION, 0, ramp, 4)
        sdo.write_unsigned(node, cd.PROFILE_DECELERATION, 0, ramp, 4)
        sdo.write_unsigned(node, cd.QUICK_STOP_DECELERATION, 0,
                           units.acceleration_to_drive(self.config.quick_stop_deceleration), 4)
        mode = sdo.read_signed(node, cd.MODES_OF_OPERATION_DISPLAY, 0)
        if mode != cd.PROFILE_VELOCITY_MODE:
            msg = (f'node {node}: modes of operation display '
                   f'{object_name(cd.MODES_OF_OPERATION_DISPLAY, 0)} is {mode} after writing '
                   f'{cd.PROFILE_VELOCITY_MODE} (profile velocity)')
            raise CanOpenError(msg)
        for pdo in _DRIVE_PDOS:
            self._configure_pdo(sdo, node, *pdo)
        state = cia402.decode_state(sdo.read_unsigned(node, cd.STATUSWORD, 0))
        if not cia402.is_fault(state):
            return False
        code = sdo.read_unsigned(node, cd.ERROR_CODE, 0)
        joint.emcy_code = code
        if code not in AUTO_RESET_CODES:
            msg = (f'{joint.drive.label} is in {state} with error code 0x{code:04X} '
                   f'{cd.ERROR_CODES.get(code, "(unknown)")} ({object_name(cd.ERROR_CODE, 0)})'
                   f': the driver clears only a lost master heartbeat (0x8130) by itself; '
                   f'remove the cause and clear the fault, then start again')
            raise CanOpenError(msg)
        return True

    def _configure_sensor(self, sdo: SdoClient, node: int) -> None:
        self._configure_common(sdo, node, cd.SENSOR_PRODUCT_CODE, cd.SENSOR_DEVICE_TYPE)
        for pdo in _SENSOR_PDOS:
            self._configure_pdo(sdo, node, *pdo)

    def _configure_pdo(self, sdo: SdoClient, node: int, communication: int, mapping: int,
                       base: int, layout: Iterable[tuple[int, int, int]]) -> None:
        """Check a PDO against can_dictionary; rewrite it per CiA 301 where it differs.

        The COB-ID matches on its 11-bit identifier and bit 31 (valid); bit 30 (no RTR) is
        the device's and kept.
        """
        wanted = [(index << 16) | (sub << 8) | bits for index, sub, bits in layout]
        cob_id = base + node
        found_cob = sdo.read_unsigned(node, communication, 1)
        found_type = sdo.read_unsigned(node, communication, 2)
        count = sdo.read_unsigned(node, mapping, 0)
        entries = [sdo.read_unsigned(node, mapping, sub) for sub in range(1, count + 1)]
        no_rtr = found_cob & cd.PDO_COB_ID_NO_RTR
        if found_cob & ~cd.PDO_COB_ID_NO_RTR == cob_id \
                and found_type == cd.PDO_TRANSMISSION_SYNCHRONOUS and entries == wanted:
            return
        # CiA 301: make the PDO invalid, set the mapping count to 0, write the entries, the
        # count, then the COB-ID with the PDO valid again.
        sdo.write_unsigned(node, communication, 1, cob_id | no_rtr | cd.PDO_COB_ID_INVALID, 4)
        sdo.write_unsigned(node, communication, 2, cd.PDO_TRANSMISSION_SYNCHRONOUS, 1)
        sdo.write_unsigned(node, mapping, 0, 0, 1)
        for sub, entry in enumerate(wanted, start=1):
            sdo.write_unsigned(node, mapping, sub, entry, 4)
        sdo.write_unsigned(node, mapping, 0, len(wanted), 1)
        sdo.write_unsigned(node, communication, 1, cob_id | no_rtr, 4)

    def _exchange(self, node: int, request: bytes | None, timeout: float) -> bytes | None:
        """Send an SDO request and wait for the node's answer (the SdoClient's transport)."""
        if request is not None:
            self._sdo_answers.pop(node, None)
            self._send(can.Message(arbitration_id=cd.SDO_RX_BASE + node, data=request,
                                   is_extended_id=False))
        self._pump(timeout, lambda: node in self._sdo_answers)
        return self._sdo_answers.pop(node, None)

    def _pump(self, timeout: float, done: Callable[[], bool] | None = None) -> None:
        """Receive and handle frames, producing the heartbeat, until done() or the timeout."""
        deadline = self._clock() + timeout
        while True:
            now = self._clock()
            self._produce_heartbeat(now)
            if (done is not None and done()) or now > deadline:
                return
            wait = deadline - now
            if self._heartbeat_due is not None:
                wait = min(wait, self._heartbeat_due - now)
            message = self.bus.recv(max(0.0, wait))
            if message is not None:
                self._on_frame(message)
            elif wait <= 0.0 and now >= deadline:
                return

    # --- the I/O thread --------------------------------------------------------------------
    def _run(self) -> None:
        period = self.config.period
        on_frame = self._on_frame
        receive = self._receive
        clock = self._clock
        next_sync = clock()
        try:
            while not self._stop_thread.is_set():
                now = clock()
                if now < next_sync:
                    message, ok = receive(next_sync - now)
                    if message is not None:
                        on_frame(message)
                    elif not ok:
                        self._stop_thread.wait(next_sync - now)  # no busy loop on a dead bus
                    continue
                # Take what waited (after a stall too) before judging the slaves; bounded, so
                # that a flooded bus cannot hold up the SYNC.
                for _ in range(DRAIN_MAX):
                    message, ok = receive(0.0)
                    if message is None:
                        break
                    on_frame(message)
                self._cycle(clock())
                next_sync += period
                if next_sync < now:
                    next_sync = now + period  # held up: no burst of SYNCs
        except Exception as exc:  # the loop must not die silently: stop and tell
            self.failure = exc
            self._latch(('failure',), '', SafetyKind.BUS_OFF, _NAN, _NAN,
                        f'the CAN master loop failed: {exc!r}')
            self._send_best_effort_stop()

    def _receive(self, timeout: float) -> tuple[can.Message | None, bool]:
        """Receive a frame: (message or None, whether the bus answered).

        A failed receive (a bad datagram, a socket error) is a bus fault that holds for
        :data:`ERROR_FRAME_HOLD`; :data:`RECEIVE_FAILURES_MAX` in a row end the loop.

        Raises
        ------
        CanBusError
            After :data:`RECEIVE_FAILURES_MAX` failed receives in a row.

        """
        try:
            message = self.bus.recv(timeout)
        except can.CanError as exc:
            self._receive_failures += 1
            self._receive_fault = f'receiving from the CAN bus failed: {exc}'
            self._receive_fault_time = self._clock()
            if self._receive_failures >= RECEIVE_FAILURES_MAX:
                msg = f'{self._receive_failures} receives in a row failed, the last: {exc}'
                raise CanBusError(msg) from exc
            return None, False
        self._receive_failures = 0
        return message, True

    def _cycle(self, now: float) -> None:
        while self._requests:
            kind, text = self._requests.popleft()
            if kind == 'stop':
                self._latch(('e-stop',), '', SafetyKind.E_STOP, _NAN, _NAN,
                            f'emergency stop: {text}')
            else:
                self._reset(now)
        self._supervise(now)
        if self._reset_until is not None:
            self._finish_reset(now)
        units = self._units
        command_timeout = self.config.command_timeout
        for index, joint in enumerate(self._joints):
            if self._latch_state.latched or self._shutting_down:
                want = cia402.Want.STOPPED
                speed = 0.0
            else:
                speed, enable, received = self._commands[index]
                want = cia402.Want.ENABLED if enable else cia402.Want.DISABLED
                if now - received > command_timeout:
                    speed = 0.0  # no fresh command: hold still, the watchdog reports it
            if joint.fault_reset and now > joint.fault_reset_until:
                joint.fault_reset = False  # the edge's time is up: no later reset by surprise
            cw = cia402.controlword(joint.state, want, joint.last_cw, joint.fault_reset)
            if cw == cd.CW_FAULT_RESET:
                joint.fault_reset = False
            joint.enabled_syncs = joint.enabled_syncs + 1 if cw == cd.CW_ENABLE_OPERATION else 0
            target = units.velocity_to_drive(speed) \
                if want is cia402.Want.ENABLED and joint.state == cia402.OPERATION_ENABLED \
                else 0
            cd.DRIVE_RPDO1.pack_into(joint.rpdo.data, 0, cw, target)
            joint.last_cw = cw
            joint.target = target
            self._send(joint.rpdo)
        self._send(self._sync)
        self._sync_count += 1
        for slave in self._slaves:
            slave.seen = False
        self._produce_heartbeat(now)

    def _supervise(self, now: float) -> None:
        for slave in self._slaves:
            # TPDOs of the previous SYNC.
            if slave.seen:
                slave.missing = 0
            else:
                slave.missing += 1
        if self._sync_count % BUS_STATE_EVERY == 0:
            self._state_fault = bus_state_fault(self.bus)
        conditions = self._conditions(now)
        for condition in conditions:
            self._events += self._latch_state.report_once(condition)
        holding = {condition.key for condition in conditions}
        self._latch_state.forget({key for key in self._latch_state.reported
                                  if isinstance(key, tuple) and key[0] in _CONDITION_KEYS
                                  and key not in holding})
        if self._latch_state.latched:
            self._restart_slaves(now)

    def _restart_slaves(self, now: float) -> None:
        """Send NMT start to slaves out of operational, so that the latch's RPDOs apply.

        A drive in pre-operational or stopped ignores RPDOs: it would keep running on its last
        target velocity (unless its abort connection option stops it). Once a heartbeat
        period, for the slave's state to show.
        """
        for slave in self._slaves:
            if slave.heartbeat_state in (cd.NMT_PRE_OPERATIONAL, cd.NMT_STOPPED) \
                    and now - slave.nmt_start_time >= self.config.heartbeat_period:
                slave.nmt_start_time = now
                self._send_nmt(cd.NMT_START, slave.node)

    def _conditions(self, now: float) -> list[Condition]:
        """List the fault conditions that hold now: what supervision latches, what forbids a reset.

        A drive in fault counts once its fault reset time is over. Events that are not states
        (an EMCY, a drive leaving operation enabled, an e-stop) are latched where they come.
        """
        config = self.config
        conditions: list[Condition] = []
        for slave in self._slaves:
            lost = self._heartbeat_fault(slave, now)
            if lost is not None:
                age = now - slave.heartbeat_time if slave.heartbeat_time is not None else _NAN
                conditions.append(Condition(
                    ('heartbeat', slave.node), slave.joint, SafetyKind.HEARTBEAT_LOST, age,
                    config.heartbeat_timeout, f'{slave.label}: {lost}'))
            if slave.missing >= config.missing_syncs:
                conditions.append(Condition(
                    ('missing', slave.node), slave.joint, SafetyKind.BUS_OFF, _NAN, _NAN,
                    f'{slave.label}: no TPDO for {slave.missing} SYNC periods'))
        for joint in self._joints:
            name = joint.config.name
            if cia402.is_fault(joint.state) and now > joint.fault_reset_until:
                code = joint.emcy_code
                conditions.append(Condition(
                    ('drive', name), name, SafetyKind.DRIVE_FAULT,
                    float(code) if code is not None else _NAN, _NAN,
                    f'{joint.drive.label} in {joint.state} ({_fault_text(code)})'))
            if joint.fault is not None:
                conditions.append(Condition(
                    ('sensor', name), name, SafetyKind.SENSOR_FAULT, joint.fault.value,
                    joint.fault.limit, f'{joint.sensor.label}: {joint.fault.text}'))
        bus_checks: tuple[tuple[str, str | None], ...] = (
            ('bus state', self._state_fault), ('send', self._send_fault()),
            ('error frame', self._error_frame_fault(now)),
            ('receive', self._receive_fault_now(now)))
        for key, text in bus_checks:
            if text is not None:
                conditions.append(Condition((key,), '', SafetyKind.BUS_OFF, _NAN, _NAN, text))
        return conditions

    def _heartbeat_fault(self, slave: _Slave, now: float) -> str | None:
        if slave.rebooted:
            return ('booted (boot-up message) while running: its configuration is lost, '
                    'restart the driver')
        if slave.heartbeat_state != cd.NMT_OPERATIONAL:
            return f'reports NMT state {_nmt_name(slave.heartbeat_state)}, not operational'
        if slave.heartbeat_time is None or now - slave.heartbeat_time > \
                self.config.heartbeat_timeout:
            age = now - slave.heartbeat_time if slave.heartbeat_time is not None else _NAN
            return (f'heartbeat lost: none for {age:.3f} s (consumer time '
                    f'{self.config.heartbeat_timeout:.3f} s)')
        return None

    def _send_fault(self) -> str | None:
        if self._send_failed is not None and self._send_failed_sync >= self._sync_count - 1:
            return self._send_failed
        return None

    def _error_frame_fault(self, now: float) -> str | None:
        if self._frame_fault is not None and now - self._frame_fault_time <= ERROR_FRAME_HOLD:
            return self._frame_fault
        return None

    def _receive_fault_now(self, now: float) -> str | None:
        if self._receive_fault is not None \
                and now - self._receive_fault_time <= ERROR_FRAME_HOLD:
            return self._receive_fault
        return None

    def _reset(self, now: float) -> None:
        """First phase of a reset: refuse it, or send the drives in fault a reset edge."""
        if not self._latch_state.latched:
            self._events.append(self._latch_state.release())  # says none was latched
            return
        if self._reset_until is not None:
            return  # the reset asked for before is under way
        if self._refuse_reset(self._conditions(now)):
            return
        # Drives in fault get their reset edge while the stop still holds; the latch is
        # released only once every one of them has left fault (_finish_reset).
        armed = [joint for joint in self._joints if cia402.is_fault(joint.state)]
        for joint in armed:
            self._arm_fault_reset(joint, now)
        self._reset_until = max((joint.fault_reset_until for joint in armed), default=now)
        self._finish_reset(now)

    def _finish_reset(self, now: float) -> None:
        """Second phase of a reset: release once no drive is in fault, refuse at the time."""
        if self._refuse_reset(self._conditions(now)):
            self._reset_until = None
            return
        in_fault = [joint for joint in self._joints if cia402.is_fault(joint.state)]
        if in_fault:
            if self._reset_until is not None and now <= self._reset_until:
                return
            self._reset_until = None
            joint = in_fault[0]
            code = joint.emcy_code
            texts = '; '.join(f'{j.drive.label} still in {j.state} after its fault reset '
                              f'({_fault_text(j.emcy_code)})' for j in in_fault)
            self._events.append(Event(joint.config.name, SafetyKind.DRIVE_FAULT,
                                      Severity.WARN,
                                      float(code) if code is not None else _NAN, _NAN, True,
                                      f'reset refused: {texts}'))
            return
        self._reset_until = None
        for index in range(len(self._joints)):
            self._commands[index] = (0.0, True, now)
        self._events.append(self._latch_state.release())

    def _refuse_reset(self, conditions: list[Condition]) -> bool:
        """WARN and return True if a condition other than a drive in fault holds."""
        refusal = self._latch_state.refusal(
            [condition for condition in conditions if condition.kind != SafetyKind.DRIVE_FAULT])
        if refusal is None:
            return False
        self._events.append(refusal)
        return True

    def _arm_fault_reset(self, joint: _Joint, now: float) -> None:
        """Allow one fault reset edge and give the drive time to leave fault."""
        joint.fault_reset = True
        joint.fault_reset_until = now + FAULT_RESET_TIME + 2 * self.config.period

    def _latch(self, key: _Key, joint: str, kind: SafetyKind,
               value: float, limit: float, text: str) -> None:
        """Raise a FATAL event for a condition not yet reported, and latch the stop."""
        self._events += self._latch_state.report_once(
            Condition(key, joint, kind, value, limit, text))

    # --- frames in -----------------------------------------------------------------------------
    def _register_handlers(self) -> None:
        handlers = self._handlers
        for joint in self._joints:
            drive, sensor = joint.drive.node, joint.sensor.node
            handlers[cd.TPDO1_BASE + drive] = partial(self._on_drive_tpdo, joint)
            handlers[cd.TPDO1_BASE + sensor] = partial(self._on_sensor_tpdo1, joint)
            handlers[cd.TPDO2_BASE + sensor] = partial(self._on_sensor_tpdo2, joint)
            handlers[cd.EMCY_BASE + drive] = partial(self._on_emcy, joint, True)
            handlers[cd.EMCY_BASE + sensor] = partial(self._on_emcy, joint, False)
        for slave in self._slaves:
            handlers[cd.HEARTBEAT_BASE + slave.node] = partial(self._on_heartbeat, slave)
            handlers[cd.SDO_TX_BASE + slave.node] = partial(self._on_sdo, slave.node)

    def _on_frame(self, message: can.Message) -> None:
        if message.is_error_frame:
            fault = error_frame_fault(message)
            if fault is not None:
                self._frame_fault = fault
                self._frame_fault_time = self._clock()
            return
        handler = self._handlers.get(message.arbitration_id)
        if handler is not None and not message.is_remote_frame:
            handler(message)

    def _on_heartbeat(self, slave: _Slave, message: can.Message) -> None:
        if not message.data:
            return
        state = message.data[0] & 0x7F
        slave.heartbeat_state = state
        slave.heartbeat_time = self._clock()
        if state == cd.NMT_BOOT_UP:
            slave.booted = True
            if self._operational:
                slave.rebooted = True
                self._latch(('heartbeat', slave.node), slave.joint, SafetyKind.HEARTBEAT_LOST,
                            0.0, self.config.heartbeat_timeout,
                            f'{slave.label}: booted (boot-up message) while running: its '
                            f'configuration is lost, restart the driver')

    def _on_sdo(self, node: int, message: can.Message) -> None:
        self._sdo_answers[node] = bytes(message.data)

    def _on_emcy(self, joint: _Joint, is_drive: bool, message: can.Message) -> None:
        data = message.data
        if len(data) < 3 or not self._operational:
            return
        code = data[0] | (data[1] << 8)
        if code == 0:
            return  # "error reset or no error": a fault was cleared
        name = cd.ERROR_CODES.get(code, 'unknown error')
        if is_drive:
            joint.emcy_code = code
            self._latch(('drive', joint.config.name), joint.config.name,
                        SafetyKind.DRIVE_FAULT, float(code), _NAN,
                        f'{joint.drive.label}: EMCY 0x{code:04X} {name} (error register '
                        f'0x{data[2]:02X})')
        else:
            self._latch(('emcy', joint.sensor.node), joint.config.name,
                        SafetyKind.SENSOR_FAULT, float(code), _NAN,
                        f'{joint.sensor.label}: EMCY 0x{code:04X} {name} (error register '
                        f'0x{data[2]:02X})')

    def _on_drive_tpdo(self, joint: _Joint, message: can.Message) -> None:
        if len(message.data) != cd.DRIVE_TPDO1.size:
            return
        status, joint.velocity, joint.current = cd.DRIVE_TPDO1.unpack(message.data)
        before = joint.state
        state = joint.state = cia402.decode_state(status)
        joint.drive.seen = True
        name = joint.config.name
        if cia402.is_fault(before) and not cia402.is_fault(state):
            joint.emcy_code = None  # the next fault's code is unknown until its EMCY
        if state == cia402.UNKNOWN:
            self._latch(('drive', name), name, SafetyKind.DRIVE_FAULT, _NAN, _NAN,
                        f'{joint.drive.label}: statusword 0x{status:04X} matches no CiA 402 '
                        f'state')
        elif before == cia402.OPERATION_ENABLED and state != before \
                and not cia402.is_fault(state) \
                and joint.enabled_syncs > self.config.missing_syncs:
            # Sent enable operation for longer than a TPDO may lag: the drive left by itself
            # (a fault is reported with its code by the supervision).
            self._latch(('drive', name), name, SafetyKind.DRIVE_FAULT, _NAN, _NAN,
                        f'{joint.drive.label} left operation enabled for {state} by itself')
        self._received(joint, _DRIVE_TPDO)

    def _on_sensor_tpdo1(self, joint: _Joint, message: can.Message) -> None:
        if len(message.data) != cd.SENSOR_TPDO1.size:
            return
        joint.position, joint.pressure_a, joint.pressure_b = cd.SENSOR_TPDO1.unpack(
            message.data)
        joint.stamp = message.timestamp
        joint.sensor.seen = True
        self._received(joint, _SENSOR_TPDO1)

    def _on_sensor_tpdo2(self, joint: _Joint, message: can.Message) -> None:
        if len(message.data) != cd.SENSOR_TPDO2.size:
            return
        joint.velocity_sensor, joint.status, joint.counter = cd.SENSOR_TPDO2.unpack(
            message.data)
        joint.sensor.seen = True
        self._received(joint, _SENSOR_TPDO2)

    def _received(self, joint: _Joint, which: int) -> None:
        """Note a TPDO; once a joint's three are in, queue its sample."""
        joint.received |= which
        if joint.received != _ALL_TPDOS:
            return
        joint.received = 0
        config = joint.config
        values = decode_sensors(joint.position, joint.pressure_a, joint.pressure_b,
                                joint.velocity_sensor, joint.status, config.stroke)
        fault = values.fault
        joint.fault = fault
        key = ('sensor', config.name)
        if fault is not None:
            self._latch(key, config.name, SafetyKind.SENSOR_FAULT, fault.value, fault.limit,
                        f'{joint.sensor.label}: {fault.text}')
        else:
            self._latch_state.forget({key})
        units = self._units
        speed = units.velocity_from_drive(joint.velocity)
        self._samples.append(JointSample(
            config.name, joint.stamp, values.position, values.velocity, values.pressure_a,
            values.pressure_b, speed, units.velocity_from_drive(joint.target),
            units.current_from_drive(joint.current),
            infer_valve_mode(config, joint.state, speed, values.pressure_a, values.pressure_b),
            joint.state, fault is not None, joint.counter))

    # --- frames out ----------------------------------------------------------------------------
    def _send(self, message: can.Message) -> bool:
        try:
            self.bus.send(message, timeout=self.config.period / 2)
        except can.CanError as exc:
            self._send_failed = (f'sending CAN frame 0x{message.arbitration_id:03X} failed: '
                                 f'{exc}')
            self._send_failed_sync = self._sync_count
            return False
        return True

    def _send_nmt(self, command: int, node: int) -> None:
        self._send(can.Message(arbitration_id=cd.NMT_COB_ID, data=bytes((command, node)),
                               is_extended_id=False))

    def _produce_heartbeat(self, now: float) -> None:
        due = self._heartbeat_due
        if due is None or now < due:
            return
        self._send(self._heartbeat)
        period = self.config.heartbeat_period
        due += period
        self._heartbeat_due = due if due > now else now + period

    def _send_best_effort_stop(self) -> None:
        """Send every drive quick stop at target 0 and a SYNC, ignoring send errors."""
        for joint in self._joints:
            cd.DRIVE_RPDO1.pack_into(joint.rpdo.data, 0, cd.CW_QUICK_STOP, 0)
            self._send(joint.rpdo)
        self._send(self._sync)

    def _index(self, joint: str) -> int:
        index = self._indices.get(joint)
        if index is None:
            msg = (f'joint {joint!r} is not on this bus: the master serves '
                   f'{", ".join(self.joints)}')
            raise HardwareConfigError(msg)
        return index


def _drain(queue: collections.deque[_T]) -> list[_T]:
    items: list[_T] = []
    while True:
        try:
            items.append(queue.popleft())
        except IndexError:
            return items


def _fault_text(code: int | None) -> str:
    if code is None:
        return 'no EMCY received since it entered fault'
    return f'error code 0x{code:04X} {cd.ERROR_CODES.get(code, "unknown error")}'


def _nmt_name(state: int | None) -> str:
    if state is None:
        return 'none (no heartbeat)'
    return _NMT_STATE_NAMES.get(state, f'0x{state:02X}')
