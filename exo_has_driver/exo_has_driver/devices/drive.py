"""A simulated COPLEY-like CiA 402 motor drive in profile velocity mode, driving a HAS plant.

The drive's speed loop is what :class:`exo_has_sim.plant.Plant` models (a first-order motor
with the plant's ``motor_time_constant``), so the drive hands the plant the ramped target
speed as its command, enabled only in *operation enabled* and *quick stop active*; in every
other state the plant's command is disabled, the motor stops and the compact valve falls to
free mode (the joint sinks under its load, as a real unpowered HAS would).

Behaviour (``config/canopen/README.md``, CiA 402):

- state machine: not ready to switch on passes to *switch on disabled* at boot; shutdown
  (0x06), switch on (0x07), enable operation (0x0F; from *ready to switch on* it switches on
  and enables in one step, CiA 402's "switch on + enable operation"), disable operation
  (0x07 in *operation enabled*: to *switched on*, motor disabled at once: no slow-down ramp),
  disable voltage (0x00: to *switch on disabled*, motor coasts), quick stop (0x02); a fault
  goes straight to *fault* (the fault reaction is "disable the motor", so *fault reaction
  active* passes within the same call), and only a rising edge of controlword bit 7 leaves
  it, to *switch on disabled*, with an EMCY "error reset" (0000h). Controlword bit 8 (halt)
  brakes to 0 on the profile deceleration and stays in *operation enabled*;
- modes of operation 6060h: only 3 (profile velocity); other values are refused by SDO with
  abort 06090030h. Quick stop option code 605Ah: only 2 (quick stop ramp 6085h, then
  *switch on disabled*); others are refused the same way. 6083h/6084h/6085h must be over 0;
- the setpoint ramps towards 60FFh at 6083h while its magnitude grows and at 6084h while it
  falls (through zero: decelerate to 0, then accelerate), in drive velocity units per second;
- statusword 6041h: bits 0-6 per state (``can_dictionary.STATES``), bit 4 voltage enabled
  from *ready to switch on* on, bit 9 remote (always), bit 10 target reached (setpoint at the
  target and the actual velocity within :data:`VELOCITY_WINDOW` of it; in *quick stop
  active*: stopped), bit 12 speed zero (actual velocity within the window of 0);
- 606Ch: the plant's motor speed; 221Ch: the motor current of the pump torque (see
  :func:`motor_current`), 0 while the motor is not energised;
- faults: :meth:`Drive.fault` (fault injection, or the master's heartbeat lost: 8130h) sets
  603Fh (kept after the reset, "error code of the last fault") and the error register 1001h,
  sends an EMCY, disables the motor and enters *fault*;
- lost connection (CiA 402 abort connection option code 6007h, CiA 301 error behaviour
  1029h): when the master's heartbeat is lost (EMCY 8130h, error register bit 4, and EMCY
  0000h when it returns), or an NMT command takes the drive out of operational (stop, enter
  pre-operational, reset communication), the drive acts per 6007h: 0 nothing, 1 fault
  (8130h, or 8100h for the NMT command), 2 disable voltage (the motor coasts), 3 quick stop
  (ramp 6085h, then switch on disabled); the EDS default is 1. On the heartbeat loss 1029h
  sub 1 then sets the NMT state: 0 (default) pre-operational, 1 no change, 2 stopped;
- NMT reset node restarts the application (switch on disabled, motor off);
- :attr:`Drive.fault_holds` (fault injection): the cause of the fault persists, a fault
  reset edge is refused.
"""

from __future__ import annotations

import math
from pathlib import Path

from exo_has_driver import can_dictionary as cd
from exo_has_driver.devices.slave import (
    ABORT_INVALID_VALUE,
    EDS_DIR,
    Send,
    Slave,
    Value,
    error_register_for,
)
from exo_has_driver.errors import DeviceError, SdoAbortError
from exo_has_driver.hardware import cia402
from exo_has_sim.plant import Plant, PlantSample

#: EDS of the drive.
DRIVE_EDS = EDS_DIR / 'has_drive.eds'

#: Motor torque constant [N m/A], assumed: the paper gives the motor's 0.8 N m nominal and
#: 1.8 N m peak torque and 4000 r/min (section 2.4) but not its winding. A 48 V motor that
#: reaches 4000 r/min (419 rad/s) at about 85 % of its supply has a back-EMF constant of
#: 0.85 * 48 V / 419 rad/s = 0.097 V s/rad, which equals the torque constant in SI units:
#: 0.1 N m/A, so 8 A nominal and 18 A peak, within a COPLEY Accelnet's 10 A/20 A.
TORQUE_CONSTANT = 0.1

