"""The watchdog's thresholds for one joint, and their defaults: :class:`SafetyLimits`.

Free of ROS. The limits come from the joint's HAS parameter set (relief pressure, stroke,
linkage, control rate) and the watchdog's settings (:meth:`SafetyLimits.from_parameters`);
:mod:`exo_has_driver.safety` applies them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from exo_has_driver.errors import SafetyConfigError
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import HasParameters

#: Fraction of the relief pressure over which a chamber pressure is an over-pressure warning.
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
