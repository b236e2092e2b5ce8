"""What the watchdog knows and judges of one joint: :class:`JointWatch`.

Free of ROS. A :class:`JointWatch` takes one joint's states, commands, reference and the publishers
on its topics, and reports each of its conditions as events of the watchdog's stop latch when it
starts, when what it is changes while it lasts, and once it has cleared, not per sample (the rules
are listed in :mod:`exo_has_driver.safety`, which holds one per joint). A condition clears when it
has been absent for :data:`CLEAR_TIME`: one that comes and goes between samples (a second plant's
states beside the real one's) stays one condition. It also lists the fatal conditions that hold on
the newest sample (not after :data:`CLEAR_TIME`), which refuse a reset, and summarises the joint
for diagnostic_msgs (:class:`JointDiagnostic`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

from exo_has_driver.events import (
    CLEAR_TIME,
    Clearing,
    Condition,
    Event,
    Phase,
    SafetyKind,
    Severity,
    StopLatch,
)
from exo_has_driver.safety_limits import SafetyLimits
from exo_has_driver.second_source import second_source
from exo_has_sim.errors import KinematicsError
from exo_has_sim.valve import ValveMode

# Levels, numbered as diagnostic_msgs/msg/DiagnosticStatus.
LEVEL_OK = 0
LEVEL_WARN = 1
LEVEL_ERROR = 2
LEVEL_STALE = 3

#: [Pa] Gauge pressures below this are impossible (an absolute vacuum is -0.101 MPa at sea level).
MIN_GAUGE_PRESSURE = -0.12e6
#: [m] Positions further beyond a stroke end are impossible: the end stop gives about 0.1 mm.
END_STOP_TOLERANCE = 2e-3
#: Fraction below the warning threshold the pressure must fall to before another warning.
PRESSURE_HYSTERESIS = 0.05
#: [m] Distance beyond the margin the position must leave an end by before another event.
STROKE_HYSTERESIS = 0.5e-3


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


def _mpa(pressure: float) -> str:
    return f'{pressure * 1e-6:.2f} MPa'


class JointWatch:
    """What the watchdog knows of one joint, and the rules it judges the joint by.

    Parameters
    ----------
    joint : str
        The joint.
    limits : SafetyLimits
        Its thresholds.
    latch : StopLatch
        The watchdog's stop latch, shared by every joint: the joint's events are its events.
    start : float
        Time the watchdog started [s], from which the start-up grace runs.

    """

    def __init__(self, joint: str, limits: SafetyLimits, latch: StopLatch,
                 start: float) -> None:
        self.joint = joint
        self.limits = limits
        self.latch = latch
        self.start = start
        self.command_epoch = start  # commands are due within the grace from here (a reset)
        self.state_time: float | None = None
        self.command_time: float | None = None
        self.position = math.nan
        self.angle: float | None = None
        self.pressure_a = math.nan
        self.pressure_b = math.nan
        self.valve_mode = -1
        self.enabled = False
        self.reference: float | None = None
        self.tracking_error: float | None = None
        self.over_limit_since: float | None = None
        # Tracking errors are judged from this time on [s]: the first reference, or a reset,
        # plus the start-up grace, since the controller first joins the reference at its rejoin
        # speed (exo_has_control.tracking: 0.05 m/s, over 30 deg 1.1 s for a hip, 0.4 s for a
        # knee).
        self.tracking_from = math.inf
        # Publishers found on the joint's topics, by topic (second_source judges them).
        self.sources: dict[str, tuple[str, ...]] = {}
        # The second source as last reported.
        self.sources_reported: Condition | None = None
        # Kinds whose condition holds now.
        self.active: set[SafetyKind] = set()
        # Kinds reported and not cleared since, with what of each was seen (a stroke end's
        # end) and when last [s]; since when each absent one has been absent.
        self.reported: dict[SafetyKind, dict[object, float]] = {}
        self.clearing: Clearing[SafetyKind] = Clearing()
        # Kinds held without an event (an over-pressure beside an open valve): they clear
        # silently too.
        self.silent: set[SafetyKind] = set()

    def take_state(self, t: float, position: float, pressure_a: float, pressure_b: float,
                   valve_mode: int, *, holding: bool) -> list[Event]:
        """Take a HAS state received at t [s]; ``holding``: whether a hold is latched."""
        self.state_time = t
        self._lapse(t, SafetyKind.STALE_STATE)
        fault = _sensor_fault(self.limits, position, pressure_a, pressure_b, valve_mode)
        angle = None
        if fault is None:
            try:
                angle = self.limits.linkage.angle_at(position)
            except KinematicsError:
                fault = (position, math.nan, f'position {position:.4f} m outside what the '
                                             'linkage can reach')
        if fault is not None:
            self.angle = self.tracking_error = self.over_limit_since = None
            value, limit, what = fault
            return self._once(t, SafetyKind.SENSOR_FAULT, Severity.FATAL, value, limit,
                              f'{self.joint}: sensor fault: {what}')
        self._lapse(t, SafetyKind.SENSOR_FAULT)
        self.position, self.angle = position, angle
        self.pressure_a, self.pressure_b, self.valve_mode = pressure_a, pressure_b, valve_mode
        return [*self._check_pressure(t), *self._check_stroke(t),
                *self._check_tracking(t, holding)]

    def take_command(self, t: float, motor_speed: float, enable: bool) -> list[Event]:
        """Take a HAS command received at t [s]; ignored while stopped (stop commands then)."""
        if self.latch.latched:
            return []
        self.command_time = t
        self._lapse(t, SafetyKind.STALE_COMMAND)
        if not math.isfinite(motor_speed):
            self.enabled = False
            return self._once(t, SafetyKind.INVALID_COMMAND, Severity.FATAL, motor_speed,
                              math.nan,
                              f'{self.joint}: invalid command: motor speed {motor_speed}')
        self._lapse(t, SafetyKind.INVALID_COMMAND)
        self.enabled = bool(enable)
        return []

    def take_reference(self, t: float, angle: float) -> None:
        """Take a reference angle [rad] received at t [s]; a non-finite one forgets it."""
        self.reference = float(angle) if math.isfinite(angle) else None
        if self.reference is not None and self.tracking_from == math.inf:
            self.tracking_from = t + self.limits.startup_grace

    def take_sources(self, topic: str, publishers: Sequence[str]) -> list[Event]:
        """Take the publishers on one of the joint's topics (the watchdog's own left out).

        A second source is reported when it arises, and again when its publishers change
        while it holds (one that ROS had not named is named).
        """
        self.sources[topic] = tuple(publishers)
        crowded = self._second_sources()
        if not crowded:
            self.active.discard(SafetyKind.SECOND_SOURCE)
            self.sources_reported = None
            return []
        first = crowded[0]
        if self.sources_reported == first:
            return []
        phase = Phase.START if self.sources_reported is None else Phase.CHANGE
        self.sources_reported = first
        self.active.add(SafetyKind.SECOND_SOURCE)
        return [self.latch.event(self.joint, SafetyKind.SECOND_SOURCE, Severity.FATAL,
                                 first.value, first.limit, first.text, phase)]

    def check_stale(self, t: float, commands: bool) -> list[Event]:
        """Check at t [s] for a stale state and, if ``commands``, a stale command."""
        age, limit, what = self.state_age(t)
        events = self._cleared(t)
        if age > limit:
            events += self._once(t, SafetyKind.STALE_STATE, Severity.FATAL, age, limit,
                                 f'{self.joint}: stale state: {what}')
        if not commands:
            return events
        if self.command_time is None:
            age, limit = t - self.command_epoch, self.limits.startup_grace
            what = f'no command within {limit:g} s of the start or reset'
        else:
            age, limit = t - self.command_time, self.limits.command_timeout
            what = f'no command for {age:.3f} s (limit {limit:.3f} s)'
        if age > limit:
            events += self._once(t, SafetyKind.STALE_COMMAND, Severity.FATAL, age, limit,
                                 f'{self.joint}: stale command: {what}')
        return events

    def holding(self, t: float) -> list[Condition]:
        """List the fatal conditions that still hold at t [s], which forbid a reset."""
        joint = self.joint
        holding = []
        age, limit, what = self.state_age(t)
        if age > limit:
            holding.append(Condition((joint, SafetyKind.STALE_STATE), joint,
                                     SafetyKind.STALE_STATE, age, limit, f'{joint}: {what}'))
        elif SafetyKind.SAFETY_VALVE_OPEN in self.active:
            pressure = max(self.pressure_a, self.pressure_b)
            holding.append(Condition((joint, SafetyKind.SAFETY_VALVE_OPEN), joint,
                                     SafetyKind.SAFETY_VALVE_OPEN, pressure,
                                     self.limits.relief_pressure,
                                     f'{joint}: safety valve still open ({_mpa(pressure)}, '
                                     f'valve mode {self.valve_mode})'))
        elif SafetyKind.SENSOR_FAULT in self.active:
            holding.append(Condition((joint, SafetyKind.SENSOR_FAULT), joint,
                                     SafetyKind.SENSOR_FAULT, math.nan, math.nan,
                                     f'{joint}: sensor fault persists'))
        return holding + self._second_sources()[:1]

    def rejoin(self, t: float, stopped: bool) -> None:
        """Start again after a reset at t [s] that released a stop (``stopped``) or a hold.

        Tracking is judged again once the joint had the start-up grace to rejoin its
        reference; after a stop, the controller resumes: its commands get the grace too.
        """
        self.tracking_from = t + self.limits.startup_grace
        self.over_limit_since = None
        # The reset's event says these are over: they are forgotten, not reported cleared.
        self._forget(SafetyKind.TRACKING_ERROR)
        if stopped:
            self.command_time = None
            self.command_epoch = t
            self.enabled = False
            self._forget(SafetyKind.STALE_COMMAND)
            self._forget(SafetyKind.INVALID_COMMAND)

    def state_age(self, t: float) -> tuple[float, float, str]:
        """Return the newest state's age [s], the limit it is held to [s], and a description."""
        if self.state_time is None:
            limit = self.limits.startup_grace
            return t - self.start, limit, f'no state within {limit:g} s of the start'
        age, limit = t - self.state_time, self.limits.state_timeout
        return age, limit, f'no state for {age:.3f} s (limit {limit:.3f} s)'

    def diagnostic(self, t: float, holding: bool) -> JointDiagnostic:
        """Summarise the joint at t [s]; ``holding``: whether a hold is latched.

        STALE without a recent state, ERROR with a fatal or error condition or while stopped
        or holding, WARN over the warning pressure, OK otherwise.
        """
        latched = self.latch.latched
        age, limit, what = self.state_age(t)
        stale = age > limit
        kinds = sorted(self.active - {SafetyKind.STALE_STATE})
        parts = [what] if stale else []
        parts += [SafetyKind(kind).label for kind in kinds]
        if latched:
            parts.append('stopped until reset')
        elif holding:
            parts.append('holding until reset: reference lost')
        if stale:
            level = LEVEL_STALE
        elif latched or holding or set(kinds) - {SafetyKind.OVER_PRESSURE}:
            level = LEVEL_ERROR
        elif kinds:
            level = LEVEL_WARN
        else:
            level = LEVEL_OK
        command_age = t - self.command_time if self.command_time is not None else math.nan
        error = self.tracking_error if self.tracking_error is not None else math.nan
        angle = self.angle if self.angle is not None else math.nan
        values = (
            ('position [m]', f'{self.position:.5f}'),
            ('angle [rad]', f'{angle:.4f}'),
            ('pressure_a [Pa]', f'{self.pressure_a:.0f}'),
            ('pressure_b [Pa]', f'{self.pressure_b:.0f}'),
            ('valve_mode', str(self.valve_mode)),
            ('tracking_error [rad]', f'{error:.4f}'),
            ('state_age [s]', f'{age:.3f}' if self.state_time is not None else 'nan'),
            ('command_age [s]', f'{command_age:.3f}'),
            ('enabled', str(self.enabled).lower()),
            ('latched', str(latched).lower()),
        )
        return JointDiagnostic(self.joint, level, '; '.join(parts) or 'ok', values)

    def _second_sources(self) -> list[Condition]:
        """Return the second sources of the joint's topics, in the order of their names."""
        found = (second_source(self.joint, topic, publishers)
                 for topic, publishers in sorted(self.sources.items()))
        return [condition for condition in found if condition is not None]

    def _once(self, t: float, kind: SafetyKind, severity: Severity, value: float, limit: float,
              text: str, what: object = None) -> list[Event]:
        """Report a condition that holds at t [s] when it starts or ``what`` it is changes.

        A change is reported when ``what`` was not seen within :data:`CLEAR_TIME`: two
        variants that alternate (a second plant at one stroke end, the real one at the other)
        are reported once each, not at every sample.
        """
        self.active.add(kind)
        self.clearing.holds(kind)
        seen = self.reported.setdefault(kind, {})
        for variant, last in list(seen.items()):
            if t - last >= CLEAR_TIME:
                del seen[variant]
        # A fatal condition while nothing is latched latches, however recently it was seen.
        if not seen or (severity >= Severity.FATAL and not self.latch.latched):
            phase = Phase.START
        elif what not in seen:
            phase = Phase.CHANGE
        else:
            seen[what] = t
            return []
        seen[what] = t
        self.silent.discard(kind)
        return [self.latch.event(self.joint, kind, severity, value, limit, text, phase)]

    def _lapse(self, t: float, kind: SafetyKind) -> None:
        """Note that a condition does not hold at t [s]: it clears after :data:`CLEAR_TIME`."""
        self.active.discard(kind)
        if kind in self.reported:
            self.clearing.absent(kind, t)

    def _forget(self, kind: SafetyKind) -> None:
        """Forget a condition without an event: it is reported anew should it return."""
        self.active.discard(kind)
        self.reported.pop(kind, None)
        self.clearing.holds(kind)
        self.silent.discard(kind)

    def _cleared(self, t: float) -> list[Event]:
        """Report the conditions absent for :data:`CLEAR_TIME` at t [s] as cleared."""
        events = []
        for kind in sorted(self.clearing.due(t)):
            del self.reported[kind]
            if kind in self.silent:
                self.silent.discard(kind)
                continue
            events.append(Event(self.joint, kind, Severity.INFO, math.nan, math.nan,
                                self.latch.latched, f'{self.joint}: {kind.label} cleared',
                                Phase.CLEAR))
        return events

    def _check_pressure(self, t: float) -> list[Event]:
        limits = self.limits
        pressure = max(self.pressure_a, self.pressure_b)
        chamber = 'A' if self.pressure_a >= self.pressure_b else 'B'
        if pressure >= limits.relief_pressure or self.valve_mode == ValveMode.RELIEF:
            events = self._once(
                t, SafetyKind.SAFETY_VALVE_OPEN, Severity.FATAL, pressure,
                limits.relief_pressure,
                f'{self.joint}: safety valve open: chamber {chamber} at {_mpa(pressure)}, relief '
                f'setting {_mpa(limits.relief_pressure)}, valve mode {self.valve_mode}')
            # The valve event says more: no over-pressure warning beside it.
            self.active.add(SafetyKind.OVER_PRESSURE)
            self.reported.setdefault(SafetyKind.OVER_PRESSURE, {})[None] = t
            self.silent.add(SafetyKind.OVER_PRESSURE)
            self.clearing.holds(SafetyKind.OVER_PRESSURE)
            return events
        self._lapse(t, SafetyKind.SAFETY_VALVE_OPEN)
        if pressure > limits.warning_pressure:
            return self._once(
                t, SafetyKind.OVER_PRESSURE, Severity.WARN, pressure, limits.warning_pressure,
                f'{self.joint}: over-pressure: chamber {chamber} at {_mpa(pressure)}, over the '
                f'warning threshold {_mpa(limits.warning_pressure)}')
        if pressure < limits.warning_pressure * (1.0 - PRESSURE_HYSTERESIS):
            self._lapse(t, SafetyKind.OVER_PRESSURE)
        return []

    def _check_stroke(self, t: float) -> list[Event]:
        limits = self.limits
        position = self.position
        if position <= limits.stroke_margin:
            end, name = 0.0, 'retracted'
        elif position >= limits.stroke - limits.stroke_margin:
            end, name = limits.stroke, 'extended'
        else:
            away = limits.stroke_margin + STROKE_HYSTERESIS
            if away < position < limits.stroke - away:
                self._lapse(t, SafetyKind.STROKE_END)
            return []
        return self._once(t, SafetyKind.STROKE_END, Severity.ERROR, position, end,
                          f'{self.joint}: stroke end: position {position * 1e3:.2f} mm within '
                          f'{limits.stroke_margin * 1e3:.2f} mm of the {name} end at '
                          f'{end * 1e3:.1f} mm', what=end)

    def _check_tracking(self, t: float, holding: bool) -> list[Event]:
        limits = self.limits
        if self.reference is None or self.angle is None:
            self.tracking_error = self.over_limit_since = None
            return []
        error = self.reference - self.angle
        self.tracking_error = error
        if abs(error) <= limits.tracking_error_limit:
            self.over_limit_since = None
            self._lapse(t, SafetyKind.TRACKING_ERROR)
            return []
        # A disabled drive does not track (its valve is in free mode); neither does a stop,
        # a hold (the joint stays put while the reference moves on), nor a joint rejoining
        # its reference after a reset.
        if self.latch.latched or holding or not self.enabled or t < self.tracking_from:
            self.over_limit_since = None
            return []
        if self.over_limit_since is None:
            self.over_limit_since = t
        duration = t - self.over_limit_since
        if duration < limits.tracking_error_time:
            return []
        return self._once(t, SafetyKind.TRACKING_ERROR, Severity.FATAL, abs(error),
                          limits.tracking_error_limit,
                          f'{self.joint}: tracking error {error:+.3f} rad '
                          f'({math.degrees(error):+.1f} deg) over '
                          f'{limits.tracking_error_limit:.3f} rad for {duration:.3f} s '
                          f'(reference {self.reference:.3f} rad, measured '
                          f'{self.angle:.3f} rad)')


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
