"""The robot loop: read the bus, check safety, run the control law, write the bus; one thread.

Free of ROS (issue 28). :meth:`RobotLoop.cycle` runs in the CANopen master's I/O thread, as its
:attr:`~exo_has_driver.hardware.master.Master.control`, once every SYNC period: after the frames
of the previous SYNC are in and before this SYNC's RPDOs go out, so nothing stands between the
bus and the law (ros2_control's read, update, write in one real-time thread). Each period:

1. timing: the cycle's lateness on the master's SYNC grid
   (:attr:`~exo_has_driver.hardware.master.Master.sync_due`) and its gap from the last one
   (:class:`~exo_has_common.timing.PeriodMonitor`); a gap over ``missed_limit`` missed periods is
   a condition the master latches as a FATAL STALE_COMMAND stop, its text naming the cause (the
   thread computing, or held off the CPU);
2. read: the master's events and the samples completed since the last period; each sample goes
   to the joint's :class:`~exo_has_control.pd.PositionLoop` and the safety core
   (:class:`~exo_has_driver.safety.Watchdog`, the watchdog node's rules);
3. the bridge's messages that have arrived, without waiting (:mod:`.robot_exchange`):
   references, reset requests, the bridge's status, gain changes, lifecycle transitions, and
   the conditions the bridge finds in the ROS graph (a second source of a joint's commands or
   states), which the master holds beside the loop's own: each latches a FATAL stop, and a
   reset is refused while it holds;
4. safety: stale states and a stale reference; a FATAL of the safety core is sent to the master
   as an e-stop (it quick-stops every drive in this very SYNC and latches);
5. control: while a stop is latched (the core's or the master's), or the loop is inactive
   and has not been active since it was configured, every joint is commanded 0 rad/s, drive
   disabled; inactive after a deactivation, every joint holds where it stood, under control,
   references ignored, until an activation; while a stale reference holds, the same until a
   reset accepted once the reference is fresh again; else
   each joint follows its reference (:class:`~exo_has_control.tracking.ReferenceFollower`) under
   the PD law, and rejoins it at the rejoin speed after a stop or a hold, as the PD controller
   node does;
6. write: the commands to the master (sent with this SYNC), and to the bridge the samples, the
   events and, every ``metrics_period``, the loop's metrics, each dropped and counted if the
   bridge cannot take it.

The lifecycle (:class:`~exo_has_bringup.robot_messages.Transition`): the loop is made inactive
(configured: the process's main thread opened the bus and started the master, drives
disabled) or active (the master started with the drives enabled). Activate enables the drives
and answers once every drive reports operation enabled, or refuses after ``enable_timeout``
naming the drives' states, or at once under a latched stop; only an active loop takes
references and judges them. Deactivate holds every joint where it stands; cleanup (from
inactive only) disables the drives and leaves :attr:`RobotLoop.cleanup_request` for the main
thread, which ends the I/O thread and closes the bus, and answers.

A reference is stale after ``stale_periods`` periods without one (the watchdog's rule: its
state timeout), unless the bridge's status, itself fresh, says the reference's publisher left
the ROS graph (a gait publisher that ended withdraws its reference; a silent bridge does not).
Nothing here logs, waits or blocks.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Protocol

from exo_has_bringup.errors import BringupError
from exo_has_bringup.robot_messages import (
    MAX_SAMPLES,
    BridgeStatus,
    EventMessage,
    GainChange,
    HeldConditions,
    LifecycleRequest,
    LoopMode,
    LoopState,
    Message,
    Metrics,
    Reference,
    ResetRequest,
    States,
    Transition,
)
from exo_has_common.joints import joint_type_of
from exo_has_common.timing import PeriodMonitor
from exo_has_control.pd import PdGains, PositionLoop, unsafe_gains
from exo_has_control.tracking import DEFAULT_REJOIN_SPEED, ReferenceFollower
from exo_has_driver.events import Condition, Event, SafetyKind
from exo_has_driver.hardware import cia402
from exo_has_driver.hardware.config import JointSample
from exo_has_driver.safety import Watchdog
from exo_has_driver.safety_limits import SafetyLimits
from exo_has_sim.parameters import HasParameters

#: Key of the loop's own condition held in the master (a gap between periods).
GAP_CONDITION = ('robot loop gap',)


class LoopConfigError(BringupError, ValueError):
    """A setting of the robot loop out of range, or gains unsafe at its rate."""


class MasterPort(Protocol):
    """What the loop uses of :class:`~exo_has_driver.hardware.master.Master`."""

    @property
    def latched(self) -> bool:
        """Whether the master's stop is latched."""

    @property
    def cause(self) -> Event | None:
        """The event that latched the master's stop, None when not latched."""

    @property
    def sync_due(self) -> float:
        """When the SYNC of the cycle being run was due [s]; NaN outside a cycle."""

    def take_samples(self) -> list[JointSample]:
        """Return the samples completed since the last call."""

    def take_events(self) -> list[Event]:
        """Return the master's events raised since the last call."""

    def set_command(self, joint: str, motor_speed: float, enable: bool,
                    now: float | None = None) -> None:
        """Take a joint's command for the next RPDO."""

    def request_stop(self, text: str) -> None:
        """Latch an e-stop."""

    def request_reset(self) -> None:
        """Ask to release the latched stop."""

    def hold_conditions(self, conditions: Sequence[Condition]) -> None:
        """Set the caller's fault conditions."""

    def all_enabled(self) -> bool:
        """Whether every drive reports operation enabled."""

    def drive_states(self) -> dict[str, str]:
        """Each joint's drive state."""


