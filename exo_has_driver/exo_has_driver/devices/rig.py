"""The simulated HAS hardware of N joints on one CAN bus: drives, sensor boards and plants.

A :class:`Rig` owns, per joint, an :class:`exo_has_sim.plant.Plant` (hip or knee parameters
from the joint name, loaded as the plant node loads it: the default rod force of
``load_mass`` at the standing lever arm), a :class:`~exo_has_driver.devices.drive.Drive` and a
:class:`~exo_has_driver.devices.sensor_board.SensorBoard` at the node IDs of
``can_dictionary``. It listens to the bus with a python-can Notifier and runs one timer thread;
one lock serialises both and the fault-injection methods, so the devices need none.

Time is the wall clock (``clock``, by default ``time.monotonic``; a test may pass its own):
every SYNC advances all plants to now, then the drives apply their RPDOs and every device
sends its TPDOs. Without SYNC the timer thread advances the plants every ``tick`` once two
ticks passed without an advance, so a joint left alone keeps moving (sinks under its load).
The same thread produces the heartbeats and checks the consumed ones.

Fault injection (also the stdin protocol of :mod:`exo_has_driver.devices.main`):
:meth:`Rig.drive_fault`, :meth:`Rig.set_heartbeat`, :meth:`Rig.set_sensor`,
:meth:`Rig.set_silent`, :meth:`Rig.set_load`, :meth:`Rig.clear`.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from types import TracebackType

import can

from exo_has_common.joints import joint_type_of
from exo_has_driver import can_dictionary as cd
from exo_has_driver.devices.drive import Drive
from exo_has_driver.devices.sensor_board import SensorBoard
from exo_has_driver.devices.slave import NMT_STATE_NAMES, Slave
from exo_has_driver.errors import DeviceError, FaultInjectionError
from exo_has_sim.errors import SimulationError
from exo_has_sim.loads import default_load_force
from exo_has_sim.parameters import load_parameters
from exo_has_sim.plant import Plant

_LOG = logging.getLogger(__name__)

#: Carried mass per joint type [kg] the default loads are derived for, as the session's.
DEFAULT_LOAD_MASS = {'hip': 50.0, 'knee': 25.0}

#: EMCY code of a plant integration that failed (CiA 301: internal software error).
_INTERNAL_SOFTWARE = 0x6100


@dataclass
class Joint:
    """One joint's plant and its two devices."""

    name: str
    plant: Plant
    drive: Drive
    board: SensorBoard
    default_load: float  # N


class _Listener(can.Listener):
    def __init__(self, rig: Rig) -> None:
        self._rig = rig

    def on_message_received(self, msg: can.Message) -> None:
        self._rig.receive(msg)

    def on_error(self, exc: Exception) -> None:
        # Keep the Notifier running: a bad frame or a transient socket error is not fatal.
        _LOG.error('CAN receive error: %s', exc)