#: Velocity window of the target-reached and speed-zero bits [rad/s of the pump]: about
#: 10 r/min, far below the 4.7 rad/s that holds a 50 kg hip load against leakage.
VELOCITY_WINDOW = 1.0

_STATE_BITS = {
    cia402.NOT_READY: 0x0000,
    cia402.SWITCH_ON_DISABLED: 0x0040,
    cia402.READY_TO_SWITCH_ON: 0x0031,
    cia402.SWITCHED_ON: 0x0033,
    cia402.OPERATION_ENABLED: 0x0037,
    cia402.QUICK_STOP_ACTIVE: 0x0017,
    cia402.FAULT_REACTION_ACTIVE: 0x001F,
    cia402.FAULT: 0x0008,
}
_REMOTE = 0x0200
_TARGET_REACHED = 0x0400
_SPEED_ZERO = 0x1000
_HALT = 0x0100
_ENERGISED = (cia402.OPERATION_ENABLED, cia402.QUICK_STOP_ACTIVE)
_POWERED = (cia402.READY_TO_SWITCH_ON, cia402.SWITCHED_ON, *_ENERGISED)
_ABORT_CONNECTION_CODES = (cd.ABORT_CONNECTION_NO_ACTION, cd.ABORT_CONNECTION_FAULT,
                           cd.ABORT_CONNECTION_DISABLE_VOLTAGE, cd.ABORT_CONNECTION_QUICK_STOP)
_I32 = (-0x80000000, 0x7FFFFFFF)
_I16 = (-0x8000, 0x7FFF)


def ramp(current: float, target: float, acceleration: float, deceleration: float,
         elapsed: float) -> float:
    """Move a velocity setpoint towards ``target`` for ``elapsed`` seconds.

    ``acceleration`` applies while the magnitude grows, ``deceleration`` while it falls; a
    change of sign decelerates to 0 first. Units are the caller's (velocity, velocity per
    second); the rates must be positive.
    """
    remaining = elapsed
    while remaining > 0.0 and current != target:
        if current > 0.0 and target < current:
            end, rate = max(target, 0.0), deceleration
        elif current < 0.0 and target > current:
            end, rate = min(target, 0.0), deceleration
        else:
            end, rate = target, acceleration
        needed = abs(end - current) / rate
        if needed > remaining:
            return current + math.copysign(rate * remaining, end - current)
        remaining -= needed
        current = end
    return current


def motor_current(sample: PlantSample, pump_displacement: float, efficiency: float,
                  gear_ratio: float, torque_constant: float) -> float:
    """Motor current [A] that drives the pump against the chamber pressures of ``sample``.

    The pump's ideal torque is ``D * (p_A - p_B)`` [N m] (D in m^3/rad, positive speed pumps
    into chamber A); the motor supplies it divided by the pump's mechanical efficiency while
    it drives the pump (or holds the load), times it while the load drives the pump back;
    the gear divides it. Motor friction and inertia are neglected.
    """
    torque = pump_displacement * (sample.pressure_a - sample.pressure_b)
    if torque * sample.motor_speed >= 0.0:
        torque /= efficiency
    else:
        torque *= efficiency
    return torque / gear_ratio / torque_constant


def saturate(value: float, low: int, high: int) -> int:
    """``value`` rounded to an integer within [low, high] (NaN gives 0)."""
    if math.isnan(value):
        return 0
    return int(min(max(round(value) if math.isfinite(value) else value, low), high))


