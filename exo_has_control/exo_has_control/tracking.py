"""From joint-angle references to cylinder targets, for one joint's controller (ROS-free).

A reference angle becomes a cylinder extension through the linkage (paper Eq. 1) and its
angular velocity a cylinder velocity through the linkage's Jacobian. Angles beyond the linkage's
reach are clamped to the stroke. A reference older than the timeout is held still: its velocity
is dropped so that a dead reference publisher leaves the joint standing, not drifting.
At the start, and after a stop or a hold (:meth:`ReferenceFollower.rejoin`), the joint does
not jump to a reference that is elsewhere (the joints of a wearer sink under load while the
drives start) or that moved on meanwhile: its target moves from where the joint stands toward
the reference at no more than the rejoin speed, then follows it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import HasParameters

#: Default rejoin speed [m/s]: under a sixth of the knee cylinder's peak speed in walking
#: (0.16 m/s with the shipped gait and linkage), under a third of either joint's in squatting
#: (0.054-0.073 m/s), and fast enough to cross a whole stroke (0.04 m) in under 3 s, within the
#: watchdog's start-up grace.
DEFAULT_REJOIN_SPEED = 0.015
#: Cylinder speed [m/s] up to which a reference that crosses the rejoin ramp between two
#: calls counts as moving there, not jumping there: above the shipped gait's 0.31 m/s and
#: twice the pumps' top speed (0.17-0.21 m/s). A reference message's own rate, twice over (for
#: messages that come in bunches), raises it.
CROSSING_SPEED = 0.5


class ReferenceFollower:
    """The newest reference of one joint, as cylinder position [m] and velocity [m/s].

    Parameters
    ----------
    joint : str
        The joint's name in the reference messages.
    params : HasParameters
        Its HAS, for the linkage.
    timeout : float
        Age [s] after which the reference is held still.
    rejoin_speed : float
        Fastest cylinder speed [m/s] at which the target joins the reference at the start
        and after :meth:`rejoin`.

    """

    def __init__(self, joint: str, params: HasParameters, timeout: float,
                 rejoin_speed: float = DEFAULT_REJOIN_SPEED) -> None:
        if not (math.isfinite(rejoin_speed) and rejoin_speed > 0.0):
            msg = f'rejoin speed {rejoin_speed!r} m/s must be positive'
            raise ValueError(msg)
        self.joint = joint
        self.linkage = Linkage.from_parameters(params)
        self.stroke = params.stroke
        self.timeout = timeout
        self.rejoin_speed = rejoin_speed
        self._target: tuple[float, float, float] | None = None  # (t [s], x [m], v [m/s])
        # While rejoining: the time [s] the ramp was last moved (None: not yet), its position
        # [m] (None: the next measured one, at the start) and the reference's offset from it
        # [m] then (0: no reference yet).
        self._ramp: tuple[float | None, float | None, float] | None = (None, None, 0.0)

    def take(self, t: float, names: Sequence[str], angles: Sequence[float],
             rates: Sequence[float]) -> str | None:
        """Take a reference message received at t [s]; return why it was refused, or None."""
        if self.joint not in names:
            return f'reference without joint {self.joint!r} (has {", ".join(names)})'
        index = list(names).index(self.joint)
        if index >= len(angles):
            return f'reference for {self.joint!r} without a position'
        angle = float(angles[index])
        rate = float(rates[index]) if index < len(rates) else 0.0
        if not (math.isfinite(angle) and math.isfinite(rate)):
            return f'non-finite reference for {self.joint!r}: {angle!r} rad, {rate!r} rad/s'
        x = self.linkage.position_at(angle)
        v = self.linkage.velocity_at(angle, rate)
        clamped = min(max(x, 0.0), self.stroke)
        self._target = (t, clamped, v if clamped == x else 0.0)
        if clamped != x:
            low, high = (math.degrees(a) for a in self.linkage.angle_range())
            return (f'reference {math.degrees(angle):.1f} deg for {self.joint!r} outside the '
                    f'linkage range [{low:.1f}, {high:.1f}] deg: clamped to the stroke')
        return None

    @property
    def rejoining(self) -> bool:
        """Whether the target is on its way to the reference (from the start until it joins)."""
        return self._ramp is not None

    def hold(self, position: float | None) -> None:
        """Forget the reference and hold a position [m].

        A reference taken later is then followed at once; :meth:`rejoin` ramps to it. None
        (nothing measured yet): the next measured position, from which a reference is joined
        at the rejoin speed, as at the start.
        """
        self._target = None if position is None else (-math.inf, position, 0.0)
        self._ramp = (None, None, 0.0) if position is None else None

    def rejoin(self, position: float | None) -> None:
        """Hold a position [m], then move toward the next references at the rejoin speed.

        None (nothing measured yet): from the next measured position, as at the start.
        """
        self.hold(position)
        self._ramp = (None, position, 0.0)

    def target(self, t: float, measured: float) -> tuple[float, float]:
        """Cylinder position [m] and velocity [m/s] to track at t [s].

        Before any reference, the first measured position is held; from there the target
        rejoins the reference (as after :meth:`rejoin`).
        """
        if self._target is None:
            self._target = (-math.inf, measured, 0.0)
        received, x, v = self._target
        if t - received > self.timeout:
            v = 0.0
        if self._ramp is None:
            return x, v
        moved, ramp, side = self._ramp
        if ramp is None:
            ramp = measured  # the first measured position, where the joint stands
        elapsed = 0.0 if moved is None else max(0.0, t - moved)
        step = self.rejoin_speed * elapsed
        gap = x - ramp
        # Caught up with a reference taken since the hold: within a step, or crossed by it
        # since the last call. In walking the reference moves several times faster than the
        # ramp and passes it by more than a step between two calls; by no more than a moving
        # reference can, though, where one that jumps across the ramp is still ramped to.
        crossed = gap * side < 0.0 \
            and abs(gap) <= step + max(CROSSING_SPEED, 2.0 * abs(v)) * elapsed
        if received > -math.inf and (abs(gap) <= step or crossed):
            self._ramp = None
            return x, v
        ramp += math.copysign(min(step, abs(gap)), gap)
        self._ramp = (t, ramp, gap if received > -math.inf else 0.0)
        return ramp, math.copysign(self.rejoin_speed, gap) if gap else 0.0