class Rig:
    """Simulated drives and sensor boards of ``joints`` on ``bus``; see the module docstring.

    Parameters
    ----------
    bus : can.BusABC
        The bus; the rig does not shut it down.
    joints : iterable of str
        Joint names (keys of ``can_dictionary.DRIVE_NODE_IDS``).
    load_mass : mapping
        Carried mass [kg] per joint type (``'hip'``, ``'knee'``); missing types take
        :data:`DEFAULT_LOAD_MASS`.
    initial_angle : float
        Joint angle of every plant at the start [rad], flexion positive.
    tick : float
        Period of the timer thread [s]: heartbeats, consumer checks, advancing without SYNC.
    clock : callable
        Time source [s].
    encoder_counts, gear_ratio, velocity_unit, current_unit
        Units of every :class:`Drive` (counts per motor revolution, motor revolutions per
        pump revolution, counts/s per velocity unit, A per current unit).

    Raises
    ------
    FaultInjectionError
        For an unknown or repeated joint.
    DeviceError, ParameterError
        For bad drive units or plant parameters.

    """

    def __init__(self, bus: can.BusABC, joints: Iterable[str] = tuple(cd.DRIVE_NODE_IDS), *,
                 load_mass: Mapping[str, float] | None = None, initial_angle: float = 0.0,
                 tick: float = cd.SYNC_PERIOD, clock: Callable[[], float] = time.monotonic,
                 encoder_counts: int = cd.ENCODER_COUNTS, gear_ratio: float = cd.GEAR_RATIO,
                 velocity_unit: float = cd.VELOCITY_UNIT,
                 current_unit: float = cd.CURRENT_UNIT) -> None:
        names = list(joints)
        if not names:
            msg = 'a rig needs at least one joint'
            raise FaultInjectionError(msg)
        if len(set(names)) != len(names):
            msg = f'joints repeated in {names}'
            raise FaultInjectionError(msg)
        if not (math.isfinite(tick) and tick > 0.0):
            msg = f'tick must be positive and finite [s], got {tick!r}'
            raise DeviceError(msg)
        masses = {**DEFAULT_LOAD_MASS, **(load_mass or {})}
        self._bus = bus
        self.tick = tick
        self.clock = clock
        self._lock = threading.RLock()
        self.joints: dict[str, Joint] = {}
        for name in names:
            if name not in cd.DRIVE_NODE_IDS:
                msg = f'unknown joint {name!r}: expected one of {", ".join(cd.DRIVE_NODE_IDS)}'
                raise FaultInjectionError(msg)
            params = load_parameters(joint_type_of(name))
            load = default_load_force(params, mass=masses[params.joint_type],
                                      standing_angle=initial_angle)
            plant = Plant(name, params, initial_angle=initial_angle, load_force=load)
            plant.warm_up()
            drive = Drive(cd.DRIVE_NODE_IDS[name], plant, self._send,
                          encoder_counts=encoder_counts, gear_ratio=gear_ratio,
                          velocity_unit=velocity_unit, current_unit=current_unit)
            board = SensorBoard(cd.SENSOR_NODE_IDS[name], plant, self._send)
            self.joints[name] = Joint(name, plant, drive, board, load)
        self.slaves: list[Slave] = [j.drive for j in self.joints.values()]
        self.slaves += [j.board for j in self.joints.values()]
        self._handlers: dict[int, Callable[[bytes, float], None]] = {
            0x000: self._on_nmt, cd.SYNC_COB_ID: self._on_sync}
        for joint in self.joints.values():
            drive, board = joint.drive, joint.board
            self._handlers[cd.RPDO1_BASE + drive.node_id] = self._rpdo_handler(drive)
            for slave in (drive, board):
                self._handlers[cd.SDO_RX_BASE + slave.node_id] = self._sdo_handler(slave)
        self._last_advance = 0.0
        self._notifier: can.Notifier | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.send_errors = 0
        self.syncs = 0

    # --- life cycle ----------------------------------------------------------------------------
    def start(self) -> None:
        """Listen to the bus, boot every device (boot-up messages), start the timer thread."""
        with self._lock:
            if self._thread is not None:
                return
            self._notifier = can.Notifier(self._bus, [_Listener(self)], timeout=0.1)
            now = self.clock()
            self._last_advance = now
            for slave in self.slaves:
                slave.boot(now)
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name='can-devices-timer',
                                            daemon=True)
            self._thread.start()

    def stop(self) -> None:
        """Stop the timer thread and the Notifier (the bus stays open)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
            self._thread = None
        if self._notifier is not None:
            self._notifier.stop(timeout=1.0)
            self._notifier = None

    def __enter__(self) -> Rig:
        self.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.stop()

    # --- bus -----------------------------------------------------------------------------------
    def _send(self, cob_id: int, data: bytes) -> None:
        try:
            self._bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))
        except can.CanError as error:
            self.send_errors += 1
            if self.send_errors == 1 or self.send_errors % 1000 == 0:
                _LOG.error('CAN send failed (%d so far): %s', self.send_errors, error)

    def receive(self, msg: can.Message) -> None:
        """Dispatch one received frame (the Notifier's thread calls this)."""
        if msg.is_error_frame or msg.is_remote_frame or msg.is_extended_id:
            return
        cob_id = msg.arbitration_id
        handler = self._handlers.get(cob_id)
        if handler is not None:
            with self._lock:
                handler(bytes(msg.data), self.clock())
        elif cd.HEARTBEAT_BASE < cob_id <= cd.HEARTBEAT_BASE + 127:
            with self._lock:
                now = self.clock()
                for slave in self.slaves:
                    slave.on_heartbeat(cob_id - cd.HEARTBEAT_BASE, now)

    def _on_nmt(self, data: bytes, now: float) -> None:
        for slave in self.slaves:
            slave.on_nmt(data, now)

    def _rpdo_handler(self, drive: Drive) -> Callable[[bytes, float], None]:
        def handle(data: bytes, now: float) -> None:
            drive.on_rpdo(data)
        return handle

    def _sdo_handler(self, slave: Slave) -> Callable[[bytes, float], None]:
        def handle(data: bytes, now: float) -> None:
            slave.on_sdo(data)
        return handle

    def _on_sync(self, data: bytes, now: float) -> None:
        self.syncs += 1
        self._advance(now)
        for joint in self.joints.values():
            sample = joint.plant.sample()
            for device in (joint.drive, joint.board):
                if not device.silent and device.nmt_state != cd.NMT_STOPPED:
                    device.on_sync(sample)

    # --- time ----------------------------------------------------------------------------------
    def _advance(self, now: float) -> None:
        elapsed = now - self._last_advance
        if elapsed < 1e-6:
            return
        self._last_advance = now
        for joint in self.joints.values():
            try:
                joint.plant.advance(elapsed)
            except SimulationError as error:
                _LOG.error('%s plant: %s', joint.name, error)
                joint.drive.fault(_INTERNAL_SOFTWARE)
            joint.drive.step(elapsed)

    def _run(self) -> None:
        while not self._stop.wait(self.tick):
            with self._lock:
                now = self.clock()
                if now - self._last_advance >= 2.0 * self.tick:
                    self._advance(now)
                for slave in self.slaves:
                    slave.poll(now)

    # --- fault injection -----------------------------------------------------------------------
    def joint(self, name: str) -> Joint:
        """Return the joint called ``name``.

        Raises
        ------
        FaultInjectionError
            For a joint this rig does not simulate.

        """
        joint = self.joints.get(name)
        if joint is None:
            msg = f'no joint {name!r} on this rig: {", ".join(self.joints)}'
            raise FaultInjectionError(msg)
        return joint

    def _select(self, name: str | None) -> list[Joint]:
        return list(self.joints.values()) if name in (None, 'all') else [self.joint(str(name))]

    def drive_fault(self, name: str, code: int, holds: bool = False) -> None:
        """Make the drive of joint ``name`` fault with CiA 301 error ``code`` (EMCY, 603Fh).

        With ``holds`` the cause persists until :meth:`clear`: fault resets are refused.
        """
        if not 0 < code <= 0xFFFF:
            msg = f'error code must be 0x0001 to 0xFFFF, got {code:#x}'
            raise FaultInjectionError(msg)
        with self._lock:
            for joint in self._select(name):
                joint.drive.fault_holds = holds
                joint.drive.fault(code)

    def set_heartbeat(self, name: str | None, on: bool, device: str = 'drive') -> None:
        """Stop (``on`` false) or resume the heartbeat of a joint's ``drive``, ``sensor``/``both``.

        Raises
        ------
        FaultInjectionError
            For an unknown joint or device.

        """
        if device not in ('drive', 'sensor', 'both'):
            msg = f'unknown device {device!r}: expected drive, sensor or both'
            raise FaultInjectionError(msg)
        with self._lock:
            for joint in self._select(name):
                if device in ('drive', 'both'):
                    joint.drive.heartbeat_enabled = on
                if device in ('sensor', 'both'):
                    joint.board.heartbeat_enabled = on

    def set_sensor(self, name: str, channel: str, value: float | None) -> None:
        """Report ``value`` (SI units; NaN: no reading) on a sensor channel; None: clear it."""
        with self._lock:
            self.joint(name).board.override(channel, value)

    def set_silent(self, name: str | None, silent: bool = True) -> None:
        """Cut (or reconnect) the devices of a joint, or of all (None or ``'all'``)."""
        with self._lock:
            for joint in self._select(name):
                joint.drive.silent = silent
                joint.board.silent = silent

    def set_load(self, name: str | None, force: float | None) -> None:
        """Set a joint's external rod force [N] (positive pushes in); None: its default load.

        Raises
        ------
        FaultInjectionError
            For an unknown joint or a non-finite force.

        """
        if force is not None and not math.isfinite(force):
            msg = f'load force must be finite [N], got {force!r}'
            raise FaultInjectionError(msg)
        with self._lock:
            for joint in self._select(name):
                joint.plant.set_load(joint.default_load if force is None else force)

    def clear(self, name: str | None = None) -> None:
        """Undo the injections on a joint (or all): heartbeats, sensors, silence, load.

        A drive fault is not undone here: its cause goes (a fault reset can then succeed), the
        master's fault reset clears it, as on hardware.
        """
        with self._lock:
            for joint in self._select(name):
                joint.drive.fault_holds = False
                for slave in (joint.drive, joint.board):
                    slave.heartbeat_enabled = True
                    slave.silent = False
                joint.board.overrides.clear()
                joint.plant.set_load(joint.default_load)

    def status(self) -> list[str]:
        """One line per device: node, NMT state, CiA 402 state or sensor values, injections."""
        lines = []
        with self._lock:
            for joint in self.joints.values():
                sample = joint.plant.sample()
                for slave in (joint.drive, joint.board):
                    flags = [f for f, on in (('silent', slave.silent),
                                             ('heartbeat off', not slave.heartbeat_enabled),
                                             ('master heartbeat lost', slave.consumer_lost))
                             if on]
                    if isinstance(slave, Drive):
                        detail = (f'{slave.state}, error 0x{slave.get(cd.ERROR_CODE):04X}, '
                                  f'motor {sample.motor_speed:.1f} rad/s')
                    else:
                        detail = (f'position {sample.position * 1e3:.2f} mm, pressure A '
                                  f'{sample.pressure_a * 1e-6:.2f} MPa, load '
                                  f'{sample.load_force:.0f} N')
                        flags += [f'{c} {v:g}' for c, v in joint.board.overrides.items()]
                    extra = f' [{", ".join(flags)}]' if flags else ''
                    lines.append(f'{joint.name} {slave.kind} {slave.node_id}: '
                                 f'{NMT_STATE_NAMES[slave.nmt_state]}, {detail}{extra}')
        return lines
