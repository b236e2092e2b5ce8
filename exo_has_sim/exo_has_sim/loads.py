"""External loads on a HAS: a constant design load, or a load that follows the motion.

The paper sized the HAS in simulations of walking and squatting "under the 50 kg load"
(section 2.4) and tested its tracking carrying 25 kg (section 5.2). Normative gait data give
the net joint moments per kilogram of body mass over the gait cycle (Winter's table: hip and
knee moments, extensor positive).

Along the motion (:class:`JointLoad`, the plant node's default): a joint's extensor moment is
the carried mass times the normative moment per kilogram at the gait phase the gait publisher
sends (walking), or times the quasi-static squat's moment per kilogram at the squat's posture
(:func:`squat_moments`); the rod force is that moment over the linkage's lever arm at the
joint's angle. The paper's circuit can only push: the rod side is open to the tank, so the
cylinder retracts only while a force pushes the piston in after the oil the pump draws from the
rodless chamber. Where the moment is a flexor moment (it would pull the rod out) or too small
to push the piston after the pump, the wearer's muscles move the limb and the cuff carries the
exoskeleton's leg along: the model takes that contact force as :func:`wearer_push`, the least
force that retracts the cylinder as fast as the pump can empty it. Without it the model stays
physical (the rodless chamber cavitates at vacuum and the piston is pulled out), but the joint
cannot follow its reference: with the signed moments of 25 kg the knee misses its walk by up
to 66 deg and the hip by 44 deg (issue 26's note).

Constant (:func:`default_load_force`): the largest normative extensor moment of the joint for a
mass, at the standing lever arm, held for the whole run: the stance-phase design case, which
the simulated CAN devices and the diagnosis's records keep.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from exo_has_sim.errors import ParameterError
from exo_has_sim.gait import GaitCycle, load_gait_cycle
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import HasParameters

FloatArray = NDArray[np.float64]

#: Load of the paper's design simulations and frequency-response tests [kg] (sections 2.4, 5.1).
PAPER_LOAD_MASS = 50.0
#: Load the paper's exoskeleton carried in its tracking tests [kg] (section 5.2).
TRACKING_LOAD_MASS = 25.0


def peak_extensor_moment(gait: GaitCycle, joint_type: str) -> float:
    """Largest extensor moment per body mass [N m/kg] of a joint over the gait cycle.

    Raises
    ------
    ParameterError
        If the gait table has no moments, or the joint type is not hip or knee.

    """
    if joint_type not in ('hip', 'knee'):
        msg = f'unknown joint type {joint_type!r}: expected hip or knee'
        raise ParameterError(msg)
    moments = gait.hip_moment if joint_type == 'hip' else gait.knee_moment
    if moments is None:
        msg = f'{gait.source}: no {joint_type}_moment column, so no load can be derived from it'
        raise ParameterError(msg)
    return float(max(moments))


def default_load_force(params: HasParameters, gait: GaitCycle | None = None,
                       mass: float = PAPER_LOAD_MASS, standing_angle: float = 0.0) -> float:
    """Rod force [N] (pushing the cylinder in) of the default external load of a HAS.

    Parameters
    ----------
    params : HasParameters
        The HAS, whose joint type and linkage are used.
    gait : GaitCycle or None
        Normative gait data with moments; Winter's table by default.
    mass : float
        Carried mass [kg].
    standing_angle : float
        Joint angle of the standing pose [rad], where the lever arm is taken.

    Raises
    ------
    ParameterError
        If the mass is not positive and finite, or the gait table has no moments.

    """
    if not (math.isfinite(mass) and mass > 0.0):
        msg = f'load mass must be positive and finite [kg], got {mass!r}'
        raise ParameterError(msg)
    table = load_gait_cycle() if gait is None else gait
    moment = mass * peak_extensor_moment(table, params.joint_type)
    lever = float(Linkage.from_parameters(params).lever_arm(standing_angle))
    return moment / lever


def wearer_push(params: HasParameters) -> float:
    """Least force [N] the wearer's limb keeps on the rod, pushing the cylinder in.

    The piston's viscous drag at the pump's top speed, ``B D_p n_max / A_A``: the force under
    which the cylinder retracts as fast as the pump can draw oil from the rodless chamber, so
    that in a steady retraction the chamber keeps its oil (a sudden full-speed command still
    outruns the load while it accelerates, and the chamber cavitates for that while). 354 N on
    the design of issue 26.
    """
    return params.damping * params.pump_displacement * params.motor_speed_max / params.area_a


class JointLoad:
    """The external rod force on one joint along the motion (see the module).

    Parameters
    ----------
    params : HasParameters
        The joint's HAS: its linkage, damping and pump.
    mass : float
        Carried mass [kg] the moments per kilogram are scaled by.

    Raises
    ------
    ParameterError
        If the mass is not positive and finite.

    """

    def __init__(self, params: HasParameters, mass: float) -> None:
        if not (math.isfinite(mass) and mass > 0.0):
            msg = f'load mass must be positive and finite [kg], got {mass!r}'
            raise ParameterError(msg)
        self.mass = mass
        self.push = wearer_push(params)
        self._linkage = Linkage.from_parameters(params)
        self._stroke = params.stroke

    def force(self, moment_per_mass: ArrayLike, position: ArrayLike) -> FloatArray:
        """Rod force [N], positive pushing the cylinder in, of a moment per kg at a position.

        Parameters
        ----------
        moment_per_mass : array_like
            The joint's extensor moment per kilogram of carried mass [N m/kg].
        position : array_like
            Cylinder extension [m] (held within the stroke): the lever arm is the linkage's at
            the joint angle it gives, the posture the joint is in rather than the one asked.

        """
        moment = self.mass * np.asarray(moment_per_mass, dtype=float)
        x = np.clip(np.asarray(position, dtype=float), 0.0, self._stroke)
        lever = self._linkage.lever_arm(self._linkage.angle(x))
        return np.asarray(np.maximum(moment / lever, self.push), dtype=float)


#: Segments of an adult of 1.75 m [m] (Winter's anthropometry: thigh 0.245, shank 0.246 of
#: the height).
THIGH_LENGTH = 0.43
SHANK_LENGTH = 0.43
#: Height of a carried load's centre of mass above the hips, on the back [m] (assumed).
LOAD_HEIGHT = 0.30
GRAVITY = 9.81  # m/s^2


def squat_moments(hip_angle: ArrayLike, knee_angle: ArrayLike,
                  mass: float) -> tuple[FloatArray, FloatArray]:
    """Extensor moments [N m] of hip and knee of one leg holding a carried mass in a squat.

    A quasi-static model in the sagittal plane: feet flat, both legs sharing the load's weight,
    the trunk carrying it at :data:`LOAD_HEIGHT` above the hips, the posture balanced with the
    load's centre over the ankles. The shank leans forward by the angle that balances it for the
    given hip and knee flexion; each joint's moment is then half the weight times the horizontal
    distance from the joint to the load's line (the knee in front of it, the hip behind).
    The body's own weight is the wearer's to carry, as Winter's moments per kg are scaled by
    the carried mass in walking.

    Parameters
    ----------
    hip_angle, knee_angle : array_like
        Flexion [rad], knee flexion at least hip flexion's share of it that the balance needs.
    mass : float
        Carried mass [kg].

    """
    hip = np.asarray(hip_angle, dtype=float)
    knee = np.asarray(knee_angle, dtype=float)
    # Horizontal positions from the ankle, the shank leaning forward by beta: knee at
    # l_s sin(beta), hip at that minus l_t sin(knee - beta), the load at the hip plus
    # h sin(hip - knee + beta). That sum is a sin(beta) - b cos(beta), rising through its zero
    # at atan2(b, a): the balance in closed form (the gait publisher evaluates this at every
    # reference, where a bisection cost many times more), held to the lean range [0, knee + 0.5].
    a = SHANK_LENGTH + THIGH_LENGTH * np.cos(knee) + LOAD_HEIGHT * np.cos(hip - knee)
    b = THIGH_LENGTH * np.sin(knee) - LOAD_HEIGHT * np.sin(hip - knee)
    beta = np.clip(np.arctan2(b, a), 0.0, np.maximum(knee, 0.0) + 0.5)
    knee_x = SHANK_LENGTH * np.sin(beta)
    hip_x = knee_x - THIGH_LENGTH * np.sin(knee - beta)
    weight = 0.5 * mass * GRAVITY
    return np.asarray(-weight * hip_x, dtype=float), np.asarray(weight * knee_x, dtype=float)
