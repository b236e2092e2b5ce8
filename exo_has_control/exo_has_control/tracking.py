"""From joint-angle references to cylinder targets, for one joint's controller (ROS-free).

A reference angle becomes a cylinder extension through the linkage (paper Eq. 1) and its
angular velocity a cylinder velocity through the linkage's Jacobian. Angles beyond the linkage's
reach are clamped to the stroke. A reference older than the timeout is held still: its velocity
is dropped so that a dead reference publisher leaves the joint standing, not drifting.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import HasParameters


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

    """

    def __init__(self, joint: str, params: HasParameters, timeout: float) -> None:
        self.joint = joint
        self.linkage = Linkage.from_parameters(params)
        self.stroke = params.stroke
        self.timeout = timeout
        self._target: tuple[float, float, float] | None = None  # (t [s], x [m], v [m/s])

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

    def hold(self, position: float | None) -> None:
        """Forget the reference and hold a position [m] (None: wait for a reference)."""
        self._target = None if position is None else (-math.inf, position, 0.0)

    def target(self, t: float, measured: float) -> tuple[float, float]:
        """Cylinder position [m] and velocity [m/s] to track at t [s].

        Before any reference, the first measured position is held.
        """
        if self._target is None:
            self._target = (-math.inf, measured, 0.0)
        received, x, v = self._target
        if t - received > self.timeout:
            return x, 0.0
        return x, v
