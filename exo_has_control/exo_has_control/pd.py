"""PD position control of a HAS cylinder, the paper's controller (section 5), free of ROS.

The paper closes the loop on the cylinder position with a PD law, P = 35 and D = 15, without
units (section 5.1); exo_has_sim's design check reads them as P = 35 (rad/s) of motor speed per
mm of position error, which gives 2.34 Hz of closed-loop bandwidth against the paper's 2.54 Hz,
and D = 15 (rad/s) per (m/s) of velocity error. The paper tuned its PD for the tracking tests
without giving the values; we add a velocity feedforward through the model's velocity gain K
(Eq. 14 with the rodless area A_A, as the model's flow balance has it), so that the position
error need not drive the whole motion. The velocity is the
backward difference of the sampled positions: the paper's sensor measures position only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from exo_has_sim import linear
from exo_has_sim.control_law import pd_speed_command
from exo_has_sim.parameters import HasParameters

#: The paper's gains (section 5.1) in SI: P = 35 (rad/s)/mm, D = 15 (rad/s)/(m/s).
PAPER_KP = 35.0e3
PAPER_KD = 15.0


@dataclass(frozen=True)
class PdGains:
    """Gains of the cylinder position loop.

    Attributes
    ----------
    kp : float
        Position gain [(rad/s) per m].
    kd : float
        Velocity-error gain [(rad/s) per (m/s)].
    kff : float
        Velocity feedforward [(rad/s) per (m/s)].
    speed_limit : float
        Motor speed saturation [rad/s].

    """

    kp: float
    kd: float
    kff: float
    speed_limit: float

    def __post_init__(self) -> None:
        for name in ('kp', 'kd', 'kff'):
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0.0):
                msg = f'{name} must be finite and not negative, got {value!r}'
                raise ValueError(msg)
        if not (math.isfinite(self.speed_limit) and self.speed_limit > 0.0):
            msg = f'speed_limit must be positive and finite [rad/s], got {self.speed_limit!r}'
            raise ValueError(msg)

    @classmethod
    def paper(cls, params: HasParameters, feedforward: bool = True) -> PdGains:
        """Return the paper's P and D, with the feedforward 1/K unless disabled.

        K is Eq. 14 with the rodless area of the model's flow balance
        (:attr:`~exo_has_sim.parameters.HasParameters.flow_area`) in the place of the paper's
        average: the velocity the pump's flow gives the cylinder in steady motion.
        """
        kff = 1.0 / linear.velocity_gain(params) if feedforward else 0.0
        return cls(PAPER_KP, PAPER_KD, kff, params.motor_speed_max)


def pd_command(gains: PdGains, x_ref: float, v_ref: float, x: float, v: float) -> float:
    """Motor speed command [rad/s] for a reference and a measurement (positions m, speeds m/s).

    The law of :func:`exo_has_sim.control_law.pd_speed_command`, which exo_has_sim's
    closed-loop simulations compute with too.
    """
    return pd_speed_command(gains.kp, gains.kd, gains.kff, gains.speed_limit, x_ref, v_ref, x,
                            v)


class PositionLoop:
    """One cylinder's sampled PD loop: differentiates the measured positions it is given."""

    def __init__(self, gains: PdGains) -> None:
        self.gains = gains
        self._last: tuple[float, float] | None = None  # (t [s], x [m])
        self.velocity = 0.0  # [m/s]

    def measure(self, t: float, x: float) -> None:
        """Take a position sample x [m] at time t [s]; a repeated or older time is ignored."""
        if self._last is not None:
            t_last, x_last = self._last
            if t <= t_last:
                return
            self.velocity = (x - x_last) / (t - t_last)
        self._last = (t, x)

    @property
    def position(self) -> float | None:
        """Newest measured position [m], or None before the first sample."""
        return None if self._last is None else self._last[1]

    def command(self, x_ref: float, v_ref: float) -> float:
        """Motor speed command [rad/s] towards x_ref [m] at v_ref [m/s].

        Raises
        ------
        ValueError
            Before the first position sample.

        """
        if self._last is None:
            msg = 'no position measured yet'
            raise ValueError(msg)
        return pd_command(self.gains, x_ref, v_ref, self._last[1], self.velocity)
