"""The CANopen master of the HAS joints: the I/O thread and the SYNC cycle.

One :class:`Master` serves N joints (a CiA 402 drive and a sensor board each) on one python-can
bus, as ``config/canopen/README.md`` specifies; it is the one entry point of this package,
configured with :class:`~.config.MasterConfig`.

Start (:meth:`Master.start`, blocking, each wait bounded): the master's heartbeat starts, then
:func:`.startup.start_slaves` resets, configures over SDO and starts every slave (identity,
cycle and heartbeat times, what a drive does on a lost connection, its mode and ramps, each
PDO checked and rewritten where it differs from :mod:`exo_has_driver.can_dictionary`; a drive
in a fault other than the master's heartbeat lost ends the start naming its code); then the
I/O thread runs and the drives are taken through the enable sequence (those in fault with
8130h through one fault reset first) to operation enabled at zero speed. A device that does
not answer raises :class:`CanOpenTimeoutError` naming the node and the object or step; a bus
that fails to receive, :class:`CanBusError`.

Cycle (the I/O thread, which alone owns the bus and the protocol state): it receives frames until
the next SYNC is due, then checks the slaves, writes every drive's RPDO1 (controlword from
:mod:`.cia402`, target velocity from the newest command, clamped to the joint's
``motor_speed_max``) and sends the SYNC; the master's heartbeat goes out every producer
period. Each frame received goes to the :class:`~.receiver.Receiver`, which decodes it and
completes the joints' samples. A failed receive is a bus fault; after
:data:`RECEIVE_FAILURES_MAX` in a row the thread ends (:attr:`Master.running` false,
:attr:`Master.failure` the error). The caller's thread only swaps a command tuple
(:meth:`set_command`), appends a request, or pops the queues (:meth:`take_samples`,
:meth:`take_events`): it never waits on the bus.

Control in the I/O thread (:attr:`Master.control`): a callable given the time [s] at the start
of every SYNC cycle, once the frames received are handled (the samples of the previous SYNC
complete) and before the requests, the supervision and the RPDOs: what it does through the
caller's methods above (commands, stop and reset requests) goes out with this very SYNC, with no
thread between the bus and the control law. The latched stop still overrides its commands.

Supervision (:class:`~.supervision.Supervision`) latches a stop on every fault of the slaves
and the bus, and releases it on a reset once none holds. While latched every drive is sent
quick stop (it brakes on its quick stop ramp to switch on disabled) and then disable voltage,
target 0, and a slave whose heartbeat reports pre-operational or stopped is sent NMT start,
so that these RPDOs reach it.

The ``canopen`` package (a dependency already: :mod:`.sdo` takes its SDO abort texts, the
simulated devices its object dictionaries) supplies none of the master's parts:

- ``canopen.Network`` reads the bus in a ``can.Notifier`` thread of its own and sends SYNC from
  python-can's ``send_periodic`` thread, where our I/O thread alone owns the bus and times the
  SYNC cycle itself.
- ``canopen.sdo.SdoClient`` waits on a queue that the network's reader thread fills, so on the
  thread that owns the bus it would wait without receiving (nor producing our heartbeat); it
  does not skip a late answer to an earlier request (a read fails on it, a write may take it
  for its own) and its errors name neither node nor object, both of which :mod:`.sdo` does.
- ``canopen.pdo`` maps read and write their configuration through that SDO client and decode
  received PDOs in callbacks subscribed on a ``Network``, where
  :func:`.startup.configure_pdo` checks the mappings against ``can_dictionary`` over
  :mod:`.sdo` and :mod:`.frames` unpacks each PDO with one struct.
- ``canopen.profiles.p402.BaseNode402`` is such a networked node whose state setter blocks its
  caller for up to 0.8 s, polling the statusword, where :mod:`.cia402` gives the I/O thread one
  controlword per SYNC period.
"""

from __future__ import annotations

import collections
import math
import threading
import time
from collections.abc import Callable, Sequence
from typing import TypeVar

import can

from exo_has_driver import can_dictionary as cd
from exo_has_driver.errors import (
    CanBusError,
    CanOpenError,
    CanOpenTimeoutError,
    HardwareConfigError,
)
from exo_has_driver.events import Condition, Event, SafetyKind
from exo_has_driver.hardware import cia402, frames, startup
from exo_has_driver.hardware.bus import bus_state_fault
from exo_has_driver.hardware.config import JointSample, MasterConfig
from exo_has_driver.hardware.receiver import Receiver
from exo_has_driver.hardware.records import JointRecord
from exo_has_driver.hardware.supervision import Supervision

