"""PD controller node: the paper's position loop for each HAS cylinder, hip and knee.

For every joint listed in ``joints``, takes the reference angle from ``joint_reference``
(sensor_msgs/JointState, by name), turns it into a cylinder extension through the joint's
linkage (paper Eq. 1), and answers every HAS state with a motor speed command: the loop runs at
the rate of the position samples, as the paper's STM32 does at 200 Hz. Before the first
reference a joint holds its first measured position, and from there it joins the reference at
no more than ``reference_rejoin_speed``. A FATAL safety event stops every joint (motor speed 0,
drive disabled: the compact valve falls to free mode) until a RESET event; a lost reference
(STALE_REFERENCE, latched) holds every joint where it stands, under control, references
ignored, until a RESET event. After either, each joint rejoins the reference in the same way::

    ros2 run exo_has_control pd_controller --ros-args -p joints:="['left_hip', 'left_knee']"

Gains are per joint type, ``hip.kp``, ``hip.kd``, ``hip.kff``, ``hip.motor_speed_limit``,
``knee.kp`` and so on. They may change while the node runs (``ros2 param set /pd_controller
hip.kp 50000.0``): a change is judged first (:func:`exo_has_control.pd.unsafe_gains`: the
sampled loop at ``rate`` on the linearised HAS must stay damped, the limit within the motor's
top speed) and refused with the reason where unsafe; otherwise it applies from the next state
on. The executor runs one callback at a time, so a change lands between two commands, never
inside one. The same judgement refuses unsafe gains at start.
"""

from __future__ import annotations

from functools import partial
from typing import Any

from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import JointState

from exo_has_common.joints import JOINT_NAMES, check_joint, joint_type_of
from exo_has_common.topics import (
    JOINT_REFERENCE_TOPIC,
    SAFETY_EVENT_TOPIC,
    has_command_topic,
    has_state_topic,
)
from exo_has_control.gain_parameters import declare_gains, declare_parameter_set, gain_changes
from exo_has_control.pd import PdGains, PositionLoop
from exo_has_control.tracking import DEFAULT_REJOIN_SPEED, ReferenceFollower
from exo_has_msgs.msg import HasCommand, HasState, SafetyEvent
from exo_has_runtime.execution import run_node
from exo_has_runtime.node_parameters import (
    apply_realtime_priority,
    declare,
    declare_realtime_priority,
)
from exo_has_runtime.profiles import SAFETY_EVENT_QOS
from exo_has_sim.parameters import HasParameters


