"""The master's supervision: the faults that hold, the stop latch they set, and the reset.

Each fault is a FATAL :class:`~exo_has_driver.events.Event` that latches the stop: a drive in
fault or an EMCY, a drive that leaves operation enabled by itself while enabled, a statusword
of no CiA 402 state (DRIVE_FAULT, value the error code; a sensor board's EMCY is a
SENSOR_FAULT), a heartbeat older than the consumer time or a slave that reports another NMT
state than operational or boots (HEARTBEAT_LOST), no TPDO from a slave for ``missing_syncs``
SYNC periods, a failed send or receive, a bus-off or error-passive bus (BUS_OFF), a sensor
channel without reading, flagged by the board or out of range (SENSOR_FAULT), an e-stop
request (E_STOP), and the conditions the caller holds (a second source of a joint's topics).
One method lists the conditions that hold (:meth:`Supervision.conditions`): supervision
latches them, a reset is refused while they hold. A condition is reported once when it starts
(FATAL) and once when it has been absent for :data:`~exo_has_driver.events.CLEAR_TIME` (INFO,
phase CLEAR), as the watchdog's are: one that comes and goes faster (a slave's TPDOs lost now
and then on a loaded machine) stays one condition, where it was reported at every return.
Events that are not states (an EMCY, a drive leaving operation enabled, an e-stop) are latched
where they come (:meth:`Supervision.report`).

:meth:`Supervision.reset` works in two phases: refused (a WARN event naming what holds) while a
condition other than a drive in fault holds; else the drives in fault get one rising edge of
the fault reset bit while the stop still holds, and once every drive has left fault (within
:data:`FAULT_RESET_TIME`, :meth:`Supervision.finish_reset` at each SYNC) the latch is released
(a RESET event) and the drives go through the enable sequence again, at zero speed until the
next command; a drive still in fault then refuses the reset (WARN). A slave that booted while
running holds until the driver restarts: its configuration is lost.

Only the master's I/O thread calls it once that runs (the caller's thread before, at start).
"""

from __future__ import annotations

import collections
import math
from collections.abc import Callable, Hashable, Sequence
from dataclasses import replace

from exo_has_driver import can_dictionary as cd
from exo_has_driver.events import (
    Clearing,
    Condition,
    Event,
    Phase,
    SafetyKind,
    Severity,
    StopLatch,
)
from exo_has_driver.hardware import cia402, frames
from exo_has_driver.hardware.config import MasterConfig
from exo_has_driver.hardware.records import JointRecord, SlaveRecord

#: How long a drive has to leave fault after its fault reset edge [s].
FAULT_RESET_TIME = 0.1
#: How long an error frame's or a failed receive's bus fault counts as holding [s].
ERROR_FRAME_HOLD = 1.0

_NAN = math.nan
# Keys of the conditions that are reported again after they stopped holding for a while.
_CONDITION_KEYS = frozenset({'missing', 'heartbeat', 'sensor', 'bus state', 'send', 'held',
                             'error frame', 'receive'})
_Key = tuple[object, ...]


