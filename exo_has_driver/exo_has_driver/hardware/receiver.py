"""Frames from the slaves: decoded into the master's records, their faults raised, samples made.

The master hands every frame it receives to :meth:`Receiver.on_frame` (its I/O thread; the
caller's thread during the start, before that runs). TPDOs are decoded (:mod:`.frames`) as they
come; once a joint's three TPDOs are in, a :class:`~.config.JointSample` is queued, stamped with
the receive time of the sensor board's TPDO1 (``Message.timestamp``: the kernel's on
SocketCAN). Heartbeats and SDO answers are recorded; what a frame reports that is a fault (an
EMCY, a boot-up while running, a statusword of no CiA 402 state, a drive that left operation
enabled by itself, a sensor fault, an error frame) goes to the master's
:class:`~.supervision.Supervision`.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable, Sequence
from functools import partial

import can

from exo_has_driver import can_dictionary as cd
from exo_has_driver.events import SafetyKind
from exo_has_driver.hardware import cia402, frames
from exo_has_driver.hardware.bus import error_frame_fault
from exo_has_driver.hardware.config import JointSample, MasterConfig, infer_valve_mode
from exo_has_driver.hardware.records import (
    ALL_TPDOS,
    DRIVE_TPDO,
    SENSOR_TPDO1,
    SENSOR_TPDO2,
    JointRecord,
    SlaveRecord,
)
from exo_has_driver.hardware.supervision import Supervision
from exo_has_driver.hardware.units import decode_sensors

#: Samples kept for the caller: a second of four joints at 200 Hz.
SAMPLE_QUEUE = 800

_NAN = math.nan


class Receiver:
    """Handles the frames the slaves send; see the module docstring.

    Parameters
    ----------
    config : MasterConfig
        Units and timing.
    joints : Sequence[JointRecord]
        The master's records of the joints and their slaves, which the frames update.
    supervision : Supervision
        Where the faults the frames report are raised.
    clock : callable
        Monotonic time [s], the master's.

    """

    def __init__(self, config: MasterConfig, joints: Sequence[JointRecord],
                 supervision: Supervision, clock: Callable[[], float]) -> None:
        self.config = config
        self._joints = joints
        self._slaves = [slave for joint in joints for slave in (joint.drive, joint.sensor)]
        self._supervision = supervision
        self._report = supervision.report
        self._clock = clock
        self._units = config.units
        #: Samples completed and not yet taken, oldest first (the oldest dropped when full).
        self.samples: collections.deque[JointSample] = collections.deque(maxlen=SAMPLE_QUEUE)
        #: The newest SDO answer of each node, until the master takes it.
        self.sdo_answers: dict[int, bytes] = {}
        #: Whether the slaves were started: EMCYs count from then on, a boot-up is a fault.
        self.operational = False
        self._handlers: dict[int, Callable[[can.Message], None]] = {}
        self._register_handlers()

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

    def on_frame(self, message: can.Message) -> None:
        """Handle a frame received from the bus."""
        if message.is_error_frame:
            fault = error_frame_fault(message)
            if fault is not None:
                self._supervision.error_frame(fault, self._clock())
            return
        handler = self._handlers.get(message.arbitration_id)
        if handler is not None and not message.is_remote_frame:
            handler(message)

    def _on_heartbeat(self, slave: SlaveRecord, message: can.Message) -> None:
        state = frames.heartbeat_state(message.data)
        if state is None:
            return
        slave.heartbeat_state = state
        slave.heartbeat_time = self._clock()
        if state == cd.NMT_BOOT_UP:
            slave.booted = True
            if self.operational:
                slave.rebooted = True
                self._report(('heartbeat', slave.node), slave.joint, SafetyKind.HEARTBEAT_LOST,
                             0.0, self.config.heartbeat_timeout,
                             f'{slave.label}: booted (boot-up message) while running: its '
                             f'configuration is lost, restart the driver')

    def _on_sdo(self, node: int, message: can.Message) -> None:
        self.sdo_answers[node] = bytes(message.data)

    def _on_emcy(self, joint: JointRecord, is_drive: bool, message: can.Message) -> None:
        if not self.operational:
            return
        emcy = frames.emcy(message.data)
        if emcy is None:
            return  # too short, or code 0: a fault was cleared
        code, register = emcy
        name = cd.ERROR_CODES.get(code, 'unknown error')
        if is_drive:
            joint.emcy_code = code
            self._report(('drive', joint.config.name), joint.config.name,
                         SafetyKind.DRIVE_FAULT, float(code), _NAN,
                         f'{joint.drive.label}: EMCY 0x{code:04X} {name} (error register '
                         f'0x{register:02X})')
        else:
            self._report(('emcy', joint.sensor.node), joint.config.name,
                         SafetyKind.SENSOR_FAULT, float(code), _NAN,
                         f'{joint.sensor.label}: EMCY 0x{code:04X} {name} (error register '
                         f'0x{register:02X})')

    def _on_drive_tpdo(self, joint: JointRecord, message: can.Message) -> None:
        values = frames.drive_tpdo1(message.data)
        if values is None:
            return
        status, joint.velocity, joint.current = values
        before = joint.state
        state = joint.state = cia402.decode_state(status)
        joint.drive.seen = True
        name = joint.config.name
        if cia402.is_fault(before) and not cia402.is_fault(state):
            joint.emcy_code = None  # the next fault's code is unknown until its EMCY
        if state == cia402.UNKNOWN:
            self._report(('drive', name), name, SafetyKind.DRIVE_FAULT, _NAN, _NAN,
                         f'{joint.drive.label}: statusword 0x{status:04X} matches no CiA 402 '
                         f'state')
        elif before == cia402.OPERATION_ENABLED and state != before \
                and not cia402.is_fault(state) \
                and joint.enabled_syncs > self.config.missing_syncs:
            # Sent enable operation for longer than a TPDO may lag: the drive left by itself
            # (a fault is reported with its code by the supervision).
            self._report(('drive', name), name, SafetyKind.DRIVE_FAULT, _NAN, _NAN,
                         f'{joint.drive.label} left operation enabled for {state} by itself')
        self._received(joint, DRIVE_TPDO)

    def _on_sensor_tpdo1(self, joint: JointRecord, message: can.Message) -> None:
        values = frames.sensor_tpdo1(message.data)
        if values is None:
            return
        joint.position, joint.pressure_a, joint.pressure_b = values
        joint.stamp = message.timestamp
        joint.sensor.seen = True
        self._received(joint, SENSOR_TPDO1)

    def _on_sensor_tpdo2(self, joint: JointRecord, message: can.Message) -> None:
        values = frames.sensor_tpdo2(message.data)
        if values is None:
            return
        joint.velocity_sensor, joint.status, joint.counter = values
        joint.sensor.seen = True
        self._received(joint, SENSOR_TPDO2)

    def _received(self, joint: JointRecord, which: int) -> None:
        """Note a TPDO; once a joint's three are in, queue its sample."""
        joint.received |= which
        if joint.received != ALL_TPDOS:
            return
        joint.received = 0
        config = joint.config
        values = decode_sensors(joint.position, joint.pressure_a, joint.pressure_b,
                                joint.velocity_sensor, joint.status, config.stroke)
        fault = values.fault
        joint.fault = fault
        key = ('sensor', config.name)
        if fault is not None:
            self._report(key, config.name, SafetyKind.SENSOR_FAULT, fault.value, fault.limit,
                         f'{joint.sensor.label}: {fault.text}')
        else:
            self._supervision.forget(key)
        units = self._units
        speed = units.velocity_from_drive(joint.velocity)
        self.samples.append(JointSample(
            config.name, joint.stamp, values.position, values.velocity, values.pressure_a,
            values.pressure_b, speed, units.velocity_from_drive(joint.target),
            units.current_from_drive(joint.current),
            infer_valve_mode(config, joint.state, speed, values.pressure_a, values.pressure_b),
            joint.state, fault is not None, joint.counter))
