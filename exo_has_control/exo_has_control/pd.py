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

import numpy as np
from scipy.signal import cont2discrete, tf2ss

from exo_has_sim import linear
from exo_has_sim.control_law import pd_speed_command
from exo_has_sim.parameters import HasParameters

#: The paper's gains (section 5.1) in SI: P = 35 (rad/s)/mm, D = 15 (rad/s)/(m/s).
PAPER_KP = 35.0e3
PAPER_KD = 15.0

#: Least damping ratio of the sampled, linearised loop's poles that gains may give [1]: above
#: zero is stable; the margin covers what the linearisation leaves out (the load, the valve,
#: the saturation). The paper's gains give 0.18 at 200 Hz and 0.11 at 1 kHz (the oil column's
#: resonance, which a PD law barely damps); doubling kp at 1 kHz gives 0.065, quadrupling it
#: makes the loop unstable at either rate.
STABILITY_DAMPING_MIN = 0.05
#: Where along the stroke the loop is judged, as shares of the stroke: the rodless volume,
#: and with it the oil's stiffness, changes along it.
STABILITY_POSITIONS = (0.05, 0.5, 0.95)


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


def loop_damping(params: HasParameters, gains: PdGains, period: float) -> float:
    """Return the least damping ratio of the sampled PD loop on the linearised HAS, on stroke.

    The plant is Eq. 12 (pump speed to position, the model's flow area) behind the motor's
    first-order speed loop, held over each period (zero-order hold); the command acts one
    period after the sample it answers (the loop delay of the plant node and of the driver);
    the velocity is the backward difference of the sampled positions, as :class:`PositionLoop`
    takes it. Each pole z of the loop is mapped to s = ln(z) / period, whose damping ratio is
    -Re(s) / |s|; negative: unstable. The feedforward and the saturation do not move the
    poles; the rodless volume does, so the loop is judged at :data:`STABILITY_POSITIONS`.

    Parameters
    ----------
    params : HasParameters
        The joint's parameter set.
    gains : PdGains
        The gains judged.
    period : float
        Control period [s].

    """
    if not (math.isfinite(period) and period > 0.0):
        msg = f'period must be positive and finite [s], got {period!r}'
        raise ValueError(msg)
    least = math.inf
    for share in STABILITY_POSITIONS:
        plant = linear.eq12(params, share * params.stroke)
        den = np.polymul(plant.den, [params.motor_time_constant, 1.0])
        a, b, c, d = tf2ss(plant.num, den)
        ad, bd, _, _, _ = cont2discrete((a, b, c, d), period, method='zoh')
        n = ad.shape[0]
        # State: the plant's, the previous position sample, the command in flight.
        loop = np.zeros((n + 2, n + 2))
        loop[:n, :n] = ad
        loop[:n, n + 1] = bd[:, 0]
        loop[n, :n] = c[0]
        loop[n + 1, :n] = -(gains.kp + gains.kd / period) * c[0]
        loop[n + 1, n] = gains.kd / period
        z = np.linalg.eigvals(loop).astype(complex)
        z = z[np.abs(z) > 1e-9]  # the delay's poles at the origin are dead-beat
        poles = np.log(z) / period
        least = min(least, float(np.min(-poles.real / np.abs(poles))))
    return least


def unsafe_gains(params: HasParameters, gains: PdGains, period: float) -> str | None:
    """Return why gains are unsafe for a joint at a control period [s], or None if they are not.

    Unsafe: a speed limit above the motor's top speed, or a sampled loop whose least damping
    ratio (:func:`loop_damping`) is under :data:`STABILITY_DAMPING_MIN`.
    """
    if gains.speed_limit > params.motor_speed_max:
        return (f'motor_speed_limit {gains.speed_limit:.5g} rad/s is above the motor top speed '
                f'{params.motor_speed_max:.5g} rad/s')
    damping = loop_damping(params, gains, period)
    if damping < STABILITY_DAMPING_MIN:
        verdict = 'unstable' if damping < 0.0 else 'too lightly damped'
        return (f'kp {gains.kp:g}, kd {gains.kd:g} at {1.0 / period:g} Hz make the '
                f'{params.joint_type} loop {verdict} (least damping ratio {damping:.3f} of the '
                f'linearised loop, at least {STABILITY_DAMPING_MIN} needed)')
    return None
