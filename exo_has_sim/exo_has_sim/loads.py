"""External loads on a HAS: the default rod force from the paper's load and normative moments.

The paper sized the HAS in simulations of walking and squatting "under the 50 kg load"
(section 2.4) and tested it with a 50 kg load on the rig (section 5.1). Normative gait data give
the net joint moments per kilogram of body mass over the gait cycle (Winter's table: hip and
knee moments, extensor positive). The default external load of a plant is the largest
normative extensor moment of its joint, carried for the paper's 50 kg, turned into a rod force
through the linkage's lever arm at the standing pose:
``F = m * max(M / m) / lever_arm(standing)``.

Held constant, it is the stance-phase design case: a load that pushes the cylinder in (the
rodless chamber carries it, paper section 3) throughout, as gravity would. It keeps the valve
in assist: a lighter load needs so little motor speed to hold that the compact valve drifts
towards free mode (see :func:`exo_has_sim.model.initial_state`). A flexor moment would pull the
rod out, which the model's rodless-chamber-only load path does not resist, so the sign changes
of the normative moment over the cycle are not reproduced.
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
    # h sin(hip - knee + beta). Balance (load over the ankle) is monotonic in beta: bisect.
    low, high = np.zeros_like(knee), np.maximum(knee, 0.0) + 0.5

    def load_x(beta: FloatArray) -> FloatArray:
        hip_x = SHANK_LENGTH * np.sin(beta) - THIGH_LENGTH * np.sin(knee - beta)
        return np.asarray(hip_x + LOAD_HEIGHT * np.sin(hip - knee + beta), dtype=float)

    for _ in range(50):
        beta = 0.5 * (low + high)
        ahead = load_x(beta) > 0.0
        high = np.where(ahead, beta, high)
        low = np.where(ahead, low, beta)
    beta = 0.5 * (low + high)
    knee_x = SHANK_LENGTH * np.sin(beta)
    hip_x = knee_x - THIGH_LENGTH * np.sin(knee - beta)
    weight = 0.5 * mass * GRAVITY
    return np.asarray(-weight * hip_x, dtype=float), np.asarray(weight * knee_x, dtype=float)
