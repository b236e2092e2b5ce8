"""Names shared by every exo_has node: the joints and the topics that connect them."""

from __future__ import annotations

#: The four actuated joints, each driven by one HAS.
JOINT_NAMES = ('left_hip', 'left_knee', 'right_hip', 'right_knee')


def check_joint(joint: str) -> str:
    """Return ``joint`` if it names an actuated joint.

    Raises
    ------
    ValueError
        Naming the unknown joint and the known ones.

    """
    if joint not in JOINT_NAMES:
        msg = f'unknown joint {joint!r}: expected one of {", ".join(JOINT_NAMES)}'
        raise ValueError(msg)
    return joint


def has_command_topic(joint: str) -> str:
    """Relative topic of a joint's exo_has_msgs/msg/HasCommand."""
    return f'{check_joint(joint)}/has_command'


def has_state_topic(joint: str) -> str:
    """Relative topic of a joint's exo_has_msgs/msg/HasState."""
    return f'{check_joint(joint)}/has_state'