class ExchangePort(Protocol):
    """What the loop uses of :class:`~exo_has_bringup.robot_exchange.DatagramExchange`."""

    dropped: int
    malformed: int
    problem: str

    def send(self, message: Message) -> bool:
        """Send without waiting; False if dropped."""

    def receive(self) -> list[Message]:
        """Take what arrived, without waiting."""


@dataclass(frozen=True)
class LoopSettings:
    """Settings of the robot loop; times in seconds.

    Attributes
    ----------
    period : float
        Control period [s], the master's SYNC period.
    stale_periods : int
        Periods without a state, or a reference, after which it is stale (the watchdog's).
    missed_limit : int
        Periods missed in a row (no cycle in them) that are a FATAL stop.
    reference_timeout : float
        Age [s] after which a reference is held still (its velocity dropped), as the PD
        controller's ``reference_timeout``.
    rejoin_speed : float
        Fastest cylinder speed [m/s] at which a joint joins the reference at the start and
        after a stop or a hold.
    startup_grace : float
        Time [s] for the first states and after a reset before tracking is judged.
    metrics_period : float
        Period [s] of the metrics (and the lifecycle state) sent to the bridge.
    enable_timeout : float
        Time [s] the drives have to reach operation enabled on an activation.

    """

    period: float = 0.005
    stale_periods: int = 40
    missed_limit: int = 9
    reference_timeout: float = 0.1
    rejoin_speed: float = DEFAULT_REJOIN_SPEED
    startup_grace: float = 5.0
    metrics_period: float = 0.1
    enable_timeout: float = 2.0

    def __post_init__(self) -> None:
        for name in ('period', 'reference_timeout', 'rejoin_speed', 'metrics_period',
                     'enable_timeout'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0.0):
                msg = f'{name} = {value!r} must be positive and finite'
                raise LoopConfigError(msg)
        if not (math.isfinite(self.startup_grace) and self.startup_grace >= 0.0):
            msg = f'startup_grace = {self.startup_grace!r} must be finite and not negative [s]'
            raise LoopConfigError(msg)
        for name in ('stale_periods', 'missed_limit'):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                msg = f'{name} = {value!r} must be an integer of at least 1'
                raise LoopConfigError(msg)

    @property
    def stale_time(self) -> float:
        """Age [s] at which a state or the reference is stale."""
        return self.stale_periods * self.period

    @property
    def gap_limit(self) -> float:
        """Longest time [s] between two periods before the loop stops every joint."""
        return (self.missed_limit + 1) * self.period


