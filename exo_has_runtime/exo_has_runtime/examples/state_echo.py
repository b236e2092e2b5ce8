"""Answer every HAS command with a HAS state that echoes it (transport only, no physics)."""

from __future__ import annotations

import math

from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from exo_has_common.joints import JOINT_NAMES
from exo_has_common.topics import (
    has_command_topic,
    has_state_topic,
)
from exo_has_msgs.msg import HasCommand, HasState
from exo_has_runtime.execution import run_node


class StateEcho(Node):
    """Publish, for each command received, a state with the command's stamp and speed."""

    def __init__(self) -> None:
        super().__init__('state_echo')
        self._state_publishers = {
            joint: self.create_publisher(HasState, has_state_topic(joint), qos_profile_sensor_data)
            for joint in JOINT_NAMES}
        for joint in JOINT_NAMES:
            self.create_subscription(HasCommand, has_command_topic(joint), self._on_command,
                                     qos_profile_sensor_data)

    def _on_command(self, command: HasCommand) -> None:
        publisher = self._state_publishers.get(command.joint)
        if publisher is None:
            self.get_logger().warning(f'command for unknown joint {command.joint!r} ignored',
                                      throttle_duration_sec=1.0)
            return
        state = HasState(joint=command.joint, motor_speed=command.motor_speed,
                         motor_speed_command=command.motor_speed, position=math.nan,
                         velocity=math.nan, pressure_a=math.nan, pressure_b=math.nan,
                         motor_current=math.nan, load_force=math.nan)
        state.header.stamp = command.header.stamp
        publisher.publish(state)


def main(args: list[str] | None = None) -> None:
    """Run the node until interrupted."""
    run_node(StateEcho, args, name='state_echo')


if __name__ == '__main__':
    main()
