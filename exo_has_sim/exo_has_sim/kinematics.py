"""Joint linkage kinematics (paper Eq. 1), with the cosine the printed equation lost.

The cylinder ab spans the two pivots a and b, at distances r1 and r2 from the joint axis O. The
printed Eq. 1, ``ab = sqrt(r1^2 + r2^2 + 2 r1 r2 (theta + theta1 + theta2))``, lost a cosine:
by the law of cosines ``ab = sqrt(r1^2 + r2^2 + 2 r1 r2 cos(psi))`` with
``psi = theta + theta_0 + theta1 + theta2``, where psi is the supplement of the angle a-O-b,
``r1 = sqrt(ac^2 + co^2)``, ``r2 = sqrt(bd^2 + od^2)``, ``theta1 = atan(ac / co)``,
``theta2 = atan(bd / od)``, and theta_0 the angle_offset between the paper's (unpublished)
angle origin and the anatomical joint angle theta (flexion positive, as in gait data).

With psi between 0 and pi, flexion shortens the cylinder, so a pushing cylinder force (the
rodless chamber carries the load, paper section 3) makes an extensor torque.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from exo_has_sim.errors import KinematicsError
from exo_has_sim.parameters import HasParameters

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class Linkage:
    """The four-bar-free linkage of one joint: pivot offsets and cylinder limits [m, rad]."""

    ac: float
    co: float
    bd: float
    od: float
    angle_offset: float
    length_min: float
    stroke: float

    @classmethod
    def from_parameters(cls, params: HasParameters) -> Linkage:
        """Build the linkage of a parameter set."""
        return cls(params.link_ac, params.link_co, params.link_bd, params.link_od,
                   params.angle_offset, params.cylinder_length_min, params.stroke)

    @property
    def r1(self) -> float:
        """Distance from the joint axis to the cylinder's first pivot [m]."""
        return math.hypot(self.ac, self.co)

    @property
    def r2(self) -> float:
        """Distance from the joint axis to the cylinder's second pivot [m]."""
        return math.hypot(self.bd, self.od)

    @property
    def psi_offset(self) -> float:
        """theta_0 + theta1 + theta2 [rad]."""
        return self.angle_offset + math.atan2(self.ac, self.co) + math.atan2(self.bd, self.od)

    def cylinder_length(self, angle: ArrayLike) -> FloatArray:
        """Pivot-to-pivot cylinder length ab [m] at joint angle(s) [rad]."""
        psi = np.asarray(angle, dtype=float) + self.psi_offset
        return np.sqrt(self.r1 ** 2 + self.r2 ** 2 + 2.0 * self.r1 * self.r2 * np.cos(psi))

    def position(self, angle: ArrayLike, check: bool = True) -> FloatArray:
        """Cylinder extension x [m] at joint angle(s) [rad].

        Raises
        ------
        KinematicsError
            If ``check`` and an angle needs an extension outside [0, stroke].

        """
        x = self.cylinder_length(angle) - self.length_min
        if check and (np.any(x < -1e-12) or np.any(x > self.stroke + 1e-12)):
            low, high = self.angle_range()
            msg = (f'joint angle outside the linkage range [{math.degrees(low):.1f}, '
                   f'{math.degrees(high):.1f}] deg (cylinder extension {np.min(x):.4f} to '
                   f'{np.max(x):.4f} m, stroke {self.stroke} m)')
            raise KinematicsError(msg)
        return x

    def angle(self, position: ArrayLike) -> FloatArray:
        """Joint angle(s) [rad] at cylinder extension(s) x [m] (the inverse of position).

        Raises
        ------
        KinematicsError
            If an extension is outside what the linkage can reach.

        """
        length = np.asarray(position, dtype=float) + self.length_min
        cos_psi = (length ** 2 - self.r1 ** 2 - self.r2 ** 2) / (2.0 * self.r1 * self.r2)
        if np.any(np.abs(cos_psi) > 1.0):
            msg = 'cylinder extension outside what the linkage can reach'
            raise KinematicsError(msg)
        return np.asarray(np.arccos(cos_psi) - self.psi_offset, dtype=float)

    def lever_arm(self, angle: ArrayLike) -> FloatArray:
        """Moment arm of the cylinder force about the joint, -d(ab)/d(theta) [m]."""
        psi = np.asarray(angle, dtype=float) + self.psi_offset
        return self.r1 * self.r2 * np.sin(psi) / self.cylinder_length(angle)

    def velocity(self, angle: ArrayLike, angular_velocity: ArrayLike) -> FloatArray:
        """Cylinder velocity [m/s] for a joint angular velocity [rad/s] (the Jacobian)."""
        rate: FloatArray = np.asarray(angular_velocity, dtype=float)
        return -self.lever_arm(angle) * rate

    def joint_torque(self, force: ArrayLike, angle: ArrayLike) -> FloatArray:
        """Joint torque [N m], positive in flexion, of a cylinder force [N] (pushing positive).

        A pushing force extends the joint, so the torque is ``-force * lever_arm``.
        """
        return -np.asarray(force, dtype=float) * self.lever_arm(angle)

    def cylinder_force(self, torque: ArrayLike, angle: ArrayLike) -> FloatArray:
        """Cylinder force [N] (pushing positive) that makes a joint torque [N m] (flexion +)."""
        return -np.asarray(torque, dtype=float) / self.lever_arm(angle)

    # Scalar forms of position, angle and velocity with math instead of numpy, which costs ten
    # times more per call on one number: the nodes convert every message with them.

    def position_at(self, angle: float) -> float:
        """Cylinder extension x [m] at one joint angle [rad], unchecked (see :meth:`position`)."""
        psi = angle + self.psi_offset
        r1, r2 = self.r1, self.r2
        return math.sqrt(r1 * r1 + r2 * r2 + 2.0 * r1 * r2 * math.cos(psi)) - self.length_min

    def angle_at(self, position: float) -> float:
        """Joint angle [rad] at one cylinder extension x [m] (see :meth:`angle`).

        Raises
        ------
        KinematicsError
            If the extension is outside what the linkage can reach.

        """
        length = position + self.length_min
        r1, r2 = self.r1, self.r2
        cos_psi = (length * length - r1 * r1 - r2 * r2) / (2.0 * r1 * r2)
        if not abs(cos_psi) <= 1.0:  # also catches NaN
            msg = 'cylinder extension outside what the linkage can reach'
            raise KinematicsError(msg)
        return math.acos(cos_psi) - self.psi_offset

    def velocity_at(self, angle: float, angular_velocity: float) -> float:
        """Cylinder velocity [m/s] at one joint angle [rad] and rate [rad/s]."""
        psi = angle + self.psi_offset
        r1, r2 = self.r1, self.r2
        length = math.sqrt(r1 * r1 + r2 * r2 + 2.0 * r1 * r2 * math.cos(psi))
        return -r1 * r2 * math.sin(psi) / length * angular_velocity

    def angle_range(self) -> tuple[float, float]:
        """Joint angles [rad] at full extension and full retraction of the cylinder."""
        extended = float(self.angle(self.stroke))
        retracted = float(self.angle(0.0))
        return extended, retracted
