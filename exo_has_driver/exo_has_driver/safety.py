"""Safety watchdog logic for the HAS joints, free of ROS.

A :class:`Watchdog` is fed plain values with the times they were received [s]: each joint's HAS
state and command, the joint references, and a periodic :meth:`Watchdog.check`. It returns
:class:`Event` records, numbered as exo_has_msgs/msg/SafetyEvent, and holds the latched stop.
The rules, per joint (thresholds in :class:`SafetyLimits`):

- safety valve open: the higher chamber pressure at or over the relief setting, or the valve
  reporting relief mode: SAFETY_VALVE_OPEN, FATAL;
- over-pressure: the higher chamber pressure over the warning threshold (by default 0.9 times
  the relief setting, which equals the maximum working pressure in our parameter sets):
  OVER_PRESSURE, WARN, raised again only once the pressure fell 5 % below the threshold;
- stroke end: the position within the margin of either end: STROKE_END, ERROR, raised again
  only once the position left the end by the margin plus 0.5 mm;
- tracking error: the reference angle minus the angle of the measured position over the limit,
  for at least the persistence time, while the joint's drive is enabled and no stop is latched
  (a disabled drive's valve is in free mode, it does not track), from the start-up grace after
  the joint's first reference or a reset on (the controller first joins the reference at its
  rejoin speed): TRACKING_ERROR, FATAL;
- stale state or command: nothing for longer than its timeout after the joint's first message,
  or nothing at all within the start-up grace: STALE_STATE / STALE_COMMAND, FATAL;
- a NaN or infinite command: INVALID_COMMAND, FATAL;
- a NaN or infinite state value, a position more than 2 mm beyond a stroke end, a pressure
  below an absolute vacuum or an unknown valve mode: SENSOR_FAULT, FATAL;
- more than one publisher of a joint's state, or of its commands (the watchdog's own stop
  commands aside), as the ROS graph shows them (:meth:`Watchdog.on_sources`): a second plant or
  driver, a second controller, a replay or a left-over test node on a running system, which
  the other rules cannot tell from the real one: SECOND_SOURCE, FATAL, naming the publishers.

One rule is for the whole system (:meth:`Watchdog.check_reference`): no joint reference for
longer than the state timeout after one came, while its publisher is still in the graph (a
link to the operator's machine lost, not a gait publisher that ended): STALE_REFERENCE, ERROR,
latched as a *hold* (:attr:`Watchdog.holding`). Not FATAL: the robot side is sound and its
controller holds each joint where it is, which is safer for a wearer in mid-squat than a
stop that disables the drives (their valves fall to free mode and the joints give way). The
hold, like a stop, lasts until :meth:`Watchdog.reset`, refused while the reference is still
stale, so that motion resumes only on request. After any reset the tracking rule waits the
start-up grace, the time a controller takes to bring each joint back to its reference.

A persisting condition is reported once, when it arises. A FATAL event latches a stop
(:attr:`Watchdog.stopped`) until :meth:`Watchdog.reset`, which is refused (a WARN event of the
condition's kind) while a fatal condition still holds: a stale state, an open safety valve, a
sensor fault, a second source. While stopped, commands are stop commands and are not checked,
but every other rule keeps reporting new conditions once each.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, fields, replace

from exo_has_driver.errors import SafetyConfigError
from exo_has_driver.events import Condition, Event, SafetyKind, Severity, StopLatch
from exo_has_sim.errors import KinematicsError
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import HasParameters
from exo_has_sim.valve import ValveMode

# Levels, numbered as diagnostic_msgs/msg/DiagnosticStatus.
LEVEL_OK = 0
LEVEL_WARN = 1
LEVEL_ERROR = 2
LEVEL_STALE = 3

DEFAULT_OVER_PRESSURE_RATIO = 0.9
#: [m] The knee's straight-leg standing pose is 3.1 mm from the cylinder's extended end in the
#: design search's linkage, so the margin stays well below that; 0.5 mm covers the end stop's
#: compression (about 0.1 mm at full thrust) and position noise.
DEFAULT_STROKE_MARGIN = 0.5e-3
#: [rad] 20 deg: the paper's hip tracking error in squatting stays within -1.5/+2.5 deg, so
#: this is far beyond normal tracking, and still below half the hip's 69 deg linkage range.
DEFAULT_TRACKING_ERROR_LIMIT = math.radians(20.0)
#: [s] Longer than the brief lag of a tracking controller at the knee's peak swing velocity,
#: short against the half second a runaway joint needs to cross its range.
DEFAULT_TRACKING_ERROR_TIME = 0.2
#: Control periods without a message after which a state or command is stale.
DEFAULT_STALE_PERIODS = 10
#: [s] Time the nodes of a session have to start and send their first messages.
DEFAULT_STARTUP_GRACE = 5.0

#: [Pa] Gauge pressures below this are impossible (an absolute vacuum is -0.101 MPa at sea level).
MIN_GAUGE_PRESSURE = -0.12e6
#: [m] Positions further beyond a stroke end are impossible: the end stop gives about 0.1 mm.
END_STOP_TOLERANCE = 2e-3
#: Fraction below the warning threshold the pressure must fall to before another warning.
PRESSURE_HYSTERESIS = 0.05
#: [m] Distance beyond the margin the position must leave an end by before another event.
STROKE_HYSTERESIS = 0.5e-3


@dataclass(frozen=True)
class SafetyLimits:
    """Thresholds of the watchdog for one joint, SI units.

    Attributes
    ----------
    relief_pressure : float
        Safety valve setting [Pa]; a chamber at or over it means the valve is open.
    warning_pressure : float
        Over-pressure warning threshold [Pa], at most the relief pressure.
    stroke : float
        Cylinder stroke [m].
    stroke_margin : float
        Distance from either end within which the stroke end counts as reached [m].
    tracking_error_limit : float
        Largest tolerated joint tracking error [rad].
    tracking_error_time : float
        How long the tracking error must stay over its limit to be a fault [s].
    state_timeout : float
        Longest tolerated gap between HAS states [s].
    command_timeout : float
        Longest tolerated gap between HAS commands [s].
    startup_grace : float
        Time from the start (or a reset, for commands) to the first message [s].
    linkage : Linkage
        The joint's linkage, to turn a cylinder extension into a joint angle.

    """

    relief_pressure: float
    warning_pressure: float
    stroke: float
    stroke_margin: float
    tracking_error_limit: float
    tracking_error_time: float
    state_timeout: float
    command_timeout: float
    startup_grace: float
    linkage: Linkage

    def __post_init__(self) -> None:
        for item in fields(self):
            value = getattr(self, item.name)
            if item.name != 'linkage' and not (isinstance(value, (int, float))
                                               and math.isfinite(value)):
                msg = f'safety limit {item.name} = {value!r} must be a finite number'
                raise SafetyConfigError(msg)
        checks = [
            ('relief_pressure', self.relief_pressure > 0.0, 'positive [Pa]'),
            ('warning_pressure', 0.0 < self.warning_pressure <= self.relief_pressure,
             f'in (0, relief_pressure = {self.relief_pressure:g}] Pa'),
            ('stroke', self.stroke > 0.0, 'positive [m]'),
            ('stroke_margin', 0.0 <= self.stroke_margin < self.stroke / 4.0,
             f'in [0, stroke / 4 = {self.stroke / 4.0:g}) m'),
            ('tracking_error_limit', self.tracking_error_limit > 0.0, 'positive [rad]'),
            ('tracking_error_time', self.tracking_error_time >= 0.0, 'non-negative [s]'),
            ('state_timeout', self.state_timeout > 0.0, 'positive [s]'),
            ('command_timeout', self.command_timeout > 0.0, 'positive [s]'),
            ('startup_grace', self.startup_grace >= 0.0, 'non-negative [s]'),
        ]
        for name, ok, expected in checks:
            if not ok:
                msg = f'safety limit {name} = {getattr(self, name)!r} must be {expected}'
                raise SafetyConfigError(msg)

    @classmethod
    def from_parameters(cls, params: HasParameters, *,
                        over_pressure_ratio: float = DEFAULT_OVER_PRESSURE_RATIO,
                        stroke_margin: float = DEFAULT_STROKE_MARGIN,
                        tracking_error_limit: float = DEFAULT_TRACKING_ERROR_LIMIT,
                        tracking_error_time: float = DEFAULT_TRACKING_ERROR_TIME,
                        stale_periods: int = DEFAULT_STALE_PERIODS,
                        control_rate: float | None = None,
                        startup_grace: float = DEFAULT_STARTUP_GRACE) -> SafetyLimits:
        """Build the limits of a joint from its HAS parameter set.

        Parameters
        ----------
        params : HasParameters
            The joint's parameter set (relief pressure, stroke, linkage, control rate).
        over_pressure_ratio : float
            Warning threshold as a fraction of the relief pressure, in (0, 1].
        stroke_margin : float
            See :class:`SafetyLimits` [m].
        tracking_error_limit : float
            See :class:`SafetyLimits` [rad].
        tracking_error_time : float
            See :class:`SafetyLimits` [s].
        stale_periods : int
            Control periods after which a state or a command is stale, at least 1.
        control_rate : float or None
            Control rate [Hz] that sets the period; None takes the parameter set's.
        startup_grace : float
            See :class:`SafetyLimits` [s].

        Raises
        ------
        SafetyConfigError
            Naming the first value out of range.

        """
        rate = params.control_rate if control_rate is None else control_rate
        if not (math.isfinite(over_pressure_ratio) and 0.0 < over_pressure_ratio <= 1.0):
            msg = f'over_pressure_ratio = {over_pressure_ratio!r} must be in (0, 1]'
            raise SafetyConfigError(msg)
        if isinstance(stale_periods, bool) or not isinstance(stale_periods, int) \
                or stale_periods < 1:
            msg = f'stale_periods = {stale_periods!r} must be an integer of at least 1'
            raise SafetyConfigError(msg)
        if not (math.isfinite(rate) and rate > 0.0):
            msg = f'control_rate = {rate!r} must be positive [Hz]'
            raise SafetyConfigError(msg)
        timeout = stale_periods / rate
        return cls(relief_pressure=params.relief_pressure,
                   warning_pressure=over_pressure_ratio * params.relief_pressure,
                   stroke=params.stroke, stroke_margin=stroke_margin,
                   tracking_error_limit=tracking_error_limit,
                   tracking_error_time=tracking_error_time, state_timeout=timeout,
                   command_timeout=timeout, startup_grace=startup_grace,
                   linkage=Linkage.from_parameters(params))


@dataclass(frozen=True)
class JointDiagnostic:
    """Summary of one joint for a diagnostic_msgs/msg/DiagnosticStatus.

    Attributes
    ----------
    joint : str
        The joint.
    level : int
        One of the ``LEVEL_*`` constants.
    message : str
        What is wrong, or ``'ok'``.
    values : tuple[tuple[str, str], ...]
        Key values (the unit in the key), formatted.

    """

    joint: str
    level: int
    message: str
    values: tuple[tuple[str, str], ...]


@dataclass
class _Joint:
    """What the watchdog knows of one joint."""

    limits: SafetyLimits
    command_epoch: float
    state_time: float | None = None
    command_time: float | None = None
    position: float = math.nan
    angle: float | None = None
    pressure_a: float = math.nan
    pressure_b: float = math.nan
    valve_mode: int = -1
    enabled: bool = False
    reference: float | None = None
    tracking_error: float | None = None
    over_limit_since: float | None = None
    # Tracking errors are judged from this time on [s]: the first reference, or a reset, plus the
    # start-up grace, since the controller first joins the reference at its rejoin speed
    # (exo_has_control.tracking: 0.05 m/s, over 30 deg 1.1 s for a hip, 0.4 s for a knee).
    tracking_from: float = math.inf
    # Publishers found on the joint's topics, by topic: more than one on any is a fault.
    sources: dict[str, tuple[str, ...]] = field(default_factory=dict)
    # The crowded topic and its publishers as last reported.
    sources_reported: tuple[str, tuple[str, ...]] | None = None
    # Kinds whose condition holds and has been reported (the deduplication).
    active: set[SafetyKind] = field(default_factory=set)


def _mpa(pressure: float) -> str:
    return f'{pressure * 1e-6:.2f} MPa'


class Watchdog:
    """Checks the joints' states, commands and references and latches a stop on a fault.

    Parameters
    ----------
    limits : Mapping[str, SafetyLimits]
        The watched joints and their limits.
    start : float
        Time the watchdog starts [s], from which the start-up grace runs.

    Raises
    ------
    SafetyConfigError
        If no joint is given or the start time is not finite.

    """

    def __init__(self, limits: Mapping[str, SafetyLimits], start: float) -> None:
        if not limits:
            msg = 'the watchdog needs at least one joint'
            raise SafetyConfigError(msg)
        if not math.isfinite(start):
            msg = f'start time {start!r} must be finite'
            raise SafetyConfigError(msg)
        self._start = start
        self._joints = {joint: _Joint(limit, start) for joint, limit in limits.items()}
        self._latch = StopLatch()
        self._reference_timeout = min(limit.state_timeout for limit in limits.values())
        self._reference_time: float | None = None
        self._hold: Event | None = None

    @property
    def joints(self) -> tuple[str, ...]:
        """The watched joints."""
        return tuple(self._joints)

    @property
    def stopped(self) -> bool:
        """Whether a stop is latched."""
        return self._latch.latched

    @property
    def holding(self) -> bool:
        """Whether a hold is latched (a lost reference): the joints hold until a reset."""
        return self._hold is not None

    @property
    def cause(self) -> Event | None:
        """The FATAL event that latched the stop, None when not stopped."""
        return self._latch.cause

    def on_state(self, joint: str, t: float, position: float, pressure_a: float,
                 pressure_b: float, valve_mode: int) -> list[Event]:
        """Take a HAS state.

        Parameters
        ----------
        joint : str
            A watched joint.
        t : float
            Receive time [s].
        position : float
            Cylinder extension [m].
        pressure_a, pressure_b : float
            Rodless and rod chamber gauge pressures [Pa].
        valve_mode : int
            One of the ``VALVE_*`` constants.

        Returns
        -------
        list[Event]
            The events this state raises.

        """
        state = self._joint(joint)
        state.state_time = t
        state.active.discard(SafetyKind.STALE_STATE)
        fault = _sensor_fault(state.limits, position, pressure_a, pressure_b, valve_mode)
        angle = None
        if fault is None:
            try:
                angle = state.limits.linkage.angle_at(position)
            except KinematicsError:
                fault = (position, math.nan, f'position {position:.4f} m outside what the '
                                             'linkage can reach')
        if fault is not None:
            state.angle = state.tracking_error = state.over_limit_since = None
            value, limit, what = fault
            return self._once(joint, state, SafetyKind.SENSOR_FAULT, Severity.FATAL, value, limit,
                              f'{joint}: sensor fault: {what}')
        state.active.discard(SafetyKind.SENSOR_FAULT)
        state.position, state.angle = position, angle
        state.pressure_a, state.pressure_b, state.valve_mode = pressure_a, pressure_b, valve_mode
        return [*self._check_pressure(joint, state), *self._check_stroke(joint, state),
                *self._check_tracking(joint, state, t)]

    def on_command(self, joint: str, t: float, motor_speed: float, enable: bool) -> list[Event]:
        """Take a HAS command; ignored while stopped (commands are stop commands then).

        Parameters
        ----------
        joint : str
            A watched joint.
        t : float
            Receive time [s].
        motor_speed : float
            Commanded motor speed [rad/s].
        enable : bool
            Whether the drive is to follow the command.

        Returns
        -------
        list[Event]
            The events this command raises.

        """
        state = self._joint(joint)
        if self._latch.latched:
            return []
        state.command_time = t
        state.active.discard(SafetyKind.STALE_COMMAND)
        if not math.isfinite(motor_speed):
            state.enabled = False
            return self._once(joint, state, SafetyKind.INVALID_COMMAND, Severity.FATAL,
                              motor_speed, math.nan,
                              f'{joint}: invalid command: motor speed {motor_speed}')
        state.active.discard(SafetyKind.INVALID_COMMAND)
        state.enabled = bool(enable)
        return []

    def on_reference(self, t: float, angles: Mapping[str, float]) -> list[Event]:
        """Take joint reference angles [rad] by joint name; other joints are ignored.

        A NaN or infinite angle forgets the joint's reference (no tracking check until a
        finite one); the controller's invalid command, if any, is what is reported. A joint's
        first finite reference starts the start-up grace of its tracking check.

        Parameters
        ----------
        t : float
            Receive time [s].
        angles : Mapping[str, float]
            Reference angle [rad] of each joint named.

        Returns
        -------
        list[Event]
            Always empty: a reference raises nothing by itself.

        """
        for joint, angle in angles.items():
            state = self._joints.get(joint)
            if state is not None:
                state.reference = float(angle) if math.isfinite(angle) else None
                self._reference_time = t
                if state.reference is not None and state.tracking_from == math.inf:
                    state.tracking_from = t + state.limits.startup_grace
        return []

    def check_reference(self, t: float, source_present: Callable[[], bool]) -> list[Event]:
        """Check at time t [s] that the joint reference still comes; call it periodically.

        Parameters
        ----------
        t : float
            Time now [s].
        source_present : Callable[[], bool]
            Tells whether the reference's publisher is still in the graph; asked only once
            the reference is stale. One that left (a gait publisher that ended) withdrew the
            reference: nothing is raised, and nothing is judged until a reference comes again.

        Returns
        -------
        list[Event]
            STALE_REFERENCE, ERROR, latched (the hold), when the reference became stale with
            its publisher present; nothing while the hold lasts.

        """
        age = self._reference_age(t)
        if age is None or self._hold is not None or age <= self._reference_timeout:
            return []
        if not source_present():
            self._reference_time = None
            return []
        self._hold = Event('', SafetyKind.STALE_REFERENCE, Severity.ERROR, float(age),
                           self._reference_timeout, True,
                           f'stale reference: no joint reference for {age:.3f} s (limit '
                           f'{self._reference_timeout:.3f} s) while its publisher is in the '
                           'graph: every joint holds until a reset')
        return [self._hold]

    def _reference_age(self, t: float) -> float | None:
        """Age [s] of the newest joint reference at t [s]; None before one (or withdrawn)."""
        return None if self._reference_time is None else t - self._reference_time

    def on_sources(self, joint: str, topic: str, publishers: Sequence[str]) -> list[Event]:
        """Take the publishers the ROS graph shows on one of a joint's topics.

        Parameters
        ----------
        joint : str
            A watched joint.
        topic : str
            Its state or command topic.
        publishers : Sequence[str]
            One name per publisher (its node's full name), the watchdog's own left out.

        Returns
        -------
        list[Event]
            SECOND_SOURCE, FATAL, when a topic of the joint comes to have more than one
            publisher, and again when its publishers change while it persists (one that ROS
            had not named is named); nothing while they stay, or once every topic has one or
            none.

        """
        state = self._joint(joint)
        state.sources[topic] = tuple(sorted(publishers))
        crowded = {name: found for name, found in state.sources.items() if len(found) > 1}
        if not crowded:
            state.active.discard(SafetyKind.SECOND_SOURCE)
            state.sources_reported = None
            return []
        name, found = next(iter(sorted(crowded.items())))
        text = (f'{joint}: second source: {len(found)} publishers on {name} '
                f'({", ".join(found)}), where one is allowed')
        if state.sources_reported == (name, found):
            return []
        # New, or the same condition held by others: a publisher that ROS had not named yet
        # (the stop must not wait for its name) is named now, or another joined.
        state.sources_reported = (name, found)
        state.active.add(SafetyKind.SECOND_SOURCE)
        return [self._latch.event(joint, SafetyKind.SECOND_SOURCE, Severity.FATAL, len(found),
                                  1.0, text)]

    def check(self, t: float) -> list[Event]:
        """Check for stale states and commands at time t [s]; call it periodically.

        Returns
        -------
        list[Event]
            The stale events that arose since the last check.

        """
        events: list[Event] = []
        # A stop latched by this very check does not hide a joint's stale command.
        commands_checked = not self._latch.latched
        for joint, state in self._joints.items():
            age, limit, what = self._state_age(state, t)
            if age > limit:
                events += self._once(joint, state, SafetyKind.STALE_STATE, Severity.FATAL, age,
                                     limit, f'{joint}: stale state: {what}')
            if not commands_checked:
                continue
            if state.command_time is None:
                age, limit = t - state.command_epoch, state.limits.startup_grace
                what = f'no command within {limit:g} s of the start or reset'
            else:
                age, limit = t - state.command_time, state.limits.command_timeout
                what = f'no command for {age:.3f} s (limit {limit:.3f} s)'
            if age > limit:
                events += self._once(joint, state, SafetyKind.STALE_COMMAND, Severity.FATAL, age,
                                     limit, f'{joint}: stale command: {what}')
        return events

    def reset(self, t: float) -> list[Event]:
        """Release a latched stop or hold at time t [s], unless a condition still holds.

        Returns
        -------
        list[Event]
            One event. Released (or nothing was latched): RESET, INFO, not latched. Refused:
            the kind, joint, value and limit of the first condition that still holds (a fatal
            one, or the stale reference of a hold), WARN, latched, the text listing every such
            condition. Not RESET: SafetyEvent defines it as a release, on which controllers
            resume.

        """
        holding = self._holding(t) if self._latch.latched else []
        age = self._reference_age(t)
        if self._hold is not None and age is not None and age > self._reference_timeout:
            holding.append(Condition(('', SafetyKind.STALE_REFERENCE), '',
                                     SafetyKind.STALE_REFERENCE, age, self._reference_timeout,
                                     f'no joint reference for {age:.3f} s'))
        refusal = self._latch.refusal(holding)
        if refusal is not None:
            return [replace(refusal, latched=True)]
        hold, self._hold = self._hold, None
        stopped = self._latch.latched
        for state in self._joints.values() if stopped or hold is not None else ():
            # Tracking is judged again once the joints had the start-up grace to rejoin.
            state.tracking_from = t + state.limits.startup_grace
            state.over_limit_since = None
            state.active.discard(SafetyKind.TRACKING_ERROR)
            if stopped:
                # Controllers resume on the reset: give them the start-up grace again.
                state.command_time = None
                state.command_epoch = t
                state.enabled = False
                state.active -= {SafetyKind.STALE_COMMAND, SafetyKind.INVALID_COMMAND}
        if hold is not None and not stopped:
            return [Event('', SafetyKind.RESET, Severity.INFO, math.nan, math.nan, False,
                          f'reset: hold released (latched by {hold.text})')]
        return [self._latch.release()]

    def diagnostics(self, t: float) -> list[JointDiagnostic]:
        """Summarise every joint at time t [s], for diagnostic_msgs.

        Returns
        -------
        list[JointDiagnostic]
            One per watched joint: STALE without a recent state, ERROR with a fatal or error
            condition or while stopped, WARN over the warning pressure, OK otherwise.

        """
        summaries = []
        for joint, state in self._joints.items():
            age, limit, what = self._state_age(state, t)
            stale = age > limit
            kinds = sorted(state.active - {SafetyKind.STALE_STATE})
            parts = [what] if stale else []
            parts += [SafetyKind(kind).label for kind in kinds]
            if self._latch.latched:
                parts.append('stopped until reset')
            elif self._hold is not None:
                parts.append('holding until reset: reference lost')
            if stale:
                level = LEVEL_STALE
            elif self._latch.latched or self._hold is not None \
                    or set(kinds) - {SafetyKind.OVER_PRESSURE}:
                level = LEVEL_ERROR
            elif kinds:
                level = LEVEL_WARN
            else:
                level = LEVEL_OK
            command_age = (t - state.command_time if state.command_time is not None
                           else math.nan)
            error = state.tracking_error if state.tracking_error is not None else math.nan
            angle = state.angle if state.angle is not None else math.nan
            values = (
                ('position [m]', f'{state.position:.5f}'),
                ('angle [rad]', f'{angle:.4f}'),
                ('pressure_a [Pa]', f'{state.pressure_a:.0f}'),
                ('pressure_b [Pa]', f'{state.pressure_b:.0f}'),
                ('valve_mode', str(state.valve_mode)),
                ('tracking_error [rad]', f'{error:.4f}'),
                ('state_age [s]', f'{age:.3f}' if state.state_time is not None else 'nan'),
                ('command_age [s]', f'{command_age:.3f}'),
                ('enabled', str(state.enabled).lower()),
                ('latched', str(self._latch.latched).lower()),
            )
            summaries.append(JointDiagnostic(joint, level, '; '.join(parts) or 'ok', values))
        return summaries

    def _joint(self, joint: str) -> _Joint:
        try:
            return self._joints[joint]
        except KeyError:
            msg = f'joint {joint!r} is not watched: watched are {", ".join(self._joints)}'
            raise SafetyConfigError(msg) from None

    def _once(self, joint: str, state: _Joint, kind: SafetyKind, severity: Severity,
              value: float, limit: float, text: str) -> list[Event]:
        """Report a condition when it arises; nothing while it persists."""
        if kind in state.active:
            return []
        state.active.add(kind)
        return [self._latch.event(joint, kind, severity, value, limit, text)]

    def _state_age(self, state: _Joint, t: float) -> tuple[float, float, str]:
        """Return the newest state's age [s], the limit it is held to [s], and a description."""
        if state.state_time is None:
            limit = state.limits.startup_grace
            return t - self._start, limit, f'no state within {limit:g} s of the start'
        age, limit = t - state.state_time, state.limits.state_timeout
        return age, limit, f'no state for {age:.3f} s (limit {limit:.3f} s)'

    def _holding(self, t: float) -> list[Condition]:
        """List the fatal conditions that still hold at t, which forbid a reset."""
        holding = []
        for joint, state in self._joints.items():
            age, limit, what = self._state_age(state, t)
            if age > limit:
                holding.append(Condition((joint, SafetyKind.STALE_STATE), joint,
                                         SafetyKind.STALE_STATE, age, limit, f'{joint}: {what}'))
            elif SafetyKind.SAFETY_VALVE_OPEN in state.active:
                pressure = max(state.pressure_a, state.pressure_b)
                holding.append(Condition((joint, SafetyKind.SAFETY_VALVE_OPEN), joint,
                                         SafetyKind.SAFETY_VALVE_OPEN, pressure,
                                         state.limits.relief_pressure,
                                         f'{joint}: safety valve still open ({_mpa(pressure)}, '
                                         f'valve mode {state.valve_mode})'))
            elif SafetyKind.SENSOR_FAULT in state.active:
                holding.append(Condition((joint, SafetyKind.SENSOR_FAULT), joint,
                                         SafetyKind.SENSOR_FAULT, math.nan, math.nan,
                                         f'{joint}: sensor fault persists'))
            crowded = sorted((name, found) for name, found in state.sources.items()
                             if len(found) > 1)
            if crowded:
                name, found = crowded[0]
                holding.append(Condition((joint, SafetyKind.SECOND_SOURCE), joint,
                                         SafetyKind.SECOND_SOURCE, len(found), 1.0,
                                         f'{joint}: still {len(found)} publishers on {name} '
                                         f'({", ".join(found)})'))
        return holding

    def _check_pressure(self, joint: str, state: _Joint) -> list[Event]:
        limits = state.limits
        pressure = max(state.pressure_a, state.pressure_b)
        chamber = 'A' if state.pressure_a >= state.pressure_b else 'B'
        if pressure >= limits.relief_pressure or state.valve_mode == ValveMode.RELIEF:
            events = self._once(
                joint, state, SafetyKind.SAFETY_VALVE_OPEN, Severity.FATAL, pressure,
                limits.relief_pressure,
                f'{joint}: safety valve open: chamber {chamber} at {_mpa(pressure)}, relief '
                f'setting {_mpa(limits.relief_pressure)}, valve mode {state.valve_mode}')
            # The valve event says more: no over-pressure warning beside it.
            state.active.add(SafetyKind.OVER_PRESSURE)
            return events
        state.active.discard(SafetyKind.SAFETY_VALVE_OPEN)
        if pressure > limits.warning_pressure:
            return self._once(
                joint, state, SafetyKind.OVER_PRESSURE, Severity.WARN, pressure,
                limits.warning_pressure,
                f'{joint}: over-pressure: chamber {chamber} at {_mpa(pressure)}, over the '
                f'warning threshold {_mpa(limits.warning_pressure)}')
        if pressure < limits.warning_pressure * (1.0 - PRESSURE_HYSTERESIS):
            state.active.discard(SafetyKind.OVER_PRESSURE)
        return []

    def _check_stroke(self, joint: str, state: _Joint) -> list[Event]:
        limits = state.limits
        position = state.position
        if position <= limits.stroke_margin:
            end, name = 0.0, 'retracted'
        elif position >= limits.stroke - limits.stroke_margin:
            end, name = limits.stroke, 'extended'
        else:
            away = limits.stroke_margin + STROKE_HYSTERESIS
            if away < position < limits.stroke - away:
                state.active.discard(SafetyKind.STROKE_END)
            return []
        return self._once(joint, state, SafetyKind.STROKE_END, Severity.ERROR, position, end,
                          f'{joint}: stroke end: position {position * 1e3:.2f} mm within '
                          f'{limits.stroke_margin * 1e3:.2f} mm of the {name} end at '
                          f'{end * 1e3:.1f} mm')

    def _check_tracking(self, joint: str, state: _Joint, t: float) -> list[Event]:
        limits = state.limits
        if state.reference is None or state.angle is None:
            state.tracking_error = state.over_limit_since = None
            return []
        error = state.reference - state.angle
        state.tracking_error = error
        if abs(error) <= limits.tracking_error_limit:
            state.over_limit_since = None
            state.active.discard(SafetyKind.TRACKING_ERROR)
            return []
        # A disabled drive does not track (its valve is in free mode); neither does a stop,
        # a hold (the joint stays put while the reference moves on), nor a joint rejoining
        # its reference after a reset.
        if self._latch.latched or self._hold is not None or not state.enabled \
                or t < state.tracking_from:
            state.over_limit_since = None
            return []
        if state.over_limit_since is None:
            state.over_limit_since = t
        duration = t - state.over_limit_since
        if duration < limits.tracking_error_time:
            return []
        return self._once(joint, state, SafetyKind.TRACKING_ERROR, Severity.FATAL, abs(error),
                          limits.tracking_error_limit,
                          f'{joint}: tracking error {error:+.3f} rad '
                          f'({math.degrees(error):+.1f} deg) over '
                          f'{limits.tracking_error_limit:.3f} rad for {duration:.3f} s '
                          f'(reference {state.reference:.3f} rad, measured '
                          f'{state.angle:.3f} rad)')


def _sensor_fault(limits: SafetyLimits, position: float, pressure_a: float, pressure_b: float,
                  valve_mode: int) -> tuple[float, float, str] | None:
    """Return value, bound crossed and description of an impossible state value, or None."""
    for name, value in (('position', position), ('pressure_a', pressure_a),
                        ('pressure_b', pressure_b)):
        if not math.isfinite(value):
            return value, math.nan, f'{name} is {value}'
    low, high = -END_STOP_TOLERANCE, limits.stroke + END_STOP_TOLERANCE
    if not low <= position <= high:
        bound = low if position < low else high
        return position, bound, (f'position {position:.4f} m beyond the stroke [0, '
                                 f'{limits.stroke:g}] m by more than {END_STOP_TOLERANCE:g} m')
    for name, value in (('pressure_a', pressure_a), ('pressure_b', pressure_b)):
        if value < MIN_GAUGE_PRESSURE:
            return value, MIN_GAUGE_PRESSURE, (f'{name} {_mpa(value)} below '
                                               f'{_mpa(MIN_GAUGE_PRESSURE)} gauge')
    if valve_mode not in (ValveMode.FREE, ValveMode.ASSIST, ValveMode.RELIEF):
        return float(valve_mode), float(ValveMode.RELIEF), f'unknown valve mode {valve_mode}'
    return None
