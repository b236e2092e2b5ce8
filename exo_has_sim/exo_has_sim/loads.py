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

from exo_has_sim.errors import ParameterError
from exo_has_sim.gait import GaitCycle, load_gait_cycle
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import HasParameters

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
