"""Names shared by every exo_has node: the topics that connect them (joints: ``joints``)."""

from __future__ import annotations

from exo_has_common.joints import check_joint


def has_command_topic(joint: str) -> str:
    """Relative topic of a joint's exo_has_msgs/msg/HasCommand."""
    return f'{check_joint(joint)}/has_command'


def has_state_topic(joint: str) -> str:
    """Relative topic of a joint's exo_has_msgs/msg/HasState."""
    return f'{check_joint(joint)}/has_state'


def load_force_topic(joint: str) -> str:
    """Relative topic of a joint's external load on the rod, std_msgs/msg/Float64 [N].

    Positive pushes the cylinder to retract, as ``HasState.load_force``.
    """
    return f'{check_joint(joint)}/load_force'


#: Joint references for every joint, sensor_msgs/msg/JointState: ``name`` lists the joints,
#: ``position`` their angles [rad] (flexion positive), ``velocity`` [rad/s].
JOINT_REFERENCE_TOPIC = 'joint_reference'

#: exo_has_msgs/msg/GaitPhase, published with every joint reference: the motion, its phase and
#: each joint's moment per kilogram of carried mass, from which the plants take their loads.
GAIT_PHASE_TOPIC = 'gait_phase'

#: exo_has_msgs/msg/SafetyEvent from the watchdog and the driver (reliable, transient local).
SAFETY_EVENT_TOPIC = 'safety_events'

#: std_msgs/msg/Empty: a request to release a latched stop (the standalone backend has no
#: services, so the reset is a topic on both backends).
SAFETY_RESET_TOPIC = 'safety_reset'

#: diagnostic_msgs/msg/DiagnosticArray, absolute as in ROS 2's diagnostic_aggregator.
DIAGNOSTICS_TOPIC = '/diagnostics'

#: Depth of the transient-local safety event history a late joiner receives.
SAFETY_EVENT_DEPTH = 100