class PdController(Node):
    """PD position control of the listed joints' cylinders, stopped by fatal safety events."""

    def __init__(self, **options: Any) -> None:
        # options: Node's keyword arguments (cli_args, context, ...), so that a container
        # can compose this node with others in one process (exo_has_runtime.container).
        super().__init__('pd_controller', **options)
        joints = list(declare(self, 'joints', list(JOINT_NAMES),
                              f'joints controlled, among {", ".join(JOINT_NAMES)}'))
        if not joints or len(set(joints)) != len(joints):
            msg = f'parameter joints must list distinct joints, got {joints}'
            raise ValueError(msg)
        timeout = declare(self, 'reference_timeout', 0.1,
                          'age [s] after which a reference is held still (its velocity dropped)',
                          (0.001, 10.0))
        rejoin_speed = declare(self, 'reference_rejoin_speed', DEFAULT_REJOIN_SPEED,
                               'fastest cylinder speed [m/s] at which a joint joins the '
                               'reference at the start and after a stop or a hold', (0.001, 1.0))
        rate = declare(self, 'rate', 200.0,
                       "rate of the states the controller answers [Hz] (the plants' or the "
                       "driver's): the period at which a gain change is judged", (1.0, 2000.0))
        priority = declare_realtime_priority(self, 'the thread that answers the states')
        self._period = 1.0 / rate
        self._params: dict[str, HasParameters] = {}
        self._gains: dict[str, PdGains] = {}  # by joint type, as the parameters are
        self._loops: dict[str, PositionLoop] = {}
        self._followers: dict[str, ReferenceFollower] = {}
        self._command_publishers = {}
        for joint in (check_joint(j) for j in joints):
            kind = joint_type_of(joint)
            if kind not in self._params:
                self._params[kind] = declare_parameter_set(self, kind)
                self._gains[kind] = declare_gains(self, self._params[kind], self._period)
            params = self._params[kind]
            self._loops[joint] = PositionLoop(self._gains[kind])
            self._followers[joint] = ReferenceFollower(joint, params, timeout, rejoin_speed)
            self._command_publishers[joint] = self.create_publisher(
                HasCommand, has_command_topic(joint), qos_profile_sensor_data)
            self.create_subscription(HasState, has_state_topic(joint),
                                     partial(self._on_state, joint), qos_profile_sensor_data)
        self._stopped = False
        self._holding = False
        self.create_subscription(JointState, JOINT_REFERENCE_TOPIC, self._on_reference,
                                 qos_profile_sensor_data)
        self.create_subscription(SafetyEvent, SAFETY_EVENT_TOPIC, self._on_event,
                                 SAFETY_EVENT_QOS)
        # This thread spins the node (in a container, every node composed with it); the DDS
        # threads, created earlier, stay ordinary. A command held up behind other processes is
        # a period of the joint without control (bench/closed_loop.py reports the longest gap
        # between commands).
        apply_realtime_priority(self, priority)
        self.add_on_set_parameters_callback(self._on_set_parameters)
        gains = '; '.join(f'{joint}: kp {loop.gains.kp:g}, kd {loop.gains.kd:g}, '
                          f'kff {loop.gains.kff:.5g}, limit {loop.gains.speed_limit:.5g}'
                          for joint, loop in self._loops.items())
        self.get_logger().info(f'pd controller ready ({gains}; kp in (rad/s)/m, kd and kff in '
                               '(rad/s)/(m/s), limit in rad/s)')

    def _on_set_parameters(self, parameters: list[Parameter]) -> SetParametersResult:
        """Judge a change of gains; apply it where safe, refuse it with the reason otherwise."""
        accepted, reason = gain_changes(parameters, self._gains, self._params, self._period)
        if reason:
            self.get_logger().warning(f'gain change refused: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        for kind, gains in accepted.items():
            self._gains[kind] = gains
            for joint, loop in self._loops.items():
                if joint_type_of(joint) == kind:
                    loop.gains = gains
            self.get_logger().info(f'{kind} gains now kp {gains.kp:g}, kd {gains.kd:g}, '
                                   f'kff {gains.kff:.5g}, limit {gains.speed_limit:.5g}')
        return SetParametersResult(successful=True)

    def _now(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def _on_reference(self, reference: JointState) -> None:
        if self._holding:
            return  # a lost reference holds the joints until a reset, even once it is back
        now = self._now()
        for follower in self._followers.values():
            problem = follower.take(now, reference.name, reference.position, reference.velocity)
            if problem:
                self.get_logger().warn(problem, throttle_duration_sec=1.0)

    def _on_state(self, joint: str, state: HasState) -> None:
        loop = self._loops[joint]
        loop.measure(state.header.stamp.sec + state.header.stamp.nanosec * 1e-9, state.position)
        if self._stopped:
            self._publish(joint, 0.0, False)
            return
        x_ref, v_ref = self._followers[joint].target(self._now(), state.position)
        self._publish(joint, loop.command(x_ref, v_ref), True)

    def _on_event(self, event: SafetyEvent) -> None:
        if event.severity == SafetyEvent.SEVERITY_FATAL and not self._stopped:
            self._stopped = True
            self.get_logger().error(f'stopped by a fatal safety event: {event.text}')
            for joint in self._loops:
                self._publish(joint, 0.0, False)
        elif event.kind == SafetyEvent.KIND_STALE_REFERENCE and event.latched \
                and event.phase != SafetyEvent.PHASE_CLEAR and not self._holding:
            self._holding = True
            for joint, loop in self._loops.items():
                self._followers[joint].hold(loop.position)
            self.get_logger().warning(f'holding every joint: {event.text}')
        elif event.kind == SafetyEvent.KIND_RESET and not event.latched \
                and (self._stopped or self._holding):
            self._stopped = self._holding = False
            for joint, loop in self._loops.items():
                self._followers[joint].rejoin(loop.position)
            self.get_logger().info('safety reset: control resumed, rejoining the reference')

    def _publish(self, joint: str, motor_speed: float, enable: bool) -> None:
        command = HasCommand(joint=joint, motor_speed=motor_speed, enable=enable)
        command.header.stamp = self.get_clock().now().to_msg()
        self._command_publishers[joint].publish(command)


def main(args: list[str] | None = None) -> None:
    """Run the controller until interrupted."""
    run_node(PdController, args, name='pd_controller')


if __name__ == '__main__':
    main()