#: Bus state polls: every this many SYNC periods (some interfaces ask the hardware).
BUS_STATE_EVERY = 10
#: Failed receives in a row after which the I/O thread gives up (after a failure it waits for
#: the next SYNC before it tries again: 0.5 s at 200 Hz).
RECEIVE_FAILURES_MAX = 100
#: Frames handled at most between two SYNCs' catch-up drains (a flooded bus must not hold up
#: the SYNC).
DRAIN_MAX = 256

_NAN = math.nan
_T = TypeVar('_T')


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
    control : callable or None
        Called by the I/O thread with the time [s] at each SYNC cycle (module docstring); the
        attribute :attr:`control` may be set at any time, read at each cycle. An exception it
        raises ends the I/O thread as a failed bus does (the drives are sent quick stop).

    """

    def __init__(self, bus: can.BusABC, config: MasterConfig,
                 clock: Callable[[], float] = time.monotonic,
                 control: Callable[[float], None] | None = None) -> None:
        self.bus = bus
        self.config = config
        self._clock = clock
        self.control = control
        self._units = config.units
        self._joints = [JointRecord(joint) for joint in config.joints]
        self._indices = {joint.config.name: index for index, joint in enumerate(self._joints)}
        self._slaves = [slave for joint in self._joints for slave in (joint.drive, joint.sensor)]
        now = clock()
        # (speed [rad/s], enable, receive time [s]) per joint; swapped whole by set_command.
        self._commands: list[tuple[float, bool, float]] = [(0.0, True, now)] * len(self._joints)
        self._requests: collections.deque[tuple[str, str]] = collections.deque()
        self._supervision = Supervision(config, self._joints, self._zero_commands)
        self._receiver = Receiver(config, self._joints, self._supervision, clock)
        self._heartbeat = frames.heartbeat(config.master_id)
        self._sync = frames.sync()
        self._heartbeat_due: float | None = None
        self._thread: threading.Thread | None = None
        self._stop_thread = threading.Event()
        self._shutting_down = False
        self._sync_count = 0
        self._receive_failures = 0
        self.failure: BaseException | None = None
        #: When the SYNC of the cycle being run was due [s] on the master's grid (the control
        #: sees its own lateness against it); NaN before the first cycle.
        self.sync_due = math.nan

    # --- the caller's side -------------------------------------------------------------------
    @property
    def joints(self) -> tuple[str, ...]:
        """The joints, in configuration order."""
        return tuple(joint.config.name for joint in self._joints)

    @property
    def latched(self) -> bool:
        """Whether a stop is latched."""
        return self._supervision.latched

    @property
    def cause(self) -> Event | None:
        """The event that latched the stop, None when not latched."""
        return self._supervision.cause

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

    def hold_conditions(self, conditions: Sequence[Condition]) -> None:
        """Set the fault conditions the caller finds, in place of those it set before.

        They count as the master's own from the next SYNC: each latches the stop once (a FATAL
        event), and a reset is refused while any is held. Their keys are made the master's
        (``('held', key)``), so that they cannot meet its own.
        """
        self._supervision.hold(conditions)

    def request_reset(self) -> None:
        """Ask to release the latched stop at the next SYNC (answered by an event)."""
        self._requests.append(('reset', ''))

    def take_samples(self) -> list[JointSample]:
        """Return the samples completed since the last call, oldest first."""
        return _drain(self._receiver.samples)

    def take_events(self) -> list[Event]:
        """Return the events raised since the last call, oldest first."""
        return _drain(self._supervision.events)

    # --- start and close ---------------------------------------------------------------------
    def start(self, enable: bool = True) -> None:
        """Bring every slave up and the drives to operation enabled at zero speed; blocking.

        With ``enable`` false the drives are left disabled (commanded so, at zero speed) and
        the call returns once the I/O thread runs: the caller's commands enable them, as a
        managed driver's activation does.

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
        if not enable:
            now = self._clock()
            self._commands = [(0.0, False, now)] * len(self._joints)
        self._thread = threading.Thread(target=self._run, name='can-master', daemon=True)
        self._thread.start()
        if not enable:
            return
        deadline = self._clock() + self.config.enable_timeout
        while not self.all_enabled():
            if self._supervision.latched or not self.running or self._clock() > deadline:
                self.close()
                if self.failure is not None:
                    msg = f'the CAN master failed while enabling the drives: {self.failure}'
                    raise CanOpenError(msg) from self.failure
                cause = self._supervision.cause
                if cause is not None:
                    msg = f'a fault while enabling the drives: {cause.text}'
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
        self._heartbeat_due = self._clock()
        for _ in range(DRAIN_MAX):  # forget frames from before the start (old boot-ups)
            if self.bus.recv(0.0) is None:
                break
        link = startup.Link(self._send_nmt, self._pump, self._exchange)
        in_fault = startup.start_slaves(link, self.config, self._joints)
        now = self._clock()
        for slave in self._slaves:
            slave.heartbeat_time = now
            slave.seen = True
            slave.missing = 0
        for joint in in_fault:
            # In fault from a lost master heartbeat only.
            self._supervision.arm_fault_reset(joint, now)
        self._receiver.operational = True

    def _exchange(self, node: int, request: bytes | None, timeout: float) -> bytes | None:
        """Send an SDO request and wait for the node's answer (the SdoClient's transport)."""
        answers = self._receiver.sdo_answers
        if request is not None:
            answers.pop(node, None)
            self._send(frames.sdo_request(node, request))
        self._pump(timeout, lambda: node in answers)
        return answers.pop(node, None)

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
                self._receiver.on_frame(message)
            elif wait <= 0.0 and now >= deadline:
                return

    # --- the I/O thread --------------------------------------------------------------------
    def _run(self) -> None:
        period = self.config.period
        on_frame = self._receiver.on_frame
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
                self.sync_due = next_sync
                self._cycle(clock())
                next_sync += period
                if next_sync < now:
                    next_sync = now + period  # held up: no burst of SYNCs
        except Exception as exc:  # the loop must not die silently: stop and tell
            self.failure = exc
            self._supervision.report(('failure',), '', SafetyKind.BUS_OFF, _NAN, _NAN,
                                     f'the CAN master loop failed: {exc!r}')
            self._send_best_effort_stop()

    def _receive(self, timeout: float) -> tuple[can.Message | None, bool]:
        """Receive a frame: (message or None, whether the bus answered).

        A failed receive (a bad datagram, a socket error) is a bus fault that holds for
        :data:`~.supervision.ERROR_FRAME_HOLD`; :data:`RECEIVE_FAILURES_MAX` in a row end the loop.

        Raises
        ------
        CanBusError
            After :data:`RECEIVE_FAILURES_MAX` failed receives in a row.

        """
        try:
            message = self.bus.recv(timeout)
        except can.CanError as exc:
            self._receive_failures += 1
            self._supervision.receive_failed(f'receiving from the CAN bus failed: {exc}',
                                             self._clock())
            if self._receive_failures >= RECEIVE_FAILURES_MAX:
                msg = f'{self._receive_failures} receives in a row failed, the last: {exc}'
                raise CanBusError(msg) from exc
            return None, False
        self._receive_failures = 0
        return message, True

    def _cycle(self, now: float) -> None:
        control = self.control
        if control is not None:
            control(now)  # its requests and commands go out with this SYNC
        while self._requests:
            kind, text = self._requests.popleft()
            if kind == 'stop':
                self._supervision.report(('e-stop',), '', SafetyKind.E_STOP, _NAN, _NAN,
                                         f'emergency stop: {text}')
            else:
                self._supervision.reset(now, self._sync_count)
        self._supervise(now)
        if self._supervision.resetting:
            self._supervision.finish_reset(now, self._sync_count)
        units = self._units
        command_timeout = self.config.command_timeout
        latched = self._supervision.latched
        for index, joint in enumerate(self._joints):
            if latched or self._shutting_down:
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
            frames.pack_rpdo1(joint.rpdo, cw, target)
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
            self._supervision.state_fault = bus_state_fault(self.bus)
        self._supervision.supervise(now, self._sync_count)
        if self._supervision.latched:
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

    # --- frames out ----------------------------------------------------------------------------
    def _send(self, message: can.Message) -> bool:
        try:
            self.bus.send(message, timeout=self.config.period / 2)
        except can.CanError as exc:
            self._supervision.send_failed(
                f'sending CAN frame 0x{message.arbitration_id:03X} failed: {exc}',
                self._sync_count)
            return False
        return True

    def _send_nmt(self, command: int, node: int) -> None:
        self._send(frames.nmt(command, node))

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
            frames.pack_rpdo1(joint.rpdo, cd.CW_QUICK_STOP, 0)
            self._send(joint.rpdo)
        self._send(self._sync)

    def _zero_commands(self, now: float) -> None:
        """Hold every joint at zero speed, enabled, until its next command (after a reset)."""
        for index in range(len(self._joints)):
            self._commands[index] = (0.0, True, now)

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

