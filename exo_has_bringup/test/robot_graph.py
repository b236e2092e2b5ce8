"""The rest of the ROS graph around the robot side, for its process tests.

A node that publishes a walking-like reference (each joint swings about a middle of its own)
and the resets, sets the bridge's parameters and asks its lifecycle transitions as ``ros2
param set`` and ``ros2 lifecycle set`` do, and keeps the states, the safety events and the
robot loop's diagnostics.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rcl_interfaces.srv import SetParameters
from rclpy.experimental import EventsExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Empty

from exo_has_bringup.robot_bridge import DIAGNOSTIC_NAME
from exo_has_common.joints import JOINT_NAMES, joint_type_of
from exo_has_common.topics import (
    DIAGNOSTICS_TOPIC,
    JOINT_REFERENCE_TOPIC,
    SAFETY_EVENT_TOPIC,
    SAFETY_RESET_TOPIC,
    has_state_topic,
)
from exo_has_msgs.msg import HasState, SafetyEvent
from exo_has_runtime.profiles import SAFETY_EVENT_QOS
from exo_has_sim.kinematics import Linkage
from exo_has_sim.parameters import load_parameters

DISCOVERY_S = 10.0  # Fast DDS's discovery on loopback: up to its 3 s announcement period
LINKAGES = {joint: Linkage.from_parameters(load_parameters(joint_type_of(joint)))
            for joint in JOINT_NAMES}
#: The swing of every joint about its middle [rad] and its frequency [Hz]: a slow walk.
SWING = math.radians(5.0)
SWING_HZ = 0.5
#: Tracking error of the swing counted as following it [rad]: 2 deg (the loop lags it by up to
#: a few periods at 5 deg * 2 pi * 0.5 Hz = 16 deg/s).
FOLLOWING = math.radians(2.0)
#: The lifecycle transitions by name, as ``ros2 lifecycle set`` takes them.
TRANSITIONS = {'configure': Transition.TRANSITION_CONFIGURE,
               'activate': Transition.TRANSITION_ACTIVATE,
               'deactivate': Transition.TRANSITION_DEACTIVATE,
               'cleanup': Transition.TRANSITION_CLEANUP}


class Graph:
    """The test's node: the reference's publisher, the reset's, and a listener."""

    def __init__(self, context: object) -> None:
        self.node = Node('robot_graph', context=context)
        self.executor = EventsExecutor(context=context)
        self.executor.add_node(self.node)
        self.states: dict[str, list[HasState]] = {joint: [] for joint in JOINT_NAMES}
        self.events: list[SafetyEvent] = []
        self.statuses: list[DiagnosticStatus] = []
        for joint in JOINT_NAMES:
            self.node.create_subscription(HasState, has_state_topic(joint),
                                          self.states[joint].append, qos_profile_sensor_data)
        self.node.create_subscription(SafetyEvent, SAFETY_EVENT_TOPIC, self.events.append,
                                      SAFETY_EVENT_QOS)
        self.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics,
                                      10)
        self.reference = self.node.create_publisher(JointState, JOINT_REFERENCE_TOPIC,
                                                    qos_profile_sensor_data)
        self.reset = self.node.create_publisher(Empty, SAFETY_RESET_TOPIC, 10)
        self.parameters = self.node.create_client(SetParameters, '/robot_bridge/set_parameters')
        self.lifecycle = self.node.create_client(ChangeState, '/robot_bridge/change_state')
        self.middle: dict[str, float] = {}
        self.walking = False

    def _on_diagnostics(self, array: DiagnosticArray) -> None:
        self.statuses += [s for s in array.status if s.name == DIAGNOSTIC_NAME]

    def target(self, joint: str, t: float) -> float:
        """Return a joint's reference angle [rad] at ``t`` [s]."""
        return self.middle[joint] + SWING * math.sin(2.0 * math.pi * SWING_HZ * t)

    def run(self, seconds: float, until: Callable[[], bool] | None = None) -> bool:
        """Publish the reference at 50 Hz (while walking) for ``seconds`` or until ``until()``."""
        deadline = time.monotonic() + seconds
        due = time.monotonic()
        while True:
            now = time.monotonic()
            if until is not None and until():
                return True
            if now >= deadline:
                return until is None
            if self.walking and now >= due:
                rate = SWING * 2.0 * math.pi * SWING_HZ * math.cos(2.0 * math.pi * SWING_HZ * now)
                self.reference.publish(JointState(
                    name=list(JOINT_NAMES), position=[self.target(j, now) for j in JOINT_NAMES],
                    velocity=[rate] * len(JOINT_NAMES)))
                due += 0.02
            self.executor.spin_once(timeout_sec=max(0.0, min(due, deadline) - now))

    def angle(self, joint: str) -> float:
        """Return a joint's newest angle [rad]."""
        return LINKAGES[joint].angle_at(self.states[joint][-1].position)

    def error(self, joint: str) -> float:
        """Return a joint's newest tracking error [rad]."""
        state = self.states[joint][-1]
        t = state.header.stamp.sec + state.header.stamp.nanosec * 1e-9
        return self.angle(joint) - self.target(joint, time.monotonic() - (time.time() - t))

    def following(self) -> bool:
        """Whether every joint follows the reference within :data:`FOLLOWING`."""
        return all(self.states[j] and abs(self.error(j)) < FOLLOWING for j in JOINT_NAMES)

    def set_parameters(self, **values: float) -> tuple[bool, str]:
        """Set the bridge's parameters as ``ros2 param set`` does; return success and reason."""
        assert self.parameters.wait_for_service(timeout_sec=DISCOVERY_S)
        future = self.parameters.call_async(SetParameters.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg() for name, value in values.items()]))
        assert self.run(5.0, future.done)
        results = future.result().results
        return all(r.successful for r in results), '; '.join(r.reason for r in results)

    def change_state(self, transition: str) -> bool:
        """Ask the bridge for a lifecycle transition by name; return whether it succeeded."""
        assert self.lifecycle.wait_for_service(timeout_sec=DISCOVERY_S)
        request = ChangeState.Request()
        request.transition.id = TRANSITIONS[transition]
        future = self.lifecycle.call_async(request)
        assert self.run(40.0, future.done)
        return bool(future.result().success)

    def start_walking(self) -> None:
        """Swing every joint from where it stands, toward the middle of its range."""
        for joint in JOINT_NAMES:
            angle = self.angle(joint)
            inward = math.copysign(SWING, sum(LINKAGES[joint].angle_range()) / 2.0 - angle)
            self.middle[joint] = angle + inward
        self.walking = True

    def still(self, seconds: float) -> dict[str, float]:
        """Run for ``seconds``; return how far each joint moved in them [rad], most to least."""
        first = {joint: len(states) for joint, states in self.states.items()}
        self.run(seconds)
        angles = {j: [LINKAGES[j].angle_at(s.position) for s in self.states[j][first[j]:]]
                  for j in JOINT_NAMES}
        assert all(angles.values()), 'no state came'
        return {j: max(a) - min(a) for j, a in angles.items()}

    def errors_deg(self) -> dict[str, float]:
        """Each joint's newest tracking error [deg]."""
        return {j: math.degrees(self.error(j)) for j in JOINT_NAMES}

    def close(self) -> None:
        """Destroy the executor and the node, before their context shuts down."""
        self.executor.shutdown()
        self.node.destroy_node()
