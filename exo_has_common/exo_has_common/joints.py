"""The exoskeleton's joints by name: which there are, and which are hips and which knees.

Nothing heavy is imported here: every node reads joint names, and none of them should load the
simulator (numba and its cache) to do it.
"""

from __future__ import annotations

from exo_has_common.errors import UnknownJointError

#: The four actuated joints, each driven by one HAS.
JOINT_NAMES = ('left_hip', 'left_knee', 'right_hip', 'right_knee')

#: Kinds of joint, each with its own HAS parameter set.
JOINT_TYPES = ('hip', 'knee')


def check_joint(joint: str) -> str:
    """Return ``joint`` if it names an actuated joint.

    Raises
    ------
    UnknownJointError
        Naming the unknown joint and the known ones.

    """
    if joint not in JOINT_NAMES:
        msg = f'unknown joint {joint!r}: expected one of {", ".join(JOINT_NAMES)}'
        raise UnknownJointError(msg)
    return joint


def joint_type_of(joint: str) -> str:
    """Return ``'hip'`` or ``'knee'`` for a joint name such as ``left_knee``.

    Raises
    ------
    UnknownJointError
        For a name that ends in neither.

    """
    for kind in JOINT_TYPES:
        if joint.endswith(kind):
            return kind
    msg = f'cannot tell hip from knee in joint name {joint!r}'
    raise UnknownJointError(msg)
