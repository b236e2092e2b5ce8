"""Safety watchdog logic for the HAS joints, free of ROS.

A :class:`Watchdog` is fed plain values with the times they were received [s]: each joint's HAS
state and command, the joint references, and a periodic :meth:`Watchdog.check`. It returns
:class:`Event` records, numbered as exo_has_msgs/msg/SafetyEvent, and holds the latched stop.
The rules, per joint (judged by :class:`~exo_has_driver.joint_watch.JointWatch`, thresholds in
:class:`~exo_has_driver.safety_limits.SafetyLimits`):

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
  commands aside), as the ROS graph shows them (:meth:`Watchdog.on_sources`; the rule
  the driver applies too, :func:`exo_has_driver.second_source.second_source`): a second plant
  or driver, a second controller, a replay or a left-over test node on a running system, which
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
from dataclasses import replace

from exo_has_driver.errors import SafetyConfigError
from exo_has_driver.events import Condition, Event, SafetyKind, Severity, StopLatch
from exo_has_driver.joint_watch import JointDiagnostic, JointWatch
from exo_has_driver.safety_limits import SafetyLimits


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
        self._latch = StopLatch()
        self._joints = {joint: JointWatch(joint, limit, self._latch, start)
                        for joint, limit in limits.items()}
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
        return self._joint(joint).take_state(t, position, pressure_a, pressure_b, valve_mode,
                                             holding=self._hold is not None)

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
        return self._joint(joint).take_command(t, motor_speed, enable)

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
                state.take_reference(t, angle)
                self._reference_time = t
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

    def withdraw_reference(self, t: float) -> None:
        """Forget every joint's reference at t [s], as when its publisher left.

        Nothing is judged against a reference, nor is one stale, until the next comes: what a
        controller that stops following (a deactivated robot loop, which holds every joint)
        needs, so that neither the hold nor its end is taken for a lost reference.
        """
        for state in self._joints.values():
            state.take_reference(t, math.nan)
        self._reference_time = None

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
        return self._joint(joint).take_sources(topic, publishers)

    def check(self, t: float) -> list[Event]:
        """Check for stale states and commands at time t [s]; call it periodically.

        Returns
        -------
        list[Event]
            The stale events that arose since the last check.

        """
        # A stop latched by this very check does not hide a joint's stale command.
        commands = not self._latch.latched
        return [event for state in self._joints.values()
                for event in state.check_stale(t, commands)]

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
        holding = [condition for state in self._joints.values()
                   for condition in state.holding(t)] if self._latch.latched else []
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
        if stopped or hold is not None:
            for state in self._joints.values():
                state.rejoin(t, stopped)
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
        return [state.diagnostic(t, self._hold is not None) for state in self._joints.values()]

    def _joint(self, joint: str) -> JointWatch:
        try:
            return self._joints[joint]
        except KeyError:
            msg = f'joint {joint!r} is not watched: watched are {", ".join(self._joints)}'
            raise SafetyConfigError(msg) from None
