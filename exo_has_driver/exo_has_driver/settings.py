"""Checks of the parameters the driver's nodes share: the joints, and a joint type's parameters.

ROS-free; each node passes the exception class of its own settings, so that the message names
the parameter at fault and the error says which node's settings are wrong.
"""

from __future__ import annotations

from exo_has_common.joints import JOINT_NAMES, check_joint
from exo_has_driver.errors import DriverError
from exo_has_sim.parameters import HasParameters, load_parameters


def checked_joints(joints: list[str], error: type[DriverError]) -> list[str]:
    """Return the joints of parameter ``joints`` if each is known and given once.

    Raises
    ------
    DriverError
        Of class ``error``, naming the parameter and the joint at fault.

    """
    if not joints:
        msg = f'parameter joints is empty: give some of {", ".join(JOINT_NAMES)}'
        raise error(msg)
    for joint in joints:
        try:
            check_joint(joint)
        except ValueError as exc:
            msg = f'parameter joints: {exc}'
            raise error(msg) from None
    if len(set(joints)) != len(joints):
        msg = f'parameter joints names a joint twice: {joints}'
        raise error(msg)
    return joints


def joint_type_parameters(kind: str, source: str, error: type[DriverError]) -> HasParameters:
    """Load the set of parameter ``<kind>.params`` and check it is of that joint type.

    Raises
    ------
    DriverError
        Of class ``error``, naming the parameter, if the set cannot be loaded or is of the
        other joint type.

    """
    try:
        params = load_parameters(source)
    except ValueError as exc:
        msg = f'parameter {kind}.params: {exc}'
        raise error(msg) from None
    if params.joint_type != kind:
        msg = f'parameter {kind}.params: {source} is a {params.joint_type} parameter set'
        raise error(msg)
    return params