class Drive(Slave):
    """A CiA 402 drive in profile velocity mode on one joint's plant; see the module docstring.

    Parameters
    ----------
    node_id : int
        CANopen node ID.
    plant : Plant
        The joint the drive's motor turns.
    send : callable
        ``send(cob_id, data)``.
    encoder_counts : int
        Encoder counts per motor revolution.
    gear_ratio : float
        Motor revolutions per pump revolution.
    velocity_unit : float
        Encoder counts/s per drive velocity unit.
    current_unit : float
        Amperes per drive current unit.
    torque_constant : float
        Motor torque constant [N m/A].
    eds : Path
        The drive's EDS file.

    Raises
    ------
    DeviceError
        For a unit that is not positive and finite, or an EDS that does not load.

    """

    kind = 'drive'

    def __init__(self, node_id: int, plant: Plant, send: Send, *,
                 encoder_counts: int = cd.ENCODER_COUNTS, gear_ratio: float = cd.GEAR_RATIO,
                 velocity_unit: float = cd.VELOCITY_UNIT,
                 current_unit: float = cd.CURRENT_UNIT,
                 torque_constant: float = TORQUE_CONSTANT, eds: Path = DRIVE_EDS) -> None:
        for name, value in (('encoder_counts', encoder_counts), ('gear_ratio', gear_ratio),
                            ('velocity_unit', velocity_unit), ('current_unit', current_unit),
                            ('torque_constant', torque_constant)):
            if not (math.isfinite(value) and value > 0):
                msg = f'drive {node_id}: {name} must be positive and finite, got {value!r}'
                raise DeviceError(msg)
        super().__init__(node_id, eds, send)
        self.plant = plant
        self.gear_ratio = float(gear_ratio)
        self.current_unit = float(current_unit)
        self.torque_constant = float(torque_constant)
        #: Pump speed [rad/s] per drive velocity unit.
        self.rad_s_per_unit = velocity_unit * 2.0 * math.pi / (encoder_counts * gear_ratio)
        self._window = VELOCITY_WINDOW / self.rad_s_per_unit
        self.state = cia402.NOT_READY
        self.setpoint = 0.0  # ramp output [drive velocity units]
        self._pending: tuple[int, int] | None = None
        self._last_controlword = 0
        self._rpdo_ok = True
        self._tpdo_ok = True
        #: Whether the cause of a fault persists (fault injection): a fault reset edge is then
        #: refused, the drive stays in fault, as a hot drive does.
        self.fault_holds = False

    # --- units ------------------------------------------------------------------------------
    def to_units(self, pump_speed: float) -> float:
        """Drive velocity units of a pump speed [rad/s]."""
        return pump_speed / self.rad_s_per_unit

    def to_rad_s(self, units: float) -> float:
        """Pump speed [rad/s] of drive velocity units."""
        return units * self.rad_s_per_unit

    # --- application hooks -------------------------------------------------------------------
    def _reset_application(self) -> None:
        self.state = cia402.SWITCH_ON_DISABLED  # not ready to switch on passes at once
        self.setpoint = 0.0
        self._pending = None
        self._last_controlword = 0
        self._command_plant()
        self._update_flags()
        self._update_outputs(self.plant.sample())

    def _check_write(self, index: int, subindex: int, value: Value) -> None:
        super()._check_write(index, subindex, value)
        where = f'drive {self.node_id} 0x{index:04X}'
        if index == cd.MODES_OF_OPERATION and value != cd.PROFILE_VELOCITY_MODE:
            msg = (f'{where}: mode of operation {value} not supported, only '
                   f'{cd.PROFILE_VELOCITY_MODE} (profile velocity)')
            raise SdoAbortError(ABORT_INVALID_VALUE, msg)
        if index == cd.QUICK_STOP_OPTION_CODE and value != cd.QUICK_STOP_RAMP_THEN_DISABLE:
            msg = (f'{where}: quick stop option code {value} not supported, only '
                   f'{cd.QUICK_STOP_RAMP_THEN_DISABLE}')
            raise SdoAbortError(ABORT_INVALID_VALUE, msg)
        if index == cd.ABORT_CONNECTION_OPTION_CODE and value not in _ABORT_CONNECTION_CODES:
            msg = f'{where}: abort connection option code {value} not supported, only 0 to 3'
            raise SdoAbortError(ABORT_INVALID_VALUE, msg)
        if index in (cd.PROFILE_ACCELERATION, cd.PROFILE_DECELERATION,
                     cd.QUICK_STOP_DECELERATION) and value == 0:
            msg = f'{where}: a ramp rate must be over 0 velocity units per second'
            raise SdoAbortError(ABORT_INVALID_VALUE, msg)
        self._check_pdo_write(index, subindex, value,
                              {cd.RPDO1_MAPPING: cd.DRIVE_RPDO1_MAP,
                               cd.TPDO1_MAPPING: cd.DRIVE_TPDO1_MAP},
                              {cd.RPDO1_COMMUNICATION: cd.RPDO1_BASE + self.node_id,
                               cd.TPDO1_COMMUNICATION: cd.TPDO1_BASE + self.node_id})

    def _written(self, index: int, subindex: int, value: Value) -> None:
        if index == cd.MODES_OF_OPERATION:
            self.values[(cd.MODES_OF_OPERATION_DISPLAY, 0)] = value
        elif index == cd.CONTROLWORD and isinstance(value, int):  # an UNSIGNED16: always
            self._controlword(value)
        elif index in (cd.RPDO1_COMMUNICATION, cd.RPDO1_MAPPING, cd.TPDO1_COMMUNICATION,
                       cd.TPDO1_MAPPING):
            self._update_flags()

    def _refresh(self, index: int) -> None:
        if index in (cd.STATUSWORD, cd.VELOCITY_ACTUAL, cd.CURRENT_ACTUAL):
            self._update_outputs(self.plant.sample())

    def _heartbeat_lost(self) -> None:
        # CiA 301's EMCY of a heartbeat consumer; the fault action (6007h = 1) sends its own.
        if self.state != cia402.FAULT \
                and self.get(cd.ABORT_CONNECTION_OPTION_CODE) != cd.ABORT_CONNECTION_FAULT:
            self.values[(cd.ERROR_REGISTER, 0)] = error_register_for(cd.ERROR_HEARTBEAT_LOST)
            self.send_emcy(cd.ERROR_HEARTBEAT_LOST)
        self._abort_connection(cd.ERROR_HEARTBEAT_LOST)

    def _heartbeat_back(self) -> None:
        if self.state != cia402.FAULT:
            self.values[(cd.ERROR_REGISTER, 0)] = 0
            self.send_emcy(0x0000)

    def _left_operational(self, code: int) -> None:
        self._abort_connection(code)

    def _abort_connection(self, code: int) -> None:
        """Stop the motor per the abort connection option code 6007h; a repeat does nothing."""
        option = self.get(cd.ABORT_CONNECTION_OPTION_CODE)
        state = self.state
        if option == cd.ABORT_CONNECTION_FAULT:
            self.fault(code)
        elif option == cd.ABORT_CONNECTION_DISABLE_VOLTAGE:
            if state in _POWERED:
                self._enter(cia402.SWITCH_ON_DISABLED)
        elif option == cd.ABORT_CONNECTION_QUICK_STOP:
            if state == cia402.OPERATION_ENABLED:
                self._enter(cia402.QUICK_STOP_ACTIVE)
            elif state in (cia402.READY_TO_SWITCH_ON, cia402.SWITCHED_ON):
                self._enter(cia402.SWITCH_ON_DISABLED)

    def _update_flags(self) -> None:
        self._rpdo_ok = self.pdo_enabled(cd.RPDO1_COMMUNICATION, cd.RPDO1_MAPPING)
        self._tpdo_ok = self.pdo_enabled(cd.TPDO1_COMMUNICATION, cd.TPDO1_MAPPING)

    # --- PDOs and SYNC -----------------------------------------------------------------------
    def on_rpdo(self, data: bytes) -> None:
        """Keep RPDO1 (controlword, target velocity) for the next SYNC."""
        if self.pdo_active and self._rpdo_ok and len(data) == cd.DRIVE_RPDO1.size:
            self._pending = cd.DRIVE_RPDO1.unpack(data)

    def on_sync(self, sample: PlantSample) -> None:
        """Apply the RPDO received before this SYNC, then send TPDO1 of the plant's ``sample``.

        The plant must have been advanced to the SYNC already.
        """
        if self._pending is not None:
            controlword, target = self._pending
            self._pending = None
            self.values[(cd.TARGET_VELOCITY, 0)] = target
            self.values[(cd.CONTROLWORD, 0)] = controlword
            self._controlword(controlword)
        statusword, velocity, current = self._update_outputs(sample)
        if self.pdo_active and self._tpdo_ok:
            self.send(cd.TPDO1_BASE + self.node_id,
                      cd.DRIVE_TPDO1.pack(statusword, velocity, current))

    def step(self, elapsed: float) -> None:
        """Advance the ramp by ``elapsed`` seconds and command the plant with the setpoint."""
        if self.state == cia402.OPERATION_ENABLED:
            get = self.get
            target = 0 if get(cd.CONTROLWORD) & _HALT else get(cd.TARGET_VELOCITY)
            self.setpoint = ramp(self.setpoint, float(target),
                                 float(get(cd.PROFILE_ACCELERATION)),
                                 float(get(cd.PROFILE_DECELERATION)), elapsed)
        elif self.state == cia402.QUICK_STOP_ACTIVE:
            rate = float(self.get(cd.QUICK_STOP_DECELERATION))
            self.setpoint = ramp(self.setpoint, 0.0, rate, rate, elapsed)
            if self.setpoint == 0.0:
                self.state = cia402.SWITCH_ON_DISABLED  # 605Ah = 2
        self._command_plant()

    def _command_plant(self) -> None:
        if self.state in _ENERGISED:
            self.plant.command(self.plant.joint, self.setpoint * self.rad_s_per_unit, True)
        else:
            self.plant.command(self.plant.joint, 0.0, False)

    def _update_outputs(self, sample: PlantSample) -> tuple[int, int, int]:
        velocity = self.to_units(sample.motor_speed)
        statusword = _STATE_BITS[self.state] | _REMOTE
        if abs(velocity) <= self._window:
            statusword |= _SPEED_ZERO
        if self.state == cia402.OPERATION_ENABLED:
            controlword = self.get(cd.CONTROLWORD)
            target = 0 if controlword & _HALT else self.get(cd.TARGET_VELOCITY)
            if self.setpoint == target and abs(velocity - target) <= self._window:
                statusword |= _TARGET_REACHED
        elif self.state == cia402.QUICK_STOP_ACTIVE and abs(velocity) <= self._window:
            statusword |= _TARGET_REACHED
        if self.state in _ENERGISED:
            params = self.plant.params
            amperes = motor_current(sample, params.pump_displacement,
                                    params.pump_mechanical_efficiency, self.gear_ratio,
                                    self.torque_constant)
        else:
            amperes = 0.0
        current = saturate(amperes / self.current_unit, *_I16)
        velocity_raw = saturate(velocity, *_I32)
        values = self.values
        values[(cd.STATUSWORD, 0)] = statusword
        values[(cd.VELOCITY_ACTUAL, 0)] = velocity_raw
        values[(cd.CURRENT_ACTUAL, 0)] = current
        return statusword, velocity_raw, current

    # --- CiA 402 state machine -----------------------------------------------------------------
    def _controlword(self, controlword: int) -> None:
        reset_edge = bool(controlword & 0x80 and not self._last_controlword & 0x80)
        self._last_controlword = controlword
        state = self.state
        new = state
        if state == cia402.FAULT:
            if reset_edge and not self.fault_holds:
                new = cia402.SWITCH_ON_DISABLED
                self.values[(cd.ERROR_REGISTER, 0)] = 0
                self.send_emcy(0x0000)  # error reset
        elif controlword & 0x82 == 0x00:  # disable voltage
            if state != cia402.SWITCH_ON_DISABLED:
                new = cia402.SWITCH_ON_DISABLED
        elif controlword & 0x86 == 0x02:  # quick stop
            if state in (cia402.READY_TO_SWITCH_ON, cia402.SWITCHED_ON):
                new = cia402.SWITCH_ON_DISABLED
            elif state == cia402.OPERATION_ENABLED:
                new = cia402.QUICK_STOP_ACTIVE
        elif controlword & 0x87 == 0x06:  # shutdown
            if state in (cia402.SWITCH_ON_DISABLED, cia402.SWITCHED_ON, cia402.OPERATION_ENABLED):
                new = cia402.READY_TO_SWITCH_ON
        elif controlword & 0x8F == 0x07:  # switch on; disable operation
            if state in (cia402.READY_TO_SWITCH_ON, cia402.OPERATION_ENABLED):
                new = cia402.SWITCHED_ON
        elif controlword & 0x8F == 0x0F and state in (cia402.READY_TO_SWITCH_ON,
                                                      cia402.SWITCHED_ON):
            new = cia402.OPERATION_ENABLED
        if new != state:
            self._enter(new)

    def _enter(self, state: str) -> None:
        if state not in _ENERGISED or self.state not in _ENERGISED:
            self.setpoint = 0.0  # the motor was (or becomes) unpowered
        self.state = state
        self._command_plant()
        self._update_outputs(self.plant.sample())

    def fault(self, code: int) -> None:
        """Enter *fault* with CiA 301 error ``code``: 603Fh, 1001h, EMCY, motor disabled.

        A second, different code while in fault is recorded and sent as another EMCY.

        Raises
        ------
        DeviceError
            For a code outside 1 to FFFFh.

        """
        if not 0 < code <= 0xFFFF:
            msg = f'drive {self.node_id}: error code must be 0x0001 to 0xFFFF, got {code:#x}'
            raise DeviceError(msg)
        if self.state == cia402.FAULT and self.get(cd.ERROR_CODE) == code:
            return
        self.values[(cd.ERROR_CODE, 0)] = code
        self.values[(cd.ERROR_REGISTER, 0)] = error_register_for(code)
        self._pending = None
        self._enter(cia402.FAULT)
        self.send_emcy(code)