class RobotLoop:
    """Safety and control of the joints, one :meth:`cycle` a period; see the module docstring.

    Parameters
    ----------
    master : MasterPort
        The CANopen master whose I/O thread calls :meth:`cycle`.
    exchange : ExchangePort
        The loop's end of the exchange with the bridge.
    params : Mapping[str, HasParameters]
        Each joint's parameter set, by joint name, in the master's order.
    settings : LoopSettings
        Timing and bounds.
    start : float
        Time [s] on the master's clock the loop starts (the safety core's start-up grace).
    clock : callable
        The master's clock [s], read at the end of a cycle for its compute time.
    cpu_clock : callable
        CPU time [s] of the calling thread, to tell a loop that computed from one held off.
    realtime : bool
        Whether the loop's thread runs under SCHED_FIFO (named in a gap's cause).
    active : bool
        Whether the loop starts active, the drives enabled already (the master started with
        them); otherwise inactive, the drives disabled until a :class:`LifecycleRequest`
        activates it.

    Raises
    ------
    LoopConfigError
        If the paper's gains are unsafe at the loop's period (exo_has_control.pd.unsafe_gains).

    """

    def __init__(self, master: MasterPort, exchange: ExchangePort,
                 params: Mapping[str, HasParameters], settings: LoopSettings, start: float,
                 clock: Callable[[], float] = time.monotonic,
                 cpu_clock: Callable[[], float] = time.thread_time,
                 realtime: bool = False, active: bool = True) -> None:
        self._master = master
        self._exchange = exchange
        self.settings = settings
        self._clock = clock
        self._cpu_clock = cpu_clock
        self._realtime = realtime
        self.joints = tuple(params)
        self._params = dict(params)
        limits = {joint: SafetyLimits.from_parameters(
            p, stale_periods=settings.stale_periods, control_rate=1.0 / settings.period,
            startup_grace=settings.startup_grace) for joint, p in params.items()}
        self.core = Watchdog(limits, start)
        self._loops: dict[str, PositionLoop] = {}
        self._followers: dict[str, ReferenceFollower] = {}
        for joint, p in params.items():
            gains = PdGains.paper(p)
            problem = unsafe_gains(p, gains, settings.period)
            if problem is not None:
                msg = f'{joint}: {problem}'
                raise LoopConfigError(msg)
            self._loops[joint] = PositionLoop(gains)
            self._followers[joint] = ReferenceFollower(joint, p, settings.reference_timeout,
                                                       settings.rejoin_speed)
        self.monitor = PeriodMonitor(round(settings.period * 1e9))
        self.longest_gap = 0.0
        self.compute_max = 0.0
        self._compute_total = 0.0
        self._last: tuple[float, float] | None = None  # (time [s], thread CPU time [s])
        self._release_ns: int | None = None  # the monitor's next release on its own grid
        self._gap: list[Condition] = []  # a gap over the limit, held
        #: The bridge's conditions (a second source in the graph), their keys made the
        #: bridge's so that they cannot meet the loop's.
        self._bridge_conditions: list[Condition] = []
        self._now = start
        self._running = True  # neither stopped nor holding
        self._holding = False
        self._stop_sent = False
        self._status: tuple[float, bool] | None = None  # (time [s], publisher present)
        self._metrics_due = start
        self.problem = ''
        self.mode = LoopMode.ACTIVE if active else LoopMode.INACTIVE
        self._enabled = active  # whether the drives are commanded enabled
        self._activation: tuple[int, float] | None = None  # (request, deadline [s])
        #: The cleanup request to carry out (the I/O thread must end first: the process's
        #: main thread does it, and answers), 0 if none.
        self.cleanup_request = 0

    # --- state ---------------------------------------------------------------------------
    @property
    def stopped(self) -> bool:
        """Whether a stop is latched (the safety core's or the master's)."""
        return self.core.stopped or self._master.latched

    @property
    def holding(self) -> bool:
        """Whether the joints hold on a stale reference until a reset."""
        return self.core.holding

    def gains(self, joint: str) -> PdGains:
        """Return the gains a joint's loop runs with now."""
        return self._loops[joint].gains

    def metrics(self, now: float) -> Metrics:
        """Return the loop's metrics at ``now`` [s]."""
        monitor = self.monitor
        periods = monitor.ticks + 1 if self._last is not None else 0
        return Metrics(now, periods, monitor.missed, monitor.late,
                       monitor.lateness_percentile(99.0), monitor.lateness_percentile(99.9),
                       monitor.max_lateness_ns * 1e-9, self.longest_gap, self.compute_max,
                       self._compute_total / periods if periods else 0.0,
                       self._exchange.dropped, self._exchange.malformed, self.stopped,
                       self.holding, self.problem or self._exchange.problem)

    def summary(self) -> str:
        """One line on how the loop kept its period."""
        return (f'{self.monitor.summary()}; longest gap between bus commands '
                f'{self.longest_gap * 1e3:.1f} ms; cycle compute max '
                f'{self.compute_max * 1e3:.2f} ms; datagrams dropped {self._exchange.dropped}, '
                f'refused {self._exchange.malformed}')

    # --- the period -------------------------------------------------------------------------
    def cycle(self, now: float) -> None:
        """Run one period at ``now`` [s] (the master's clock); the master's ``control``."""
        self._now = now
        self._timing(now)
        master = self._master
        core = self.core
        events = master.take_events()
        samples = master.take_samples()
        for sample in samples:
            if math.isfinite(sample.position):
                self._loops[sample.joint].measure(sample.stamp, sample.position)
            events += core.on_state(sample.joint, now, sample.position, sample.pressure_a,
                                    sample.pressure_b, sample.valve_mode)
        for message in self._exchange.receive():
            events += self._take(now, message)
        events += core.check(now)
        if self._activation is not None:
            self._activating(now)
        if self.mode is LoopMode.ACTIVE:
            events += core.check_reference(now, self._reference_source_present)
        if core.stopped and not self._stop_sent:
            cause = core.cause
            master.request_stop(cause.text if cause is not None else 'the safety core stopped')
        self._stop_sent = core.stopped
        events += self._command(now)
        exchange = self._exchange
        for first in range(0, len(samples), MAX_SAMPLES):
            exchange.send(States(now, tuple(samples[first:first + MAX_SAMPLES])))
        for event in events:
            exchange.send(EventMessage(now, event))
        if now >= self._metrics_due:
            exchange.send(self.metrics(now))
            exchange.send(LoopState(self.mode, 0, True))
            due = self._metrics_due + self.settings.metrics_period
            self._metrics_due = due if due > now else now + self.settings.metrics_period
        spent = self._clock() - now
        self._compute_total += spent
        self.compute_max = max(self.compute_max, spent)

    def _timing(self, now: float) -> None:
        """Count the period; latch a stop in the master on a gap over the limit."""
        cpu = self._cpu_clock()
        self._tick(now)
        last, self._last = self._last, (now, cpu)
        if last is None:
            return
        gap = now - last[0]
        self.longest_gap = max(self.longest_gap, gap)
        limit = self.settings.gap_limit
        if gap > limit:
            self._gap = [Condition(
                GAP_CONDITION, '', SafetyKind.STALE_COMMAND, gap, limit,
                f'robot loop: {gap * 1e3:.1f} ms between two periods, '
                f'{round(gap / self.settings.period) - 1} missed (limit '
                f'{self.settings.missed_limit}): {self._gap_cause(gap, cpu - last[1])}')]
            self._hold()
        elif self._gap:
            self._gap = []  # latched already: the reset releases it
            self._hold()

    def _hold(self) -> None:
        """Hold the loop's conditions and the bridge's in the master."""
        self._master.hold_conditions([*self._gap, *self._bridge_conditions])

    def _tick(self, now: float) -> None:
        """Count a cycle at ``now`` [s] in the monitor, late as it is on the master's SYNC grid.

        The master sends each SYNC a period after the last one's due time, unless it is
        already past, as after a hold-up: then a period after it ran
        (:attr:`~exo_has_driver.hardware.master.Master.sync_due`). The monitor's grid, fixed
        at its first tick, would count every later cycle late by the hold-up's remainder; so
        the lateness is taken on the master's grid and handed to the monitor on a grid of its
        own. (A grid mirrored from the loop's first cycle would be late by that cycle's own
        lateness, and hide as much of every later one.)
        """
        due = self._master.sync_due
        late_ns = max(0, round((now - due) * 1e9)) if math.isfinite(due) else 0
        monitor = self.monitor
        if self._release_ns is None:
            monitor.tick(0)
            self._release_ns = monitor.period_ns
        else:
            monitor.tick(self._release_ns + late_ns)
            self._release_ns += (late_ns // monitor.period_ns + 1) * monitor.period_ns

    def _gap_cause(self, gap: float, cpu: float) -> str:
        """Say why a gap happened, from the CPU time [s] the loop's thread had in it."""
        scheduler = 'SCHED_FIFO' if self._realtime else 'the default scheduler (no SCHED_FIFO)'
        if cpu > 0.5 * gap:
            return (f'its thread computed for {cpu * 1e3:.1f} ms of them (the bus traffic, the '
                    'control law, a garbage collection)')
        return (f'its thread was held off the CPU for {(gap - cpu) * 1e3:.1f} ms of them '
                f'under {scheduler} (other processes, a lock, the interpreter lock)')

    def _take(self, now: float, message: Message) -> list[Event]:
        """Take a message of the bridge; return the events it raises."""
        core = self.core
        if isinstance(message, Reference):
            if self.mode is not LoopMode.ACTIVE:
                return []  # only an active loop follows a reference
            angles = dict(zip(message.names, message.angles, strict=True))
            events = core.on_reference(now, angles)
            if not core.holding:  # a hold ignores references until a reset
                for follower in self._followers.values():
                    if follower.joint in angles:
                        follower.take(now, message.names, message.angles, message.rates)
            return events
        if isinstance(message, ResetRequest):
            events = core.reset(now)
            released = bool(events) and events[0].kind == SafetyKind.RESET \
                and not events[0].latched
            if released and self._master.latched:
                self._master.request_reset()
            return events
        if isinstance(message, BridgeStatus):
            self._status = (now, message.reference_source_present)
        elif isinstance(message, GainChange):
            self._change_gains(message)
        elif isinstance(message, LifecycleRequest):
            self._transition(now, message)
        elif isinstance(message, HeldConditions):
            held = [replace(c, key=('bridge', c.key)) for c in message.conditions]
            if held != self._bridge_conditions:
                self._bridge_conditions = held
                self._hold()
        return []

    def _answer(self, request: int, ok: bool, text: str = '') -> None:
        self._exchange.send(LoopState(self.mode, request, ok, text))

    def _transition(self, now: float, message: LifecycleRequest) -> None:
        """Carry out (or start, or refuse) a lifecycle transition; answer it."""
        transition, request = message.transition, message.request
        if transition is Transition.CONFIGURE:
            self._answer(request, True)  # configured already
        elif transition is Transition.ACTIVATE:
            if self.mode is LoopMode.ACTIVE:
                self._answer(request, True)
            elif self.stopped:
                cause = self.core.cause or self._master.cause
                self._answer(request, False, 'a stop is latched: '
                             f'{cause.text if cause is not None else "the master stopped"}; '
                             'reset it first')
            elif self._activation is None:
                self._enabled = True
                self._activation = (request, now + self.settings.enable_timeout)
        elif transition is Transition.DEACTIVATE:
            if self.mode is LoopMode.ACTIVE:
                self.mode = LoopMode.INACTIVE  # every joint holds, enabled, under control
                self.core.withdraw_reference(now)
            self._answer(request, self._activation is None,
                         'an activation is under way' if self._activation else '')
        elif self.mode is LoopMode.ACTIVE or self._activation is not None:
            self._answer(request, False, 'the loop is active: deactivate it before a cleanup')
        else:
            self._enabled = False
            self.cleanup_request = request

    def _activating(self, now: float) -> None:
        """Follow an activation: active once every drive is enabled, else refused in time."""
        assert self._activation is not None
        request, deadline = self._activation
        if self._master.all_enabled():
            self._activation = None
            self.mode = LoopMode.ACTIVE
            self.core.withdraw_reference(now)  # judged from the first reference on
            self._answer(request, True)
            return
        if not (self.stopped or now > deadline):
            return
        self._activation = None
        self._enabled = False
        cause = self.core.cause or self._master.cause
        if cause is not None:
            text = f'a fault while enabling the drives: {cause.text}'
        else:
            states = ', '.join(f'{joint} drive in {state}'
                               for joint, state in self._master.drive_states().items()
                               if state != cia402.OPERATION_ENABLED)
            text = (f'drives not in operation enabled within '
                    f'{self.settings.enable_timeout:g} s: {states}')
        self._answer(request, False, text)

    def _change_gains(self, change: GainChange) -> None:
        """Apply new gains to every joint of a type, refusing invalid ones.

        The bridge judges their damping at the loop's rate (exo_has_control.pd.unsafe_gains,
        milliseconds of linear algebra) before it sends them; here they are applied between
        two periods, checked only for what a period can afford: finite, not negative, a limit
        within the motor's top speed.
        """
        joints = [joint for joint in self.joints if joint_type_of(joint) == change.joint_type]
        if not joints:
            return
        try:
            gains = PdGains(change.kp, change.kd, change.kff, change.speed_limit)
        except ValueError as exc:
            self.problem = f'{change.joint_type} gain change refused: {exc}'
            return
        top = self._params[joints[0]].motor_speed_max
        if gains.speed_limit > top:
            self.problem = (f'{change.joint_type} gain change refused: speed limit '
                            f'{gains.speed_limit:.5g} rad/s over the motor top speed '
                            f'{top:.5g} rad/s')
            return
        for joint in joints:
            self._loops[joint].gains = gains

    def _reference_source_present(self) -> bool:
        """Whether the stale reference's source is still there (asked once it is stale).

        Only a fresh status of the bridge saying the publisher left withdraws the reference;
        a bridge that is silent is late or dead, and the joints hold.
        """
        status = self._status
        if status is None or self._now - status[0] > self.settings.stale_time:
            return True
        return status[1]

    def _command(self, now: float) -> list[Event]:
        """Command every joint for this SYNC; return the events the commands raise."""
        stopped = self.stopped
        # An inactive loop holds (enabled, after a deactivation) or stands disabled.
        holding = self.core.holding or self.mode is not LoopMode.ACTIVE
        if holding and not self._holding:
            for joint, follower in self._followers.items():
                follower.hold(self._loops[joint].position)
        running = not (stopped or holding)
        if running and not self._running:
            for joint, follower in self._followers.items():
                follower.rejoin(self._loops[joint].position)
        self._holding, self._running = holding, running
        master = self._master
        core = self.core
        events: list[Event] = []
        for joint, loop in self._loops.items():
            position = loop.position
            if stopped or not self._enabled:
                speed, enable = 0.0, False
            elif position is None:
                speed, enable = 0.0, True  # nothing measured yet: stand still
            else:
                x_ref, v_ref = self._followers[joint].target(now, position)
                speed, enable = loop.command(x_ref, v_ref), True
            master.set_command(joint, speed, enable, now)
            events += core.on_command(joint, now, speed, enable)
        return events