class Supervision:
    """The fault conditions of the master's slaves and bus, its stop latch and its reset.

    Parameters
    ----------
    config : MasterConfig
        Timing (heartbeat consumer time, missing SYNCs, period).
    joints : Sequence[JointRecord]
        The master's records of the joints and their slaves, which it keeps up to date.
    on_release : callable
        Called with the time [s] when a reset releases the latch, before the RESET event is
        queued (the master zeroes the commands there).

    """

    def __init__(self, config: MasterConfig, joints: Sequence[JointRecord],
                 on_release: Callable[[float], None]) -> None:
        self.config = config
        self._joints = joints
        self._slaves = [slave for joint in joints for slave in (joint.drive, joint.sensor)]
        self._on_release = on_release
        self._latch = StopLatch()
        #: Events raised and not yet taken, oldest first.
        self.events: collections.deque[Event] = collections.deque()
        # Conditions the caller finds (a second publisher of a joint's topics): swapped whole.
        self._held: tuple[Condition, ...] = ()
        #: The bus state's fault, as the master last polled it; None while the bus is sound.
        self.state_fault: str | None = None
        self._send_failed: str | None = None
        self._send_failed_sync = -1
        self._frame_fault: str | None = None
        self._frame_fault_time = -math.inf
        self._receive_fault: str | None = None
        self._receive_fault_time = -math.inf
        # End of the second phase of a reset: drives sent a fault reset edge must leave fault.
        self._reset_until: float | None = None
        # The conditions reported and not cleared, by key, and since when each is absent.
        self._reported: dict[Hashable, Condition] = {}
        self._clearing: Clearing[Hashable] = Clearing()

    @property
    def latched(self) -> bool:
        """Whether a stop is latched."""
        return self._latch.latched

    @property
    def cause(self) -> Event | None:
        """The event that latched the stop, None when not latched."""
        return self._latch.cause

    @property
    def resetting(self) -> bool:
        """Whether a reset waits for the drives in fault to leave it."""
        return self._reset_until is not None

    def hold(self, conditions: Sequence[Condition]) -> None:
        """Set the fault conditions the caller finds, in place of those it set before.

        Their keys are made the master's (``('held', key)``), so that they cannot meet its own.
        """
        self._held = tuple(replace(condition, key=('held', condition.key))
                           for condition in conditions)

    def report(self, key: _Key, joint: str, kind: SafetyKind, value: float, limit: float,
               text: str) -> None:
        """Raise a FATAL event for a condition not yet reported, and latch the stop."""
        self.events += self._latch.report_once(Condition(key, joint, kind, value, limit, text))

    def forget(self, key: _Key) -> None:
        """Forget a condition that no longer holds: it is reported again should it return."""
        self._latch.forget({key})

    def send_failed(self, text: str, sync_count: int) -> None:
        """Note a failed send in SYNC period ``sync_count``: a fault in it and the next."""
        self._send_failed = text
        self._send_failed_sync = sync_count

    def error_frame(self, text: str, now: float) -> None:
        """Note an error frame's bus fault at ``now`` [s]: a fault for ERROR_FRAME_HOLD."""
        self._frame_fault = text
        self._frame_fault_time = now

    def receive_failed(self, text: str, now: float) -> None:
        """Note a failed receive at ``now`` [s]: a fault for ERROR_FRAME_HOLD."""
        self._receive_fault = text
        self._receive_fault_time = now

    def supervise(self, now: float, sync_count: int) -> None:
        """Latch the conditions that hold now; report cleared those absent for CLEAR_TIME."""
        conditions = self.conditions(now, sync_count)
        for condition in conditions:
            self._clearing.holds(condition.key)
            started = self._latch.report_once(condition)
            if started:
                self._reported[condition.key] = condition
                self.events += started
        holding = {condition.key for condition in conditions}
        reported = self._latch.reported
        for key in [k for k in self._reported if k not in reported]:
            del self._reported[key]  # forgotten otherwise (a reset): no clear to report
            self._clearing.holds(key)
        for key in self._reported:
            if key not in holding and isinstance(key, tuple) and key[0] in _CONDITION_KEYS:
                self._clearing.absent(key, now)
        due = self._clearing.due(now)
        for key in [k for k in self._reported if k in due]:
            condition = self._reported.pop(key)
            self._latch.forget({key})
            self.events.append(Event(condition.joint, condition.kind, Severity.INFO, _NAN, _NAN,
                                     self._latch.latched, f'cleared: {condition.text}',
                                     Phase.CLEAR))

    def conditions(self, now: float, sync_count: int) -> list[Condition]:
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
                    f'{joint.drive.label} in {joint.state} ({frames.fault_text(code)})'))
            if joint.fault is not None:
                conditions.append(Condition(
                    ('sensor', name), name, SafetyKind.SENSOR_FAULT, joint.fault.value,
                    joint.fault.limit, f'{joint.sensor.label}: {joint.fault.text}'))
        bus_checks: tuple[tuple[str, str | None], ...] = (
            ('bus state', self.state_fault), ('send', self._send_fault(sync_count)),
            ('error frame', self._held_fault(self._frame_fault, self._frame_fault_time, now)),
            ('receive', self._held_fault(self._receive_fault, self._receive_fault_time, now)))
        for key, text in bus_checks:
            if text is not None:
                conditions.append(Condition((key,), '', SafetyKind.BUS_OFF, _NAN, _NAN, text))
        conditions.extend(self._held)
        return conditions

    def reset(self, now: float, sync_count: int) -> None:
        """First phase of a reset: refuse it, or send the drives in fault a reset edge."""
        if not self._latch.latched:
            self.events.append(self._latch.release())  # says none was latched
            return
        if self._reset_until is not None:
            return  # the reset asked for before is under way
        if self._refuse_reset(self.conditions(now, sync_count)):
            return
        # Drives in fault get their reset edge while the stop still holds; the latch is
        # released only once every one of them has left fault (finish_reset).
        armed = [joint for joint in self._joints if cia402.is_fault(joint.state)]
        for joint in armed:
            self.arm_fault_reset(joint, now)
        self._reset_until = max((joint.fault_reset_until for joint in armed), default=now)
        self.finish_reset(now, sync_count)

    def finish_reset(self, now: float, sync_count: int) -> None:
        """Second phase of a reset: release once no drive is in fault, refuse at the time."""
        if self._refuse_reset(self.conditions(now, sync_count)):
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
                              f'({frames.fault_text(j.emcy_code)})' for j in in_fault)
            self.events.append(Event(joint.config.name, SafetyKind.DRIVE_FAULT, Severity.WARN,
                                     float(code) if code is not None else _NAN, _NAN, True,
                                     f'reset refused: {texts}'))
            return
        self._reset_until = None
        self._on_release(now)
        self.events.append(self._latch.release())

    def arm_fault_reset(self, joint: JointRecord, now: float) -> None:
        """Allow one fault reset edge and give the drive time to leave fault."""
        joint.fault_reset = True
        joint.fault_reset_until = now + FAULT_RESET_TIME + 2 * self.config.period

    def _refuse_reset(self, conditions: list[Condition]) -> bool:
        """WARN and return True if a condition other than a drive in fault holds."""
        refusal = self._latch.refusal(
            [condition for condition in conditions if condition.kind != SafetyKind.DRIVE_FAULT])
        if refusal is None:
            return False
        self.events.append(refusal)
        return True

    def _heartbeat_fault(self, slave: SlaveRecord, now: float) -> str | None:
        if slave.rebooted:
            return ('booted (boot-up message) while running: its configuration is lost, '
                    'restart the driver')
        if slave.heartbeat_state != cd.NMT_OPERATIONAL:
            return f'reports NMT state {frames.nmt_name(slave.heartbeat_state)}, not operational'
        if slave.heartbeat_time is None or now - slave.heartbeat_time > \
                self.config.heartbeat_timeout:
            age = now - slave.heartbeat_time if slave.heartbeat_time is not None else _NAN
            return (f'heartbeat lost: none for {age:.3f} s (consumer time '
                    f'{self.config.heartbeat_timeout:.3f} s)')
        return None

    def _send_fault(self, sync_count: int) -> str | None:
        if self._send_failed is not None and self._send_failed_sync >= sync_count - 1:
            return self._send_failed
        return None

    @staticmethod
    def _held_fault(text: str | None, since: float, now: float) -> str | None:
        if text is not None and now - since <= ERROR_FRAME_HOLD:
            return text
        return None
