"""Publish sinusoidal HAS motor-speed commands for every joint and time the echoed states."""

from __future__ import annotations

import math
import statistics

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data

from exo_has_common.joints import JOINT_NAMES
from exo_has_common.topics import (
    has_command_topic,
    has_state_topic,
)
from exo_has_msgs.msg import HasCommand, HasState
from exo_has_runtime.execution import run_node


class CommandTalker(Node):
    """Send a motor-speed sine to each joint and log the command-to-state round trip."""

    def __init__(self) -> None:
        super().__init__('command_talker')
        self.declare_parameter('rate', 200.0, ParameterDescriptor(
            description='command rate [Hz]',
            floating_point_range=[FloatingPointRange(from_value=1.0, to_value=2000.0)]))
        self.declare_parameter('amplitude', 100.0, ParameterDescriptor(
            description='motor speed amplitude [rad/s]'))
        self.declare_parameter('frequency', 0.5, ParameterDescriptor(
            description='sine frequency [Hz]'))
        self.declare_parameter('duration', 0.0, ParameterDescriptor(
            description='seconds to send once every command topic has a subscriber, then shut '
                        'down; 0 runs until interrupted'))
        self._rate = self.get_parameter('rate').value
        self._amplitude = self.get_parameter('amplitude').value
        self._frequency = self.get_parameter('frequency').value
        self._duration = self.get_parameter('duration').value
        # Set once every command topic has a subscriber: discovery takes seconds here.
        self._start_ns: int | None = None
        self._sent = 0
        self._round_trips_s: list[float] = []
        self._command_publishers = {
            joint: self.create_publisher(HasCommand, has_command_topic(joint),
                                         qos_profile_sensor_data)
            for joint in JOINT_NAMES}
        for joint in JOINT_NAMES:
            self.create_subscription(HasState, has_state_topic(joint), self._on_state,
                                     qos_profile_sensor_data)
        self.create_timer(1.0 / self._rate, self._on_tick)
        self.create_timer(1.0, self._on_report)

    def _on_tick(self) -> None:
        now = self.get_clock().now()
        if self._start_ns is None:
            if any(p.get_subscription_count() == 0 for p in self._command_publishers.values()):
                return
            self._start_ns = now.nanoseconds
        elapsed_s = (now.nanoseconds - self._start_ns) * 1e-9
        if self._duration and elapsed_s >= self._duration:
            self._on_report()
            self.context.try_shutdown()  # ends the spin loop of run_node
            return
        speed = self._amplitude * math.sin(2.0 * math.pi * self._frequency * elapsed_s)
        for joint, publisher in self._command_publishers.items():
            command = HasCommand(joint=joint, motor_speed=speed, enable=True)
            command.header.stamp = now.to_msg()
            publisher.publish(command)
            self._sent += 1

    def _on_state(self, state: HasState) -> None:
        now_ns = self.get_clock().now().nanoseconds
        sent_ns = state.header.stamp.sec * 1_000_000_000 + state.header.stamp.nanosec
        self._round_trips_s.append((now_ns - sent_ns) * 1e-9)

    def _on_report(self) -> None:
        received = len(self._round_trips_s)
        if received:
            ordered = sorted(self._round_trips_s)
            p99 = ordered[min(received - 1, int(0.99 * received))]
            timing = (f'round trip p50 {statistics.median(ordered) * 1e3:.3f} ms, '
                      f'p99 {p99 * 1e3:.3f} ms')
        else:
            timing = 'no state received yet'
        self.get_logger().info(f'commands sent {self._sent}, states received {received}; '
                               f'{timing}')


def main(args: list[str] | None = None) -> None:
    """Run the node until interrupted or its duration is over."""
    run_node(CommandTalker, args, name='command_talker')


if __name__ == '__main__':
    main()
